"""Trajectory files: TUM (default) and KITTI, readable by evo unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.geometry import pose_to_tum, tum_to_pose
from seedmap.io.atomic import atomic_write_text
from seedmap.records import Trajectory


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """``timestamp tx ty tz qx qy qz qw`` per line."""
    rows = pose_to_tum(traj.poses) if len(traj) else np.zeros((0, 7))
    lines = [
        f"{t:.6f} " + " ".join(f"{v:.9f}" for v in r) for t, r in zip(traj.timestamps, rows, strict=True)
    ]
    atomic_write_text(Path(path), "\n".join(lines) + ("\n" if lines else ""))


def read_tum(path: str | Path) -> Trajectory:
    path = Path(path)
    if not path.is_file():
        raise InputError("trajectory file not found", path)
    rows = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(f"line {i}: TUM rows need 8 numbers (t tx ty tz qx qy qz qw), got {len(parts)}", path)
        try:
            rows.append([float(x) for x in parts])
        except ValueError:
            raise InputError(f"line {i}: not a number", path) from None
    a = np.asarray(rows, float).reshape(-1, 8)
    return Trajectory(a[:, 0], tum_to_pose(a[:, 1:]) if len(a) else np.zeros((0, 4, 4)))


def write_kitti(path: str | Path, traj: Trajectory) -> None:
    """12 numbers per line: the first 3 rows of ``T_world_cam``, row-major."""
    lines = [" ".join(f"{v:.9e}" for v in T[:3, :4].reshape(-1)) for T in traj.poses]
    atomic_write_text(Path(path), "\n".join(lines) + ("\n" if lines else ""))


def read_kitti(path: str | Path, timestamps: np.ndarray | None = None) -> Trajectory:
    path = Path(path)
    if not path.is_file():
        raise InputError("trajectory file not found", path)
    try:
        a = np.loadtxt(path, ndmin=2)
    except ValueError as e:
        raise InputError(f"not a KITTI pose file ({e})", path) from None
    if a.shape[1] != 12:
        raise InputError(f"KITTI rows need 12 numbers, got {a.shape[1]}", path)
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :4] = a.reshape(-1, 3, 4)
    ts = np.arange(len(a), dtype=float) if timestamps is None else np.asarray(timestamps, float)
    return Trajectory(ts, T)
