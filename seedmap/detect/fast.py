"""The ``fast`` detector: classical, vectorised OpenCV, real-time on a 2-core CPU.

Why classical: with flash imaging the seeds are the bright, compact, non-green blobs of the image
and have a known size (4–8 px at the default resolution), which is exactly what a scale-tuned
blob filter finds. It needs no training data and runs in a few tens of milliseconds per image.

Pipeline (all sizes scale with ``FastConfig.seed_px``):

1. *Seediness* image ``f``: a brightness channel with green (leaf) pixels suppressed,
   ``f = 0.5 R + 0.35 G + 0.15 B - k * max(G - R, 0)``.
2. Blob response: difference of Gaussians ``DoG = G(σ) * f - G(1.6 σ) * f`` with σ matched to
   the seed radius (≈ LoG at scale ``r / √2``).
3. Seeds = local maxima of the DoG (grey dilation over ``peak_sep * seed_px``) above
   ``min_response`` on pixels brighter than ``min_brightness``.
4. Touching seeds are split by a marker watershed (``cv2.watershed``) seeded at those maxima,
   restricted to the foreground (``f`` above a fraction of the local peak brightness); background
   pixels are pre-labelled so the flooding only touches the few seed pixels.
5. One ellipse per watershed region (vectorised second moments); keypoint = ellipse centre.
"""

from __future__ import annotations

import cv2
import numpy as np

from seedmap.detect.base import Detector, check_image, register_detector
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

    def detect(self, image: np.ndarray) -> Detections:
        img = check_image(image)
        c = self.cfg
        s = float(c.work_scale)
        if s != 1.0:
            img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        d = c.seed_px * s
        f = seediness(img, c.max_green_excess / 16.0 if c.max_green_excess > 0 else 0.0)
        sigma = max(d / (2.0 * np.sqrt(2.0)), 0.7)
        # uint8 blurs use OpenCV's fixed-point SIMD path; the DoG is formed in int16
        g1 = cv2.GaussianBlur(f, (0, 0), sigma * 0.6)
        dog = cv2.subtract(g1, cv2.GaussianBlur(f, (0, 0), sigma * 1.6), dtype=cv2.CV_16S)
        k = max(3, int(round(c.peak_sep * d)) | 1)
        kern = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
        dil = cv2.dilate(dog, kern)
        peaks = cv2.compare(dog, dil, cv2.CMP_GE)
        peaks &= cv2.compare(dog, float(c.min_response), cv2.CMP_GT)
        peaks &= cv2.compare(g1, float(c.min_brightness), cv2.CMP_GT)
        pts = cv2.findNonZero(peaks)
        if pts is None:
            return Detections()
        pts = pts.reshape(-1, 2)
        pu, pv = pts[:, 0], pts[:, 1]
        n = len(pu)
        # foreground: brighter than region_rel of the local peak level and above the background
        ref = cv2.dilate(g1, kern)
        fg = cv2.compare(f, cv2.max(cv2.multiply(ref, float(c.region_rel)), float(c.min_brightness) * 0.5),
                         cv2.CMP_GT)
        markers = cv2.bitwise_not(fg).view(np.int8).astype(np.int32) & 1
        markers[pv, pu] = np.arange(2, n + 2, dtype=np.int32)
        cv2.watershed(cv2.merge([g1, g1, g1]), markers)
        # watershed draws -1 lines on every boundary, including seed/background: give foreground
        # line pixels back to an adjacent seed region so masks (and boxes) keep their outer ring
        h, w = markers.shape
        lp = cv2.findNonZero(((markers == -1) & (fg > 0)).view(np.uint8))
        if lp is not None:
            lp = lp.reshape(-1, 2)
            lu, lv = lp[:, 0], lp[:, 1]
            best = np.zeros(len(lu), np.int32)
            for dv in (-1, 0, 1):
                for du in (-1, 0, 1):
                    best = np.maximum(best, markers[np.clip(lv + dv, 0, h - 1), np.clip(lu + du, 0, w - 1)])
            markers[lv, lu] = np.where(best > 1, best, -1)
        # moments of each region (labels 2..n+1), over the few foreground pixels only
        sp = cv2.findNonZero((markers > 1).view(np.uint8))
        sp = sp.reshape(-1, 2) if sp is not None else np.zeros((0, 2), np.int32)
        xs, ys = sp[:, 0], sp[:, 1]
        lab = markers[ys, xs] - 2
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
            reg = np.where(markers > 1, markers - 1, 0)
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
            # pixel-centre convention: u_full = (u_small + 0.5) / s - 0.5
            ell[:, :2] = (ell[:, :2] + 0.5) / s - 0.5
            ell[:, 2:4] /= s
            boxes = boxes / s
        return Detections(boxes=boxes, scores=score, ellipses=ell)


def _factory(dataset=None, weights=None, config=None) -> FastDetector:
    return FastDetector(config.fast if config is not None else None)


register_detector("fast", _factory, "classical OpenCV blob + watershed detector, real-time on CPU (default)")
