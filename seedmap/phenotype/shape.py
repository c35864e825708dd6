"""Geometry of one panicle's 3D points and the row frame the phenotype table is written in.

The row frame: x along the row (direction of travel), y across (towards the row for a camera looking along
+y, as in the simulator), z up with the ground at z = 0. Everything here is metres and degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.records import Trajectory

#: half-width (m) of the stretch of camera path whose mean height is the local camera height
GROUND_WINDOW_M = 0.25
#: the world counts as z-up (ground at z = 0, e.g. a run anchored to the simulator's poses) when the cameras'
#: mean up direction is within ~11 degrees of +z
UP_COS = 0.98


@dataclass
class RowFrame:
    """``p_row = axes @ (p_world - origin)``; ``height_source`` says where z = 0 (the ground) came from;
    ``cameras``: the camera positions and optical axes (N x 6) in the row frame."""

    axes: np.ndarray
    origin: np.ndarray
    height_source: str
    cameras: np.ndarray

    def to_row(self, xyz: np.ndarray) -> np.ndarray:
        return (np.asarray(xyz, float).reshape(-1, 3) - self.origin) @ self.axes.T

    def ground(self, x: float, y: float) -> float:
        """Ground height (row frame) under the point seen at ``(x, y)``: the camera rides at a constant height
        above the ground looking sideways, so the ground follows the height of the cameras' line of sight at
        depth ``y`` (mean over the cameras within GROUND_WINDOW_M along the row), and is 0 at the start.
        This also cancels the map's slow drift in height and pitch, which moves the cameras' lines of sight and
        the landmarks together."""
        c = self.cameras
        if len(c) == 0:
            return 0.0

        def sight(x0: float) -> float:
            near = np.abs(c[:, 0] - x0) <= GROUND_WINDOW_M
            if not near.any():
                near = np.abs(c[:, 0] - x0) == np.abs(c[:, 0] - x0).min()
            q = c[near]
            depth = (y - q[:, 1]) / np.maximum(q[:, 4], 1e-3)  # along the optical axis to the row
            return float(np.mean(q[:, 2] + depth * q[:, 5]))

        return sight(x) - sight(float(c[0, 0]))


def row_frame(traj: Trajectory, mount_height_m: float) -> RowFrame:
    """The row frame of a trajectory ``T_world_cam`` (OpenCV cameras: y down).

    A world whose z already points up (the cameras' mean up within ~11 degrees of +z) is taken as is
    (``height_source = "world"``: the ground is the world's z = 0). Otherwise x is the direction of travel,
    z the cameras' mean up, the origin the first camera's position ``mount_height_m`` above the ground
    (``"camera_mount"``); y = z x x, so y = 0 is the camera path. Heights are taken above
    :meth:`RowFrame.ground`."""
    if len(traj) == 0:
        return RowFrame(np.eye(3), np.zeros(3), "world", np.zeros((0, 6)))
    up = -traj.poses[:, :3, 1].mean(axis=0)
    up /= max(np.linalg.norm(up), 1e-12)
    if up[2] >= UP_COS:
        return RowFrame(np.eye(3), np.zeros(3), "world", np.c_[traj.positions, traj.poses[:, :3, 2]])
    pos = traj.positions
    travel = pos[-1] - pos[0]
    travel = travel - (travel @ up) * up
    if np.linalg.norm(travel) < 1e-6:  # a standing camera: its right axis
        travel = traj.poses[0, :3, 0] - (traj.poses[0, :3, 0] @ up) * up
    ex = travel / np.linalg.norm(travel)
    ey = np.cross(up, ex)
    axes, origin = np.stack([ex, ey, up]), pos[0] - mount_height_m * up
    return RowFrame(axes, origin, "camera_mount", np.c_[(pos - origin) @ axes.T, traj.poses[:, :3, 2] @ axes.T])


@dataclass
class Shape:
    """Centre (on the principal axis through the mean, half-way between the extreme points), principal axis (pointing up), extents along the axis (length) and across it in the view
    plane (width), tilt of the axis from vertical."""

    centre: np.ndarray
    axis: np.ndarray
    length_m: float
    width_m: float
    tilt_deg: float


def panicle_shape(xyz_row: np.ndarray) -> Shape:
    """The :class:`Shape` of points in the row frame. The width is measured along the direction perpendicular
    to the axis and to y (the viewing direction), the extent a side view sees whole."""
    p = np.asarray(xyz_row, float).reshape(-1, 3)
    c = p.mean(axis=0)
    q = p - c
    if len(p) < 3:
        return Shape(c, np.array([0.0, 0.0, 1.0]), float(np.ptp(q[:, 2])) if len(p) else 0.0, 0.0, 0.0)
    _, vecs = np.linalg.eigh(q.T @ q)
    axis = vecs[:, -1] * (1.0 if vecs[2, -1] >= 0 else -1.0)
    across = np.cross(axis, [0.0, 1.0, 0.0])
    if np.linalg.norm(across) < 1e-6:  # axis along the viewing direction
        across = np.array([1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    tilt = float(np.degrees(np.arccos(np.clip(axis[2], -1.0, 1.0))))
    t = q @ axis
    # the middle of the axial extent, not the mean: seeds are not spread evenly along the axis
    return Shape(c + 0.5 * (t.max() + t.min()) * axis, axis, float(np.ptp(t)), float(np.ptp(q @ across)), tilt)


def hull_volume(xyz: np.ndarray) -> float:
    """Convex-hull volume (m^3) of the points; 0 for flat or too few points."""
    from scipy.spatial import ConvexHull, QhullError

    if len(xyz) < 4:
        return 0.0
    try:
        return float(ConvexHull(np.asarray(xyz, float)).volume)
    except (QhullError, ValueError):
        return 0.0


def ellipsoid_volume(length_m: float, width_m: float) -> float:
    """Volume (m^3) of the spheroid with that length and a round cross-section of that width."""
    return float(np.pi * length_m * width_m ** 2 / 6.0)
