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


def pixel_motion(depth: np.ndarray, T_mid: np.ndarray, T_sub: np.ndarray, calib: StereoCalib
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel's 3D point (z-``depth`` (H, W), seen from ``T_mid``) projects in the camera at
    ``T_sub``: float32 maps ``(u, v)`` (H, W)."""
    H, W = depth.shape
    z = np.where(np.isfinite(depth), depth, FAR_DEPTH).astype(np.float64)
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    X = np.stack([(uu - calib.cx) / calib.fx * z, (vv - calib.cy) / calib.fy * z, z], -1)
    T = invert(T_sub) @ T_mid
    Y = X @ T[:3, :3].T + T[:3, 3]
    zs = np.maximum(Y[..., 2], 1e-3)
    return ((calib.fx * Y[..., 0] / zs + calib.cx).astype(np.float32),
            (calib.fy * Y[..., 1] / zs + calib.cy).astype(np.float32))


def blur_along_motion(lin: np.ndarray, depth: np.ndarray, T_mid: np.ndarray, subs: np.ndarray,
                      calib: StereoCalib) -> np.ndarray:
    """``lin`` (H, W, 3) float32 seen from ``T_mid``, averaged over the camera poses ``subs`` (K, 4, 4) of the
    exposure interval (a new array)."""
    import cv2

    H, W = depth.shape
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float32)
    acc = np.zeros_like(lin)
    for T in subs:
        u, v = pixel_motion(depth, T_mid, T, calib)
        # the point seen at (uu, vv) lands at (u, v): sample the sharp image back along that motion
        acc += cv2.remap(lin, 2 * uu - u, 2 * vv - v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    acc *= np.float32(1.0 / len(subs))
    return acc
