"""A tiny learned second stage for the ``fast`` detector: seed/no-seed score and the box, per candidate.

Why: at ~5 px a box 1 px off fails IoU >= 0.5, and the classical region extent is often 1 px off
(error analysis on ``data/det_s1``: ~15 % of the misses were found seeds with a bad box, and ~50 % of
the false positives were leaf/stalk edges or over-split seeds). A 2-hidden-layer MLP on an 11x11
patch of the seediness image around each candidate, plus the region's box and ellipse, predicts

* a logit: is the candidate's keypoint on a real seed (GT instance of >= 6 visible px)?
* the GT box's four edges relative to the candidate's centre pixel (rounded to whole pixels, the GT
  box convention: x0, y0 inclusive, x1, y1 exclusive).

The keypoint (ellipse centre) is left unchanged. Inference is numpy only (two small matrix
products, a few ms per image); training uses torch on CPU in a few minutes
(``seedmap train fast-refiner data/det_s1 --out FILE``: 144 s CPU on the 26 images of det_s1). Weights are safetensors (numpy arrays + JSON metadata).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from seedmap.detect.base import logit
from seedmap.errors import InputError
from seedmap.records import Detections

#: half size of the patch (the patch is (2 R + 1)^2 pixels)
PATCH_R = 5
#: box coordinates and axes are divided by this (px) to keep the inputs O(1)
SCALE_PX = 5.0


def default_refiner_path() -> Path:
    """The shipped refiner (trained on the simulated range ``data/det_s1``, even frames)."""
    return Path(__file__).with_name("weights") / "fast_refiner.safetensors"


def patches(img: np.ndarray, x: np.ndarray, y: np.ndarray, r: int) -> np.ndarray:
    """``(N, (2r+1)^2 * channels)`` float32: the square of half size ``r`` around each pixel ``x``, ``y`` (N,) int
    (inside the image) of the uint8 ``img`` (H, W) or (H, W, C), / 255, zero outside the image; row-major, the
    channels of a pixel together. One gather of flat indices into the padded image."""
    pad = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    ch = 1 if pad.ndim == 2 else pad.shape[2]
    wp = pad.shape[1]
    idx = np.arange(-r, r + 1)
    offs = ((idx[:, None] * wp + idx[None, :])[..., None] * ch + np.arange(ch)).ravel()
    base = ((np.asarray(y, np.int64) + r) * wp + (np.asarray(x, np.int64) + r)) * ch
    return np.take(pad.ravel(), base[:, None] + offs[None, :]).astype(np.float32) / 255.0


def candidate_features(f: np.ndarray, det: Detections, r: int = PATCH_R) -> tuple[np.ndarray, np.ndarray]:
    """``(features (N, (2r+1)^2 + 9) float32, centre pixel (N, 2) int)`` of the candidates ``det``.

    ``f`` is the uint8 seediness image the detector worked on (same pixel grid as the detections).
    Features: the patch of ``f / 255`` around the rounded keypoint, the region box relative to that
    pixel and the ellipse axes (both / 5 px), the ellipse angle as (cos 2a, sin 2a), the DoG score.
    """
    n = len(det)
    c = np.round(det.keypoints).astype(np.int64).reshape(-1, 2)
    if n == 0:
        return np.zeros((0, (2 * r + 1) ** 2 + 9), np.float32), c
    h, w = f.shape
    c[:, 0] = np.clip(c[:, 0], 0, w - 1)
    c[:, 1] = np.clip(c[:, 1], 0, h - 1)
    patch = patches(f, c[:, 0], c[:, 1], r)
    rb = (np.asarray(det.boxes, np.float64) - np.c_[c, c]) / SCALE_PX
    e = np.asarray(det.ellipses, np.float64)
    a = np.radians(2.0 * e[:, 4])
    x = np.c_[patch, rb, e[:, 2:4] / SCALE_PX, np.cos(a), np.sin(a), np.asarray(det.scores, np.float64)]
    return x.astype(np.float32), c


@dataclass
class Refiner:
    """MLP weights (``w0 b0 w1 b1 w2 b2``; ``x @ w + b``, ReLU between) and the patch radius.

    ``kind``: which candidates it was trained on -- ``fast_refiner`` (the classical detector's regions, this
    module) or ``cnn_refiner`` (the CNN's heatmap peaks, :mod:`seedmap.detect.cnn_refine`); a file of one kind is
    refused where the other is expected."""

    layers: list[tuple[np.ndarray, np.ndarray]]
    patch_r: int = PATCH_R
    info: dict | None = None
    kind: str = "fast_refiner"

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``(N, 5)``: 4 box-edge offsets (/ 5 px, relative to the region box) and the seed logit."""
        # cv2.gemm, not numpy's BLAS: a multi-threaded BLAS spends 4x the CPU time of this small
        # product spinning its threads on a busy 2-core machine (measured: 8 vs 2 ms per image)
        x = np.ascontiguousarray(x, np.float32)
        for k, (w, b) in enumerate(self.layers):
            x = cv2.gemm(x, w, 1.0, None, 0.0) + b if len(x) else np.zeros((0, w.shape[1]), np.float32)
            if k < len(self.layers) - 1:
                np.maximum(x, 0.0, out=x)
        return x

    def refine(self, f: np.ndarray, det: Detections, threshold: float = 0.5) -> Detections:
        """Candidates with seed probability >= ``threshold``, with the predicted whole-pixel boxes."""
        if len(det) == 0:
            return det
        x, c = candidate_features(f, det, self.patch_r)
        o = self.forward(x)
        n_patch = (2 * self.patch_r + 1) ** 2
        box = np.round((o[:, :4] + x[:, n_patch:n_patch + 4]) * SCALE_PX) + np.c_[c, c]
        box[:, 2] = np.maximum(box[:, 2], box[:, 0] + 1)
        box[:, 3] = np.maximum(box[:, 3], box[:, 1] + 1)
        keep = o[:, 4] >= logit(threshold)
        p = 1.0 / (1.0 + np.exp(-o[keep, 4].astype(np.float64)))
        return Detections(boxes=box[keep], scores=p.astype(np.float32), ellipses=np.asarray(det.ellipses)[keep])

    def save(self, path: str | Path) -> Path:
        from safetensors.numpy import save

        from seedmap.io.atomic import atomic_write_bytes

        t = {}
        for k, (w, b) in enumerate(self.layers):
            t[f"w{k}"] = np.ascontiguousarray(w, np.float32)
            t[f"b{k}"] = np.ascontiguousarray(b, np.float32)
        meta = {"seedmap_kind": self.kind, "patch_r": str(self.patch_r), "info": json.dumps(self.info or {})}
        atomic_write_bytes(Path(path), save(t, metadata=meta))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path, kind: str = "fast_refiner") -> Refiner:
        from seedmap.io.tensors import read_safetensors

        p = Path(path)
        if not p.is_file():
            raise InputError(f"{kind.replace('_', ' ')} weights not found", p)
        t, meta = read_safetensors(p)
        if meta.get("seedmap_kind") != kind:
            raise InputError(f"holds {meta.get('seedmap_kind') or 'unknown'} weights, expected {kind}", p)
        n = len([k for k in t if k.startswith("w")])
        if n == 0 or any(f"b{k}" not in t for k in range(n)):
            raise InputError(f"{kind} weights lack their layers (w0, b0, ...)", p)
        layers = [(t[f"w{k}"].astype(np.float32), t[f"b{k}"].astype(np.float32)) for k in range(n)]
        for k in range(n):
            w, b = layers[k]
            if w.ndim != 2 or b.shape != (w.shape[1],) or (k and w.shape[0] != layers[k - 1][0].shape[1]):
                raise InputError(f"{kind} layer {k} has shape {w.shape} / {b.shape}, which does not chain", p)
        return cls(layers, int(meta.get("patch_r", PATCH_R)), json.loads(meta.get("info", "{}")), kind)


