"""Trajectory files: TUM (default) and KITTI, readable by evo unchanged."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.geometry import pose_to_tum, tum_to_pose
from seedmap.io.atomic import atomic_write_text
from seedmap.records import Trajectory


def tum_line(t: float, row: np.ndarray) -> str:
    """One TUM line ``timestamp tx ty tz qx qy qz qw`` (``row``: :func:`pose_to_tum`'s 7 values; no newline)."""
    return f"{t:.6f} " + " ".join(f"{v:.9f}" for v in row)


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """``timestamp tx ty tz qx qy qz qw`` per line."""
    rows = pose_to_tum(traj.poses) if len(traj) else np.zeros((0, 7))
    lines = [tum_line(t, r) for t, r in zip(traj.timestamps, rows, strict=True)]
    atomic_write_text(Path(path), "\n".join(lines) + ("\n" if lines else ""))


def read_tum(path: str | Path) -> Trajectory:
    path = Path(path)
    if not path.is_file():
        raise InputError("trajectory file not found", path)
    rows = []
    try:
        text = path.read_text()
    except (UnicodeDecodeError, OSError):
        raise InputError("trajectory file is not text", path) from None
    for i, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(f"line {i}: TUM rows need 8 numbers (t tx ty tz qx qy qz qw), got {len(parts)}", path)
        try:
            row = [float(x) for x in parts]
        except ValueError:
            raise InputError(f"line {i}: not a number", path) from None
        if not np.all(np.isfinite(row)):
            raise InputError(f"line {i}: NaN or inf in a pose", path)
        if np.linalg.norm(row[4:8]) < 1e-12:
            raise InputError(f"line {i}: zero quaternion (qx qy qz qw must be a rotation)", path)
        rows.append(row)
    a = np.asarray(rows, float).reshape(-1, 8)
    return Trajectory(a[:, 0], tum_to_pose(a[:, 1:]) if len(a) else np.zeros((0, 4, 4)))


def gt_overlapping(timestamps: np.ndarray, gt: Trajectory | None, where: str | Path) -> Trajectory | None:
    """``gt``, or ``None`` with a warning when its pose times do not overlap the frame timestamps at all (another
    clock: every GT metric would be empty or wrong). Warnings go to the ``seedmap.io`` logger (the CLI prints
    them as ``warning:`` lines)."""
    t = np.asarray(timestamps, float).reshape(-1)
    if gt is None or not len(gt) or not len(t):
        return gt
    tol = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    g = np.asarray(gt.timestamps, float)
    if t.max() >= g.min() - tol and t.min() <= g.max() + tol:
        return gt
    import logging

    logging.getLogger("seedmap.io").warning(
        f"{where}: the frame timestamps (times.txt, {t.min():.3f}..{t.max():.3f} s) do not overlap the ground-truth "
        f"poses (gt/poses_tum.txt, {g.min():.3f}..{g.max():.3f} s): going on without GT metrics")
    return None


def write_kitti(path: str | Path, traj: Trajectory) -> None:
    """12 numbers per line: the first 3 rows of ``T_world_cam``, row-major."""
    lines = [" ".join(f"{v:.9e}" for v in T[:3, :4].reshape(-1)) for T in traj.poses]
    atomic_write_text(Path(path), "\n".join(lines) + ("\n" if lines else ""))


def read_kitti(path: str | Path, timestamps: np.ndarray | None = None) -> Trajectory:
    path = Path(path)
    if not path.is_file():
        raise InputError("trajectory file not found", path)
    try:
        empty = not path.read_text().strip()
    except (UnicodeDecodeError, OSError):
        raise InputError("trajectory file is not text", path) from None
    a = np.zeros((0, 12))
    if not empty:
        try:
            with warnings.catch_warnings():  # a file of comments only: no data, handled as empty below
                warnings.simplefilter("ignore", UserWarning)
                a = np.loadtxt(path, ndmin=2)
        except ValueError as e:
            raise InputError(f"not a KITTI pose file ({str(e).splitlines()[0][:100]})", path) from None
    if a.size == 0:
        if timestamps is not None and len(np.asarray(timestamps).reshape(-1)):
            raise InputError(f"KITTI pose file is empty but {len(np.asarray(timestamps).reshape(-1))} timestamps "
                             "were given", path)
        return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    if a.shape[1] != 12:
        raise InputError(f"KITTI rows need 12 numbers, got {a.shape[1]}", path)
    if not np.all(np.isfinite(a)):
        raise InputError("NaN or inf in a KITTI pose", path)
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :4] = a.reshape(-1, 3, 4)
    ts = np.arange(len(a), dtype=float) if timestamps is None else np.asarray(timestamps, float).reshape(-1)
    if len(ts) != len(a):
        raise InputError(f"{len(a)} poses but {len(ts)} timestamps", path)
    return Trajectory(ts, T)
