"""Stereo calibration files of other tools -> one :class:`StereoRig` record -> a rectified :class:`StereoCalib`.

Formats read (all give a :class:`StereoRig`; :func:`load_rig` picks the parser from the content):

* seedmap ``calib.yaml`` (already rectified, :meth:`StereoCalib.to_dict`);
* ROS ``camera_info`` YAML (``camera_calibration`` output), one file per camera (left + right);
* Kalibr camchain YAML (``cam0``/``cam1``, ``T_cn_cnm1`` of cam1 = transform cam0 -> cam1);
* OpenCV FileStorage YAML (``%YAML:1.0``) as ORB-SLAM2/3 settings: ``Camera.fx ... Camera.bf`` (rectified),
  ``LEFT.K/D/R/P`` + ``RIGHT.*`` (ORB-SLAM2 rectification of raw images), ``Camera1.* Camera2.* Stereo.T_c1_c2``
  (ORB-SLAM3);
* EuRoC ``sensor.yaml`` pairs (``T_BS`` body <- sensor extrinsics of each camera);
* KITTI ``calib.txt`` (odometry: ``P0..P3``) and ``calib_cam_to_cam.txt`` (raw: ``P_rect_0x``, ``S_rect_0x``);
* GTSAM's stereo VO calibration ``fx fy skew u0 v0 baseline`` (one line).

Extrinsic convention (OpenCV's ``stereoCalibrate``): ``x_right = R @ x_left + T`` in metres, so a well-formed
horizontal rig has ``T ~ [-baseline, 0, 0]`` and the right camera centre ``-R.T @ T`` at ``+x`` of the left.

:func:`rectify` turns a rig into the rectified ``StereoCalib`` every seedmap module uses plus the OpenCV
remap tables (``None`` when the images are already rectified) - computed once per sequence.
"""


from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from seedmap.errors import InputError, SeedmapError
from seedmap.io.calib_formats import (  # noqa: F401  (re-exported: the parsers)
    _rig_from_rect,
    kitti_cam_offset,
    parse_euroc_pair,
    parse_gtsam_stereo_calib,
    parse_kalibr_camchain,
    parse_kitti_calib,
    parse_opencv_settings,
    parse_ros_camera_info,
    parse_seedmap_calib,
    read_kitti_calib_file,
    read_opencv_yaml,
    read_yaml_any,
)
from seedmap.io.rig import (  # noqa: F401  (re-exported: the records)
    DISTORTION_MODELS,
    CameraModel,
    RectifyMaps,
    StereoRig,
    _calib_from_P,
    check_image_size,
    check_rig,
)
from seedmap.io.text import read_text
from seedmap.records import StereoCalib

