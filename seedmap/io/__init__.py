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
Each loader module registers itself in :mod:`seedmap.io.registry`; importing this package imports them all.
"""

from seedmap.io import euroc, folder, kitti, rosbag, seedmap_dataset  # noqa: F401  (each registers its loader)
from seedmap.io.registry import StereoSequence, detect_format, loader_names, open_dataset, register_loader

__all__ = ["StereoSequence", "detect_format", "loader_names", "open_dataset", "register_loader"]
