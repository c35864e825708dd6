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

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from seedmap.errors import InputError, SeedmapError
from seedmap.records import StereoCalib

DISTORTION_MODELS = ("radtan", "equidistant")
_RADTAN_ALIASES = {"radtan", "radial-tangential", "plumb_bob", "rational_polynomial", "pinhole", ""}
_EQUI_ALIASES = {"equidistant", "fisheye", "equi", "kannala_brandt"}


@dataclass(frozen=True)
class CameraModel:
    """One pinhole camera: ``K`` (3x3, pixels), distortion ``D`` (OpenCV order), image size (pixels).

    ``distortion`` is ``"radtan"`` (OpenCV/ROS plumb_bob: k1 k2 p1 p2 [k3 ...]) or ``"equidistant"``
    (Kalibr/OpenCV fisheye: k1..k4).
    """

    K: np.ndarray
    D: np.ndarray
    width: int
    height: int
    distortion: str = "radtan"

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", np.ascontiguousarray(np.asarray(self.K, float).reshape(3, 3)))
        object.__setattr__(self, "D", np.ascontiguousarray(np.asarray(self.D, float).reshape(-1)))
        if self.distortion not in DISTORTION_MODELS:
            raise ValueError(f"unknown distortion model {self.distortion!r}")

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``."""
        return (int(self.width), int(self.height))


@dataclass(frozen=True)
class StereoRig:
    """Two cameras and their extrinsics (``x_right = R x_left + T``, metres), possibly unrectified.

    ``rect`` optionally carries a rectification the file itself prescribes (``R1, R2, P1, P2`` as in
    ROS camera_info / ORB-SLAM2 ``LEFT.R/P``); :func:`rectify` then uses it instead of recomputing one.
    ``source`` names the file for error messages.
    """

    left: CameraModel
    right: CameraModel
    R: np.ndarray
    T: np.ndarray
    rect: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    source: Path | None = None
    warnings: list[str] = field(default_factory=list, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.ascontiguousarray(np.asarray(self.R, float).reshape(3, 3)))
        object.__setattr__(self, "T", np.ascontiguousarray(np.asarray(self.T, float).reshape(3)))

    @property
    def baseline(self) -> float:
        """Distance between the two camera centres (metres)."""
        return float(np.linalg.norm(self.T))

    @property
    def right_center_in_left(self) -> np.ndarray:
        """Position of the right camera's optical centre in the left camera frame (metres)."""
        return -self.R.T @ self.T

    @property
    def is_rectified(self) -> bool:
        """True when the images need no remap: no distortion, same K, parallel axes, pure x offset."""
        return (
            not np.any(self.left.D) and not np.any(self.right.D)
            and np.allclose(self.left.K, self.right.K, rtol=1e-6, atol=1e-6)
            and np.allclose(self.R, np.eye(3), atol=1e-9)
            and abs(self.T[1]) < 1e-9 and abs(self.T[2]) < 1e-9
            and self.left.size == self.right.size
        )

    @staticmethod
    def from_calib(calib: StereoCalib, source: Path | None = None) -> StereoRig:
        """The (trivial) rig of an already rectified pair."""
        cam = CameraModel(calib.K, np.zeros(5), calib.width, calib.height)
        return StereoRig(cam, cam, np.eye(3), np.array([-calib.baseline, 0.0, 0.0]), source=source)


