"""The ``fast`` detector's small CNN, run in onnxruntime (no torch needed).

Why: the classical blob stage misses or merges a third of the seeds (partly hidden slivers of
6–12 px); a CenterNet-style network trained on simulated ranges (:mod:`seedmap.detect.train_cnn`)
predicts for every pixel a seed-centre heatmap, the four box edges and the keypoint's sub-pixel
offset, so touching and partly hidden seeds get their own peak and a pixel-exact box.

Speed: seeds cover ~5 % of a frame, so the network runs only on ``tile``-px tiles (plus a ``margin``
of context) that a cheap gate marks: the seediness image (bright, non-green; see
:func:`seedmap.detect.fast.seediness`) at half resolution with a difference-of-Gaussians blob
response above ``gate_response``. Peaks: 3x3 max-pool non-maximum suppression of the heatmap, above
``threshold``. Box = peak pixel +- the rounded predicted edge distances (x0, y0 inclusive, x1, y1
exclusive); keypoint = peak pixel + predicted offset; ellipse = axis-aligned, inscribed in the box.

Arm scans (session 6): close-up panicle views show seeds ~2x the area of the row-range seeds (~33 vs ~17 px),
white ones flash-saturated (61 % of their pixels at 255 on panicle 140: neighbouring seeds merge into one white
blob). The field network puts >= 2 keypoints on ~43 % of such seeds. Two remedies, measured on the validation
panicles 140-141 (left images, GT >= 12 px; box F1 / seeds with exactly one keypoint / with >= 2):
field network 0.41 / 0.37 / 0.43; ``cnn.scale`` 0.8 (the image resized so the seeds are nearer the training
size, outputs mapped back) 0.54 / 0.55 / 0.16; a network trained on ranges + arm scans (``cnn.domain=arm``,
``fast_cnn_arm.onnx``) 0.62 / 0.56 / 0.12 (at threshold 0.35, which the reconstruction uses: 0.55 / 0.50 /
0.30, more recall for the counter to de-duplicate). The arm network costs 0.014 F1 on the row ranges (validation
det_s36 0.884 vs 0.898), so ``fast`` keeps the field network by default and the panicle reconstruction asks
for the arm one (ReconConfig.detector_overrides).
Session 7: those numbers were measured on flash-saturated renders. Arm scans are now exposed for their stand-off
(:mod:`seedmap.sim.panicle_scan`) and ``fast_cnn_arm.onnx`` was retrained on such scans (same recipe, panicles
130-139): box F1 on the new renders of panicles 140-141 0.622 at threshold 0.40 (what the reconstruction uses),
against 0.560 for the session-6 arm network and 0.513 for the field network at their best thresholds.

Measured and not adopted (session 4, det_s36): onnxruntime int8 static quantization (QDQ or
QOperator, calibrated on training tiles) is *slower* on this AVX2 CPU at 8-24 channels (92 / 105 ms
vs 85 ms fp32 for the session-3 network); dropping a peak whose keypoint lies in a stronger peak's
box costs recall (F1 0.824-0.852 vs 0.855); a 5x5 peak window (``peak_window``) trades recall for
precision at about equal F1. Session-4 weights: 8/16 channels (2.2x fewer multiply-adds than
session 3's 12/24), 46 ms CPU per 1434x1050 image on one thread.

Measured and not adopted (session 5, session-4 weights, validation det_s36 F1 0.898 at threshold 0.45):
box-IoU non-maximum suppression of the peaks (cv2.dnn.NMSBoxes at IoU 0.3 / 0.4 / 0.5 / 0.6: 0.896 / 0.899 /
0.900 / 0.899), a constant added to all four predicted edges before rounding (+-0.1 px: 0.897 / 0.887), a
higher threshold for small predicted boxes (no change: false positives on slivers get whole-seed-sized
boxes), threshold 0.5 (0.901 on det_s36 but 0.880 vs 0.883 on the second validation range det_s45).
Session 11 (arm scans, ``fast_cnn_arm.onnx``): box NMS of the peaks is available as ``nms_iou`` (off). With it a
lower threshold reaches more of the countable seeds at the same duplicate rate (six tuning panicles, threshold 0.25 +
NMS at IoU 0.2: 91.5 % reachable / 12.1 % duplicates vs 85.3 / 12.9 % at 0.40 without), but the seed counts got worse
at every setting tried (``benchmarks/count_reach.py``; README, panicle reconstruction, session 11).
Session 7: ``smooth`` 0 / 1 / 16 instead of 4: det_s36 F1 0.895 / 0.896 / 0.896 vs 0.898 (a sliver's peak pixel
itself predicts the too-large box; ``benchmarks/detect_errors.py --set cnn.smooth=S``).

Session 12: the peaks go through a learned second stage by default (``refiner``, :mod:`seedmap.detect.cnn_refine`):
candidates at ``refine_candidates`` (0.25), rescored and their boxes corrected, kept at ``refine_threshold`` (0.30);
held-out pooled box F1 0.870 -> 0.917. ``flip_tta`` (opt-in) averages the outputs with those of the left-right
mirrored tiles (:func:`unmirror`): +0.008 pooled for 1.85x the network's CPU.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from seedmap.detect.base import Detector, check_image, logit, map_to_input
from seedmap.detect.config import CnnConfig, FastConfig
from seedmap.errors import ConfigError, InputError
from seedmap.records import Detections, StereoDetections, StereoFrame


def default_cnn_path(domain: str = "field") -> Path:
    """The shipped network of ``domain`` (``cnn.domain``): ``field`` = trained on the simulated ranges of seeds 1
    and 31-35, held-out seed 36 (session 4); ``arm`` =
    trained on those ranges and the arm scans of panicles 130-139 (session 6; retrained on auto-exposed scans in
    session 7; commands and numbers in
    :mod:`seedmap.detect.train_cnn`)."""
    if domain not in ("field", "arm"):
        raise ConfigError(f"cnn.domain must be field or arm, got {domain!r}")
    return Path(__file__).with_name("weights") / ("fast_cnn.onnx" if domain == "field" else "fast_cnn_arm.onnx")


def cnn_weights_path(cfg: CnnConfig, weights: str | Path | None = None) -> Path:
    """The ONNX file a detector with config ``cfg`` runs: ``weights``, else ``cfg.weights``, else the
    shipped network of ``cfg.domain``.

    Opt-in networks shipped in session 9 (training and held-out numbers in :mod:`seedmap.detect.train_cnn`):
    ``fast_cnn_s9.onnx`` (the field network fine-tuned on ranges from the later renderer; same cost) and
    ``fast_cnn_s9_wide.onnx`` (10/20 channels, 1.5x the CPU); session 10: ``fast_cnn_s10.onnx`` (8/20 channels
    from scratch on the session-9 ranges, 1.2x the CPU). A bare file name that is not a file in the working directory names one of the shipped networks in
    ``seedmap/detect/weights/`` (e.g. ``--set cnn.weights=fast_cnn_s9.onnx``), so an opt-in network can be
    chosen without knowing where the package is installed."""
    return shipped_or_path(weights or cfg.weights or default_cnn_path(cfg.domain))


def shipped_or_path(name: str | Path) -> Path:
    """``name`` as a path, unless it is a bare file name that is no file in the working directory but one of the
    files shipped in ``seedmap/detect/weights/`` (then that one)."""
    p = Path(name)
    if p.parent == Path(".") and not p.is_file():
        shipped = Path(__file__).with_name("weights") / p.name
        if shipped.is_file():
            return shipped
    return p


def load_refiner(cfg: CnnConfig, cnn_path: Path, explicit_weights: bool = False):  # noqa: ANN201 - CnnRefiner | None
    """The second stage ``cfg.refiner`` asks for, checked against the network ``cnn_path`` (None = off)."""
    from seedmap.detect.cnn_refine import CnnRefiner, default_cnn_refiner_path

    name = (cfg.refiner or "none").strip()
    if name.lower() == "none":
        return None
    if name.lower() == "auto":
        shipped = not explicit_weights and cfg.weights is None and cfg.domain == "field"
        p = default_cnn_refiner_path()
        if not (shipped and p.is_file()):
            return None
    else:
        p = shipped_or_path(name)
    ref = CnnRefiner.load(p)
    ref.check_network(cnn_path)
    return ref


def load_session(path: str | Path, threads: int = 0, kind: str = "fast_cnn"):  # noqa: ANN201 - ort.InferenceSession
    """An onnxruntime session of a seedmap ONNX file whose metadata says ``kind`` (``fast_cnn``: the network;
    ``cnn_refiner``: its second stage); a one-line :class:`InputError` otherwise."""
    import onnxruntime as ort

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{'fast CNN' if kind == 'fast_cnn' else kind.replace('_', ' ')} weights not found", p)
    so = ort.SessionOptions()
    if threads > 0:
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    try:
        sess = ort.InferenceSession(str(p), so, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types for bad files
        raise InputError(f"not a readable ONNX model ({str(e).splitlines()[0][:120]})", p) from None
    meta = sess.get_modelmeta().custom_metadata_map
    if meta.get("seedmap_kind") != kind:
        raise InputError(f"holds {meta.get('seedmap_kind') or 'unknown'} weights, expected {kind}", p)
    return sess


def gate_tiles(f: np.ndarray, cfg: CnnConfig, half: bool = False, shape: tuple[int, int] | None = None
               ) -> np.ndarray:
    """``(K, 2)`` int ``(ty, tx)`` indices of the ``cfg.tile``-px tiles worth running the network on.

    Half-resolution DoG (sigma 0.6 / 1.5 px there, i.e. ~ a 5 px seed at full resolution) of the
    seediness image ``f`` (uint8), counted per tile. ``half``: ``f`` is already at half resolution
    (the seediness of the half-size image: 4x fewer pixels to convert) and ``shape`` is the
    full-resolution ``(h, w)``.
    """
    h, w = shape if (half and shape is not None) else (f.shape[0] * (2 if half else 1), f.shape[1] * (2 if half else 1))
    t = int(cfg.tile)
    nty, ntx = -(-h // t), -(-w // t)
    if cfg.gate_min_px <= 0:
        return np.argwhere(np.ones((nty, ntx), bool))
    f2 = f if half else cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    g1 = cv2.GaussianBlur(f2, (0, 0), 0.6)
    dog = cv2.subtract(g1, cv2.GaussianBlur(f2, (0, 0), 1.5), dtype=cv2.CV_16S)
    hit = (dog > cfg.gate_response) & (g1 > cfg.gate_brightness)
    t2 = t // 2
    ph, pw = nty * t2, ntx * t2
    pad = np.zeros((ph, pw), np.uint16)
    hh, ww = min(hit.shape[0], ph), min(hit.shape[1], pw)
    pad[:hh, :ww] = hit[:hh, :ww]
    cnt = pad.reshape(nty, t2, ntx, t2).sum(axis=(1, 3))
    return np.argwhere(cnt >= cfg.gate_min_px)


_K3 = np.ones((3, 3), np.uint8)


def peak_kernel(window: int) -> np.ndarray:
    """Max-filter footprint of the peak test: 3 = the 3x3 square, 5 = the 5x5 disk (corners off)."""
    if window == 3:
        return _K3
    if window == 5:
        return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    raise ConfigError(f"cnn.peak_window must be 3 or 5, got {window}")


def decode(out: np.ndarray, threshold: float, valid: tuple[int, int, int, int], smooth: float = 0.0,
           kernel: np.ndarray = _K3) -> tuple[np.ndarray, ...]:
    """Peaks of a batch of network outputs ``(N, 7, H, W)``: ``(n, x, y, logit, l, t, r, b, dx, dy)``.

    A peak is a pixel whose heat logit is the maximum over ``kernel`` (3x3 by default).
    Only peaks inside ``valid = (y0, y1, x0, x1)`` (a tile's core, not its margin) are kept.
    ``smooth > 0``: every pixel of a seed predicts the same box edges and keypoint, so the peak's
    values are the average over its 3x3 neighbourhood weighted by ``sigmoid(heat) ** smooth``.
    """
    n, _, h, w = out.shape
    y0, y1, x0, x1 = valid
    # the tiles stacked vertically: one 3x3 max filter for all (rows that mix two tiles lie in margins)
    heat = np.ascontiguousarray(out[:, 0]).reshape(n * h, w)
    pk = heat >= logit(threshold)
    pk &= heat >= cv2.dilate(heat, kernel)
    pk = pk.reshape(n, h, w)
    win = np.zeros((h, w), bool)
    win[max(y0, 1):min(y1, h - 1), max(x0, 1):min(x1, w - 1)] = True
    pk &= win
    ns, ys, xs = np.nonzero(pk)
    hv = out[ns, 0, ys, xs]
    if smooth <= 0 or len(xs) == 0:
        return (ns, xs, ys, hv, *(out[ns, k, ys, xs] for k in range(1, 7)))
    acc = np.zeros((6, len(xs)), np.float32)
    ws = np.zeros(len(xs), np.float32)
    sgn = np.array([-1, -1, 1, 1, 1, 1], np.float32)[:, None]
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            v = out[ns, :, ys + dy, xs + dx].T  # (7, K); peaks are >= 1 px inside their tile
            wk = (1.0 / (1.0 + np.exp(-v[0]))) ** smooth
            # a neighbour's prediction, moved to the peak pixel: edges/keypoint shift by (dx, dy)
            off = np.array([dx, dy, dx, dy, dx, dy], np.float32)[:, None]
            acc += wk * (v[1:] + sgn * off)
            ws += wk
    acc /= ws
    return (ns, xs, ys, hv, *acc)


class CnnDetector(Detector):
    """CenterNet-style CNN in onnxruntime on gated tiles; see the module docstring."""

    name = "fast-cnn"

    def __init__(self, config: CnnConfig | None = None, fast: FastConfig | None = None,
                 weights: str | Path | None = None) -> None:
        self.cfg = config or CnnConfig()
        self.fast_cfg = fast or FastConfig()
        if self.cfg.tile and (self.cfg.tile % 2 or self.cfg.margin % 2):
            raise ConfigError(f"cnn.tile ({self.cfg.tile}) and cnn.margin ({self.cfg.margin}) must be even "
                              "(the network halves the resolution)")
        self.path = cnn_weights_path(self.cfg, weights)
        self.sess = load_session(self.path, self.cfg.threads)
        self.refiner = load_refiner(self.cfg, self.path, explicit_weights=weights is not None)
        #: the score a detection needs (cnn.threshold; cnn.refine_threshold with a refiner) ...
        self.threshold = float(self.cfg.refine_threshold if self.refiner else self.cfg.threshold)
        #: ... and the heatmap peak threshold that makes the candidates
        self.peak_threshold = float(self.cfg.refine_candidates if self.refiner else self.cfg.threshold)
        meta = self.sess.get_modelmeta().custom_metadata_map
        self.info = json.loads(meta.get("info", "{}"))
        self.kernel = peak_kernel(int(self.cfg.peak_window))
        self._pool = None

    def detect_stereo(self, frame: StereoFrame) -> StereoDetections:
        """Left and right image; with ``cnn.stereo_threads = 2`` the two run concurrently (onnxruntime
        and OpenCV release the GIL), so a stereo frame uses both cores of a 2-core CPU."""
        if int(self.cfg.stereo_threads) < 2:
            return super().detect_stereo(frame)
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(1, thread_name_prefix="fast-cnn")
        left = self._pool.submit(self.detect, frame.left)
        right = self.detect(frame.right)
        return StereoDetections(index=frame.index, timestamp=frame.timestamp, left=left.result(), right=right)

    def _run(self, x: np.ndarray) -> np.ndarray:
        out = self.sess.run(None, {"image": x})[0]
        if not self.cfg.flip_tta:
            return out
        back = unmirror(self.sess.run(None, {"image": np.ascontiguousarray(x[..., ::-1])})[0])
        return 0.5 * (out + back)

    def detect(self, image: np.ndarray) -> Detections:
        """Seeds in one RGB image: boxes, sigmoid scores, keypoints (ellipse centres).

        With ``cnn.scale`` != 1 the network runs on the image resized by that factor (seeds
        larger than the training seeds are brought to the training size) and the boxes, keypoints
        and ellipse axes are mapped back to the input's pixels."""
        img = check_image(image)
        s = float(self.cfg.scale)
        if s == 1.0:
            return self._detect(img)
        h, w = img.shape[:2]
        ws, hs = max(1, int(round(w * s))), max(1, int(round(h * s)))
        small = cv2.resize(img, (ws, hs), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        d = self._detect(small)
        if len(d) == 0:
            return d
        boxes, ell = map_to_input(d.boxes, d.ellipses, ws / w, hs / h, s)
        return Detections(boxes=boxes, scores=d.scores, ellipses=ell)

    def _detect(self, img: np.ndarray) -> Detections:
        """The network's detections in ``img`` at its own resolution (refined, with a refiner)."""
        pk = self.peaks(img)
        if self.refiner is not None and len(pk):
            raw = self.refiner.refine(img, pk.x, pk.y, pk.raw)
            keep = raw[:, 0] >= logit(self.threshold)
            pk = CnnPeaks(pk.x[keep], pk.y[keep], raw[keep])
        return self.to_detections(pk, img.shape[:2])

    def peaks(self, img: np.ndarray) -> CnnPeaks:
        """The heatmap peaks above ``peak_threshold`` in ``img`` with the network's raw predictions there."""
        from seedmap.detect.fast import seediness

        h, w = img.shape[:2]
        c = self.cfg
        parts = []
        if not c.tile:
            x = (img.astype(np.float32) * (1.0 / 255.0)).transpose(2, 0, 1)[None]
            # even size for the stride-2 body, 1 px border so peaks at the image edge have neighbours
            ph, pw = h + h % 2 + 2, w + w % 2 + 2
            x = np.pad(x, ((0, 0), (0, 0), (1, ph - h - 1), (1, pw - w - 1)))
            d = decode(self._run(np.ascontiguousarray(x)), self.peak_threshold, (1, h + 1, 1, w + 1), c.smooth, self.kernel)
            parts.append((d[1:], d[1] - 1, d[2] - 1))
        else:
            g = self.fast_cfg.max_green_excess / 16.0 if self.fast_cfg.max_green_excess > 0 else 0.0
            # the gate works at half resolution: seediness of the half-size image (4x fewer pixels)
            tiles = gate_tiles(seediness(cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA), g), c,
                               half=True, shape=(h, w))
            t, m = int(c.tile), int(c.margin)
            s = t + 2 * m
            nty, ntx = -(-h // t), -(-w // t)
            pad = cv2.copyMakeBorder(img, m, nty * t - h + m, m, ntx * t - w + m, cv2.BORDER_CONSTANT, value=0)
            bs = max(1, int(c.batch))
            for k0 in range(0, len(tiles), bs):
                tb = tiles[k0:k0 + bs]
                x = np.stack([pad[ty * t: ty * t + s, tx * t: tx * t + s] for ty, tx in tb])
                x = np.ascontiguousarray((x.astype(np.float32) * (1.0 / 255.0)).transpose(0, 3, 1, 2))
                d = decode(self._run(x), self.peak_threshold, (m, m + t, m, m + t), c.smooth, self.kernel)
                # image pixel = tile origin (minus the margin) + position in the padded window
                parts.append((d[1:], d[1] + tb[d[0], 1] * t - m, d[2] + tb[d[0], 0] * t - m))
        if sum(len(p[1]) for p in parts) == 0:
            return CnnPeaks.empty()
        xs = np.concatenate([p[1] for p in parts]).astype(np.float64)
        ys = np.concatenate([p[2] for p in parts]).astype(np.float64)
        raw = np.stack([np.concatenate([p[0][k] for p in parts]).astype(np.float64) for k in range(2, 9)], axis=1)
        keep = (xs < w) & (ys < h)
        return CnnPeaks(xs[keep], ys[keep], raw[keep])

    def to_detections(self, pk: CnnPeaks, shape: tuple[int, int]) -> Detections:
        """Boxes (whole pixels, clipped to the image of ``shape`` (h, w)), scores and keypoints of the peaks."""
        if len(pk) == 0:
            return Detections()
        h, w = shape
        xs, ys = pk.x, pk.y
        lg, l, tp, r, b, dx, dy = pk.raw.T
        x0 = xs - np.round(np.maximum(l, 0))
        y0 = ys - np.round(np.maximum(tp, 0))
        x1 = np.maximum(xs + np.round(np.maximum(r, 0)), x0 + 1)
        y1 = np.maximum(ys + np.round(np.maximum(b, 0)), y0 + 1)
        boxes = np.stack([np.clip(x0, 0, w), np.clip(y0, 0, h), np.clip(x1, 0, w), np.clip(y1, 0, h)], axis=1)
        bw, bh = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
        ell = np.stack([xs + dx, ys + dy, np.maximum(bw, bh), np.minimum(bw, bh),
                        np.where(bw >= bh, 0.0, 90.0)], axis=1)
        score = 1.0 / (1.0 + np.exp(-lg))
        if self.cfg.nms_iou > 0 and len(score) > 1:
            k = box_nms(boxes, score, self.cfg.nms_iou)
            boxes, score, ell = boxes[k], score[k], ell[k]
        return Detections(boxes=boxes, scores=score, ellipses=ell)


@dataclass
class CnnPeaks:
    """Heatmap peaks of one image: pixel ``x``, ``y`` (N,) and the network's raw predictions there, ``raw`` (N, 7):
    heat logit, box edges left, top, right, bottom (px from the pixel), keypoint offset dx, dy (px)."""

    x: np.ndarray
    y: np.ndarray
    raw: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    @staticmethod
    def empty() -> CnnPeaks:
        return CnnPeaks(np.zeros(0), np.zeros(0), np.zeros((0, 7)))


def unmirror(out: np.ndarray) -> np.ndarray:
    """The network's output ``(N, 7, H, W)`` on a left-right mirrored input, brought back to the input's pixels.

    Pixel x of the mirrored input is pixel W - 1 - x of the input. The box edges are pixel counts with x0
    inclusive and x1 exclusive (left = x - x0, right = x1 - x), so the mirrored prediction's right edge is this
    pixel's left edge + 1 and its left edge this pixel's right edge - 1, and the keypoint offset dx changes
    sign. Channels: heat logit, l, t, r, b, dx, dy."""
    m = out[..., ::-1]
    return np.stack([m[:, 0], m[:, 3] - 1.0, m[:, 2], m[:, 1] + 1.0, m[:, 4], -m[:, 5], m[:, 6]], axis=1)


def box_nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Indices (ascending) of the boxes (N, 4) x0, y0, x1, y1 kept by greedy non-maximum suppression at
    ``iou`` (cv2.dnn.NMSBoxes, strongest first)."""
    b = np.asarray(boxes, np.float64)
    rects = np.column_stack([b[:, 0], b[:, 1], b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]]).tolist()
    k = cv2.dnn.NMSBoxes(rects, np.asarray(scores, np.float64).tolist(), 0.0, float(iou))
    return np.sort(np.asarray(k, np.int64).reshape(-1))

