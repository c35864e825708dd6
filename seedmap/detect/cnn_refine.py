"""The fast CNN's refiner: every heatmap peak rescored and its box corrected by a small MLP.

Per peak the MLP (:class:`~seedmap.detect.mlp.Mlp`, kind ``cnn_refiner``) reads the RGB patch around the peak pixel,
the network's raw predictions there and the context of its strongest higher neighbour within 8 px
(:func:`peak_features`); it outputs a new seed logit and residuals added to the four box edges. The keypoint is
unchanged. A refiner file records the SHA-256 of the network it was trained on and refuses any other. Why and how it
was measured: docs/method/detection.md; training: :mod:`seedmap.detect.train_refiner`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from seedmap.detect.kernels import peak_context
from seedmap.detect.mlp import KIND, Mlp, patches
from seedmap.detect.runtime import WEIGHTS_DIR, load_session
from seedmap.errors import ConfigError, InputError

#: default half size of the patch (13 x 13 px)
PATCH_R = 6
#: box edges and neighbour offsets are divided by this (px) to keep the inputs O(1)
SCALE_PX = 5.0
#: radius (px) of the neighbour context
NEIGHBOUR_PX = 8.0
#: the context also counts the peaks within this distance (px)
NEAR_PX = 4.0
#: neighbours looked at per peak (the densest 8-px discs hold fewer)
NEIGHBOUR_K = 12
#: feature columns after the patch: raw predictions (7) and neighbour context (8)
N_EXTRA = 15


def default_cnn_refiner_path() -> Path:
    """The shipped refiner of the shipped field network (``fast_cnn.onnx``)."""
    return WEIGHTS_DIR / "fast_cnn_refiner.onnx"


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def peak_features(img: np.ndarray, x: np.ndarray, y: np.ndarray, raw: np.ndarray, r: int = PATCH_R) -> np.ndarray:
    """``(N, 3 (2r+1)^2 + 15)`` float32 features of the peaks at pixels ``x``, ``y`` (N,) of the RGB ``img``
    with the network's ``raw`` (N, 7) predictions (module docstring): patch / 255, raw predictions with the box edges / 5 px,
    neighbour flag, offset (/ 5 px), logit difference, box size (/ 5 px), peaks within 4 and 8 px."""
    n = len(x)
    if n == 0:
        return np.zeros((0, 3 * (2 * r + 1) ** 2 + N_EXTRA), np.float32)
    h, w = img.shape[:2]
    # the patch columns and, after them, the N_EXTRA columns filled below (no concatenation)
    feats = patches(img, np.clip(np.asarray(x, np.int64), 0, w - 1), np.clip(np.asarray(y, np.int64), 0, h - 1), r,
                    extra=N_EXTRA)
    rw = np.asarray(raw, np.float32).copy()
    rw[:, 1:5] /= SCALE_PX
    # neighbour context: the strongest other peak within NEIGHBOUR_PX whose logit is higher (compiled; the KD-tree
    # on the rows where its order decides)
    xy = np.c_[np.asarray(x, np.float64), np.asarray(y, np.float64)]
    k = min(NEIGHBOUR_K + 1, n)
    nb, amb = peak_context(xy, rw, k, NEIGHBOUR_PX, NEAR_PX, SCALE_PX)
    if amb.any():
        rows = np.flatnonzero(amb)
        nb[rows] = _context_kdtree(xy, rw, rows, k)
    feats[:, -N_EXTRA:-8] = rw
    feats[:, -8:] = nb
    return feats


def _context_kdtree(xy: np.ndarray, rw: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """The neighbour context (:func:`seedmap.detect.kernels.peak_context`) of the peaks ``rows`` from the KD-tree's
    ``k`` nearest within NEIGHBOUR_PX, the tree's order deciding between equal distances and equal logits."""
    n, m = len(xy), len(rows)
    d, j = cKDTree(xy).query(xy[rows], k=k, distance_upper_bound=NEIGHBOUR_PX)
    d, j = d.reshape(m, k), j.reshape(m, k)
    ok = (j < n) & (j != rows[:, None])
    lg = np.append(rw[:, 0], -np.inf)
    lj = np.where(ok, lg[np.minimum(j, n)], -np.inf)
    higher = ok & (lj > lg[rows][:, None])
    best = np.argmax(np.where(higher, lj, -np.inf), axis=1)
    has = higher[np.arange(m), best]
    b = np.where(has, j[np.arange(m), best], 0)
    nb = np.zeros((m, 8), np.float32)
    nb[:, 0] = has
    nb[:, 1:3] = np.where(has[:, None], (xy[b] - xy[rows]) / SCALE_PX, 0.0)
    nb[:, 3] = np.where(has, rw[b, 0] - rw[rows, 0], 0.0)
    nb[:, 4] = np.where(has, rw[b, 1] + rw[b, 3], 0.0)
    nb[:, 5] = np.where(has, rw[b, 2] + rw[b, 4], 0.0)
    nb[:, 6] = (ok & (d <= NEAR_PX)).sum(axis=1)
    nb[:, 7] = ok.sum(axis=1)
    return nb