@dataclass
class RectifyMaps:
    """OpenCV remap tables for both cameras (fixed-point ``CV_16SC2`` form, fast to apply)."""

    left: tuple[np.ndarray, np.ndarray]
    right: tuple[np.ndarray, np.ndarray]
    size: tuple[int, int]  # output (width, height)

    def apply(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectify one raw pair (bilinear interpolation)."""
        lo = cv2.remap(left, self.left[0], self.left[1], cv2.INTER_LINEAR)
        ro = cv2.remap(right, self.right[0], self.right[1], cv2.INTER_LINEAR)
        return lo, ro


# ----------------------------------------------------------------------------------------------
# checks
# ----------------------------------------------------------------------------------------------


def check_rig(rig: StereoRig) -> None:
    """Refuse rigs seedmap cannot use, with the fix in one line (wrong sign, swapped cameras, vertical)."""
    src = rig.source
    for name, cam in (("left", rig.left), ("right", rig.right)):
        K = cam.K
        if not np.all(np.isfinite(K)) or not np.all(np.isfinite(cam.D)):
            raise InputError(f"{name} camera intrinsics/distortion contain NaN or inf", src)
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"{name} camera focal lengths must be positive (got fx={K[0, 0]}, fy={K[1, 1]})", src)
        if cam.width <= 0 or cam.height <= 0:
            raise InputError(f"{name} camera image size must be positive (got {cam.width}x{cam.height})", src)
    if not np.all(np.isfinite(rig.R)) or not np.all(np.isfinite(rig.T)):
        raise InputError("stereo extrinsics contain NaN or inf", src)
    if not np.allclose(rig.R @ rig.R.T, np.eye(3), atol=1e-4) or np.linalg.det(rig.R) < 0:
        raise InputError("stereo rotation R is not a rotation matrix (orthonormal, det +1)", src)
    if rig.baseline <= 0:
        raise InputError("stereo baseline is zero (both camera centres coincide)", src)
    c = rig.right_center_in_left
    if abs(c[0]) < 0.5 * np.linalg.norm(c):
        raise InputError(
            f"right camera centre is at {np.round(c, 4).tolist()} m in the left frame: not a horizontal rig "
            "(seedmap needs the right camera beside the left one along +x)", src)
    if c[0] < 0:
        raise InputError(
            f"right camera sits at x={c[0]:.4f} m of the left camera (must be +x): the cameras are swapped "
            "(exchange left/right) or the baseline sign is wrong (T maps left to right: x_r = R x_l + T, "
            "so T ~ [-baseline, 0, 0])", src)
    if rig.left.size != rig.right.size:
        raise InputError(f"left ({rig.left.width}x{rig.left.height}) and right ({rig.right.width}x"
                         f"{rig.right.height}) image sizes differ in the calibration", src)


def check_image_size(calib_size: tuple[int, int], image: np.ndarray, image_path: Path | str,
                     calib_source: Path | str | None) -> None:
    """Calibration and images must have the same resolution (no silent rescaling)."""
    h, w = image.shape[:2]
    if (w, h) != tuple(calib_size):
        src = f" ({calib_source})" if calib_source else ""
        raise InputError(
            f"image is {w}x{h} but the calibration{src} is for {calib_size[0]}x{calib_size[1]}: use the "
            "calibration of this resolution, or scale fx, fy, cx, cy (and the image size) with the images",
            image_path)


# ----------------------------------------------------------------------------------------------
# rectification
# ----------------------------------------------------------------------------------------------


def _calib_from_P(P1: np.ndarray, P2: np.ndarray, size: tuple[int, int], src: Path | None) -> StereoCalib:
    P1 = np.asarray(P1, float).reshape(3, 4)
    P2 = np.asarray(P2, float).reshape(3, 4)
    if not (np.all(np.isfinite(P1)) and np.all(np.isfinite(P2))):
        raise InputError("rectification failed (NaN in the projection matrices): check that the principal point "
                         "lies inside the image and the intrinsics are sane", src)
    fx = P1[0, 0]
    if abs(P2[1, 3] - P1[1, 3]) > abs(P2[0, 3] - P1[0, 3]):
        raise InputError("rectified projection P2 has a vertical baseline (P2[1,3] != 0): not a horizontal rig", src)
    baseline = (P1[0, 3] - P2[0, 3]) / fx
    if not np.isfinite(baseline) or baseline <= 0:
        # "P2" is OpenCV's name of the right camera's projection; in a KITTI calib.txt it is P3 (or P1)
        cause = ("the right camera's projection has no baseline term: it must hold -fx*baseline in its [0,3]"
                 if baseline == 0 else "the cameras are swapped (exchange left/right) or the baseline sign is wrong")
        raise InputError(
            f"rectified baseline is {baseline:.6g} m (right camera's projection P[0,3] - left's = "
            f"{P2[0, 3] - P1[0, 3]:.6g}; must be -fx*baseline < 0): {cause}", src)
    try:
        return StereoCalib(fx=float(fx), fy=float(P1[1, 1]), cx=float(P1[0, 2]), cy=float(P1[1, 2]),
                           baseline=float(baseline), width=int(size[0]), height=int(size[1]))
    except SeedmapError as e:
        raise InputError(str(e), src) from None


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
        return StereoCalib(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
                           baseline=float(-rig.T[0]), width=size[0], height=size[1]), None
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
# low-level readers
# ----------------------------------------------------------------------------------------------


def _fs_node_to_py(node: cv2.FileNode):
    if node.isMap():
        if node.keys() and set(node.keys()) >= {"rows", "cols", "data"} and node.getNode("dt").isNone() is False:
            return node.mat()
        return {k: _fs_node_to_py(node.getNode(k)) for k in node.keys()}
    if node.isSeq():
        return [_fs_node_to_py(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def read_opencv_yaml(path: Path) -> dict:
    """Read an OpenCV FileStorage YAML (``%YAML:1.0`` header, ``!!opencv-matrix``) into plain Python."""
    path = Path(path)
    def why(e: Exception) -> str:
        lines = str(e).strip().splitlines()
        return (lines[-1] if lines else type(e).__name__)[:120]

    try:  # OpenCV raises cv2.error, and SystemError from its bindings on some malformed files
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except Exception as e:
        raise InputError(f"not a readable OpenCV YAML file ({why(e)})", path) from None
    try:
        if not fs.isOpened():
            raise InputError("not a readable OpenCV YAML file", path)
        out = _fs_node_to_py(fs.root())
    except InputError:
        raise
    except Exception as e:
        raise InputError(f"not a readable OpenCV YAML file ({why(e)})", path) from None
    finally:
        fs.release()
    if not isinstance(out, dict):
        raise InputError("OpenCV YAML file must be a mapping at top level", path)
    return out


def read_yaml_any(path: Path) -> dict:
    """A YAML mapping from either a plain YAML file or an OpenCV FileStorage one."""
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found", path)
    try:
        text = path.read_text(errors="strict")
    except (UnicodeDecodeError, OSError):
        raise InputError("calibration file is not UTF-8 text", path) from None
    if text.lstrip().startswith("%YAML:"):
        return read_opencv_yaml(path)
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(f"not valid YAML ({str(e).splitlines()[0][:100]})", path) from None
    except Exception as e:  # pyyaml raises a few non-YAMLError types on odd input
        raise InputError(f"not valid YAML ({type(e).__name__})", path) from None
    if not isinstance(d, dict):
        raise InputError("calibration must be a YAML mapping", path)
    return d


def _arr(d: dict, key: str, n: int | tuple[int, ...], path: Path, default=None) -> np.ndarray:
    """A numeric array field (plain list, ``{rows, cols, data}`` or OpenCV matrix) of ``n`` values."""
    if key not in d or d[key] is None:
        if default is not None:
            return np.asarray(default, float)
        raise InputError(f"calibration lacks {key!r}", path)
    v = d[key]
    if isinstance(v, dict):
        if "data" not in v:
            raise InputError(f"{key!r} has no 'data' list", path)
        v = v["data"]
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{key!r} must be numbers", path) from None
    shape = (n,) if isinstance(n, int) else n
    size = int(np.prod(shape))
    if a.size != size:
        raise InputError(f"{key!r} must have {size} numbers, got {a.size}", path)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{key!r} contains NaN or inf", path)
    return a.reshape(shape)


def _num(d: dict, key: str, path: Path, default: float | None = None) -> float:
    if key not in d or d[key] is None:
        if default is not None:
            return float(default)
        raise InputError(f"calibration lacks {key!r}", path)
    v = d[key]
    if isinstance(v, bool):
        raise InputError(f"{key!r} must be a number", path)
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{key!r} must be a number, got {v!r}", path) from None
    if not np.isfinite(x):
        raise InputError(f"{key!r} must be finite", path)
    return x


def _int(d: dict, key: str, path: Path, default: int | None = None) -> int:
    x = _num(d, key, path, None if default is None else float(default))
    if x != int(x) or x <= 0:
        raise InputError(f"{key!r} must be a positive integer, got {x!r}", path)
    return int(x)


def _distortion_name(model: object, path: Path) -> str:
    m = str(model or "").strip().lower()
    if m in _RADTAN_ALIASES:
        return "radtan"
    if m in _EQUI_ALIASES:
        return "equidistant"
    raise InputError(f"unsupported distortion model {model!r} (supported: radtan/plumb_bob, equidistant)", path)


def _K(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _rig_from_rect(K1, D1, R1, P1, K2, D2, R2, P2, size1, size2, model: str, path: Path) -> StereoRig:
    """Rig with the file's rectification (ROS / ORB-SLAM2 style R1, P1, R2, P2).

    The extrinsics follow from the rectification: ``x_rect1 = R1 x_l``, ``x_rect2 = R2 x_r = x_rect1 - [b, 0, 0]``
    so ``R = R2^T R1`` and ``T = -R2^T [b, 0, 0]`` with ``b = (P1[0,3] - P2[0,3]) / P2[0,0]``.
    """
    P1 = np.asarray(P1, float).reshape(3, 4)
    P2 = np.asarray(P2, float).reshape(3, 4)
    R1 = np.asarray(R1, float).reshape(3, 3)
    R2 = np.asarray(R2, float).reshape(3, 3)
    if P2[0, 0] <= 0:
        raise InputError("right projection matrix P has a non-positive focal length", path)
    b = (P1[0, 3] - P2[0, 3]) / P2[0, 0]
    R = R2.T @ R1
    T = -R2.T @ np.array([b, 0.0, 0.0])
    left = CameraModel(K1, D1, size1[0], size1[1], model)
    right = CameraModel(K2, D2, size2[0], size2[1], model)
    rect = (R1, R2, P1, P2)
    if not np.any(D1) and not np.any(D2) and np.allclose(R1, np.eye(3)) and np.allclose(R2, np.eye(3)) \
            and np.allclose(K1, P1[:3, :3]) and np.allclose(K2, P2[:3, :3]):
        rect = None  # images are rectified already: nothing to remap
        left = CameraModel(P1[:3, :3], np.zeros(5), size1[0], size1[1])
        right = CameraModel(P1[:3, :3], np.zeros(5), size2[0], size2[1])
    return StereoRig(left, right, R, T, rect=rect, source=path)


# ----------------------------------------------------------------------------------------------
# format parsers
# ----------------------------------------------------------------------------------------------


def parse_seedmap_calib(d: dict, path: Path) -> StereoRig:
    """seedmap's own rectified ``calib.yaml``."""
    b = _num(d, "baseline_m", path)
    if b <= 0:
        raise InputError(f"baseline_m is {b:g}: it must be positive (right camera at +x of the left); a negative "
                         "value means swapped cameras or a sign error", path)
    try:
        calib = StereoCalib(fx=_num(d, "fx", path), fy=_num(d, "fy", path), cx=_num(d, "cx", path),
                            cy=_num(d, "cy", path), baseline=_num(d, "baseline_m", path),
                            width=_int(d, "image_width", path), height=_int(d, "image_height", path))
    except InputError:
        raise
    except SeedmapError as e:
        raise InputError(str(e), path) from None
    return StereoRig.from_calib(calib, source=path)


def _ros_camera(d: dict, path: Path) -> tuple:
    w = _int(d, "image_width", path)
    h = _int(d, "image_height", path)
    K = _arr(d, "camera_matrix", (3, 3), path)
    Dd = d.get("distortion_coefficients")
    D = np.zeros(5) if Dd is None else _arr(d, "distortion_coefficients", _count(Dd, path), path)
    R = _arr(d, "rectification_matrix", (3, 3), path, default=np.eye(3))
    P = _arr(d, "projection_matrix", (3, 4), path)
    model = _distortion_name(d.get("distortion_model", "plumb_bob"), path)
    return K, D, R, P, (w, h), model


def _count(v, path: Path) -> int:
    if isinstance(v, dict):
        v = v.get("data", [])
    if not isinstance(v, (list, tuple, np.ndarray)):
        raise InputError("distortion coefficients must be a list of numbers", path)
    n = len(v)
    if n not in (4, 5, 8, 12, 14):
        raise InputError(f"distortion needs 4, 5, 8, 12 or 14 coefficients, got {n}", path)
    return n


def parse_ros_camera_info(left: dict, right: dict, left_path: Path, right_path: Path) -> StereoRig:
    """ROS ``camera_info`` YAML files of the left and right camera (K, D, R, P as ``image_proc`` uses them)."""
    K1, D1, R1, P1, s1, m1 = _ros_camera(left, left_path)
    K2, D2, R2, P2, s2, m2 = _ros_camera(right, right_path)
    if m1 != m2:
        raise InputError(f"left uses {m1} distortion but right uses {m2}", right_path)
    if not np.any(P2[:, :3]):
        raise InputError("projection_matrix is all zero: the camera_info lacks a stereo rectification "
                         "(calibrate the pair with camera_calibration, or give a Kalibr camchain)", right_path)
    return _rig_from_rect(K1, D1, R1, P1, K2, D2, R2, P2, s1, s2, m1, left_path)


def parse_kalibr_camchain(d: dict, path: Path) -> StereoRig:
    """Kalibr camchain: ``cam0``/``cam1`` with ``intrinsics [fu fv pu pv]``, ``distortion_coeffs``,
    ``resolution [w h]`` and, on cam1, ``T_cn_cnm1`` (maps cam0 coordinates to cam1: our ``[R|T]``)."""
    cams = []
    for name in ("cam0", "cam1"):
        c = d.get(name)
        if not isinstance(c, dict):
            raise InputError(f"camchain lacks {name!r}", path)
        model = str(c.get("camera_model", "pinhole")).lower()
        if model != "pinhole":
            raise InputError(f"{name}: camera_model {model!r} unsupported (only pinhole)", path)
        fu, fv, pu, pv = _arr(c, "intrinsics", 4, path)
        w, h = _arr(c, "resolution", 2, path)
        dist = _distortion_name(c.get("distortion_model", "radtan"), path)
        D = _arr(c, "distortion_coeffs", 4, path, default=np.zeros(4))
        if w <= 0 or h <= 0 or w != int(w) or h != int(h):
            raise InputError(f"{name}: resolution must be two positive integers", path)
        cams.append(CameraModel(_K(fu, fv, pu, pv), D, int(w), int(h), dist))
    T = _arr(d["cam1"], "T_cn_cnm1", (4, 4), path)
    if cams[0].distortion != cams[1].distortion:
        raise InputError("cam0 and cam1 use different distortion models", path)
    return StereoRig(cams[0], cams[1], T[:3, :3], T[:3, 3], source=path)


def _euroc_camera(d: dict, path: Path) -> tuple[CameraModel, np.ndarray]:
    model = str(d.get("camera_model", "pinhole")).lower()
    if model != "pinhole":
        raise InputError(f"camera_model {model!r} unsupported (only pinhole)", path)
    fu, fv, cu, cv = _arr(d, "intrinsics", 4, path)
    w, h = _arr(d, "resolution", 2, path)
    if w <= 0 or h <= 0 or w != int(w) or h != int(h):
        raise InputError("resolution must be two positive integers", path)
    dist = _distortion_name(d.get("distortion_model", "radtan"), path)
    D = _arr(d, "distortion_coefficients", 4, path)
    T_BS = _arr(d, "T_BS", (4, 4), path)
    return CameraModel(_K(fu, fv, cu, cv), D, int(w), int(h), dist), T_BS


def parse_euroc_pair(left: dict, right: dict, left_path: Path, right_path: Path) -> tuple[StereoRig, np.ndarray]:
    """EuRoC ``sensor.yaml`` of cam0 and cam1 -> rig and ``T_B_cam0`` (body <- left camera, 4x4)."""
    c0, T_B0 = _euroc_camera(left, left_path)
    c1, T_B1 = _euroc_camera(right, right_path)
    if c0.distortion != c1.distortion:
        raise InputError("cam0 and cam1 use different distortion models", right_path)
    try:
        T_10 = np.linalg.inv(T_B1) @ T_B0
    except np.linalg.LinAlgError:
        raise InputError("T_BS is singular", right_path) from None
    return StereoRig(c0, c1, T_10[:3, :3], T_10[:3, 3], source=left_path), T_B0


def parse_opencv_settings(d: dict, path: Path) -> StereoRig:
    """ORB-SLAM2/3 style OpenCV settings (see module docstring for the three variants)."""
    def mat(key: str, shape) -> np.ndarray:
        v = d.get(key)
        if isinstance(v, np.ndarray):
            if v.size != int(np.prod(shape)):
                raise InputError(f"{key!r} must have {int(np.prod(shape))} numbers, got {v.size}", path)
            if not np.all(np.isfinite(v)):
                raise InputError(f"{key!r} contains NaN or inf", path)
            return v.astype(float).reshape(shape)
        return _arr(d, key, shape, path)

    def size_of(prefix: str) -> tuple[int, int]:
        for p in (prefix, "Camera"):
            if f"{p}.width" in d and f"{p}.height" in d:
                return _int(d, f"{p}.width", path), _int(d, f"{p}.height", path)
        raise InputError(f"calibration lacks {prefix}.width/{prefix}.height (image size)", path)

    def radtan(prefix: str) -> np.ndarray:
        keys = ("k1", "k2", "p1", "p2", "k3")
        D = [_num(d, f"{prefix}.{k}", path, default=0.0) for k in keys]
        return np.asarray(D)

    if "LEFT.K" in d or "RIGHT.K" in d:
        size = size_of("LEFT")
        sizer = (_int(d, "RIGHT.width", path), _int(d, "RIGHT.height", path)) if "RIGHT.width" in d else size
        Dl = _dist_vec(d, "LEFT.D", path)
        Dr = _dist_vec(d, "RIGHT.D", path)
        return _rig_from_rect(mat("LEFT.K", (3, 3)), Dl, mat("LEFT.R", (3, 3)), mat("LEFT.P", (3, 4)),
                              mat("RIGHT.K", (3, 3)), Dr, mat("RIGHT.R", (3, 3)), mat("RIGHT.P", (3, 4)),
                              size, sizer, "radtan", path)
    if "Camera1.fx" in d and "Stereo.T_c1_c2" in d:
        cams = []
        ctype = str(d.get("Camera.type", "PinHole")).lower()
        dist = "equidistant" if ctype in ("kannalabrandt8", "kannala_brandt", "fisheye") else "radtan"
        for p in ("Camera1", "Camera2"):
            K = _K(_num(d, f"{p}.fx", path), _num(d, f"{p}.fy", path), _num(d, f"{p}.cx", path),
                   _num(d, f"{p}.cy", path))
            D = (np.asarray([_num(d, f"{p}.k{i}", path, 0.0) for i in range(1, 5)]) if dist == "equidistant"
                 else radtan(p))
            w, h = size_of(p)
            cams.append(CameraModel(K, D, w, h, dist))
        T12 = mat("Stereo.T_c1_c2", (4, 4))
        try:
            T21 = np.linalg.inv(T12)
        except np.linalg.LinAlgError:
            raise InputError("Stereo.T_c1_c2 is singular", path) from None
        return StereoRig(cams[0], cams[1], T21[:3, :3], T21[:3, 3], source=path)
    prefix = "Camera1" if "Camera1.fx" in d else "Camera"
    if f"{prefix}.fx" not in d:
        raise InputError("no stereo calibration found (expected Camera.fx..., LEFT.K/RIGHT.K, or Camera1.*)", path)
    fx = _num(d, f"{prefix}.fx", path)
    K = _K(fx, _num(d, f"{prefix}.fy", path), _num(d, f"{prefix}.cx", path), _num(d, f"{prefix}.cy", path))
    if "Stereo.b" in d:
        b = _num(d, "Stereo.b", path)
    elif "Camera.bf" in d:
        b = _num(d, "Camera.bf", path) / fx
    else:
        raise InputError("calibration lacks the baseline (Camera.bf or Stereo.b)", path)
    if b <= 0:
        raise InputError(f"baseline is {b:.6g} m: it must be positive (Camera.bf = fx * baseline, right camera at "
                         "+x of the left); check its sign or swap the cameras", path)
    w, h = size_of(prefix)
    D = radtan(prefix)
    cam = CameraModel(K, D, w, h)
    return StereoRig(cam, cam, np.eye(3), np.array([-b, 0.0, 0.0]), source=path)


def _dist_vec(d: dict, key: str, path: Path) -> np.ndarray:
    """A distortion vector (OpenCV matrix or list) of 4, 5, 8, 12 or 14 numbers; zeros when absent."""
    v = d.get(key)
    if v is None:
        return np.zeros(5)
    try:
        a = np.asarray(v.get("data") if isinstance(v, dict) else v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{key!r} must be numbers", path) from None
    if a.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(a)):
        raise InputError(f"{key!r} needs 4, 5, 8, 12 or 14 finite numbers, got {a.size}", path)
    return a


_KITTI_LINE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)$")


