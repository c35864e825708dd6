"""The ``fast`` detector: classical, vectorised OpenCV + numpy, real-time on a 2-core CPU.

Since session 3 the name ``fast`` runs the small CNN of :mod:`seedmap.detect.cnn` when its shipped
weights exist (``fast.use_cnn``; held-out F1 at the detectable-seed size, session-4 weights: 0.871 / 0.888
vs 0.855 / 0.826 on seeds 2 / 21); this
classical pipeline stays available as ``fast-classic`` (and with ``fast.use_cnn=false``).

Why classical: with flash imaging the seeds are the bright, compact, non-green blobs of the image
and have a known size (4–8 px at the default resolution), which is exactly what a scale-tuned
blob filter finds. It needs no training data and runs in a few tens of milliseconds per image.

Pipeline (all sizes scale with ``FastConfig.seed_px``):

1. *Seediness* image ``f``: a brightness channel with green (leaf) pixels suppressed,
   ``f = 0.5 R + 0.35 G + 0.15 B - k * max(G - R, 0)``.
2. Blob response: difference of Gaussians ``DoG = G(a σ) * f - G(b σ) * f`` with σ = d / (2√2)
   matched to the seed diameter d (a LoG-like band-pass; a, b = ``dog_inner``, ``dog_outer``).
3. Candidate seeds = 3x3 local maxima of the DoG above ``min_response`` on pixels brighter than
   ``min_brightness``. Bright leaf and stalk edges give ridge-shaped DoG maxima (on the
   simulated range ~70 % of the false positives lay off any seed, most along leaf edges); SIFT's
   edge test on the 2x2 Hessian of the DoG at the peak (curvature ratio below ``edge_ratio``)
   drops them.
4. Touching seeds are separated by *steepest ascent* on the DoG (a watershed by drainage): every
   pixel with DoG > ``region_min`` within a seed diameter of a candidate points at its highest 3x3
   neighbour; following the pointers (pointer jumping, vectorised) ends at a local maximum, so
   each region is the basin of one seed, split along the dark rims between neighbouring seeds.
   (``cv2.watershed`` floods by colour gradient, which at 5 px scale splits seeds badly; measured.)
5. One ellipse per region (vectorised second moments, or cv2.fitEllipse); keypoint = its centre;
   box = the region's pixel bounds, inclusive-exclusive like the GT boxes (measured: boxes derived
   from the ellipse axes instead score lower, F1 0.636 vs 0.639 on det_s1).

The filter scale ``seed_px`` defaults to 3.5 px although whole seeds are ~5 px: half of the GT
instances are partly hidden seeds whose visible part is smaller, and a smaller scale finds them.
"""

from __future__ import annotations

import cv2
import numpy as np

from seedmap.detect.base import Detector, check_image, map_to_input, register_detector
from seedmap.detect.config import FastConfig
from seedmap.detect.ellipse import ellipse_from_moments, fit_ellipses_labels
from seedmap.records import Detections


def seediness(image: np.ndarray, green_k: float = 1.5) -> np.ndarray:
    """uint8 brightness with leaf-green suppressed (grey levels), in two saturating OpenCV passes."""
    f = cv2.transform(image, np.array([[0.5, 0.35, 0.15]], np.float32))
    if green_k > 0:
        ge = cv2.subtract(image[..., 1], image[..., 0])  # saturating uint8: max(G - R, 0)
        f = cv2.addWeighted(f, 1.0, ge, -float(green_k), 0.0)  # saturates at 0
    return f


