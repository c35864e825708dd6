"""KITTI odometry sequence: ``image_2/`` + ``image_3/`` (colour), ``calib.txt`` (``P0..P3``), ``times.txt``.

Images are already rectified; the calibration is ``P2``/``P3`` (baseline ``(P2[0,3] - P3[0,3]) / fx``).
Without ``image_2/`` the grayscale ``image_0/`` + ``image_1/`` pair is used (``P0``/``P1``), converted to
3-channel RGB. Ground truth: ``poses.txt`` in the folder, ``../../poses/<seq>.txt`` (the KITTI tree), or
``poses=``; KITTI poses are ``T_world_cam0`` with world = cam0 at frame 0 - we return them for the
*left camera used* (``T_world_cam2 = T_world_cam0 @ T_cam0_cam2``, a 6 cm offset along x for cam 2).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.calibration import kitti_cam_offset, parse_kitti_calib
from seedmap.io.common import LoaderWarnings, RectifiedPairs, list_images, read_image_rgb
from seedmap.io.registry import construct, register_loader
from seedmap.io.timestamps import read_times_txt
from seedmap.io.trajectory import read_kitti
from seedmap.records import Trajectory


class KittiSequence(RectifiedPairs):
    """One KITTI odometry sequence folder (e.g. ``dataset/sequences/00``)."""

    name = "kitti"

    def __init__(self, root: str | Path, poses: str | Path | None = None, fps: float = 10.0) -> None:
        self.root = Path(root)
        self.warnings: list[str] = LoaderWarnings(self.root)
        if (self.root / "image_2").is_dir() and (self.root / "image_3").is_dir():
            self.cams = (2, 3)
        elif (self.root / "image_0").is_dir() and (self.root / "image_1").is_dir():
            self.cams = (0, 1)
        else:
            raise InputError("no image_2/ + image_3/ (or image_0/ + image_1/) folders", self.root)
        ldir, rdir = (self.root / f"image_{c}" for c in self.cams)
        left, right = list_images(ldir), list_images(rdir)
        if not left:
            raise InputError("no images in this folder", ldir)
        if len(left) != len(right):
            raise InputError(f"image_{self.cams[0]}/ has {len(left)} images but image_{self.cams[1]}/ has "
                             f"{len(right)}: the sequence is incomplete (re-extract it)", self.root)
        if [p.name for p in left] != [p.name for p in right]:
            raise InputError(f"file names in image_{self.cams[0]}/ and image_{self.cams[1]}/ differ", self.root)
        self._pairs = list(zip(left, right, strict=True))
        times = self.root / "times.txt"
        if times.is_file():
            self.timestamps = read_times_txt(times, n=len(self._pairs))
        else:
            self.timestamps = np.arange(len(self._pairs), dtype=float) / fps
            self.warnings.append(f"no times.txt: timestamps are frame index / {fps:g} Hz")
        self.calib_path = self.root / "calib.txt"
        if not self.calib_path.is_file():
            raise InputError("calib.txt (P0..P3) not found", self.calib_path)
        first, _ = read_image_rgb(left[0])
        rig = parse_kitti_calib(self.calib_path, self.cams, (first.shape[1], first.shape[0]))
        self._setup_rectification(rig)
        self.poses_path = Path(poses) if poses is not None else self._find_poses()

    def _find_poses(self) -> Path | None:
        for p in (self.root / "poses.txt", self.root.parent.parent / "poses" / f"{self.root.name}.txt"):
            if p.is_file():
                return p
        return None

    @staticmethod
    def is_dataset(path: Path) -> bool:
        p = Path(path)
        return p.is_dir() and (p / "calib.txt").is_file() and ((p / "image_2").is_dir() or (p / "image_0").is_dir())

    def gt_trajectory(self) -> Trajectory | None:
        """Ground-truth ``T_world_leftcam`` at the frame timestamps, or ``None`` without a poses file."""
        if self.poses_path is None:
            return None
        traj = read_kitti(self.poses_path)
        if len(traj) != len(self):
            raise InputError(f"has {len(traj)} poses but the sequence has {len(self)} frames", self.poses_path)
        T_c0_cl = kitti_cam_offset(self.calib_path, self.cams[0])
        return Trajectory(self.timestamps.copy(), traj.poses @ T_c0_cl)


register_loader("kitti", KittiSequence.is_dataset, lambda p, **kw: construct(KittiSequence, p, kw), order=40)
