"""Parsers of other tools' stereo calibration files, each giving a :class:`~seedmap.io.rig.StereoRig`.

Formats: seedmap ``calib.yaml``, ROS ``camera_info`` pairs, Kalibr camchains, OpenCV FileStorage (ORB-SLAM2/3
settings), EuRoC ``sensor.yaml`` pairs, KITTI ``calib.txt`` / ``calib_cam_to_cam.txt``, GTSAM's stereo VO line.
:func:`seedmap.io.calibration.load_rig` picks the parser from the content.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import yaml

from seedmap.errors import InputError, SeedmapError
from seedmap.io.rig import _EQUI_ALIASES, _RADTAN_ALIASES, CameraModel, StereoRig, _calib_from_P
from seedmap.io.text import read_text
from seedmap.records import StereoCalib


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
    text = read_text(path, "calibration file")
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


def check_principal_point(calib: StereoCalib, path: Path) -> StereoCalib:
    """A calibration file's principal point lies in its own image, or near it (half an image) after an
    off-centre rectification; ``cx=-5000`` ran to the end with every frame lost."""
    w, h = calib.width, calib.height
    if not (-0.5 * w <= calib.cx <= 1.5 * w and -0.5 * h <= calib.cy <= 1.5 * h):
        raise InputError(f"principal point (cx={calib.cx:g}, cy={calib.cy:g}) is outside the {w}x{h} image", path)
    return calib


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
    return StereoRig.from_calib(check_principal_point(calib, path), source=path)


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
    text = read_text(path, "calibration file")
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
    toks = read_text(path, "calibration file").split()
    try:
        vals = [float(x) for x in toks]
    except ValueError:
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