def read_kitti_calib_file(path: Path) -> dict[str, np.ndarray]:
    """``KEY: numbers`` lines (KITTI calib.txt / calib_cam_to_cam.txt); non-numeric values are skipped."""
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found", path)
    try:
        text = path.read_text()
    except (UnicodeDecodeError, OSError):
        raise InputError("calibration file is not text", path) from None
    out: dict[str, np.ndarray] = {}
    for i, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        m = _KITTI_LINE.match(line)
        if not m:
            raise InputError(f"line {i}: expected 'KEY: numbers'", path)
        key, rest = m.group(1), m.group(2).split()
        try:
            vals = np.array([float(x) for x in rest])
        except ValueError:
            continue  # e.g. calib_time: 09-Jan-2012 13:57:47
        out[key] = vals
    return out


def parse_kitti_calib(path: Path, cams: tuple[int, int] = (2, 3),
                      image_size: tuple[int, int] | None = None) -> StereoRig:
    """KITTI rectified projections ``P{i}`` (odometry calib.txt) or ``P_rect_0{i}`` (raw calib_cam_to_cam.txt).

    The baseline is ``(P_l[0,3] - P_r[0,3]) / fx`` (0.54 m for cams 0/1 and ~0.53 m for 2/3). The size
    comes from ``S_rect_0{i}`` when present, else ``image_size`` (odometry calib.txt has none).
    """
    path = Path(path)
    d = read_kitti_calib_file(path)
    P = []
    for c in cams:
        for key in (f"P{c}", f"P_rect_{c:02d}"):
            if key in d:
                if d[key].size != 12:
                    raise InputError(f"{key} must have 12 numbers, got {d[key].size}", path)
                if not np.all(np.isfinite(d[key])):
                    raise InputError(f"{key} contains NaN or inf", path)
                P.append(d[key].reshape(3, 4))
                break
        else:
            raise InputError(f"calibration lacks P{c} (or P_rect_{c:02d})", path)
    key = f"S_rect_{cams[0]:02d}"
    if key in d and d[key].size == 2:
        image_size = (int(d[key][0]), int(d[key][1]))
    if image_size is None:
        raise InputError("calibration has no image size (pass it from the images)", path)
    if P[0][0, 0] <= 0 or P[0][1, 1] <= 0:
        raise InputError(f"P{cams[0]} has non-positive focal lengths", path)
    calib = _calib_from_P(np.hstack([P[0][:, :3], np.zeros((3, 1))]),
                          np.hstack([P[0][:, :3], (P[1][:, 3:] - P[0][:, 3:])]), image_size, path)
    return StereoRig.from_calib(calib, source=path)


