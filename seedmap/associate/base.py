"""The matcher interface shared by the semantic seed matcher and the descriptor baselines.

A matcher turns a stereo frame into :class:`FrameFeatures` (keypoints in both images plus the
left<->right matches) and associates the *left* keypoints of two frames in time. The SLAM
front-end and back-end only see these records, so every matcher runs through the same pipeline,
lost rule and metrics.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from seedmap.config import ConfigModel
from seedmap.records import Matches, StereoFrame

#: Reference image width (px) that the paper's pixel parameters (facts.md) refer to.
FULL_RES_WIDTH = 4096.0


@dataclass
class FrameFeatures:
    """Keypoints of one stereo frame and their stereo matches.

    ``kp_left`` (N, 2) and ``kp_right`` (M, 2) are pixel coordinates; ``stereo`` pairs indices of
    ``kp_left`` with indices of ``kp_right``. Descriptors are present for descriptor matchers only.
    ``seed_ids_*`` carry ground-truth seed ids when known (oracle detector), else -1, and are used
    only for evaluation, never for matching.
    """

    index: int
    timestamp: float
    kp_left: np.ndarray
    kp_right: np.ndarray
    stereo: Matches
    desc_left: np.ndarray | None = None
    desc_right: np.ndarray | None = None
    seed_ids_left: np.ndarray | None = None
    seed_ids_right: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.kp_left = np.asarray(self.kp_left, np.float64).reshape(-1, 2)
        self.kp_right = np.asarray(self.kp_right, np.float64).reshape(-1, 2)
        if self.seed_ids_left is None:
            self.seed_ids_left = np.full(len(self.kp_left), -1, np.int64)
        if self.seed_ids_right is None:
            self.seed_ids_right = np.full(len(self.kp_right), -1, np.int64)


class GateConfig(ConfigModel):
    """Horizontal-travel gates applied to every matcher (facts.md defaults, full-resolution pixels).

    Pixel values are given for a 4096 px wide image and scaled linearly with the actual width.
    ``travel_sign`` is the sign of the image-u shift of static points between consecutive frames:
    -1 when the camera moves towards its +x (points slide left in the image).
    """

    #: stereo: largest row offset |v_l - v_r|
    stereo_max_dy_px: float = 20.0
    #: stereo: smallest disparity u_l - u_r
    stereo_min_disparity_px: float = 50.0
    #: stereo: keypoints this close to the left / right image edge are not matched
    stereo_border_px: float = 200.0
    #: temporal: largest row offset of a candidate pair
    temporal_max_dy_px: float = 250.0
    #: temporal: largest row offset of a kept pair
    temporal_post_max_dy_px: float = 60.0
    #: temporal: smallest u shift along the travel direction
    temporal_min_shift_px: float = 50.0
    #: temporal: keypoints this close to the left / right image edge are not matched
    temporal_border_px: float = 300.0
    #: sign of the image-u shift of static points between frames (-1: the camera moves towards its +x)
    travel_sign: int = -1

    def scaled(self, image_width: int) -> GateConfig:
        """Return a copy with every pixel value scaled to ``image_width``."""
        s = image_width / FULL_RES_WIDTH
        d = self.model_dump()
        for k in list(d):
            if k.endswith("_px"):
                d[k] = d[k] * s
        return GateConfig(**d)


@runtime_checkable
class Matcher(Protocol):
    """What the SLAM pipeline needs from any matcher."""

    name: str

    def features(self, frame: StereoFrame) -> FrameFeatures:
        """Keypoints in both images and their gated left<->right matches."""
        ...

    def match_temporal(self, prev: FrameFeatures, cur: FrameFeatures) -> Matches:
        """Gated matches ``prev.kp_left[idx_a] <-> cur.kp_left[idx_b]``."""
        ...
