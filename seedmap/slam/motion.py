"""Frame-to-frame motion from matched 3D seeds: RANSAC over minimal Kabsch (Umeyama, no scale) fits.

Why: temporal seed matches still contain a few wrong associations; a minimal-sample RANSAC with
the inlier test done in the *image* (stereo reprojection error) treats near and far seeds fairly,
unlike a 3D distance threshold (stereo depth error grows with depth squared).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.records import StereoCalib


def kabsch(src: np.ndarray, dst: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid ``(R, t)`` with ``dst ≈ R @ src + t``; batched over leading axes.

    ``src``/``dst`` (..., N, 3). Reflections are corrected (det R = +1).
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    if w is None:
        cs, cd = src.mean(-2, keepdims=True), dst.mean(-2, keepdims=True)
        H = np.swapaxes(src - cs, -1, -2) @ (dst - cd)
    else:
        w = np.asarray(w, float)[..., None]
        ws = w.sum(-2, keepdims=True)
        cs, cd = (w * src).sum(-2, keepdims=True) / ws, (w * dst).sum(-2, keepdims=True) / ws
        H = np.swapaxes(w * (src - cs), -1, -2) @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(d == 0, 1.0, d)
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cd[..., 0, :] - np.einsum("...ij,...j->...i", R, cs[..., 0, :])
    return R, t


@dataclass
class MotionEstimate:
    """``T_prev_cur`` (4x4) maps points of the current camera frame into the previous one."""

    T_prev_cur: np.ndarray
    inliers: np.ndarray  # (K,) bool over the input pairs
    rms_px: float


def stereo_reproj_error(calib: StereoCalib, pts_cam: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Max of |Δu_left|, |Δu_right|, |Δv| (px) of ``(..., K, 3)`` points vs obs rows ``(uL, uR, v)``."""
    p = np.asarray(pts_cam, float)
    z = p[..., 2]
    zs = np.where(z > 1e-6, z, np.nan)
    ul = calib.fx * p[..., 0] / zs + calib.cx
    v = calib.fy * p[..., 1] / zs + calib.cy
    ur = ul - calib.fx * calib.baseline / zs
    e = np.stack([np.abs(ul - obs[..., 0]), np.abs(ur - obs[..., 1]), np.abs(v - obs[..., 2])], -1).max(-1)
    return np.where(np.isfinite(e), e, np.inf)


def _translation_inliers(calib: StereoCalib, pp: np.ndarray, t: np.ndarray, obs: np.ndarray,
                         thresh_px: float) -> np.ndarray:
    """``(H, K)`` bool: ``stereo_reproj_error(calib, pp - t[h], obs) < thresh_px`` for every
    translation hypothesis ``t`` (H, 3), bit for bit, without the ``(H, K, 3)`` temporaries: the
    same floating-point expressions per coordinate, each axis's test applied in place (NaN, i.e.
    a point behind the camera, fails every test as the infinite error does)."""
    z = pp[None, :, 2] - t[:, 2:3]
    zs = np.where(z > 1e-6, z, np.nan)
    x = pp[None, :, 0] - t[:, 0:1]
    x *= calib.fx
    x /= zs
    x += calib.cx  # u_left
    e = np.abs(x - obs[None, :, 0])
    ok = e < thresh_px
    x -= calib.fx * calib.baseline / zs  # u_right
    np.subtract(x, obs[None, :, 1], out=e)
    ok &= np.abs(e, out=e) < thresh_px
    y = pp[None, :, 1] - t[:, 1:2]
    y *= calib.fy
    y /= zs
    y += calib.cy
    y -= obs[None, :, 2]
    ok &= np.abs(y, out=y) < thresh_px
    return ok


