"""Per view: SGBM disparity, a coloured point cloud, and 3D seed centres from detections."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from seedmap.recon.config import CloudConfig, SeedCentreConfig, SgbmConfig
from seedmap.records import Detections, StereoCalib
from seedmap.stereo import sgbm_disparity


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


def disparity_range(calib: StereoCalib, cloud: CloudConfig, sgbm: SgbmConfig, scale: float) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering the configured depth range at ``scale``."""
    if sgbm.min_disparity is not None and sgbm.num_disparities is not None:
        return int(sgbm.min_disparity * scale), max(16, int(np.ceil(sgbm.num_disparities * scale / 16)) * 16)
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
    lo, n = disparity_range(calib, cloud, sgbm, s)
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
    disp = sgbm_disparity(L, R, lo, n, sgbm.block_size, sgbm.uniqueness_ratio, sgbm.disp12_max_diff,
                          p1_factor=sgbm.p1_factor, p2_factor=sgbm.p2_factor,
                          speckle_window=sgbm.speckle_window_size, speckle_range=sgbm.speckle_range,
                          mode=sgbm.mode, grey=False, pad_left=False)
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
    step = cfg.pixel_step
    d = disp[::step, ::step]
    xyz = cv2.reprojectImageTo3D(np.nan_to_num(d, nan=-1.0).astype(np.float32), _scaled_Q(calib, step))
    lit = rgb[::step, ::step].max(axis=2) > cfg.min_intensity
    ok = np.isfinite(d) & (d > 0) & lit & (xyz[..., 2] >= cfg.min_depth) & (xyz[..., 2] <= cfg.max_depth)
    pts = xyz[ok].astype(np.float64)
    cols = rgb[::step, ::step][ok]
    lab = det_labels[::step, ::step][ok].astype(np.int64) if det_labels is not None else np.full(len(pts), -1)
    return ViewCloud(pts, cols, lab)


def _scaled_Q(calib: StereoCalib, step: int) -> np.ndarray:
    """Q for a disparity image sub-sampled by ``step`` (pixel coordinates scaled, disparity unchanged)."""
    Q = calib.Q.copy()
    Q[0, 3] = -calib.cx / step
    Q[1, 3] = -calib.cy / step
    Q[2, 3] = calib.fx / step
    return Q


def match_keypoints(uv_left: np.ndarray, prior: np.ndarray, right: Detections, cfg: SeedCentreConfig) -> np.ndarray:
    """Disparity from left/right keypoint pairs: for each left keypoint with an SGBM prior
    disparity, the right keypoint on the same row (|dv| <= match_dv_px) whose disparity is closest to
    the prior (within match_dd_px); mutual-nearest only. NaN where no unambiguous match exists."""
    from scipy.spatial import cKDTree

    out = np.full(len(uv_left), np.nan)
    if len(right) == 0 or len(uv_left) == 0:
        return out
    ok = np.isfinite(prior)
    # predicted right position (u - d, v); nearest right keypoint in a metric that weighs rows
    scale = cfg.match_dd_px / cfg.match_dv_px
    pred = np.column_stack([uv_left[:, 0] - np.nan_to_num(prior), uv_left[:, 1] * scale])
    kr = right.keypoints
    tree = cKDTree(np.column_stack([kr[:, 0], kr[:, 1] * scale]))
    dist, j = tree.query(pred[ok], distance_upper_bound=cfg.match_dd_px)
    idx = np.flatnonzero(ok)
    found = np.isfinite(dist)
    idx, j = idx[found], j[found]
    # mutual: each right keypoint used by its closest left prediction only
    best = {}
    for i, jj, dd in zip(idx, j, dist[found], strict=True):
        if jj not in best or dd < best[jj][1]:
            best[jj] = (i, dd)
    for jj, (i, _) in best.items():
        if abs(kr[jj, 1] - uv_left[i, 1]) <= cfg.match_dv_px:
            out[i] = uv_left[i, 0] - kr[jj, 0]
    return out


def seed_centres(disp: np.ndarray, det: Detections, calib: StereoCalib, cfg: SeedCentreConfig,
                 cloud: CloudConfig, right: Detections | None = None) -> SeedObservations:
    """3D centre of each detected seed: median valid disparity inside the (shrunk) ellipse at the
    ellipse centre (``method = keypoints``: refined by the matching right keypoint), triangulated;
    optionally pushed back along the ray by the seed radius (the disparity measures the visible
    front surface, the centre lies ~one radius deeper)."""
    lab = detection_label_image(disp.shape, det, cfg.shrink)
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
        if b > a and good[k] >= cfg.min_valid_fraction * max(total[k], 1):
            med[k] = np.median(sorted_d[a:b])
    if cfg.method == "keypoints" and right is not None:
        kd = match_keypoints(det.keypoints, med, right, cfg)
        med = kd  # seeds without an unambiguous right match are dropped: their SGBM depth is unreliable
    keep = np.isfinite(med) & (med > 0)
    uv = det.keypoints[keep]
    xyz = calib.triangulate(uv, uv[:, 0] - med[keep])
    z = xyz[:, 2]
    # ellipse full axes (px) -> diameter (m) at that depth
    diam = 0.5 * (det.ellipses[keep, 2] + det.ellipses[keep, 3]) * z / calib.fx
    surf = xyz.copy()
    if cfg.surface_to_centre and len(xyz):
        rays = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        xyz = xyz + rays * (0.5 * diam)[:, None]
    inrange = (xyz[:, 2] >= cloud.min_depth) & (xyz[:, 2] <= cloud.max_depth) if len(xyz) else np.zeros(0, bool)
    dets = np.flatnonzero(keep)
    return SeedObservations(xyz[inrange], diam[inrange], dets[inrange], det.seed_ids[dets[inrange]], surf[inrange])
