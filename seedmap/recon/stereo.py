"""Per view: SGBM disparity, a coloured point cloud, and 3D seed centres from detections."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from seedmap.recon.config import CloudConfig, SgbmConfig
from seedmap.records import Detections, StereoCalib
from seedmap.stereo import sgbm_disparity

#: SGBM smoothness penalties P1 / P2 = factor * channels * block_size^2
SGBM_P1_FACTOR, SGBM_P2_FACTOR = 8, 32
#: SGBM speckle filter: window (px) and disparity range within a speckle (px)
SGBM_SPECKLE_WINDOW, SGBM_SPECKLE_RANGE = 100, 2
#: SGBM left-right consistency tolerance (px)
SGBM_DISP12_MAX_DIFF = 1
#: OpenCV SGBM mode (3-way dynamic programming)
SGBM_MODE = "3way"
#: a seed centre needs this share of valid-disparity pixels in its (shrunk) ellipse
SEED_MIN_VALID_FRACTION = 0.2
#: the seed's disparity is the median over the central part of its ellipse (axis scale)
SEED_ELLIPSE_SHRINK = 0.7


@dataclass
class ViewCloud:
    """Points of one view in the LEFT camera frame (m), RGB colours (uint8) and per-point
    detection index (-1 = not inside a detected seed ellipse)."""

    xyz: np.ndarray  # (N, 3) float64
    rgb: np.ndarray  # (N, 3) uint8
    det: np.ndarray  # (N,) int64

    def __len__(self) -> int:
        return len(self.xyz)


@dataclass
class SeedObservations:
    """3D seed centres of one view in the LEFT camera frame: one row per detection that had enough
    valid disparity. ``det`` indexes the view's detections; ``diameter`` is the seed size (m)."""

    xyz: np.ndarray  # (M, 3) seed centres (pushed back by the radius when configured)
    diameter: np.ndarray  # (M,)
    det: np.ndarray  # (M,) int64
    seed_id: np.ndarray  # (M,) GT id from an oracle detector, -1 otherwise
    surface_xyz: np.ndarray | None = None  # (M, 3) the measured visible-surface points (registration)

    def __len__(self) -> int:
        return len(self.xyz)


def disparity_range(calib: StereoCalib, cloud: CloudConfig, scale: float) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering the configured depth range at ``scale``."""
    dmax = calib.fx * scale * calib.baseline / cloud.min_depth
    dmin = calib.fx * scale * calib.baseline / cloud.max_depth
    lo = int(np.floor(dmin)) - 2
    n = int(np.ceil((dmax - lo + 2) / 16.0)) * 16
    return max(lo, 0), max(n, 16)


def compute_disparity(left: np.ndarray, right: np.ndarray, calib: StereoCalib, sgbm: SgbmConfig,
                      cloud: CloudConfig) -> np.ndarray:
    """OpenCV StereoSGBM on a rectified RGB pair -> float32 disparity (px, full resolution), NaN
    where invalid. With ``sgbm.downscale < 1`` the pair is matched smaller and upsampled (speed)."""
    s = float(sgbm.downscale)
    if s < 1.0:
        size = (int(round(left.shape[1] * s)), int(round(left.shape[0] * s)))
        L = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
        R = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
    else:
        L, R = left, right
    lo, n = disparity_range(calib, cloud, s)
    H, W = L.shape[:2]
    r0, r1, c0, c1 = 0, H, 0, W
    if sgbm.crop_to_lit:
        lit = L.max(axis=2) > cloud.min_intensity
        rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
        if len(rows) == 0:
            return np.full(left.shape[:2], np.nan, np.float32)
        pad = 2 * sgbm.block_size + 2
        r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, H)
        # identical crops keep disparities; the left margin holds the disparity search range
        c0, c1 = max(cols[0] - pad - lo - n, 0), min(cols[-1] + pad + 1, W)
        L, R = L[r0:r1, c0:c1], R[r0:r1, c0:c1]
    disp = sgbm_disparity(L, R, lo, n, sgbm.block_size, sgbm.uniqueness_ratio, SGBM_DISP12_MAX_DIFF,
                          p1_factor=SGBM_P1_FACTOR, p2_factor=SGBM_P2_FACTOR,
                          speckle_window=SGBM_SPECKLE_WINDOW, speckle_range=SGBM_SPECKLE_RANGE,
                          mode=SGBM_MODE, grey=False, pad_left=False)
    if (r0, r1, c0, c1) != (0, H, 0, W):
        full = np.full((H, W), np.nan, np.float32)
        full[r0:r1, c0:c1] = disp
        disp = full
    if s < 1.0:
        disp = cv2.resize(disp, (left.shape[1], left.shape[0]), interpolation=cv2.INTER_NEAREST) / s
    return disp


def detection_label_image(shape: tuple[int, int], det: Detections, shrink: float = 1.0) -> np.ndarray:
    """int32 image of detection indices (-1 = none) from the detections' ellipses (axes * shrink)."""
    lab = np.full(shape, -1, np.int32)
    for k, (cx, cy, ma, mi, ang) in enumerate(det.ellipses):
        axes = (max(int(round(ma * shrink / 2)), 1), max(int(round(mi * shrink / 2)), 1))
        cv2.ellipse(lab, (int(round(cx)), int(round(cy))), axes, float(ang), 0, 360, int(k), -1)
    return lab


