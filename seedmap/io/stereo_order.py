"""Swapped stereo folders: detected on one rectified pair from the sign of the disparities of matched points.

In a rectified pair a point sits further right in the left image than in the right one (disparity
``u_left - u_right > 0``). When ``left/`` and ``right/`` are exchanged most matched points have a negative
disparity; without this check such a dataset ended as "too few verified 3D matches" with no hint why.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from seedmap.errors import InputError

#: width (px) the pair is reduced to for the check (ORB on a small image: a few ms)
CHECK_WIDTH = 640
#: matched points needed (with a clear disparity sign) before the check says anything
MIN_POINTS = 15
#: fraction of negative disparities that means "swapped" (mismatches split about evenly)
SWAPPED_FRACTION = 0.8


def negative_disparity_fraction(left: np.ndarray, right: np.ndarray) -> tuple[float, int]:
    """``(fraction of negative disparities, points counted)`` of ORB matches on the same row (|dy| <= 1.5 px
    at the reduced size, |disparity| > 0.5 px)."""
    def gray(img: np.ndarray) -> np.ndarray:
        g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
        s = min(1.0, CHECK_WIDTH / g.shape[1])
        return cv2.resize(g, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1.0 else g

    gl, gr = gray(left), gray(right)
    orb = cv2.ORB_create(nfeatures=1000, fastThreshold=10)
    kl, dl = orb.detectAndCompute(gl, None)
    kr, dr = orb.detectAndCompute(gr, None)
    if dl is None or dr is None or len(kl) < MIN_POINTS or len(kr) < MIN_POINTS:
        return 0.0, 0
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    d = np.array([kl[m.queryIdx].pt[0] - kr[m.trainIdx].pt[0] for m in matches
                  if abs(kl[m.queryIdx].pt[1] - kr[m.trainIdx].pt[1]) <= 1.5])
    d = d[np.abs(d) > 0.5] if len(d) else d
    if len(d) == 0:
        return 0.0, 0
    return float(np.mean(d < 0)), int(len(d))


def check_stereo_order(left: np.ndarray, right: np.ndarray, where: str | Path) -> None:
    """One-line error when the pair looks swapped (most matched points have a negative disparity)."""
    frac, n = negative_disparity_fraction(left, right)
    if n >= MIN_POINTS and frac >= SWAPPED_FRACTION:
        raise InputError(f"the left and right images look swapped: {100 * frac:.0f} % of {n} points matched in the "
                         "first pair lie further left in the left image than in the right one (negative "
                         "disparity); exchange the left/ and right/ folders (or the camera topics/calibration)",
                         where)
