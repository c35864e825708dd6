"""Typed configuration of the panicle reconstruction pipeline (``seedmap reconstruct`` / ``count``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from seedmap.config import ConfigModel, apply_overrides
from seedmap.io.options import DatasetOptions

#: Per-detector settings of the multiview counter, applied on top of CountConfig by CountConfig.for_detector
#: (chosen per detector on tuning panicles only; docs/method/counting.md). ``gt``: joint four-ray links at 1.5 px
#: and pixel tolerances scaled with the seed size; ``fast``: doubled, size-scaled pixel tolerances, joins of
#: view-sharing tracks within 0.6 diameters, stereo candidates weighted by their row residual, a second linking pass.
DETECTOR_PROFILES: dict[str, list[str]] = {
    "gt": ["mv_link_joint=true", "mv_link_px=1.5", "mv_scale_ref_px=7.0", "mv_scale_power=1.5"],
    "fast": ["mv_dedupe_shared=0.6", "mv_stereo_dv_px=4", "mv_link_px=4", "mv_max_reproj_px=5", "mv_grow_px=4",
             "mv_min_support=0.5", "mv_scale_ref_px=6.0", "mv_scale_power=1.5",
             "mv_row_sigma_px=1.5", "mv_relink_px=10", "mv_relink_min_support=1.5"],
}


class SgbmConfig(ConfigModel):
    """OpenCV StereoSGBM settings (pixels); the disparity range follows the depth range of :class:`CloudConfig`."""

    #: matching block size (px)
    block_size: int = Field(3, ge=1)
    #: uniqueness margin of the best disparity (percent)
    uniqueness_ratio: int = Field(10, ge=0)
    #: run SGBM on images scaled by this factor (speed)
    downscale: float = Field(1.0, gt=0, le=1)
    #: match only the bounding box of flash-lit pixels (speed; the unlit background has no depth anyway)
    crop_to_lit: bool = True


class CloudConfig(ConfigModel):
    """Per-view point cloud: depth limits (m) and voxel size (m); the depth limits also bound the seed search."""

    #: nearest depth kept (m)
    min_depth: float = Field(0.2, gt=0)
    #: farthest depth kept (m)
    max_depth: float = Field(0.42, gt=0)
    #: voxel of the per-view and merged clouds (m)
    voxel_size: float = Field(0.001, gt=0)
    #: drop pixels darker than this (unlit background, where SGBM matches noise)
    min_intensity: int = Field(20, ge=0, le=255)


class RegisterConfig(ConfigModel):
    """Refining the FK poses by ICP against the growing model (seedmap.recon.register)."""

    #: fk = forward kinematics only; full = full-cloud ICP; seeds = ICP on the seed centres (the paper's)
    mode: Literal["fk", "full", "seeds"] = "seeds"
    #: larger ICP corrections are rejected (m)
    max_correction_m: float = Field(0.02, gt=0)
    #: larger ICP rotations are rejected (degrees)
    max_correction_deg: float = Field(5.0, gt=0)


class CountConfig(ConfigModel):
    """Seed counting (seedmap.recon.count; docs/method/counting.md)."""

    #: multiview = 2D association + triangulation (default); density = the paper's DBSCAN + density maxima on
    #: per-view 3D seed centres
    method: Literal["multiview", "density"] = "multiview"
    #: views that must support a seed
    min_observations: int = Field(2, ge=1)
    #: views are ordered around a closed circle (lags wrap around)
    circular: bool = True
    #: multiview: link stereo matches of views up to this many steps apart
    max_lag: int = Field(3, ge=1)
    #: density: DBSCAN neighbourhood (m) that separates seed groups and outliers
    dbscan_eps: float = Field(0.004, gt=0)
    #: density: Gaussian density smoothing sigma (m)
    bandwidth: float = Field(0.0008, gt=0)
    #: density: minimum distance of two seed centres, in median seed diameters
    separation: float = Field(0.6, gt=0)
    #: multiview: max row difference of a left/right match (px)
    mv_stereo_dv_px: float = Field(2.0, gt=0)
    #: multiview: reprojection scale of the neighbouring views' support score (px)
    mv_support_sigma_px: float = Field(1.0, gt=0)
    #: multiview: minimum support of a stereo match (sum over the verifying images, each <= 1)
    mv_min_support: float = Field(1.5, ge=0)
    #: multiview: stereo assignment weight exp(-dv^2 / 2 sigma^2) of the pair's row difference dv (px; 0 = off)
    mv_row_sigma_px: float = Field(0.0, ge=0)
    #: multiview: max reprojection error of a cross-view link (px)
    mv_link_px: float = Field(2.0, gt=0)
    #: multiview: link two views through the point of all four rays (instead of each view's stereo point)
    mv_link_joint: bool = False
    #: multiview: second linking pass for tracks short of min_observations, this tolerance (px; <= mv_link_px = off)
    mv_relink_px: float = Field(0.0, ge=0)
    #: multiview: the second pass links only stereo matches with at least this support
    mv_relink_min_support: float = Field(2.5, ge=0)
    #: multiview: observations reprojecting farther from their track's point are dropped (px)
    mv_max_reproj_px: float = Field(2.5, gt=0)
    #: multiview: tracks claim left+right keypoints this close to their projection in views they lack (px; 0 = off)
    mv_grow_px: float = Field(2.0, ge=0)
    #: multiview: join counted tracks sharing no view closer than this many median seed diameters
    mv_dedupe: float = Field(0.9, ge=0)
    #: multiview: join counted tracks closer than this many median diameters even when they share views (0 = off)
    mv_dedupe_shared: float = Field(0.0, ge=0)
    #: multiview: pixel tolerances are for seeds of this median detection size (px); larger ones scale them (0 = off)
    mv_scale_ref_px: float = Field(0.0, ge=0)
    #: multiview: exponent of the size ratio of that scaling
    mv_scale_power: float = Field(1.0, ge=0)
    #: calibrated count estimate (seedmap.recon.calibrate): auto = the shipped calibration of the run's detector
    #: where the run matches it, none, or a file from `seedmap train count-calibration`
    calibration: str = "auto"
    #: apply the detector's profile (DETECTOR_PROFILES) on top of these settings (false = exactly these settings)
    detector_profile: bool = True

    def for_detector(self, detector: str) -> CountConfig:
        """These settings with the profile of ``detector`` applied (unless ``detector_profile`` is
        false or the detector has none); the result has ``detector_profile`` false (applied once)."""
        ov = DETECTOR_PROFILES.get(detector, []) if self.detector_profile else []
        if not ov:
            return self
        data = apply_overrides(self.model_dump(), list(ov))
        data["detector_profile"] = False
        return type(self).model_validate(data)


class ReconConfig(ConfigModel):
    """Whole reconstruction run (defaults suit the simulated UR5 scan at 0.3 m stand-off)."""

    #: random seed of the quality scores' sampling
    seed: int = 0
    #: detector name (seedmap.detect); ``gt`` reads the simulator's ground truth (ORACLE, simulated scans only)
    detector: str = "fast"
    #: key=value overrides of the detector config (``fast`` runs its arm-scan network at threshold 0.4); setting
    #: this list replaces all three defaults, so keep the ones you want
    detector_overrides: list[str] = Field(default_factory=lambda: ["gt.min_area_px=12", "cnn.domain=arm",
                                                                  "cnn.threshold=0.4"])
    sgbm: SgbmConfig = Field(default_factory=SgbmConfig)
    cloud: CloudConfig = Field(default_factory=CloudConfig)
    registration: RegisterConfig = Field(default_factory=RegisterConfig)
    count: CountConfig = Field(default_factory=CountConfig)
    #: how the scan is opened: seedmap layout, or any format seedmap reads (an image folder with a Kalibr /
    #: ROS / OpenCV calibration, a bag...), e.g. ``--set dataset.format=folder`` (see seedmap.io)
    dataset: DatasetOptions = Field(default_factory=DatasetOptions)
    #: measured joint angles, one row per view (``view,q1..q6`` in radians); None = ``joints.csv`` beside the
    #: images (in the dataset folder, or next to a bag file)
    joints: str | None = None
    #: the arm description (UR5 DH, base pose, hand-eye); None = ``arm.yaml`` beside the images
    arm: str | None = None