def training_samples(dataset: str | Path, frames: list[int] | None, config=None, min_gt_area: int = 6,
                     progress: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(features, target box offsets (N, 4) / 5 px, is_seed (N,))`` from a simulated dataset's GT.

    Candidates are the classical detector's (refinement off); a candidate is a seed when its
    keypoint pixel lies in a GT instance mask of >= ``min_gt_area`` pixels, and its target box is
    that instance's box.
    """
    from seedmap.detect.config import FastConfig
    from seedmap.detect.fast import FastDetector
    from seedmap.io.images import read_rgb
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(dataset)
    if not ds.has_gt:
        raise InputError("dataset has no ground truth (gt/instances/) to train on", dataset)
    cfg = (config or FastConfig()).model_copy(update={"refine": False})
    det = FastDetector(cfg)
    items = [(i, cam) for i in (frames if frames is not None else range(len(ds))) for cam in ("left", "right")]
    if progress:
        from tqdm import tqdm

        items = tqdm(items, desc="refiner samples", unit="img")
    xs, ys, ss = [], [], []
    for i, cam in items:
        img = read_rgb(ds.image_path(i, cam))
        inst = ds.gt_instances(i, cam)
        lab = ds.gt_label_image(i, cam).astype(np.int64)
        d, f = det.detect_with_seediness(img)
        x, c = candidate_features(f, d)
        lut = np.full(int(max(lab.max(), inst.label.max(initial=0))) + 1, -1, np.int64)
        lut[inst.label.astype(np.int64)] = np.arange(len(inst))
        g = lut[lab[c[:, 1], c[:, 0]]]
        pos = g >= 0
        pos[pos] &= inst.area[g[pos]] >= min_gt_area
        y = np.zeros((len(d), 4), np.float32)
        y[pos] = (inst.boxes[g[pos]] - np.c_[c[pos], c[pos]]) / SCALE_PX
        xs.append(x)
        ys.append(y)
        ss.append(pos)
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ss)


def train_refiner(x: np.ndarray, y: np.ndarray, is_seed: np.ndarray, steps: int = 3000, hidden: tuple = (96, 64),
                  lr: float = 2e-3, batch: int = 512, seed: int = 0, box_cols: slice | None = None,
                  has_box: np.ndarray | None = None, standardize: bool = False, cosine: bool = False,
                  beta: float = 0.1, box_weight: float = 1.0, kind: str = "fast_refiner",
                  progress: bool = False) -> Refiner:
    """Fit the MLP (torch, CPU): BCE on ``is_seed`` + smooth-L1 (``beta``) of (output + the candidate's own box
    ``x[:, box_cols]``) against ``y`` on the rows of ``has_box`` (default: the seeds), weighted ``box_weight``.

    ``box_cols`` defaults to the classical candidates' region box (:func:`candidate_features`). ``standardize``:
    inputs scaled to zero mean and unit variance for training (``x`` is modified in place to save memory) and the
    scaling folded into the first layer, so the saved MLP takes raw features. ``cosine``: the learning rate decays
    to 3 % over the steps."""
    import torch

    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    dims = [x.shape[1], *hidden, 5]
    mods: list = []
    for k in range(len(dims) - 1):
        mods.append(torch.nn.Linear(dims[k], dims[k + 1]))
        if k < len(dims) - 2:
            mods.append(torch.nn.ReLU())
    net = torch.nn.Sequential(*mods)
    opt = torch.optim.Adam(net.parameters(), lr)
    n_patch = x.shape[1] - 9
    box_cols = box_cols if box_cols is not None else slice(n_patch, n_patch + 4)
    x = np.ascontiguousarray(x, np.float32)
    rb = torch.from_numpy(x[:, box_cols].copy())  # the candidates' own boxes, unscaled
    mu = sd = None
    if standardize:
        # in blocks and in place: the features can be gigabytes (a float64 copy would double them)
        s1 = np.zeros(x.shape[1], np.float64)
        s2 = np.zeros(x.shape[1], np.float64)
        for k0 in range(0, len(x), 65536):
            blk = x[k0:k0 + 65536].astype(np.float64)
            s1 += blk.sum(axis=0)
            s2 += (blk * blk).sum(axis=0)
        mu = (s1 / len(x)).astype(np.float32)
        sd = (np.sqrt(np.maximum(s2 / len(x) - (s1 / len(x)) ** 2, 0.0)) + 1e-3).astype(np.float32)
        for k0 in range(0, len(x), 65536):
            x[k0:k0 + 65536] -= mu
            x[k0:k0 + 65536] /= sd
    X = torch.from_numpy(x)
    Y = torch.from_numpy(np.nan_to_num(np.ascontiguousarray(y, np.float32)))
    S = torch.from_numpy(np.asarray(is_seed, bool))
    B = torch.from_numpy(np.asarray(is_seed if has_box is None else has_box, bool))
    sched = (torch.optim.lr_scheduler.LambdaLR(opt, lambda k: 0.03 + 0.97 * 0.5 * (1 + np.cos(np.pi * k / steps)))
             if cosine else None)
    losses = []
    it = range(steps)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="refiner", unit="step", mininterval=1.0)
    for _ in it:
        b = torch.randint(0, len(X), (min(batch, len(X)),), generator=g)
        o = net(X[b])
        loss = torch.nn.functional.binary_cross_entropy_with_logits(o[:, 4], S[b].float())
        m = B[b]
        if m.any():
            loss = loss + box_weight * torch.nn.functional.smooth_l1_loss(o[m, :4] + rb[b][m], Y[b][m], beta=beta)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if sched is not None:
            sched.step()
        losses.append(loss.item())
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    layers = [(m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy()) for m in lin]
    if standardize:  # (x - mu) / sd @ w + b  =  x @ (w / sd) + (b - (mu / sd) @ w)
        w0, b0 = layers[0]
        layers[0] = ((w0 / sd[:, None]).astype(np.float32), (b0 - (mu / sd) @ w0).astype(np.float32))
    r = int(round((np.sqrt(n_patch) - 1) / 2))
    return Refiner(layers, r, {"steps": steps, "samples": int(len(X)), "seed_fraction": float(S.float().mean()),
                               "loss_first_100": float(np.mean(losses[:100])),
                               "loss_last_100": float(np.mean(losses[-100:]))}, kind)
