"""Motion blur of one camera's linear image from its motion over the exposure interval.

The image rendered at the middle of the exposure is warped to each sub-sample pose of the interval by the motion
of its pixels' 3D points (depth map; the world held still) and the warps are averaged: the streak of each pixel
follows its own motion (translation parallax, rotation, vibration), not one global direction. Plant motion
within the exposure is not blurred (docs/method/conditions.md).
"""

from __future__ import annotations

import numpy as np

from seedmap.geometry import invert
from seedmap.records import StereoCalib

#: depth (m) given to pixels that see nothing (they are black; any finite depth will do)
FAR_DEPTH = 5.0


def _camera_points(depth: np.ndarray, calib: StereoCalib) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame coordinates (three float32 (H, W) planes) of each pixel's point at z-``depth``."""
    H, W = depth.shape
    z = np.where(np.isfinite(depth), depth, np.float32(FAR_DEPTH)).astype(np.float32)
    x = ((np.arange(W, dtype=np.float32) - np.float32(calib.cx)) / np.float32(calib.fx))[None, :] * z
    y = ((np.arange(H, dtype=np.float32) - np.float32(calib.cy)) / np.float32(calib.fy))[:, None] * z
    return x, y, z


def _project(X: tuple[np.ndarray, np.ndarray, np.ndarray], T: np.ndarray, calib: StereoCalib
             ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (float32 (H, W) maps) of the points ``X`` moved by ``T`` (4, 4) into a camera frame."""
    R, t = T[:3, :3].astype(np.float32), T[:3, 3].astype(np.float32)
    Y = [R[i, 0] * X[0] + R[i, 1] * X[1] + R[i, 2] * X[2] + t[i] for i in range(3)]
    zs = np.maximum(Y[2], np.float32(1e-3))
    return (np.float32(calib.fx) * Y[0] / zs + np.float32(calib.cx),
            np.float32(calib.fy) * Y[1] / zs + np.float32(calib.cy))


def pixel_motion(depth: np.ndarray, T_mid: np.ndarray, T_sub: np.ndarray, calib: StereoCalib
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel's 3D point (z-``depth`` (H, W), seen from ``T_mid``) projects in the camera at
    ``T_sub``: float32 maps ``(u, v)`` (H, W)."""
    return _project(_camera_points(depth, calib), invert(T_sub) @ T_mid, calib)


def blur_along_motion(lin: np.ndarray, depth: np.ndarray, T_mid: np.ndarray, subs: np.ndarray,
                      calib: StereoCalib) -> np.ndarray:
    """``lin`` (H, W, 3) float32 seen from ``T_mid``, averaged over the camera poses ``subs`` (K, 4, 4) of the
    exposure interval (a new array)."""
    import cv2

    H, W = depth.shape
    uu = np.arange(W, dtype=np.float32)[None, :]
    vv = np.arange(H, dtype=np.float32)[:, None]
    X = _camera_points(depth, calib)
    acc = np.zeros_like(lin)
    for T in subs:
        u, v = _project(X, invert(T) @ T_mid, calib)
        # the point seen at (uu, vv) lands at (u, v): sample the sharp image back along that motion
        u = 2 * uu - u
        v = 2 * vv - v
        acc += cv2.remap(lin, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    acc *= np.float32(1.0 / len(subs))
    return acc
