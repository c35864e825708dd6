"""Generic stereo folder: ``left/`` + ``right/`` (or ``cam0/`` + ``cam1/``) image files.

::

    FOLDER/
      left/ ... right/          (or cam0/ cam1/) png/jpg..., paired by file name, else by sorted order
      times.txt                 optional: one timestamp (s) per pair; else numeric file names of 16+ digits
                                are read as nanosecond stamps, else frame index / fps
      calibration               calib.yaml (seedmap), camchain.yaml (Kalibr), left.yaml + right.yaml
                                (ROS camera_info), cam0/sensor.yaml + cam1/sensor.yaml (EuRoC),
                                settings/stereo .yaml (ORB-SLAM), calib.txt (KITTI) - or passed as ``calib=``

Unrectified pairs are rectified once per image with the maps of :func:`seedmap.io.calibration.rectify`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.calibration import StereoRig, load_rig
from seedmap.io.common import LoaderWarnings, RectifiedPairs, list_images, read_image_rgb
from seedmap.io.registry import construct, register_loader
from seedmap.io.timestamps import check_timestamps, read_times_txt
from seedmap.records import StereoCalib, Trajectory

CAMERA_DIRS = (("left", "right"), ("cam0", "cam1"), ("image_left", "image_right"))
CALIB_CANDIDATES = ("calib.yaml", "calibration.yaml", "camchain.yaml", "stereo.yaml", "settings.yaml",
                    "calib.txt", "left.yaml", "cam0/sensor.yaml")


def find_camera_dirs(root: Path) -> tuple[Path, Path] | None:
    for a, b in CAMERA_DIRS:
        if (root / a).is_dir() and (root / b).is_dir():
            return root / a, root / b
    return None


def find_calibration(root: Path) -> Path | None:
    """The calibration file in a dataset folder (first of :data:`CALIB_CANDIDATES`, then ``*camchain*.yaml``)."""
    for name in CALIB_CANDIDATES:
        if (root / name).is_file():
            return root / name
    hits = sorted(root.glob("*camchain*.yaml"))
    return hits[0] if hits else None


def resolve_rig(calib: str | Path | StereoRig | StereoCalib | None, root: Path,
                image_size: tuple[int, int] | None, right_calib: str | Path | None = None) -> StereoRig:
    """A rig from an object, an explicit file, or the calibration file found in ``root``."""
    if isinstance(calib, StereoRig):
        return calib
    if isinstance(calib, StereoCalib):
        return StereoRig.from_calib(calib)
    path = Path(calib) if calib is not None else find_calibration(root)
    if path is None:
        raise InputError("no calibration found (put calib.yaml / camchain.yaml / left.yaml+right.yaml / calib.txt "
                         "in the folder, or pass --set dataset.calib=FILE)", root)
    return load_rig(path, right=right_calib, image_size=image_size)


class StereoFolder(RectifiedPairs):
    """Two folders of images; see the module docstring for the layout rules."""

    name = "folder"

    def __init__(self, root: str | Path, calib: str | Path | StereoRig | StereoCalib | None = None,
                 right_calib: str | Path | None = None, fps: float = 5.0, rectify_alpha: float = 0.0) -> None:
        self.root = Path(root)
        self.warnings: list[str] = LoaderWarnings(self.root)
        dirs = find_camera_dirs(self.root)
        if dirs is None:
            raise InputError("no left/ + right/ (or cam0/ + cam1/) image folders", self.root)
        self.left_dir, self.right_dir = dirs
        left, right = list_images(self.left_dir), list_images(self.right_dir)
        if not left:
            raise InputError("no images (png/jpg) in this folder", self.left_dir)
        if not right:
            raise InputError("no images (png/jpg) in this folder", self.right_dir)
        self._pairs = self._pair_files(left, right)
        times = self.root / "times.txt"
        if times.is_file():
            self.timestamps = read_times_txt(times, n=len(self._pairs))
        else:
            stems = [p.stem for p, _ in self._pairs]
            if all(s.isdigit() and len(s) >= 16 for s in stems):
                self.timestamps = check_timestamps(np.array([int(s) for s in stems], dtype=np.float64) * 1e-9,
                                                   self.left_dir)
                self.warnings.append("no times.txt: timestamps taken from nanosecond file names")
            else:
                if not fps > 0:
                    raise InputError(f"fps must be positive, got {fps}", self.root)
                self.timestamps = np.arange(len(self._pairs), dtype=float) / fps
                self.warnings.append(f"no times.txt: timestamps are frame index / {fps:g} Hz")
        first, _ = read_image_rgb(self._pairs[0][0])
        rig = resolve_rig(calib, self.root, (first.shape[1], first.shape[0]), right_calib)
        self._setup_rectification(rig, rectify_alpha)

    def _pair_files(self, left: list[Path], right: list[Path]) -> list[tuple[Path, Path]]:
        rmap = {p.stem: p for p in right}
        common = [p for p in left if p.stem in rmap]
        if len(common) == len(left) == len(right):
            return [(p, rmap[p.stem]) for p in left]
        if common and len(common) >= 0.5 * max(len(left), len(right)):
            dropped = len(left) + len(right) - 2 * len(common)
            self.warnings.append(f"{dropped} images without a partner of the same name were skipped")
            return [(p, rmap[p.stem]) for p in common]
        if len(left) != len(right):
            raise InputError(f"{self.left_dir.name}/ has {len(left)} images but {self.right_dir.name}/ has "
                             f"{len(right)} and their names differ: give both cameras the same file names "
                             "(or the same count)", self.root)
        return list(zip(left, right, strict=True))

    @staticmethod
    def is_dataset(path: Path) -> bool:
        return Path(path).is_dir() and find_camera_dirs(Path(path)) is not None

    def gt_trajectory(self) -> Trajectory | None:
        """``gt/poses_tum.txt`` or ``poses_tum.txt`` (TUM, left camera) when present."""
        from seedmap.io.trajectory import read_tum

        for p in (self.root / "gt" / "poses_tum.txt", self.root / "poses_tum.txt"):
            if p.is_file():
                return read_tum(p)
        return None


register_loader("folder", StereoFolder.is_dataset, lambda p, **kw: construct(StereoFolder, p, kw), order=50)
