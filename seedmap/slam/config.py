"""Configuration of the semantic stereo SLAM pipeline (``seedmap slam --config/--set``).

Pixel parameters marked *full-res* refer to a 4096 px wide image (facts.md) and are scaled to
the dataset's width at run time, like the gates.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from seedmap.associate.base import GateConfig
from seedmap.associate.config import SemanticConfig
from seedmap.detect.config import DetectConfig
from seedmap.io.options import DatasetOptions
from seedmap.phenotype.config import PhenotypeConfig
from seedmap.config import ConfigModel


class FrontendConfig(ConfigModel):
    """Frame-to-frame motion from matched 3D seeds (RANSAC)."""

    #: "translation": 1-point RANSAC translation, rotation left to the graph; "se3": 3-point RANSAC + Kabsch
    motion_model: Literal["translation", "se3"] = "translation"
    #: RANSAC hypotheses per frame pair
    ransac_iters: int = Field(300, ge=1)
    #: inlier threshold on the stereo reprojection error (max of |du_l|, |du_r|, |dv|), full-res px
    ransac_reproj_px: float = Field(3.0, gt=0)


class BackendConfig(ConfigModel):
    """GTSAM factor graph: Pose3 per frame, Point3 per seed landmark, stereo factors."""

    #: noise of a stereo observation (image px, after scaling), under a Huber loss
    stereo_sigma_px: float = Field(1.0, gt=0)
    #: expected per-frame rotation change of the platform (1 sigma; 0.002 rad = 0.11 deg, a slow wheeled robot)
    between_sigma_rot_rad: float = Field(0.002, gt=0)
    #: expected per-frame deviation of the translation from the motion estimate (1 sigma, m)
    between_sigma_trans_m: float = Field(0.01, gt=0)
    #: stereo observations a track needs before it becomes a landmark of the graph
    min_observations: int = Field(2, ge=2)
    #: smallest disparity of an observation that counts towards that (full-res px, facts.md)
    min_disparity_px: float = Field(20.0, ge=0)
    #: online optimiser per frame: isam2 (whole graph), fixed_lag (bounded smoother), none (motion only)
    online: Literal["isam2", "fixed_lag", "none"] = "isam2"
    #: fixed_lag: extra frames a pose or landmark stays in the smoother after the last frame that involved it
    lag_frames: int = Field(0, ge=0)
    #: optional batch optimisation of the whole graph at the end
    final_batch: Literal["none", "lm", "dogleg"] = "lm"
    #: most new landmarks admitted to the graph per frame (spread over a 16 x 12 grid; None = all, the rest stay tracks)
    max_new_landmarks: int | None = Field(150, ge=1)


class LostConfig(ConfigModel):
    """When the track ends: too few RANSAC-verified 3D seed matches between consecutive frames
    (docs/method/slam.md)."""

    #: fewest RANSAC-verified 3D seed matches to the previous frame before the track is lost
    min_inliers: int = Field(12, ge=3)


class ClusterConfig(ConfigModel):
    """DBSCAN (Open3D) grouping of landmarks into panicles for landmarks.ply / csv."""

    #: DBSCAN neighbourhood radius (m)
    eps_m: float = Field(0.02, gt=0)
    #: DBSCAN minimum cluster size (landmarks)
    min_points: int = Field(5, ge=1)


class SlamAssociationConfig(SemanticConfig):
    """The pipeline's association: the paper's cost inside a local displacement field with the
    constant-velocity temporal prediction. The paper's method is
    ``--set association.refine=none --set association.temporal_prediction=false``
    (docs/method/association.md)."""

    refine: Literal["none", "field"] = "field"
    temporal_prediction: bool = True


class SlamConfig(ConfigModel):
    """Everything ``seedmap slam`` reads (``--config FILE``, ``--set key=value``)."""

    #: seed of the RANSAC random generator
    seed: int = 0
    gates: GateConfig = Field(default_factory=GateConfig)
    association: SlamAssociationConfig = Field(default_factory=SlamAssociationConfig)
    frontend: FrontendConfig = Field(default_factory=FrontendConfig)
    backend: BackendConfig = Field(default_factory=BackendConfig)
    lost: LostConfig = Field(default_factory=LostConfig)
    cluster: ClusterConfig = Field(default_factory=ClusterConfig)
    #: how the input is opened (format, bag topics, calibration file...): seedmap.io.options.DatasetOptions
    dataset: DatasetOptions = Field(default_factory=DatasetOptions)
    #: settings of the seed detector (seedmap.detect.config.DetectConfig), e.g. ``--set detect.cnn.threshold=0.4``
    detect: DetectConfig = Field(default_factory=DetectConfig)
    #: the phenotype table written with a seeds run (seedmap.phenotype.config.PhenotypeConfig)
    phenotype: PhenotypeConfig = Field(default_factory=PhenotypeConfig)
    #: parameters of the descriptor baselines (seedmap.associate.features.FeatureMatcherConfig)
    features: dict[str, Any] = Field(default_factory=dict)
    #: process at most this many frames (None = all)
    max_frames: int | None = Field(None, ge=1)
    #: frames decoded and detected ahead in a background thread while the current one is associated (0 = none)
    prefetch_frames: int = Field(1, ge=0, le=8)
    #: the run's matcher (seeds | sift | orb | akaze | surf; None: seeds; --matcher overrides it)
    matcher: str | None = None
    #: the run's seed detector (None: the best real detector, `fast`; `gt` is the ORACLE; --detector overrides it)
    detector: str | None = None
