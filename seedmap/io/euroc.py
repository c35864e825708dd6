"""EuRoC MAV (ASL) layout: ``mav0/cam0`` + ``mav0/cam1`` with ``data.csv``, ``data/*.png`` and ``sensor.yaml``.

The cameras are *unrectified* (radial-tangential distortion, slightly rotated): the rectification is built
once with ``cv2.stereoRectify`` from the two ``sensor.yaml`` (``T_BS``: body <- camera) and every image is
remapped; :attr:`calib` is the rectified calibration. EuRoC images are 8-bit **grayscale**; the loader
replicates them to 3-channel RGB so every seedmap module gets the same image type (there is no colour
information - seed detectors trained on colour will do poorly on them).

Pairs are matched by nanosecond stamp (nearest within ``sync_tol_s``; unmatched images are dropped and
counted in :attr:`warnings`). Ground truth, when ``mav0/state_groundtruth_estimate0/data.csv`` exists, is
converted from the body (IMU) frame to the **rectified left camera optical frame**:
``T_world_camrect = T_world_body @ T_body_cam0 @ R1^T`` and interpolated (SLERP) at the frame stamps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.calib_formats import _arr
from seedmap.io.calibration import (parse_euroc_pair, read_yaml_any, rectified_rotation,
                                    warn_implausible_baseline)
from seedmap.io.common import LoaderWarnings, RectifiedPairs
from seedmap.io.registry import construct, register_loader
from seedmap.io.sync import match_stamps
from seedmap.io.timestamps import check_timestamps
from seedmap.records import Trajectory


def read_euroc_csv(path: Path, min_cols: int = 2) -> list[list[str]]:
    """Rows of a EuRoC csv (``#`` header skipped), each split on commas."""
    path = Path(path)
    if not path.is_file():
        raise InputError("data.csv not found", path)
    try:
        lines = path.read_text().splitlines()
    except (UnicodeDecodeError, OSError):
        raise InputError("not a text csv file", path) from None
    rows = []
    for i, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = [x.strip() for x in s.split(",")]
        if len(parts) < min_cols:
            raise InputError(f"line {i}: expected at least {min_cols} comma-separated columns", path)
        rows.append(parts)
    return rows


def _camera_table(cam_dir: Path) -> tuple[np.ndarray, list[Path]]:
    csv = cam_dir / "data.csv"
    rows = read_euroc_csv(csv)
    if not rows:
        raise InputError("lists no images", csv)
    try:
        stamps = np.array([int(r[0]) for r in rows], dtype=np.int64)
    except ValueError:
        raise InputError("first column must be integer nanosecond timestamps", csv) from None
    check_timestamps(stamps.astype(np.float64), csv)
    files = [cam_dir / "data" / r[1] for r in rows]
    return stamps, files


class EurocSequence(RectifiedPairs):
    """One EuRoC sequence (the folder holding ``mav0/``, or ``mav0/`` itself)."""

    name = "euroc"

    def __init__(self, root: str | Path, sync_tol_s: float = 0.002, rectify_alpha: float = 0.0) -> None:
        root = Path(root)
        self.mav0 = root / "mav0" if (root / "mav0").is_dir() else root
        self.root = root
        self.warnings: list[str] = LoaderWarnings(root)
        c0, c1 = self.mav0 / "cam0", self.mav0 / "cam1"
        for c in (c0, c1):
            if not c.is_dir():
                raise InputError("camera folder not found (EuRoC needs mav0/cam0 and mav0/cam1)", c)
        s0, f0 = _camera_table(c0)
        s1, f1 = _camera_table(c1)
        il, ir, dropped = match_stamps(s0.astype(np.float64) * 1e-9, s1.astype(np.float64) * 1e-9, sync_tol_s)
        if len(il) == 0:
            raise InputError(f"no cam0/cam1 images share a timestamp within {sync_tol_s * 1e3:g} ms "
                             "(are cam0 and cam1 from the same recording?)", self.mav0)
        if dropped:
            self.warnings.append(f"{dropped} images without a stereo partner within {sync_tol_s * 1e3:g} ms dropped")
        self._pairs = [(f0[i], f1[j]) for i, j in zip(il, ir, strict=True)]
        self.stamps_ns = s0[il]
        self.timestamps = self.stamps_ns.astype(np.float64) * 1e-9
        lp, rp = c0 / "sensor.yaml", c1 / "sensor.yaml"
        rig, self.T_body_cam0 = parse_euroc_pair(read_yaml_any(lp), read_yaml_any(rp), lp, rp)
        warn_implausible_baseline(rig, f"{lp} + {rp.parent.name}/{rp.name}")
        self._setup_rectification(rig, rectify_alpha)
        self._alpha = rectify_alpha

    @staticmethod
    def is_dataset(path: Path) -> bool:
        p = Path(path)
        m = p / "mav0" if (p / "mav0").is_dir() else p
        return (m / "cam0" / "data.csv").is_file() and (m / "cam1").is_dir()

    def T_body_camrect(self) -> np.ndarray:
        """Body (IMU) <- rectified left camera, 4x4."""
        R1 = rectified_rotation(self.rig, self._alpha)
        T = np.eye(4)
        T[:3, :3] = R1.T
        return self.T_body_cam0 @ T

    def gt_trajectory(self) -> Trajectory | None:
        """Rectified-left-camera poses at the frame stamps inside the ground-truth time span, or ``None``."""
        from scipy.spatial.transform import Rotation, Slerp

        gt_dir = self.mav0 / "state_groundtruth_estimate0"
        csv = gt_dir / "data.csv"
        if not csv.is_file():
            return None
        rows = read_euroc_csv(csv, min_cols=8)
        try:
            a = np.array([[float(x) for x in r[:8]] for r in rows])
        except ValueError:
            raise InputError("ground truth must be numbers (timestamp, p xyz, q wxyz, ...)", csv) from None
        if len(a) < 2:
            raise InputError("ground truth needs at least two rows", csv)
        t = a[:, 0] * 1e-9
        check_timestamps(t, csv)
        T_bs_gt = np.eye(4)
        if (gt_dir / "sensor.yaml").is_file():
            T_bs_gt = _arr(read_yaml_any(gt_dir / "sensor.yaml"), "T_BS", (4, 4), gt_dir / "sensor.yaml")
        rot = Rotation.from_quat(a[:, [5, 6, 7, 4]])  # EuRoC stores w x y z
        inside = (self.timestamps >= t[0]) & (self.timestamps <= t[-1])
        if not inside.any():
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        tq = self.timestamps[inside]
        R = Slerp(t, rot)(tq).as_matrix()
        p = np.column_stack([np.interp(tq, t, a[:, k]) for k in (1, 2, 3)])
        T_w_s = np.tile(np.eye(4), (len(tq), 1, 1))
        T_w_s[:, :3, :3] = R
        T_w_s[:, :3, 3] = p
        T_w_b = T_w_s @ np.linalg.inv(T_bs_gt)
        return Trajectory(tq, T_w_b @ self.T_body_camrect())


register_loader("euroc", EurocSequence.is_dataset, lambda p, **kw: construct(EurocSequence, p, kw), order=30)
