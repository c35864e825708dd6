"""The calibration records: one camera's intrinsics and distortion, a stereo rig, rectification maps, their checks.

Extrinsic convention (OpenCV's ``stereoCalibrate``): ``x_right = R @ x_left + T`` in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

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