def kitti_cam_offset(path: Path, cam: int) -> np.ndarray:
    """``T_cam0_camX`` (4x4) of rectified KITTI camera ``cam`` from its ``P`` (pure translation)."""
    d = read_kitti_calib_file(path)
    key = f"P{cam}" if f"P{cam}" in d else f"P_rect_{cam:02d}"
    if key not in d or d[key].size != 12:
        raise InputError(f"calibration lacks P{cam}", path)
    Pm = d[key].reshape(3, 4)
    t = np.linalg.solve(Pm[:, :3], Pm[:, 3])  # x_camX = x_cam0 + t
    T = np.eye(4)
    T[:3, 3] = -t
    return T


def parse_gtsam_stereo_calib(path: Path, image_size: tuple[int, int] | None = None) -> StereoRig:
    """GTSAM stereo VO calibration: one line ``fx fy skew u0 v0 baseline`` (no size: pass ``image_size``,
    default ``(2*u0+1, 2*v0+1)`` rounded, i.e. principal point at the centre)."""
    path = Path(path)
    try:
        toks = path.read_text().split()
        vals = [float(x) for x in toks]
    except (UnicodeDecodeError, OSError, ValueError):
        raise InputError("expected six numbers 'fx fy skew u0 v0 baseline'", path) from None
    if len(vals) != 6:
        raise InputError(f"expected six numbers 'fx fy skew u0 v0 baseline', got {len(vals)}", path)
    fx, fy, skew, u0, v0, b = vals
    if not np.all(np.isfinite(vals)):
        raise InputError("calibration contains NaN or inf", path)
    if abs(skew) > 1e-9:
        raise InputError(f"skew {skew} != 0 is not supported", path)
    if b <= 0:
        raise InputError(f"baseline {b} must be positive (right camera at +x of the left)", path)
    if image_size is None:
        image_size = (max(1, int(round(2 * u0 + 1))), max(1, int(round(2 * v0 + 1))))
    try:
        calib = StereoCalib(fx, fy, u0, v0, b, int(image_size[0]), int(image_size[1]))
    except SeedmapError as e:
        raise InputError(str(e), path) from None
    return StereoRig.from_calib(calib, source=path)


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
        try:
            head = path.read_text()
        except (UnicodeDecodeError, OSError):
            raise InputError("calibration file is not text", path) from None
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
