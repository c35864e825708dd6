"""Rigid-body helpers on 4x4 homogeneous matrices (the one place for SE(3) conversions)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def make_pose(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of one (4, 4) or a stack (N, 4, 4) of rigid transforms."""
    T = np.asarray(T, float)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    Ti[..., 3, 3] = 1.0
    return Ti


def transform_points(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points."""
    pts = np.asarray(pts, float).reshape(-1, 3)
    return pts @ T[:3, :3].T + T[:3, 3]


def pose_to_tum(T: np.ndarray) -> np.ndarray:
    """(4, 4) or (N, 4, 4) -> (N, 7) rows ``tx ty tz qx qy qz qw``."""
    T = np.asarray(T, float).reshape(-1, 4, 4)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x y z w
    return np.hstack([T[:, :3, 3], q])


def tum_to_pose(rows: np.ndarray) -> np.ndarray:
    """(N, 7) ``tx ty tz qx qy qz qw`` -> (N, 4, 4)."""
    rows = np.asarray(rows, float).reshape(-1, 7)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 3:7]).as_matrix()
    T[:, :3, 3] = rows[:, :3]
    return T


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angle (degrees) of one or many 3x3 rotation matrices."""
    R = np.asarray(R, float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))