def _rectification(rig: StereoRig, alpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``R1, R2, P1, P2``: the file's own rectification, else OpenCV's (zero disparity at infinity)."""
    if rig.rect is not None:
        R1, R2, P1, P2 = (np.ascontiguousarray(a, float) for a in rig.rect)
        return R1.reshape(3, 3), R2.reshape(3, 3), P1.reshape(3, 4), P2.reshape(3, 4)
    size = rig.left.size
    try:
        if rig.left.distortion == "equidistant":
            R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(
                rig.left.K, rig.left.D[:4], rig.right.K, rig.right.D[:4], size, rig.R, rig.T.reshape(3, 1),
                flags=cv2.CALIB_ZERO_DISPARITY, newImageSize=size, balance=float(alpha), fov_scale=1.0)
        else:
            R1, R2, P1, P2, *_ = cv2.stereoRectify(
                rig.left.K, rig.left.D, rig.right.K, rig.right.D, size, rig.R, rig.T.reshape(3, 1),
                flags=cv2.CALIB_ZERO_DISPARITY, alpha=float(alpha), newImageSize=size)
    except Exception as e:  # cv2.error, or SystemError from the bindings
        lines = str(e).strip().splitlines()
        raise InputError(f"OpenCV could not rectify this rig ({lines[-1] if lines else type(e).__name__})",
                         rig.source) from None
    return (np.asarray(R1, float), np.asarray(R2, float), np.asarray(P1, float).reshape(3, 4),
            np.asarray(P2, float).reshape(3, 4))


def rectify(rig: StereoRig, alpha: float = 0.0) -> tuple[StereoCalib, RectifyMaps | None]:
    """Rectified calibration and the remap tables of a rig (``None`` maps: images already rectified).

    ``alpha`` is OpenCV's free scaling (0: only valid pixels, no black borders - what seed detectors want;
    1: keep every source pixel). Uses the file's own rectification (``rig.rect``) when it has one, else
    ``cv2.stereoRectify`` (``cv2.fisheye.stereoRectify`` for equidistant lenses) with zero disparity at
    infinity (same ``cx`` in both images). Compute it once per sequence; :meth:`RectifyMaps.apply` per pair.
    """
    check_rig(rig)
    size = rig.left.size
    if rig.is_rectified and rig.rect is None:
        K = rig.left.K
        try:
            return StereoCalib(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
                               baseline=float(-rig.T[0]), width=size[0], height=size[1]), None
        except SeedmapError as e:
            raise InputError(str(e), rig.source) from None
    R1, R2, P1, P2 = _rectification(rig, alpha)
    calib = _calib_from_P(P1, P2, size, rig.source)
    maps = []
    for cam, Ri, Pi in ((rig.left, R1, P1), (rig.right, R2, P2)):
        if cam.distortion == "equidistant":
            m = cv2.fisheye.initUndistortRectifyMap(cam.K, cam.D[:4], Ri, Pi[:3, :3], size, cv2.CV_16SC2)
        else:
            m = cv2.initUndistortRectifyMap(cam.K, cam.D, Ri, Pi[:3, :3], size, cv2.CV_16SC2)
        maps.append(m)
    return calib, RectifyMaps(left=maps[0], right=maps[1], size=size)


def rectified_rotation(rig: StereoRig, alpha: float = 0.0) -> np.ndarray:
    """``R1``: rotation from the raw left camera frame to the rectified left frame (``x_rect = R1 x_raw``).

    Poses of the raw left camera become poses of the rectified one as ``T_world_rect = T_world_raw @ [R1^T | 0]``.
    """
    if rig.is_rectified and rig.rect is None:
        return np.eye(3)
    return _rectification(rig, alpha)[0]


# ----------------------------------------------------------------------------------------------
# dispatch
# ----------------------------------------------------------------------------------------------


def load_rig(path: str | Path, right: str | Path | None = None,
             image_size: tuple[int, int] | None = None, kitti_cams: tuple[int, int] = (2, 3)) -> StereoRig:
    """Read any supported calibration file (``right``: the second file of per-camera formats).

    ``image_size`` ``(w, h)`` is needed only by formats that do not store it (KITTI odometry, GTSAM).
    Oddities that are not errors (a baseline that looks like millimetres) land in ``rig.warnings``.
    """
    rig = _load_rig(path, right, image_size, kitti_cams)
    warn_implausible_baseline(rig, path)
    return rig


def warn_implausible_baseline(rig: StereoRig, where: str | Path) -> None:
    """A baseline over 2 m is almost always a calibration in millimetres: say so in ``rig.warnings``."""
    if rig.baseline > 2.0:
        rig.warnings.append(f"{where}: stereo baseline is {rig.baseline:.4g} m - is the calibration in millimetres? "
                            "seedmap works in metres")


def _load_rig(path: str | Path, right: str | Path | None, image_size: tuple[int, int] | None,
              kitti_cams: tuple[int, int]) -> StereoRig:
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found", path)
    if path.suffix.lower() == ".txt":
        head = read_text(path, "calibration file")
        if ":" in head:
            return parse_kitti_calib(path, kitti_cams, image_size)
        return parse_gtsam_stereo_calib(path, image_size)
    d = read_yaml_any(path)
    if "baseline_m" in d:
        return parse_seedmap_calib(d, path)
    if "cam0" in d and "cam1" in d:
        return parse_kalibr_camchain(d, path)
    if "camera_matrix" in d:
        rp = Path(right) if right is not None else _guess_partner(path)
        if rp is None:
            raise InputError("ROS camera_info file of one camera: give the right camera's file too", path)
        return parse_ros_camera_info(d, read_yaml_any(rp), path, rp)
    if "T_BS" in d and "intrinsics" in d:
        rp = Path(right) if right is not None else _guess_partner(path)
        if rp is None:
            raise InputError("EuRoC sensor.yaml of one camera: give the other camera's sensor.yaml too", path)
        return parse_euroc_pair(d, read_yaml_any(rp), path, rp)[0]
    if any(isinstance(k, str) and k.startswith(("Camera.", "Camera1.", "LEFT.")) for k in d):
        return parse_opencv_settings(d, path)
    raise InputError("unrecognised calibration format (seedmap calib.yaml, ROS camera_info, Kalibr camchain, "
                     "EuRoC sensor.yaml, ORB-SLAM settings, KITTI calib.txt or GTSAM fx fy skew u0 v0 b)", path)


def _guess_partner(path: Path) -> Path | None:
    """The right camera's file next to a left one: left->right, cam0->cam1 in the name or parent folder."""
    swaps = (("left", "right"), ("Left", "Right"), ("LEFT", "RIGHT"), ("cam0", "cam1"), ("_l.", "_r."))
    for a, b in swaps:
        if a in path.name:
            q = path.with_name(path.name.replace(a, b))
            if q.is_file():
                return q
        if a in path.parent.name:
            q = path.parent.with_name(path.parent.name.replace(a, b)) / path.name
            if q.is_file():
                return q
    return None


def save_calib_yaml(calib: StereoCalib, path: str | Path) -> None:
    """Write a rectified calibration in seedmap's ``calib.yaml`` form (atomically)."""
    from seedmap.io.atomic import atomic_write_text
    from seedmap.io.seedmap_dataset import FORMAT_VERSION

    d = {"seedmap_dataset": FORMAT_VERSION, **calib.to_dict()}
    atomic_write_text(Path(path), yaml.safe_dump(d, sort_keys=False))
