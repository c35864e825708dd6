"""Configuration of the semantic stereo SLAM pipeline (``seedmap slam --config/--set``).

Pixel parameters marked *full-res* refer to a 4096 px wide image (facts.md) and are scaled to
the dataset's width at run time, like the gates.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from seedmap.associate.base import GateConfig
from seedmap.associate.semantic import SemanticConfig
from seedmap.detect.config import DetectConfig
from seedmap.io.options import DatasetOptions
from seedmap.config import ConfigModel


class FrontendConfig(ConfigModel):
    """Frame-to-frame motion from matched 3D seeds: RANSAC over 3-point Kabsch fits."""

    #: "translation": 1-point RANSAC translation, rotation left to the graph (see
    #: seedmap.slam.motion.ransac_translation); "se3": 3-point RANSAC + Kabsch
    motion_model: Literal["translation", "se3"] = "translation"
    ransac_iters: int = Field(300, ge=1)
    #: inlier threshold on the stereo reprojection error (max of |du_l|, |du_r|, |dv|), full-res px
    ransac_reproj_px: float = Field(3.0, gt=0)
    refine_iters: int = Field(3, ge=0)


class BackendConfig(ConfigModel):
    """GTSAM factor graph: Pose3 per frame, Point3 per seed landmark, stereo factors."""

    stereo_sigma_px: float = Field(1.0, gt=0)  # image pixels (after scaling)
    huber_k: float = Field(1.345, gt=0)
    prior_sigma_rot_rad: float = Field(1e-4, gt=0)
    prior_sigma_trans_m: float = Field(1e-4, gt=0)
    #: per-frame rotation change the platform is expected to make (1 sigma). 0.002 rad = 0.11 deg per
    #: frame, i.e. ~0.6 deg/s at 5 Hz: a wheeled robot driving slowly along a row (the simulator's
    #: robot wobbles 0.3 deg in amplitude, <= 0.11 deg per frame). Why it matters: with seeds at
    #: nearly one depth, a small pitch and a vertical translation move the image alike, and the
    #: session-3 value 0.005 let the graph trade one for the other (1 m range: 1.1 deg pitch + 15 mm
    #: in one step). Measured (same back-end otherwise): 1 m range seed 3 ATE 7.3 -> 4.7 mm (gt) and
    #: 6.9 -> 4.7 mm (fast, GT-validated 80 -> 100 %); paper2 0.42 -> 0.29 % (gt), 0.39 -> 0.25 %
    #: (fast). 0.001 is better still on the simulator (paper2 0.18 / 0.14 %) but assumes a smoother
    #: platform than a field robot; raise it for rough ground or hand-held rigs.
    between_sigma_rot_rad: float = Field(0.002, gt=0)
    between_sigma_trans_m: float = Field(0.01, gt=0)
    min_observations: int = Field(2, ge=2)
    min_disparity_px: float = Field(20.0, ge=0)  # full-res px (facts.md)
    #: online optimiser per frame
    online: Literal["isam2", "none"] = "isam2"
    #: optional batch optimisation of the whole graph at the end
    final_batch: Literal["none", "lm", "dogleg"] = "lm"
    #: iSAM2 relinearisation: threshold and how many updates between relinearisation checks
    isam_relinearize_threshold: float = Field(0.01, gt=0)
    isam_relinearize_skip: int = Field(1, ge=1)
    #: at most this many new landmarks admitted to the graph per frame (spread over a 16 x 12 image
    #: grid); None = all. The others stay tracks: they still carry the motion estimate and are in
    #: the map (placed from their stereo points with the optimised poses, ``in_graph = 0``), but add
    #: no factors. 150 cut the back-end 10x (paper2, gt: 514 -> 49 ms/frame; final batch 18.3 -> 6.8 s)
    #: and did not hurt accuracy (ATE 0.484 -> 0.418 % there; slam_r1 7.96 -> 7.33 mm with gt,
    #: 7.93 -> 7.37 mm with fast).
    max_new_landmarks: int | None = Field(150, ge=1)
    #: a per-frame correction of the motion estimate larger than this means the optimiser failed
    max_correction_m: float = Field(0.10, gt=0)


class LostConfig(ConfigModel):
    """When the track ends (paper: < 100 3D matches at full resolution with thousands of seeds).

    Our default: fewer than ``min_inliers`` RANSAC-verified 3D seed matches between consecutive
    frames. The simulated ranges at the default 1434 px width give a few hundred verified matches
    per frame pair while panicles are in view, so 12 leaves a wide margin while still well above
    the 3 points a rigid fit needs (a 12-point fit has a pose error of ~1 mm at 0.7 m).
    """

    min_inliers: int = Field(12, ge=3)


class ClusterConfig(ConfigModel):
    """DBSCAN (Open3D) grouping of landmarks into panicles for landmarks.ply / csv."""

    eps_m: float = Field(0.02, gt=0)
    min_points: int = Field(5, ge=1)


class SlamAssociationConfig(SemanticConfig):
    """The pipeline's association defaults: the paper's cost assigned inside a local displacement
    field prior (``refine="field"``, see seedmap.associate.semantic) with the constant-velocity
    temporal prediction. The paper's method unchanged is
    ``--set association.refine=none --set association.temporal_prediction=false``; the session-1
    default was ``--set association.refine=consensus``.

    ``--set association.stereo_prior=sgbm`` (session 4) assigns the stereo pairs around the dense
    SGBM disparity of each left keypoint instead (seedmap.associate.disparity; add
    ``--set association.sgbm_lr_tol_px=3`` for the left-right check, a second SGBM run): higher
    stereo precision *and* recall with the gt oracle (slam_r1: 0.965/0.748 -> 0.979/0.805; fresh
    seed-13 range: 0.944/0.692 -> 0.981/0.824), but it is *not* the default because SLAM on the 1 m
    range gets worse with it (gt: ATE 7.3 -> 7.5 mm, first-pose-aligned 22 -> 34 mm; fast:
    GT-validated MDM 100 -> 76 %, ATE 7.4 -> 7.7 mm) although the 5 m paper2 range gets better
    (ATE 0.42 -> 0.31 % of the distance with gt, 0.39 -> 0.29 % with fast), and the prior costs
    ~220 ms CPU per frame (SGBM).
    Not explained: neither dropping pairs whose disparity disagrees with their neighbours'
    (``prior_max_dev_px``) nor re-centring SGBM on the keypoints (``prior_debias``) removed the
    1 m range's start-of-range drift with the fast detector.
    ``--set association.prior_score=learned`` (session 6, with the sgbm prior) scores the stereo
    candidates by a logistic log-odds (prior residuals, patch NCC, neighbour-prior disagreement,
    the paper's cost) and ``--set association.temporal_min_ncc=0.3`` drops temporal pairs whose
    patches disagree: stereo precision >= 0.99 on two of four ranges, but not the default because
    the trajectories are not better everywhere (README, "Session 6: a learned candidate score").

    ``--set association.stereo_carry=true`` adds the stereo-temporal loop (stereo carried through
    the left and right temporal matches, parallax test, loop check of the temporal matches): much
    higher stereo precision, but it is *not* the default because the SLAM trajectory gets worse with
    it (1 m range, gt detector: ATE 11.6 vs 5.4 mm, see the module docstring of
    seedmap.associate.semantic)."""

    refine: Literal["none", "consensus", "field"] = "field"
    temporal_prediction: bool = True
    stereo_carry: bool = False
    stereo_prior: Literal["none", "sgbm"] = "none"


class SlamConfig(ConfigModel):
    seed: int = 0
    gates: GateConfig = Field(default_factory=GateConfig)
    association: SlamAssociationConfig = Field(default_factory=SlamAssociationConfig)
    frontend: FrontendConfig = Field(default_factory=FrontendConfig)
    backend: BackendConfig = Field(default_factory=BackendConfig)
    lost: LostConfig = Field(default_factory=LostConfig)
    cluster: ClusterConfig = Field(default_factory=ClusterConfig)
    #: how the input is opened (format, bag topics, calibration file...): seedmap.io.options.DatasetOptions
    dataset: DatasetOptions = Field(default_factory=DatasetOptions)
    #: settings of the seed detector (seedmap.detect.config.DetectConfig), e.g. ``--set
    #: detect.cnn.threshold=0.4`` or ``--set detect.exposure.enabled=true``
    detect: DetectConfig = Field(default_factory=DetectConfig)
    #: parameters of the descriptor baselines (seedmap.associate.features.FeatureMatcherConfig)
    features: dict[str, Any] = Field(default_factory=dict)
    #: process at most this many frames (None = all)
    max_frames: int | None = Field(None, ge=1)
    #: the run's matcher (seeds | sift | orb | akaze | surf) and seed detector; a result's config.yaml records
    #: them so that ``seedmap slam DATA --config RESULT/config.yaml`` repeats the run (the --matcher and
    #: --detector options override them; None: seeds and the gt oracle, the options' defaults)
    matcher: str | None = None
    detector: str | None = None
