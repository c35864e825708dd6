"""Small typed records that modules exchange.

Conventions (the whole package follows them):

* Units are metres, seconds and pixels.
* Images are ``H x W x 3`` ``uint8`` arrays in **RGB** order (loaders convert from OpenCV's BGR).
* Pixel coordinates: ``(u, v)`` = (column, row); the centre of the top-left pixel is ``(0, 0)``
  (OpenCV's convention), so a pixel ``[r, c]`` covers ``u in [c - 0.5, c + 0.5)``.
* Poses are ``T_world_cam`` 4x4 matrices; the camera frame is the optical frame of the **left**
  camera (x right, y down, z forward). The right camera of a rectified pair sits at
  ``+baseline`` along the left camera's x axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seedmap.errors import ConfigError


@dataclass(frozen=True)
class StereoCalib:
    """A rectified stereo pair: shared pinhole intrinsics and a horizontal baseline (metres)."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (self.baseline > 0 and np.isfinite(self.baseline)):
            raise ConfigError(f"stereo baseline must be positive and finite, got {self.baseline!r} m")
        if not (self.fx > 0 and self.fy > 0 and np.isfinite(self.fx) and np.isfinite(self.fy)):
            raise ConfigError(f"focal lengths must be positive and finite, got fx={self.fx!r}, fy={self.fy!r}")
        if self.width <= 0 or self.height <= 0:
            raise ConfigError(f"image size must be positive, got {self.width}x{self.height}")
        if not (np.isfinite(self.cx) and np.isfinite(self.cy)):
            raise ConfigError(f"principal point must be finite, got cx={self.cx!r}, cy={self.cy!r}")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def P_left(self) -> np.ndarray:
        """3x4 projection matrix of the left camera (OpenCV ``P1``)."""
        return np.hstack([self.K, np.zeros((3, 1))])

    @property
    def P_right(self) -> np.ndarray:
        """3x4 projection matrix of the right camera (OpenCV ``P2``: ``P[0, 3] = -fx * baseline``)."""
        P = self.P_left.copy()
        P[0, 3] = -self.fx * self.baseline
        return P

    @property
    def Q(self) -> np.ndarray:
        """4x4 disparity-to-depth matrix (OpenCV ``Q``) for ``cv2.reprojectImageTo3D``."""
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.cx],
                [0.0, 1.0, 0.0, -self.cy],
                [0.0, 0.0, 0.0, self.fx],
                [0.0, 0.0, 1.0 / self.baseline, 0.0],
            ]
        )

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` as OpenCV wants it."""
        return (self.width, self.height)

    def scaled(self, scale: float) -> StereoCalib:
        """The same rig imaged at ``scale`` times the resolution (pixel-centre convention kept)."""
        w = int(round(self.width * scale))
        h = int(round(self.height * scale))
        sx, sy = w / self.width, h / self.height
        return StereoCalib(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            baseline=self.baseline,
            width=w,
            height=h,
        )

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project ``(N, 3)`` points in the left camera frame.

        Returns ``(uv_left (N, 2), u_right (N,))``; points behind the camera give NaN.
        """
        p = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        z = np.where(p[:, 2] > 1e-9, p[:, 2], np.nan)
        u = self.fx * p[:, 0] / z + self.cx
        v = self.fy * p[:, 1] / z + self.cy
        ur = u - self.fx * self.baseline / z
        return np.stack([u, v], axis=1), ur

    def disparity_of_depth(self, z: np.ndarray | float) -> np.ndarray:
        return self.fx * self.baseline / np.asarray(z, dtype=float)

    def triangulate(self, uv_left: np.ndarray, u_right: np.ndarray) -> np.ndarray:
        """Rectified-stereo triangulation: ``(N, 2)`` left pixels and ``(N,)`` right columns ->
        ``(N, 3)`` points in the left camera frame. Non-positive disparity gives NaN."""
        uv = np.asarray(uv_left, dtype=float).reshape(-1, 2)
        d = uv[:, 0] - np.asarray(u_right, dtype=float).reshape(-1)
        d = np.where(d > 1e-9, d, np.nan)
        z = self.fx * self.baseline / d
        x = (uv[:, 0] - self.cx) * z / self.fx
        y = (uv[:, 1] - self.cy) * z / self.fy
        return np.stack([x, y, z], axis=1)

    def to_dict(self) -> dict:
        """Plain YAML-able form, including OpenCV-style matrices for other tools."""
        return {
            "model": "pinhole_rectified_stereo",
            "image_width": self.width,
            "image_height": self.height,
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "baseline_m": float(self.baseline),
            "K": self.K.tolist(),
            "D": [0.0, 0.0, 0.0, 0.0, 0.0],
            "P1": self.P_left.tolist(),
            "P2": self.P_right.tolist(),
            "R": np.eye(3).tolist(),
            "T": [-float(self.baseline), 0.0, 0.0],
            "Q": self.Q.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> StereoCalib:
        return cls(
            fx=float(d["fx"]),
            fy=float(d["fy"]),
            cx=float(d["cx"]),
            cy=float(d["cy"]),
            baseline=float(d["baseline_m"]),
            width=int(d["image_width"]),
            height=int(d["image_height"]),
        )


@dataclass
class StereoFrame:
    """One rectified stereo pair at one instant."""

    index: int
    timestamp: float
    left: np.ndarray
    right: np.ndarray


@dataclass
class Detections:
    """Seeds found in one image.

    ``ellipses`` rows are ``(cx, cy, major, minor, angle_deg)`` with *full* axis lengths in pixels
    and the angle as ``cv2.fitEllipse`` reports it; ``keypoints`` are the ellipse centres.
    ``seed_ids`` are ground-truth ids for oracle/evaluation use, ``-1`` where unknown.
    """

    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))  # x0, y0, x1, y1
    scores: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.float32))
    ellipses: np.ndarray = field(default_factory=lambda: np.zeros((0, 5), np.float32))
    seed_ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.boxes = np.asarray(self.boxes, np.float32).reshape(-1, 4)
        self.scores = np.asarray(self.scores, np.float32).reshape(-1)
        self.ellipses = np.asarray(self.ellipses, np.float32).reshape(-1, 5)
        n = len(self.ellipses)
        if len(self.boxes) != n or len(self.scores) != n:
            raise ValueError(f"Detections: {len(self.boxes)} boxes, {len(self.scores)} scores, {n} ellipses")
        if self.seed_ids is None:
            self.seed_ids = np.full(n, -1, np.int64)
        self.seed_ids = np.asarray(self.seed_ids, np.int64).reshape(-1)

    def __len__(self) -> int:
        return len(self.ellipses)

    @property
    def keypoints(self) -> np.ndarray:
        """``(N, 2)`` float64 ellipse centres ``(u, v)`` in full-image pixels."""
        return self.ellipses[:, :2].astype(np.float64)

    def subset(self, idx: np.ndarray) -> Detections:
        return Detections(self.boxes[idx], self.scores[idx], self.ellipses[idx], self.seed_ids[idx])


@dataclass
class StereoDetections:
    """Detections in both images of one stereo frame."""

    index: int
    timestamp: float
    left: Detections
    right: Detections


@dataclass
class Matches:
    """A one-to-one association between keypoints of image A (``idx_a``) and image B (``idx_b``)."""

    idx_a: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.int64))
    idx_b: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.int64))
    cost: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.float64))

    def __post_init__(self) -> None:
        self.idx_a = np.asarray(self.idx_a, np.int64).reshape(-1)
        self.idx_b = np.asarray(self.idx_b, np.int64).reshape(-1)
        self.cost = np.asarray(self.cost, np.float64).reshape(-1)
        if not (len(self.idx_a) == len(self.idx_b) == len(self.cost)):
            raise ValueError("Matches: idx_a, idx_b and cost must have the same length")

    def __len__(self) -> int:
        return len(self.idx_a)


@dataclass
class Trajectory:
    """Timestamped poses ``T_world_cam`` (N x 4 x 4)."""

    timestamps: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, np.float64).reshape(-1, 4, 4)
        if len(self.timestamps) != len(self.poses):
            raise ValueError("Trajectory: timestamps and poses differ in length")

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions(self) -> np.ndarray:
        return self.poses[:, :3, 3]

    def path_length(self) -> np.ndarray:
        """Cumulative distance travelled (metres) at each pose, starting at 0."""
        if len(self) == 0:
            return np.zeros(0)
        steps = np.linalg.norm(np.diff(self.positions, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(steps)])