@dataclass
class CnnRefiner:
    """A trained refiner: the MLP, run in onnxruntime when loaded from its ``.onnx`` export (one thread) or in numpy
    from the ``.safetensors``."""

    mlp: Mlp
    path: Path
    runner: object | None = None  # the onnxruntime inference object of the exported graph

    @property
    def cnn_sha256(self) -> str:
        return str((self.mlp.info or {}).get("cnn_sha256", ""))

    @classmethod
    def load(cls, path: str | Path) -> CnnRefiner:
        p = Path(path)
        if p.suffix.lower() == ".onnx":
            sess, patch_r, info, dims = _load_onnx(p)
            mlp = Mlp([], patch_r, info, KIND)
            n_in, n_out = dims
        else:
            mlp = Mlp.load(p, KIND, PATCH_R)
            sess = None
            n_in, n_out = mlp.layers[0][0].shape[0], mlp.layers[-1][0].shape[1]
        if n_in != 3 * (2 * mlp.patch_r + 1) ** 2 + N_EXTRA or n_out != 5:
            raise InputError(f"cnn_refiner input/output sizes {n_in}/{n_out} do not match its patch radius "
                             f"{mlp.patch_r}", p)
        return cls(mlp, p, sess)

    def check_network(self, cnn_path: str | Path) -> None:
        """Refuse to refine the peaks of a network other than the one this refiner was trained on."""
        if self.cnn_sha256 and file_sha256(cnn_path) != self.cnn_sha256:
            raise ConfigError(f"cnn.refiner {self.path} was trained on the peaks of another network "
                              f"(SHA-256 {self.cnn_sha256[:12]}...), not of {cnn_path}; train one for it with "
                              "`seedmap train cnn-refiner`, or set cnn.refiner=none")

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``(N, 5)``: the four box-edge residuals (/ 5 px) and the seed logit."""
        if self.runner is None:
            return self.mlp.forward(x)
        return self.runner.run(None, {"features": np.ascontiguousarray(x, np.float32)})[0]

    def refine(self, img: np.ndarray, x: np.ndarray, y: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """The peaks' ``raw`` (N, 7) with the seed logit replaced and the box edges corrected."""
        if len(x) == 0:
            return raw
        o = self.forward(peak_features(img, x, y, raw, self.mlp.patch_r))
        out = np.asarray(raw, np.float64).copy()
        out[:, 0] = o[:, 4]
        out[:, 1:5] += o[:, :4] * SCALE_PX
        return out


def _load_onnx(p: Path) -> tuple[object, int, dict, tuple[int, int]]:
    sess = load_session(p, threads=1, kind=KIND)
    meta = sess.get_modelmeta().custom_metadata_map
    n_in = sess.get_inputs()[0].shape[1]
    n_out = sess.get_outputs()[0].shape[1]
    return sess, int(meta.get("patch_r", PATCH_R)), json.loads(meta.get("info", "{}")), (int(n_in), int(n_out))
