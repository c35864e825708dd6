"""The ``fast`` detector: a small CenterNet-style CNN on gated tiles, run in onnxruntime (no torch), plus its refiner.

For every pixel the network predicts a seed-centre heat logit, the four box edges and the keypoint's sub-pixel
offset. It runs only on ``cnn.tile``-px tiles (plus an 8-px margin of context) that a cheap gate marks: the
seediness image (:func:`seediness`: bright, non-green) at half resolution with a difference-of-Gaussians blob
response. Peaks: 3x3 max-filter non-maximum suppression of the heat logit. Box = peak pixel +- the rounded edge
distances (x0, y0 inclusive, x1, y1 exclusive); keypoint = peak pixel + offset; ellipse = axis-aligned, inscribed
in the box. With the shipped field network the peaks go through the refiner (:mod:`seedmap.detect.cnn_refine`).
The input is resized so that the seeds have the network's size: by ``cnn.scale`` / ``cnn.seed_px``, by the network's
recorded ``images_seed_px``, or (``cnn.scale = auto``) from the seed size :mod:`seedmap.detect.autoscale` estimates on
the first image (:meth:`CnnDetector.reset_scale` asks for a new estimate).
Method and measurements: docs/method/detection.md; training: :mod:`seedmap.detect.train_cnn`.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from seedmap.detect.autoscale import SCORE_SIZE, UNRECORDED_SCORE_SIZE, estimate_seed_px
from seedmap.detect.base import Detector, check_image, logit, map_to_input, register_detector
from seedmap.detect.cnn_refine import CnnRefiner, default_cnn_refiner_path
from seedmap.detect.config import ESTIMATED_SCALES, TRAINED_SEED_PX, CnnConfig
from seedmap.detect.kernels import INPUT_LUT, window_batch
from seedmap.detect.runtime import WEIGHTS_DIR, load_session, shipped_or_path
from seedmap.errors import ConfigError
from seedmap.records import Detections, StereoDetections, StereoFrame

#: context (px) added around every tile: the receptive-field radius is 9 px, 8 gives the same F1 for less CPU
MARGIN = 8
#: tile gate: half-resolution DoG of the seediness image above this (grey levels) ...
GATE_RESPONSE = 18.0
#: ... and its smoothed brightness above this (grey levels) ...
GATE_BRIGHTNESS = 60.0
#: ... on at least this many half-resolution pixels of the tile
GATE_MIN_PX = 4
#: box edges and keypoint averaged over the peak's 3x3 neighbours weighted by sigmoid(heat) ** SMOOTH
SMOOTH = 4.0
#: tiles per onnxruntime call
BATCH = 32
#: leaf suppression of the seediness image: f -= GREEN_K * max(G - R, 0)
GREEN_K = 15.0 / 16.0


#: the shipped network of each ``cnn.domain``
SHIPPED_NETWORKS = {"field": "fast_cnn.onnx", "arm": "fast_cnn_arm.onnx", "photo": "fast_cnn_photo.onnx"}
#: the seed-size cue of a shipped network (seedmap.detect.autoscale.CUES); a trained network records its own
#: (``info["scale_cue"]``: its starting network's), else ``boxes``
SHIPPED_CUES = {"fast_cnn_photo.onnx": "score"}


def is_shipped(path: str | Path) -> bool:
    """True when ``path`` is a network file shipped with seedmap (in seedmap/detect/weights/)."""
    return Path(path).resolve().parent == WEIGHTS_DIR.resolve()


def network_scale_cue(path: str | Path, info: dict) -> str:
    """The seed-size cue of the network at ``path`` whose ONNX info is ``info``."""
    shipped = SHIPPED_CUES.get(Path(path).name) if is_shipped(path) else None
    return str(info.get("scale_cue") or shipped or "boxes")


def network_score_size(path: str | Path, info: dict) -> float:
    """The ``score`` cue's multiple (seedmap.detect.autoscale) of the network at ``path`` whose ONNX info is
    ``info``: recorded by training (a fine-tune inherits its starting network's), SCORE_SIZE for a shipped
    network, else UNRECORDED_SCORE_SIZE."""
    if info.get("score_size"):
        return float(info["score_size"])
    return SCORE_SIZE if is_shipped(path) else UNRECORDED_SCORE_SIZE


def default_cnn_path(domain: str = "field") -> Path:
    """The shipped network of ``domain`` (``cnn.domain``): ``field`` = fast_cnn.onnx (trained on simulated row
    ranges), ``arm`` = fast_cnn_arm.onnx (ranges + close-up arm scans of panicles), ``photo`` = fast_cnn_photo.onnx
    (ranges + simulated grain photos: loose grain, piles and panicles on varied backgrounds and light)."""
    if domain not in SHIPPED_NETWORKS:
        raise ConfigError(f"cnn.domain must be one of {', '.join(SHIPPED_NETWORKS)}, got {domain!r}")
    return WEIGHTS_DIR / SHIPPED_NETWORKS[domain]


def cnn_weights_path(cfg: CnnConfig, weights: str | Path | None = None) -> Path:
    """The ONNX file a detector with config ``cfg`` runs: ``weights``, else ``cfg.weights``, else the shipped network
    of ``cfg.domain``; a bare file name that is no file in the working directory names a shipped file."""
    return shipped_or_path(weights or cfg.weights or default_cnn_path(cfg.domain))


#: with ``cnn.scale = auto`` a ``boxes``-cue network runs at scale 1 while the estimated seed size lies within these
#: multiples of its operating seed size (the band it detects well, docs/method/detection.md) ...
SCALE_BAND = (0.75, 1.3)
#: ... and at scale operating size / estimate (at most 4) outside it; a ``score``-cue network always runs at the size
#: it scores highest for (its F1 falls off faster around its operating size)


def fixed_scale(cfg: CnnConfig, operating_px: float, images_seed_px: float | None = None
                ) -> tuple[float | None, str]:
    """The input scale set by the config (or the network) and how it was set: ``cnn.seed_px`` (``seed_px``:
    ``operating_px / cnn.seed_px``), a number ``cnn.scale`` (``scale``), or, with ``cnn.scale = auto``, a network
    fine-tuned on images of a recorded seed size (``network``: ``operating_px / images_seed_px``); ``(None, "auto")``
    when the scale is to be estimated from the images."""
    if cfg.seed_px is not None:
        if cfg.scale not in ESTIMATED_SCALES and float(cfg.scale) != 1.0:
            raise ConfigError(f"set cnn.scale ({cfg.scale:g}) or cnn.seed_px ({cfg.seed_px:g}), not both")
        return _bounded(float(operating_px) / float(cfg.seed_px), "cnn.seed_px", cfg.seed_px, operating_px), "seed_px"
    if cfg.scale not in ESTIMATED_SCALES:
        return float(cfg.scale), "scale"
    if images_seed_px:
        return _bounded(float(operating_px) / float(images_seed_px), "the network's images_seed_px", images_seed_px,
                        operating_px), "network"
    return None, "auto"


def _bounded(s: float, what: str, px: float, operating_px: float) -> float:
    if s > 4.0:
        raise ConfigError(f"{what}={px:g}: seeds under {operating_px / 4.0:g} px are too small for the network "
                          f"(trained on {operating_px:g}-px seeds; at most 4x upscaling)")
    return s


def auto_scale(seed_px: float | None, operating_px: float, band: bool = True) -> float:
    """The input scale for images of estimated seed size ``seed_px``: 1 without an estimate or (``band``) inside
    SCALE_BAND, else ``operating_px / seed_px`` (at most 4)."""
    if seed_px is None or band and SCALE_BAND[0] * operating_px <= seed_px <= SCALE_BAND[1] * operating_px:
        return 1.0
    return min(float(operating_px) / float(seed_px), 4.0)


def load_refiner(cfg: CnnConfig, cnn_path: Path, explicit_weights: bool = False) -> CnnRefiner | None:
    """The refiner ``cfg.refiner`` asks for, checked against the network ``cnn_path`` (None = off)."""
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


def seediness(image: np.ndarray, green_k: float = GREEN_K) -> np.ndarray:
    """uint8 brightness with leaf-green suppressed (grey levels), in two saturating OpenCV passes."""
    f = cv2.transform(image, np.array([[0.5, 0.35, 0.15]], np.float32))
    if green_k > 0:
        ge = cv2.subtract(image[..., 1], image[..., 0])  # saturating uint8: max(G - R, 0)
        f = cv2.addWeighted(f, 1.0, ge, -float(green_k), 0.0)  # saturates at 0
    return f


def gate_tiles(f: np.ndarray, tile: int, half: bool = False, shape: tuple[int, int] | None = None) -> np.ndarray:
    """``(K, 2)`` int ``(ty, tx)`` indices of the ``tile``-px tiles worth running the network on.

    Half-resolution DoG (sigma 0.6 / 1.5 px there, i.e. ~ a 5 px seed at full resolution) of the
    seediness image ``f`` (uint8), counted per tile. ``half``: ``f`` is already at half resolution
    (the seediness of the half-size image: 4x fewer pixels to convert) and ``shape`` is the
    full-resolution ``(h, w)``.
    """
    h, w = shape if (half and shape is not None) else (f.shape[0] * (2 if half else 1), f.shape[1] * (2 if half else 1))
    t = int(tile)
    nty, ntx = -(-h // t), -(-w // t)
    f2 = f if half else cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    g1 = cv2.GaussianBlur(f2, (0, 0), 0.6)
    dog = cv2.subtract(g1, cv2.GaussianBlur(f2, (0, 0), 1.5), dtype=cv2.CV_16S)
    hit = (dog > GATE_RESPONSE) & (g1 > GATE_BRIGHTNESS)
    t2 = t // 2
    ph, pw = nty * t2, ntx * t2
    pad = np.zeros((ph, pw), np.uint16)
    hh, ww = min(hit.shape[0], ph), min(hit.shape[1], pw)
    pad[:hh, :ww] = hit[:hh, :ww]
    cnt = pad.reshape(nty, t2, ntx, t2).sum(axis=(1, 3))
    return np.argwhere(cnt >= GATE_MIN_PX)


def tile_runs(tiles: np.ndarray) -> np.ndarray:
    """``(R, 3)`` int ``(ty, tx, n)``: the row-major ``(ty, tx)`` tiles (:func:`gate_tiles`) as runs of ``n``
    neighbouring tiles along a row starting at tile ``(ty, tx)``. The network runs once per run (its windows
    share their margins, and the tiles inside a run see each other as context)."""
    if len(tiles) == 0:
        return np.zeros((0, 3), np.int64)
    ty, tx = tiles[:, 0].astype(np.int64), tiles[:, 1].astype(np.int64)
    start = np.r_[True, (ty[1:] != ty[:-1]) | (tx[1:] != tx[:-1] + 1)]
    first = np.flatnonzero(start)
    return np.stack([ty[first], tx[first], np.diff(np.r_[first, len(ty)])], axis=1)


_K3 = np.ones((3, 3), np.uint8)


def decode(out: np.ndarray, threshold: float, valid: tuple[int, int, int, int], smooth: float = 0.0
           ) -> tuple[np.ndarray, ...]:
    """Peaks of a batch of network outputs ``(N, 7, H, W)``: ``(n, x, y, logit, l, t, r, b, dx, dy)``.

    A peak is a pixel whose heat logit is the maximum over its 3x3 neighbourhood.
    Only peaks inside ``valid = (y0, y1, x0, x1)`` (a tile's core, not its margin) are kept.
    ``smooth > 0``: every pixel of a seed predicts the same box edges and keypoint, so the peak's
    values are the average over its 3x3 neighbourhood weighted by ``sigmoid(heat) ** smooth``.
    """
    n, _, h, w = out.shape
    y0, y1, x0, x1 = valid
    # the tiles stacked vertically: one 3x3 max filter for all (rows that mix two tiles lie in margins)
    heat = np.ascontiguousarray(out[:, 0]).reshape(n * h, w)
    pk = heat >= logit(threshold)
    pk &= heat >= cv2.dilate(heat, _K3)
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
    # all 7 outputs at the 3x3 neighbours of every peak in one gather: (3, 3, 7, K); peaks are >= 1 px inside
    # their tile
    at = ((ns * 7)[None, :] + np.arange(7)[:, None]) * (h * w) + ys * w + xs
    nbr = np.take(np.ascontiguousarray(out).reshape(-1),
                  at[None, None] + (np.arange(-1, 2)[:, None] * w + np.arange(-1, 2)[None, :])[..., None, None])
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            v = nbr[dy + 1, dx + 1]  # (7, K)
            wk = (1.0 / (1.0 + np.exp(-v[0]))) ** smooth
            # a neighbour's prediction, moved to the peak pixel: edges/keypoint shift by (dx, dy)
            off = np.array([dx, dy, dx, dy, dx, dy], np.float32)[:, None]
            acc += wk * (v[1:] + sgn * off)
            ws += wk
    acc /= ws
    return (ns, xs, ys, hv, *acc)


class CnnDetector(Detector):
    """The ``fast`` detector: the CNN on gated tiles, then its refiner (module docstring)."""

    name = "fast"

    def __init__(self, config: CnnConfig | None = None, weights: str | Path | None = None) -> None:
        self.cfg = config or CnnConfig()
        if self.cfg.tile % 2:
            raise ConfigError(f"cnn.tile ({self.cfg.tile}) must be even (the network halves the resolution)")
        self.path = cnn_weights_path(self.cfg, weights)
        self.sess = load_session(self.path, self.cfg.threads)
        self.refiner = load_refiner(self.cfg, self.path, explicit_weights=weights is not None)
        #: the score a detection needs (cnn.threshold; cnn.refine_threshold with a refiner) ...
        self.threshold = float(self.cfg.refine_threshold if self.refiner else self.cfg.threshold)
        #: ... and the heatmap peak threshold that makes the candidates
        self.peak_threshold = float(self.cfg.refine_candidates if self.refiner else self.cfg.threshold)
        meta = self.sess.get_modelmeta().custom_metadata_map
        self.info = json.loads(meta.get("info", "{}"))
        #: the seed diameter (px) the network operates at: recorded by `seedmap train fast-cnn`, else the shipped
        #: networks' (TRAINED_SEED_PX of cnn.domain)
        self.trained_seed_px = float(self.info.get("seed_px") or TRAINED_SEED_PX[self.cfg.domain])
        #: how the seed size is read off the scale ladder (``auto``): the cue and the ``score`` cue's multiple
        self.scale_cue = network_scale_cue(self.path, self.info)
        self.score_size = network_score_size(self.path, self.info)
        #: the network runs on the image resized by this factor: set by the config or the network (``scale_source``
        #: seed_px | scale | network), else (``auto``) from the seed size estimated on the next image it sees
        self.scale, self.scale_source = fixed_scale(self.cfg, self.trained_seed_px, self.info.get("images_seed_px"))
        #: the seed size (px) estimated from an image (``auto`` only; None before one, or without seeds found) and
        #: the size the network is run for (autoscale.SeedSizeEstimate.run_px; sets the scale)
        self.seed_px_estimate: float | None = None
        self.run_px_estimate: float | None = None
        self._pool = None

    def reset_scale(self) -> None:
        """With ``cnn.scale = auto``: estimate the seed size again on the next image (a new photo); else nothing."""
        if self.scale_source == "auto":
            self.scale, self.seed_px_estimate, self.run_px_estimate = None, None, None

    def set_seed_px_estimate(self, seed_px: float | None, run_px: float | None = None) -> None:
        """With ``cnn.scale = auto``: use the seed size ``seed_px`` (px; None = none found) as if estimated, and run
        the network for seeds of ``run_px`` (default ``seed_px``), until :meth:`reset_scale`; else nothing."""
        if self.scale_source == "auto":
            self.seed_px_estimate = seed_px
            self.run_px_estimate = seed_px if run_px is None else run_px
            self.scale = self.scale_for(self.run_px_estimate)

    def scale_for(self, seed_px: float | None) -> float:
        """The input scale ``cnn.scale = auto`` runs images of seed size ``seed_px`` (px; None = unknown: 1) at,
        :func:`auto_scale`: a ``boxes``-cue network keeps scale 1 inside SCALE_BAND, a ``score``-cue one always brings
        ``seed_px`` to its own size."""
        return auto_scale(seed_px, self.trained_seed_px, band=self.scale_cue == "boxes")

    def ensure_scale(self, image: np.ndarray) -> float:
        """The input scale, estimated from RGB ``image`` first when it is not known yet (``auto``)."""
        if self.scale is None:
            e = estimate_seed_px(self.peaks, check_image(image), self.trained_seed_px, self.scale_cue,
                                 self.score_size)
            self.set_seed_px_estimate(e.seed_px, e.run_px)
        return self.scale

    def settings(self) -> dict:
        """The input scale, the seed size (px of the input images) it assumes, how it was set (``scale_source``:
        auto | scale | seed_px | network) and the estimated seed size (auto), for a result's meta.json."""
        s = self.scale if self.scale is not None else 1.0
        return {"cnn_scale": s, "seed_px": self.trained_seed_px / s, "trained_seed_px": self.trained_seed_px,
                "scale_source": self.scale_source, "seed_px_estimate": self.seed_px_estimate}

    def detect_stereo(self, frame: StereoFrame) -> StereoDetections:
        """Left and right image; with ``cnn.stereo_threads = 2`` the two run concurrently (onnxruntime
        and OpenCV release the GIL)."""
        self.ensure_scale(frame.left)  # once per sequence: from its first left image
        if int(self.cfg.stereo_threads) < 2:
            return super().detect_stereo(frame)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="fast")
        left = self._pool.submit(self.detect, frame.left)
        right = self.detect(frame.right)
        return StereoDetections(index=frame.index, timestamp=frame.timestamp, left=left.result(), right=right)

    def _run(self, x: np.ndarray) -> np.ndarray:
        return self.sess.run(None, {"image": x})[0]

    def detect(self, image: np.ndarray) -> Detections:
        """Seeds in one RGB image: boxes, sigmoid scores, keypoints (ellipse centres); refined with a refiner.

        With a scale != 1 (``cnn.scale``, ``cnn.seed_px``, the network's images_seed_px, or estimated on the first
        image with ``cnn.scale = auto``) the network runs on the image resized by that factor (seeds brought to the
        training size) and the boxes, keypoints and ellipse axes are mapped back to the input's pixels."""
        img = check_image(image)
        s = self.ensure_scale(img)
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
        h, w = img.shape[:2]
        c = self.cfg
        parts = []
        if not c.tile:
            x = (img.astype(np.float32) * (1.0 / 255.0)).transpose(2, 0, 1)[None]
            # even size for the stride-2 body, 1 px border so peaks at the image edge have neighbours
            ph, pw = h + h % 2 + 2, w + w % 2 + 2
            x = np.pad(x, ((0, 0), (0, 0), (1, ph - h - 1), (1, pw - w - 1)))
            d = decode(self._run(np.ascontiguousarray(x)), self.peak_threshold, (1, h + 1, 1, w + 1), SMOOTH)
            parts.append((d[1:], d[1] - 1, d[2] - 1))
        else:
            # the gate works at half resolution: seediness of the half-size image (4x fewer pixels)
            tiles = gate_tiles(seediness(cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA)), c.tile,
                               half=True, shape=(h, w))
            t, m = int(c.tile), MARGIN
            nty, ntx = -(-h // t), -(-w // t)
            pad = cv2.copyMakeBorder(img, m, nty * t - h + m, m, ntx * t - w + m, cv2.BORDER_CONSTANT, value=0)
            runs = tile_runs(tiles)
            for n in np.unique(runs[:, 2]):  # runs of n tiles: one window of n tiles plus the margin each
                rn = runs[runs[:, 2] == n]
                per = max(1, BATCH // int(n))
                for k0 in range(0, len(rn), per):
                    rb = rn[k0:k0 + per]
                    x = window_batch(pad, np.ascontiguousarray(rb[:, :2] * t, np.int64), t + 2 * m, int(n) * t + 2 * m,
                                     INPUT_LUT)
                    d = decode(self._run(x), self.peak_threshold, (m, m + t, m, m + int(n) * t), SMOOTH)
                    # image pixel = window origin (minus the margin) + position in the window
                    parts.append((d[1:], d[1] + rb[d[0], 1] * t - m, d[2] + rb[d[0], 0] * t - m))
        if sum(len(p[1]) for p in parts) == 0:
            return CnnPeaks.empty()
        xs = np.concatenate([p[1] for p in parts]).astype(np.float64)
        ys = np.concatenate([p[2] for p in parts]).astype(np.float64)
        raw = np.stack([np.concatenate([p[0][k] for p in parts]).astype(np.float64) for k in range(2, 9)], axis=1)
        keep = (xs < w) & (ys < h)
        if c.tile:  # tile by tile (row-major), then row-major inside a tile: the order does not depend on the runs
            t = int(c.tile)
            order = np.lexsort((xs, ys, xs // t, ys // t))
            keep = order[keep[order]]
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


def _factory(dataset=None, weights=None, config=None) -> CnnDetector:  # noqa: ANN001 - registry signature
    return CnnDetector(config.cnn if config is not None else None, weights)


register_detector("fast", _factory, "small CNN on gated tiles + learned refiner, onnxruntime on CPU (default); "
                  "weights: --weights or cnn.weights, else the shipped fast_cnn.onnx")