class FastDetector(Detector):
    """Blob (DoG) peaks + marker watershed + moment ellipses; see the module docstring."""

    name = "fast"

    def __init__(self, config: FastConfig | None = None) -> None:
        self.cfg = config or FastConfig()
        self.refiner = None
        c = self.cfg
        if c.refine and c.work_scale == 1.0:
            from seedmap.detect.refine import Refiner, default_refiner_path

            # the shipped refiner is optional (absent: classical boxes); a named file must exist
            if c.refine_weights or default_refiner_path().is_file():
                self.refiner = Refiner.load(c.refine_weights or default_refiner_path())

    def detect(self, image: np.ndarray) -> Detections:
        """Seeds in one RGB image; with the learned refiner (``fast.refine``) its score and boxes."""
        d, f = self.detect_with_seediness(image)
        if self.refiner is not None:
            d = self.refiner.refine(f, d, self.cfg.refine_threshold)
        return d

    def detect_with_seediness(self, image: np.ndarray) -> tuple[Detections, np.ndarray]:
        """The classical candidates (no refinement) and the seediness image they came from."""
        img = check_image(image)
        c = self.cfg
        s = float(c.work_scale)
        if s != 1.0:
            img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        f = seediness(img, c.max_green_excess / 16.0 if c.max_green_excess > 0 else 0.0)
        return self._detect(f, s), f

    def _detect(self, f: np.ndarray, s: float) -> Detections:
        c = self.cfg
        d = c.seed_px * s
        sigma = max(d / (2.0 * np.sqrt(2.0)), 0.7)
        # uint8 blurs take OpenCV's fixed-point SIMD path (2-3x faster than float32)
        g1 = cv2.GaussianBlur(f, (0, 0), sigma * c.dog_inner)
        dog = cv2.subtract(g1, cv2.GaussianBlur(f, (0, 0), sigma * c.dog_outer), dtype=cv2.CV_16S)
        h, w = dog.shape
        # candidate seeds: local maxima of the DoG that are strong and bright enough
        peaks = cv2.compare(dog, cv2.dilate(dog, np.ones((3, 3), np.uint8)), cv2.CMP_GE)
        peaks &= cv2.compare(dog, float(c.min_response), cv2.CMP_GT)
        peaks &= cv2.compare(g1, float(c.min_brightness), cv2.CMP_GT)
        # support of the regions: band-pass response above region_min within a seed diameter of a
        # candidate (keeps the per-pixel work to the seeds, not the whole frame)
        r = max(1, int(np.ceil(d / 2 + 1)))
        near = cv2.dilate(peaks, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        fgp = cv2.findNonZero(near & cv2.compare(dog, float(c.region_min), cv2.CMP_GT))
        if fgp is None:
            return Detections()
        fgp = fgp.reshape(-1, 2)
        xs, ys = fgp[:, 0].astype(np.int64), fgp[:, 1].astype(np.int64)
        m = len(xs)
        # steepest ascent on the DoG: every support pixel points at its highest 3x3 neighbour
        # (itself first, so ties keep it); following the pointers to their roots gives the basins
        # of the blob response, i.e. one region per seed, split along the dark rims between seeds
        # integer DoG: break ties by brightness so plateaus still drain to one maximum
        # (flat indices into a 1-px padded copy: no clipping, one 1-D gather per neighbour)
        key = cv2.copyMakeBorder(dog.astype(np.int32) * 256 + g1, 1, 1, 1, 1, cv2.BORDER_CONSTANT,
                                 value=np.iinfo(np.int32).min).ravel()
        wp = w + 2
        base = (ys + 1) * wp + (xs + 1)
        offs = np.array([0] + [dy * wp + dx for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx], np.int64)
        best = np.argmax(np.stack([key[base + o] for o in offs]), axis=0)
        index = np.full(key.shape, -1, np.int32)
        index[base] = np.arange(m, dtype=np.int32)
        sel = np.arange(m)
        parent = index[base + offs[best]].astype(np.int64)
        parent = np.where(parent < 0, sel, parent)
        for _ in range(32):
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                break
            parent = nxt
        roots = np.flatnonzero(parent == np.arange(m))
        ok_root = (dog[ys[roots], xs[roots]] > c.min_response) & (g1[ys[roots], xs[roots]] > c.min_brightness)
        if c.edge_ratio > 0:
            ok_root &= _blob_like(dog, xs[roots], ys[roots], c.edge_ratio)
        roots = roots[ok_root]
        n = len(roots)
        if n == 0:
            return Detections()
        rid = np.full(m, -1, np.int64)
        rid[roots] = np.arange(n)
        lab = rid[parent]
        keep_px = lab >= 0
        lab, xs, ys = lab[keep_px], xs[keep_px], ys[keep_px]
        pu, pv = fgp[roots, 0], fgp[roots, 1]
        cnt = np.bincount(lab, minlength=n).astype(np.float64)
        ok = cnt >= max(1, c.min_area_px * s * s)
        if c.ellipse == "moments":
            x = xs.astype(np.float64)
            y = ys.astype(np.float64)
            # centre coordinates on each region's peak for conditioning
            x -= pu[lab]
            y -= pv[lab]
            ell = ellipse_from_moments(cnt, np.bincount(lab, x, n), np.bincount(lab, y, n),
                                       np.bincount(lab, x * x, n), np.bincount(lab, y * y, n),
                                       np.bincount(lab, x * y, n))
            ell[:, 0] += pu
            ell[:, 1] += pv
        else:
            reg = np.zeros((h, w), np.int32)
            reg[ys, xs] = lab + 1
            ell = fit_ellipses_labels(reg, np.arange(1, n + 1), "contour")
        # per-region pixel bounds: sort once by label, then reduce each run
        x0 = np.full(n, np.inf)
        y0 = np.full(n, np.inf)
        x1 = np.full(n, -np.inf)
        y1 = np.full(n, -np.inf)
        if len(lab):
            order = np.argsort(lab, kind="stable")
            ls = lab[order]
            starts = np.flatnonzero(np.r_[True, ls[1:] != ls[:-1]])
            ids = ls[starts]
            x0[ids] = np.minimum.reduceat(xs[order], starts)
            y0[ids] = np.minimum.reduceat(ys[order], starts)
            x1[ids] = np.maximum.reduceat(xs[order], starts) + 1
            y1[ids] = np.maximum.reduceat(ys[order], starts) + 1
        ok &= np.isfinite(ell).all(axis=1) & np.isfinite(x0)
        boxes = np.stack([x0, y0, x1, y1], axis=1)[ok]
        ell = ell[ok]
        score = np.clip(dog[pv, pu][ok].astype(np.float32) / (4.0 * c.min_response), 0.0, 1.0)
        if s != 1.0:
            boxes, ell = map_to_input(boxes, ell, s, s, s)
        return Detections(boxes=boxes, scores=score, ellipses=ell)


def _blob_like(dog: np.ndarray, x: np.ndarray, y: np.ndarray, ratio: float) -> np.ndarray:
    """True where the DoG peak at ``(x, y)`` is a blob, not a ridge along an edge.

    SIFT's edge test on the 2x2 Hessian of the response (finite differences at the peak): a bright
    leaf or stalk edge gives one large and one small curvature, a seed two similar ones. Keeps peaks
    with ``tr(H)^2 / det(H) < (r + 1)^2 / r`` and both curvatures negative (a maximum).
    """
    h, w = dog.shape
    xm, xp = np.clip(x - 1, 0, w - 1), np.clip(x + 1, 0, w - 1)
    ym, yp = np.clip(y - 1, 0, h - 1), np.clip(y + 1, 0, h - 1)
    d = dog.astype(np.float32)
    c = d[y, x]
    dxx = d[y, xp] + d[y, xm] - 2 * c
    dyy = d[yp, x] + d[ym, x] - 2 * c
    dxy = (d[yp, xp] - d[yp, xm] - d[ym, xp] + d[ym, xm]) / 4
    tr = dxx + dyy
    det = dxx * dyy - dxy * dxy
    return (det > 0) & (tr < 0) & (tr * tr * ratio < (ratio + 1) ** 2 * det)


def _classic_factory(dataset=None, weights=None, config=None) -> FastDetector:
    return FastDetector(config.fast if config is not None else None)


def fast_alias(config=None) -> str:
    """Which registered detector ``fast`` is with this config: ``fast-cnn`` or ``fast-classic``
    (so callers that run every detector, like ``seedmap benchmark``, do not run one twice)."""
    fc = config.fast if config is not None else FastConfig()
    if fc.use_cnn:
        from seedmap.detect.cnn import default_cnn_path

        cc = config.cnn if config is not None else None
        if (cc is not None and cc.weights) or default_cnn_path(cc.domain if cc is not None else "field").is_file():
            return "fast-cnn"
    return "fast-classic"


def _factory(dataset=None, weights=None, config=None) -> Detector:
    """``fast``: the small CNN (seedmap.detect.cnn) when ``fast.use_cnn`` and its weights exist, else classical."""
    fc = config.fast if config is not None else FastConfig()
    if fast_alias(config) == "fast-cnn":
        from seedmap.detect.cnn import CnnDetector

        return CnnDetector(config.cnn if config is not None else None, fc)
    return FastDetector(fc)


def _cnn_factory(dataset=None, weights=None, config=None) -> Detector:
    from seedmap.detect.cnn import CnnDetector

    return CnnDetector(config.cnn if config is not None else None, config.fast if config is not None else None,
                       weights)


register_detector("fast", _factory, "seed detector for CPU: the small CNN (fast-cnn) when its shipped weights "
                  "exist, else (or with fast.use_cnn=false) the classical one (fast-classic) (default)")
register_detector("fast-classic", _classic_factory,
                  "classical OpenCV blob + watershed detector + patch refiner (session 2), real-time on CPU")
register_detector("fast-cnn", _cnn_factory, "small CenterNet-style CNN on gated tiles (onnxruntime, CPU); "
                  "weights: --weights or cnn.weights, else the shipped fast_cnn.onnx")