def disparity_to_cloud(disp: np.ndarray, rgb: np.ndarray, calib: StereoCalib, cfg: CloudConfig,
                       det_labels: np.ndarray | None = None) -> ViewCloud:
    """Valid disparities -> points (left camera frame, m) within [min_depth, max_depth] (uses
    ``cv2.reprojectImageTo3D`` with the calibration's Q)."""
    xyz = cv2.reprojectImageTo3D(np.nan_to_num(disp, nan=-1.0).astype(np.float32), _reprojection_Q(calib))
    lit = rgb.max(axis=2) > cfg.min_intensity
    ok = np.isfinite(disp) & (disp > 0) & lit & (xyz[..., 2] >= cfg.min_depth) & (xyz[..., 2] <= cfg.max_depth)
    pts = xyz[ok].astype(np.float64)
    cols = rgb[ok]
    lab = det_labels[ok].astype(np.int64) if det_labels is not None else np.full(len(pts), -1)
    return ViewCloud(pts, cols, lab)


def _reprojection_Q(calib: StereoCalib) -> np.ndarray:
    """The disparity-to-depth matrix Q of ``cv2.reprojectImageTo3D`` for the rectified left camera."""
    Q = calib.Q.copy()
    Q[0, 3] = -calib.cx
    Q[1, 3] = -calib.cy
    Q[2, 3] = calib.fx
    return Q


def seed_centres(disp: np.ndarray, det: Detections, calib: StereoCalib, cloud: CloudConfig) -> SeedObservations:
    """3D centre of each detected seed: median valid disparity inside the (shrunk) ellipse at the
    ellipse centre, triangulated and pushed back along the ray by the seed radius (the disparity
    measures the visible front surface, the centre lies ~one radius deeper)."""
    lab = detection_label_image(disp.shape, det, SEED_ELLIPSE_SHRINK)
    valid = np.isfinite(disp)
    flat_lab = lab.reshape(-1)
    inside = flat_lab >= 0
    idx = flat_lab[inside]
    dvals = disp.reshape(-1)[inside]
    vmask = valid.reshape(-1)[inside]
    n = len(det)
    total = np.bincount(idx, minlength=n)
    good = np.bincount(idx[vmask], minlength=n)
    med = np.full(n, np.nan)
    order = np.argsort(idx[vmask], kind="stable")
    sorted_idx = idx[vmask][order]
    sorted_d = dvals[vmask][order]
    bounds = np.searchsorted(sorted_idx, np.arange(n + 1))
    for k in range(n):
        a, b = bounds[k], bounds[k + 1]
        if b > a and good[k] >= SEED_MIN_VALID_FRACTION * max(total[k], 1):
            med[k] = np.median(sorted_d[a:b])
    keep = np.isfinite(med) & (med > 0)
    uv = det.keypoints[keep]
    xyz = calib.triangulate(uv, uv[:, 0] - med[keep])
    z = xyz[:, 2]
    # ellipse full axes (px) -> diameter (m) at that depth
    diam = 0.5 * (det.ellipses[keep, 2] + det.ellipses[keep, 3]) * z / calib.fx
    surf = xyz.copy()
    if len(xyz):
        rays = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        xyz = xyz + rays * (0.5 * diam)[:, None]
    inrange = (xyz[:, 2] >= cloud.min_depth) & (xyz[:, 2] <= cloud.max_depth) if len(xyz) else np.zeros(0, bool)
    dets = np.flatnonzero(keep)
    return SeedObservations(xyz[inrange], diam[inrange], dets[inrange], det.seed_ids[dets[inrange]], surf[inrange])