def ransac_motion(
    calib: StereoCalib,
    pts_prev: np.ndarray,
    pts_cur: np.ndarray,
    obs_cur: np.ndarray,
    rng: np.random.Generator,
    iters: int = 300,
    thresh_px: float = 3.0,
    refine_iters: int = 3,
) -> MotionEstimate | None:
    """Robust ``T_prev_cur`` from K >= 3 matched 3D points (prev and current camera frames).

    The inlier test projects the previous-frame points into the current stereo pair and compares
    with the current measurements ``obs_cur`` (K, 3) = (uL, uR, v). Returns None when K < 3.
    """
    pp = np.asarray(pts_prev, float).reshape(-1, 3)
    pc = np.asarray(pts_cur, float).reshape(-1, 3)
    k = len(pp)
    if k < 3:
        return None
    # hypotheses from random triples (vectorised)
    idx = np.stack([rng.choice(k, 3, replace=False) for _ in range(iters)]) if k > 3 else np.arange(3)[None]
    R, t = kabsch(pc[idx], pp[idx])  # prev = R cur + t
    # prev -> cur: x_cur = R^T (x_prev - t)
    q = np.einsum("hji,hkj->hki", R, pp[None] - t[:, None, :])
    err = stereo_reproj_error(calib, q, obs_cur[None])
    inl = err < thresh_px
    best = int(np.argmax(inl.sum(1)))
    mask = inl[best]
    Rb, tb = R[best], t[best]
    for _ in range(refine_iters):
        if mask.sum() < 3:
            break
        Rb, tb = kabsch(pc[mask], pp[mask])
        e = stereo_reproj_error(calib, (pp - tb) @ Rb, obs_cur)
        new = e < thresh_px
        if np.array_equal(new, mask):
            break
        mask = new
    e = stereo_reproj_error(calib, (pp - tb) @ Rb, obs_cur)
    T = np.eye(4)
    T[:3, :3] = Rb
    T[:3, 3] = tb
    rms = float(np.sqrt(np.mean(e[mask] ** 2))) if mask.any() else float("inf")
    return MotionEstimate(T, mask, rms)


def ransac_translation(
    calib: StereoCalib,
    pts_prev: np.ndarray,
    pts_cur: np.ndarray,
    obs_cur: np.ndarray,
    rng: np.random.Generator,
    iters: int = 100,
    thresh_px: float = 3.0,
    refine_iters: int = 3,
) -> MotionEstimate | None:
    """Robust translation-only ``T_prev_cur`` (rotation = identity) from K >= 1 matched 3D points.

    Why: a side-looking camera travelling along a row sees seeds in a shallow depth band, where a
    sideways translation and a yaw (or a vertical translation and a pitch) move the image almost
    identically; a full 6-DoF fit between two frames then trades one for the other under small
    non-rigid motion (wind sway of ~1 mm per frame gives ~1 degree rotation errors on the
    simulated ranges). Between consecutive frames the rotation is tiny (horizontal travel, the
    paper's prior), so the front-end estimates a 1-point-RANSAC translation (refined as the
    median over inliers) and leaves the small rotation to the factor graph, where the
    between-factor carries it as a prior with ``between_sigma_rot_rad``.
    """
    pp = np.asarray(pts_prev, float).reshape(-1, 3)
    pc = np.asarray(pts_cur, float).reshape(-1, 3)
    k = len(pp)
    if k < 1:
        return None
    idx = rng.choice(k, size=min(iters, k), replace=False)
    t = pp[idx] - pc[idx]  # hypotheses (H, 3): prev = cur + t
    inl = _translation_inliers(calib, pp, t, np.asarray(obs_cur, float).reshape(-1, 3), thresh_px)
    best = int(np.argmax(inl.sum(1)))
    mask = inl[best]
    tb = t[best]
    for _ in range(refine_iters):
        if not mask.any():
            break
        tb = np.median(pp[mask] - pc[mask], axis=0)
        new = stereo_reproj_error(calib, pp - tb, obs_cur) < thresh_px
        if np.array_equal(new, mask):
            break
        mask = new
    e = stereo_reproj_error(calib, pp - tb, obs_cur)
    T = np.eye(4)
    T[:3, 3] = tb
    rms = float(np.sqrt(np.mean(e[mask] ** 2))) if mask.any() else float("inf")
    return MotionEstimate(T, mask, rms)
