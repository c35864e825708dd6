"""Dataloaders (one per format) and every file format seedmap reads or writes.

Every dataloader exposes the same small interface (:class:`StereoSequence`): ``calib``,
``timestamps``, ``len()``, ``[i] -> StereoFrame``, and ``gt_trajectory()`` (``None`` without GT).
:func:`open_dataset` picks the loader from the path (first match in this order, or ``fmt=``):

* ``seedmap`` - seedmap's own layout (:mod:`seedmap.io.seedmap_dataset`);
* ``rosbag``  - ROS1 ``.bag``, ROS2 ``.db3``/``.mcap``/bag folder (:mod:`seedmap.io.rosbag`);
* ``euroc``   - EuRoC MAV ``mav0/cam0``+``cam1`` (:mod:`seedmap.io.euroc`);
* ``kitti``   - KITTI odometry sequence (:mod:`seedmap.io.kitti`);
* ``folder``  - any ``left/``+``right/`` or ``cam0/``+``cam1/`` image folder (:mod:`seedmap.io.folder`).

Unrectified data (EuRoC, raw bags, folders with a Kalibr/ROS/ORB-SLAM calibration) are rectified at load
(:mod:`seedmap.io.calibration`); ``calib`` is always the rectified pair and images are always RGB uint8.
Loader options: keyword arguments of each loader, or :class:`seedmap.io.options.DatasetOptions`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from seedmap.errors import ConfigError, InputError
from seedmap.records import StereoCalib, StereoFrame, Trajectory


@runtime_checkable
class StereoSequence(Protocol):
    name: str
    calib: StereoCalib
    timestamps: np.ndarray

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> StereoFrame: ...

    def gt_trajectory(self) -> Trajectory | None: ...


# (name, detector(path) -> bool, opener(path, **kw) -> StereoSequence), tried in order.
_LOADERS: list[tuple[str, Callable[[Path], bool], Callable[..., StereoSequence]]] = []


def register_loader(name: str, detect: Callable[[Path], bool], opener: Callable[..., StereoSequence]) -> None:
    _LOADERS.append((name, detect, opener))


def loader_names() -> list[str]:
    return [n for n, _, _ in _LOADERS]


def detect_format(path: str | Path) -> str | None:
    """Name of the first loader that recognises ``path`` (``None``: none does)."""
    p = Path(path)
    for name, detect, _ in _LOADERS:
        if detect(p):
            return name
    return None


def open_dataset(path: str | Path, fmt: str | None = None, **kwargs) -> StereoSequence:
    """Open any supported stereo dataset; ``fmt`` forces a loader by name; ``kwargs`` go to the loader."""
    p = Path(path)
    if not p.exists():
        raise InputError("dataset not found", p)
    for name, detect, opener in _LOADERS:
        if (fmt is None and detect(p)) or fmt == name:
            return opener(p, **kwargs)
    if fmt is not None:
        raise InputError(f"unknown dataset format {fmt!r} (known: {', '.join(loader_names())})", p)
    raise InputError(f"no loader recognises this path{_near_miss(p)} (known formats: {', '.join(loader_names())})", p)


def _near_miss(p: Path) -> str:
    """What a folder that almost has a known layout lacks (``""`` when it resembles none)."""
    if not p.is_dir():
        return ""
    if any((p / d).is_dir() for d in ("image_0", "image_2")) and not (p / "calib.txt").is_file():
        return ": it has KITTI image folders but no calib.txt"
    m = p / "mav0"
    if m.is_dir() and not (m / "cam0" / "data.csv").is_file():
        return ": it has mav0/ (EuRoC) but no mav0/cam0/data.csv"
    if m.is_dir() and not (m / "cam1").is_dir():
        return ": it has mav0/cam0 (EuRoC) but no mav0/cam1 (a stereo pair is needed)"
    if (p / "left").is_dir() != (p / "right").is_dir() or (p / "cam0").is_dir() != (p / "cam1").is_dir():
        return ": it has one camera folder but not the other (left/ + right/ or cam0/ + cam1/)"
    return ""


def _is_seedmap(p: Path) -> bool:
    from seedmap.io.seedmap_dataset import SeedmapDataset, frame_name

    # a generic folder with calib.yaml + times.txt but other file names is left to the folder loader
    return SeedmapDataset.is_dataset(p) and (
        (p / "left" / frame_name(0)).is_file() or not any((p / "left").iterdir()))


def _construct(cls: type, p: Path, kw: dict) -> StereoSequence:
    """``cls(p, **kw)`` with a one-line ConfigError for options this format does not have."""
    import inspect

    accepted = set(inspect.signature(cls).parameters) - {"root", "path"}
    bad = sorted(set(kw) - accepted)
    if bad:
        raise ConfigError(f"format {cls.name!r} has no option {', '.join(bad)} (it takes: "
                          f"{', '.join(sorted(accepted)) or 'none'})", p)
    return cls(p, **kw)


def _register_builtin() -> None:
    """Loaders tried in this order; each opener takes the path plus its own keyword options."""

    def seedmap_opener(p: Path, **kw) -> StereoSequence:
        from seedmap.io.seedmap_dataset import SeedmapDataset

        if kw:
            raise ConfigError(f"the seedmap dataset format takes no options (got {', '.join(sorted(kw))})", p)
        return SeedmapDataset(p)

    def rosbag_detect(p: Path) -> bool:
        from seedmap.io.rosbag import is_bag

        return is_bag(p)

    def rosbag_opener(p: Path, **kw) -> StereoSequence:
        from seedmap.io.rosbag import RosbagSequence

        return _construct(RosbagSequence, p, kw)

    def euroc_detect(p: Path) -> bool:
        from seedmap.io.euroc import EurocSequence

        return EurocSequence.is_dataset(p)

    def euroc_opener(p: Path, **kw) -> StereoSequence:
        from seedmap.io.euroc import EurocSequence

        return _construct(EurocSequence, p, kw)

    def kitti_detect(p: Path) -> bool:
        from seedmap.io.kitti import KittiSequence

        return KittiSequence.is_dataset(p)

    def kitti_opener(p: Path, **kw) -> StereoSequence:
        from seedmap.io.kitti import KittiSequence

        return _construct(KittiSequence, p, kw)

    def folder_detect(p: Path) -> bool:
        from seedmap.io.folder import StereoFolder

        return StereoFolder.is_dataset(p)

    def folder_opener(p: Path, **kw) -> StereoSequence:
        from seedmap.io.folder import StereoFolder

        return _construct(StereoFolder, p, kw)

    register_loader("seedmap", _is_seedmap, seedmap_opener)
    register_loader("rosbag", rosbag_detect, rosbag_opener)
    register_loader("euroc", euroc_detect, euroc_opener)
    register_loader("kitti", kitti_detect, kitti_opener)
    register_loader("folder", folder_detect, folder_opener)


_register_builtin()
