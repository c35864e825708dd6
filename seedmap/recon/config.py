"""Typed configuration of the panicle reconstruction pipeline (``seedmap reconstruct`` / ``count``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from seedmap.config import ConfigModel, apply_overrides
from seedmap.io.options import DatasetOptions

#: Per-detector settings of the multiview counter, applied on top of CountConfig by
#: CountConfig.for_detector (the pipeline and ``seedmap count`` pick them from the run's detector
#: name). Chosen on the tuning panicles 95-100 only (benchmarks/bench_recon.py, README):
#: ``gt`` -- the oracle's keypoints are visible-mask centres, exact for whole seeds but biased
#: for partly hidden ones (left and right see different parts), so two views are linked jointly
#: (four rays) with a tighter tolerance; the detectors' noisier keypoints and false positives make
#: ghost tracks that way, so they keep the plain link test. ``fast`` (CNN) fires 2-3 px apart on one
#: seed: keypoints are merged first; both detectors fire more than once on the arm-scan seeds
#: (larger than the row-image seeds they were trained on), so close tracks sharing views are joined.
#: ``gt`` also scales its pixel tolerances with the scan's median detection size (7 px = as configured,
#: factor (size / 7) ** 1.5, session 5: panicle 114 with 9.2-px seeds -17.7 % -> -6.2 %); the detectors'
#: own ellipse sizes hardly follow the seed size (``fast`` 5.5-7 px in 0.5-px steps, ``fast-classic``
#: 5.0-5.3 px where ``gt`` spans 6.3-9.3 px), so scaling by them did not help and they keep fixed pixels.
#: Session 6: ``fast`` on arm scans is the arm-scan network (``cnn.domain=arm``, threshold 0.35, set by
#: ReconConfig.detector_overrides); its keypoints on the large, often flash-saturated arm-scan seeds scatter
#: more than the oracle's, so its pixel tolerances are twice the defaults (row 4 px, link 4 px, reprojection
#: 5 px, growing 4 px). Tuning panicles 95-99 + 111-115: MAPE 7.1 % (-1.6 % signed) against 11.9 % (-11.8 %)
#: for the session-4 network with the session-5 profile (merge 3 px, join 0.8 diameters, default pixels).
#: Session 7 (arm scans exposed for their stand-off, arm network retrained on them, threshold 0.4): the network's
#: boxes now follow the seed size (median 6.0-8.5 px where ``gt`` spans 6.8-9.3 px on the tuning panicles) and it
#: puts two keypoints on far fewer seeds, so the ``fast`` profile keeps the doubled pixels but scales them like
#: ``gt`` (x (median size / 6 px) ** 1.5, clipped to 1-1.6), stops merging keypoints (merge 3 px off), joins
#: view-sharing tracks only within 0.4 diameters and accepts stereo matches with half the verification support
#: (0.5): 95-98 % of the countable seeds carry a ``fast`` keypoint in >= 2 views, the losses were in pairing and
#: linking. Tuning panicles 95-99 + 111-115: MAPE 17.9 % (-17.9 %) with the session-6 profile -> 5.9 % (-0.8 %).
#: Session 7b (issue #6: the network fires twice on the seeds of dark varieties, e.g. 115 +9.9 %): view-sharing
#: tracks are joined within 0.6 median diameters (was 0.4; two tracks on one seed lie 0.63 diameters apart on 115,
#: neighbouring seeds >= 0.8): tuning MAPE 5.89 % (-0.8 %) -> 5.38 % (-1.7 %), 115 +9.9 -> +4.8 %, 96 +5.1 -> +3.7 %,
#: 97 +8.2 -> +7.8 %; the under-counted large-seeded panicles lose a little more (114 -15.3 -> -16.0 %, 98 -6.0 -> -6.6 %).
#: A per-image keypoint merge scaled with the detection size (mv_merge_size) lost seeds on bright panicles instead.
#: Session 8 (issue #6, traced with GT seed labels on every keypoint, seedmap.recon.count step 1): the count is the
#: balance of ghost tracks (wrong left/right pairings, 11-24 % of the countable seeds) and missed seeds (7-31 %);
#: ``fast`` now ranks stereo candidates by their row residual too (mv_row_sigma_px 1.5: fewer ghosts AND fewer
#: misses) and links leftover single-view matches in a second pass (mv_relink_px 10, support >= 1.5): tuning MAPE
#: 5.38 % (-1.7 %) -> 4.84 % (-2.2 %), ghosts 3538 -> 3097, missed 4267 -> 3912 on the ten tuning panicles.
#: Session 10 (issue #6, red large-seeded over-count): unchanged; the opt-in track-sized joins
#: (``mv_dedupe_size=track mv_dedupe_shared=0.7``, best on the tuning + red tuning-only panicles, 4.95 -> 4.88 %)
#: scored 6.03 -> 6.12 % on the 70 never-tuned + fresh panicles (seedmap.recon.count step 4).
DETECTOR_PROFILES: dict[str, list[str]] = {
    "gt": ["mv_link_joint=true", "mv_link_px=1.5", "mv_scale_ref_px=7.0", "mv_scale_power=1.5"],
    "fast": ["mv_dedupe_shared=0.6", "mv_stereo_dv_px=4", "mv_link_px=4", "mv_max_reproj_px=5", "mv_grow_px=4",
             "mv_min_support=0.5", "mv_scale_ref_px=6.0", "mv_scale_power=1.5",
             "mv_row_sigma_px=1.5", "mv_relink_px=10", "mv_relink_min_support=1.5"],
    "fast-classic": ["mv_dedupe_shared=1.0"],
}
# The appearance term of the stereo assignment (session 11) is in no profile: on top of the ``fast`` profile
# (``--set count.mv_desc_size=6 --set count.mv_desc_grid=15 --set count.mv_appearance_weight=5``) it raised every
# count by 2.8 +- 1.2 points without narrowing the per-panicle spread (README, panicle reconstruction).
#: ``fast-cnn`` is the same network as ``fast`` (when its weights exist), so it counts with the same profile
DETECTOR_PROFILES["fast-cnn"] = list(DETECTOR_PROFILES["fast"])


#: Pixel tolerances of the multiview counter that scale with the seeds' image size
#: (CountConfig.mv_scale_ref_px): a partly hidden seed's visible centre differs between the left and the
#: right image and between neighbouring views by a fraction of its size, so a panicle with larger seeds
#: (closer, or a larger variety) needs wider row, link, reprojection and claim tolerances.
#: The support scale (mv_support_sigma_px) is not scaled: widening it lets ghost matches gather
#: support (``gt``, tuning panicles 95-100 + 111-115: +2 to +7 % doubles on the large-seeded ones).
SCALED_PX_KEYS: tuple[str, ...] = ("mv_stereo_dv_px", "mv_link_px", "mv_max_reproj_px", "mv_grow_px")


class SgbmConfig(ConfigModel):
    """OpenCV StereoSGBM parameters (pixels). ``min_disparity``/``num_disparities`` of ``None`` are
    derived from the depth range of :class:`CloudConfig` and the calibration."""

    min_disparity: int | None = None
    num_disparities: int | None = Field(None, description="multiple of 16")
    block_size: int = Field(3, ge=1)
    p1_factor: int = Field(8, ge=0, description="P1 = p1_factor * channels * block_size^2")
    p2_factor: int = Field(32, ge=0, description="P2 = p2_factor * channels * block_size^2")
    uniqueness_ratio: int = Field(10, ge=0)
    speckle_window_size: int = Field(100, ge=0)
    speckle_range: int = Field(2, ge=0)
    disp12_max_diff: int = Field(1)
    mode: Literal["sgbm", "hh", "3way"] = "3way"
    downscale: float = Field(1.0, gt=0, le=1, description="run SGBM on images scaled by this factor (speed)")
    crop_to_lit: bool = Field(True, description="match only the bounding box of flash-lit pixels (speed; "
                                                 "the unlit background has no depth anyway)")


class CloudConfig(ConfigModel):
    """Per-view point cloud: depth limits (m) and voxel size (m)."""

    min_depth: float = Field(0.2, gt=0)
    max_depth: float = Field(0.42, gt=0)
    voxel_size: float = Field(0.001, gt=0)
    pixel_step: int = Field(1, ge=1, description="use every n-th pixel (speed)")
    min_intensity: int = Field(20, ge=0, le=255, description="drop pixels darker than this (unlit background, "
                                                              "where SGBM matches noise)")


class SeedCentreConfig(ConfigModel):
    """3D seed centres from disparity inside each detected ellipse."""

    method: Literal["disparity", "keypoints"] = Field(
        "disparity", description="disparity = median SGBM disparity in the ellipse; keypoints = that median only "
                                 "picks the matching right-image detection, whose ellipse centre gives the disparity")
    match_dv_px: float = Field(1.5, gt=0, description="max row difference of a left/right keypoint match (px)")
    match_dd_px: float = Field(4.0, gt=0, description="max difference from the SGBM disparity prior (px)")
    min_valid_fraction: float = Field(0.2, ge=0, le=1, description="valid-disparity pixels needed in the ellipse")
    shrink: float = Field(0.7, gt=0, le=1, description="use the central part of the ellipse (axis scale)")
    surface_to_centre: bool = Field(True, description="push the visible-surface point back by the seed radius")


class RegisterConfig(ConfigModel):
    """Refining FK poses with ICP (Open3D) against the growing model."""

    mode: Literal["fk", "full", "seeds"] = "seeds"
    strategy: Literal["sequential", "global"] = Field(
        "sequential", description="sequential = each view against the growing model of the views before it (drifts "
                              "around the circle); global = every view against all other views, Jacobi passes")
    passes: int = Field(3, ge=1, description="global strategy: refinement passes")
    init: Literal["fk", "chain"] = Field(
        "chain", description="initial guess: FK pose, or FK motion since the previous refined view")
    full_method: Literal["point_to_point", "point_to_plane"] = "point_to_plane"
    seeds_method: Literal["point_to_point", "point_to_plane"] = "point_to_point"
    full_max_corr: list[float] = Field(default_factory=lambda: [0.004, 0.002, 0.001],
                                       description="coarse-to-fine max correspondence distances, full clouds (m)")
    seeds_max_corr: list[float] = Field(default_factory=lambda: [0.004, 0.002, 0.001],
                                        description="coarse-to-fine max correspondence distances, seed centres (m)")
    full_voxel: float = Field(0.002, gt=0, description="voxel of the clouds used for full-cloud ICP (m)")
    normal_radius: float = Field(0.005, gt=0)
    max_iterations: int = Field(50, ge=1)
    min_seed_pairs: int = Field(8, ge=3, description="fewer seed correspondences -> keep the initial pose")
    max_correction_m: float = Field(0.02, gt=0, description="larger ICP corrections are rejected (m)")
    max_correction_deg: float = Field(5.0, gt=0)


class CountConfig(ConfigModel):
    """De-duplication of seed detections in 3D (see seedmap.recon.count for the methods)."""

    method: Literal["multiview", "rays", "tracks", "density"] = Field(
        "multiview", description="multiview = 2D association + triangulation (needs the detections and poses); "
                                 "rays / tracks / density de-duplicate per-view 3D seed centres")
    link_radius: float = Field(0.0025, gt=0, description="tracks: max 3D distance of a cross-view link (m)")
    max_lag: int = Field(3, ge=1, description="tracks, rays: link views up to this many steps apart (around the circle)")
    dbscan_eps: float = Field(0.004, gt=0, description="DBSCAN neighbourhood (m): separates seed groups/outliers")
    dbscan_min_points: int = Field(2, ge=1)
    bandwidth: float = Field(0.0008, gt=0, description="Gaussian density smoothing sigma (m)")
    separation: float = Field(0.6, gt=0, description="min distance between two seed centres, in median diameters")
    min_observations: int = Field(2, ge=1, description="views that must support a seed")
    sigma_lateral: float = Field(0.0003, gt=0, description="rays: position error across the viewing ray (m)")
    sigma_depth: float = Field(0.0015, gt=0, description="rays: position error along the viewing ray (m)")
    gate_chi2: float = Field(9.0, gt=0, description="rays: max squared Mahalanobis distance of a link")
    circular: bool = Field(True, description="views are ordered around a closed circle (lag wraps around)")
    merge_passes: int = Field(1, ge=0, description="rays: passes of group-level merging (fragments of one seed "
                                                   "seen from views more than max_lag apart)")
    merge_chi2: float = Field(9.0, gt=0, description="rays: max squared Mahalanobis distance of two merged groups")
    merge_radius: float = Field(0.004, gt=0, description="rays: never merge groups farther apart (m)")
    max_pair_distance: float = Field(0.012, gt=0, description="rays: never link observations farther apart (m)")
    mv_verify_views: int = Field(2, ge=1, description="multiview: views on each side that verify a stereo match")
    mv_support_ref_deg: float = Field(15.0, ge=0, description="multiview: view spacing (deg) the minimum supports "
                                                             "are for (the 24-view circle)")
    mv_support_density_gain: float = Field(3.0, ge=0, description="multiview: a scan whose views are >= 5 % closer "
                                                                 "than mv_support_ref_deg adds this x (ref / spacing "
                                                                 "- 1) to the minimum supports")
    mv_stereo_dv_px: float = Field(2.0, gt=0, description="multiview: max row difference of a left/right match (px)")
    mv_support_sigma_px: float = Field(1.0, gt=0, description="multiview: reprojection scale of the support score (px)")
    mv_min_support: float = Field(1.5, ge=0, description="multiview: min support of a stereo match (sum over the "
                                                         "verifying images, each <= 1)")
    mv_row_sigma_px: float = Field(0.0, ge=0, description="multiview: the one-to-one stereo assignment maximises "
                                                          "support x exp(-dv^2 / 2 sigma^2), dv = row difference of "
                                                          "the pair (px; 0 = support only)")
    mv_appearance_weight: float = Field(0.0, ge=0, description="multiview: the stereo assignment also weighs "
                                                                "each candidate by exp(beta (ncc - 1)), ncc = "
                                                                "normalised cross-correlation of the two keypoints' "
                                                                "colour context patches (needs descriptors: "
                                                                "mv_desc_size > 0 when the views are prepared; "
                                                                "0 = off)")
    mv_appearance_min: float = Field(-1.0, ge=-1, le=1, description="multiview: drop stereo candidates whose "
                                                                     "context ncc is below this (with "
                                                                     "mv_appearance_weight > 0)")
    mv_desc_size: float = Field(0.0, ge=0, description="multiview: half-width of the context patch of every "
                                                       "keypoint, in median left detection sizes of its view "
                                                       "(computed when the views are prepared; 0 = none)")
    mv_desc_grid: int = Field(11, ge=2, description="multiview: cells per side of the context patch descriptor")
    mv_dup_size: float = Field(0.0, ge=0, description="multiview: left keypoints of one image closer than this "
                                                     "many times the smaller of their two detection sizes enter "
                                                     "the stereo assignment as one row (the group's best candidate "
                                                     "per right keypoint; a second detection on one seed then makes "
                                                     "no stereo match of its own; 0 = off)")
    mv_link_px: float = Field(2.0, gt=0, description="multiview: max reprojection error of a cross-view link (px)")
    mv_link_px_per_lag: float = Field(0.0, ge=0, description="multiview: link tolerance added per view of lag "
                                                              "beyond the first (px)")
    mv_relink_px: float = Field(0.0, ge=0, description="multiview: second linking pass between observations "
                                                         "still short of min_observations views, with this wider "
                                                         "tolerance (px; <= mv_link_px = off)")
    mv_relink_min_support: float = Field(2.5, ge=0, description="multiview: second pass links only stereo "
                                                                 "matches with at least this support")
    mv_max_reproj_px: float = Field(2.5, gt=0, description="multiview: observations reprojecting farther from "
                                                           "their track's point are dropped (px)")
    mv_drop_worst_only: bool = Field(True, description="multiview: per re-triangulation round drop only the worst "
                                                        "observation of each track beyond mv_max_reproj_px (one wrong "
                                                        "observation no longer takes the good ones with it)")
    mv_reproj_rounds: int = Field(12, ge=1, description="multiview: re-triangulation rounds of the reprojection check")
    mv_dedupe: float = Field(0.9, ge=0, description="multiview: join counted tracks closer than this many median "
                                                    "seed diameters that share no view")
    mv_dedupe_shared: float = Field(0.0, ge=0, description="multiview: join counted tracks closer than this many "
                                                           "median seed diameters even when they share views "
                                                           "(duplicate detections of one seed; 0 = off)")
    mv_dedupe_size: Literal["median", "track"] = Field("median", description="multiview: the diameter of the "
                                                       "two join radii above: the scan's median seed, or the mean "
                                                       "of the two tracks' own median diameters")
    mv_surface_tol: float = Field(0.0, ge=0, description="multiview: drop stereo match candidates whose depth "
                                                         "lies more than this behind (and, unless "
                                                         "mv_surface_front_tol, in front of) the SGBM surface depth "
                                                         "at the left keypoint (m; 0 = off; keypoints without valid "
                                                         "SGBM keep all candidates)")
    mv_surface_front_tol: float | None = Field(None, ge=0, description="multiview: the same check for matches in "
                                                                     "FRONT of the SGBM surface (m; None = "
                                                                     "mv_surface_tol)")
    mv_merge_px: float = Field(0.0, ge=0, description="multiview: first join keypoints of one image closer than "
                                                       "this (px; duplicate detections of one seed; 0 = off)")
    mv_merge_size: float = Field(0.0, ge=0, description="multiview: first join left keypoints of one image closer "
                                                         "than this many times the smaller of their two detection "
                                                         "sizes (right keypoints: x the image's median left size; "
                                                         "mv_merge_px > 0 caps the radius; 0 = off)")
    mv_min_depth: float = Field(0.2, gt=0, description="multiview: nearest seed depth considered (m)")
    mv_max_depth: float = Field(0.42, gt=0, description="multiview: farthest seed depth considered (m)")
    mv_link_joint: bool = Field(False, description="multiview: link two stereo matches when the point triangulated "
                                                   "from their four rays reprojects within the tolerance into all "
                                                   "four images (instead of projecting each one's stereo point "
                                                   "into the other view)")
    mv_link_search: float = Field(2.0, ge=1, description="multiview, joint links: partner search radius in link "
                                                         "tolerances")
    mv_grow_px: float = Field(2.0, ge=0, description="multiview: a track of >= min_observations views claims the "
                                                      "left+right keypoints within this distance of its projection in "
                                                      "the views around it (px; 0 = off)")
    mv_grow_unique_px: float = Field(4.0, ge=0, description="multiview: a track claims a left keypoint only when "
                                                            "no other left keypoint lies within this distance of "
                                                            "its projection (px; 0 = no check)")
    mv_grow_fill_only: bool = Field(True, description="multiview: grow only into views with views of the track "
                                                      "on both sides (within mv_grow_views), not beyond its arc")
    mv_grow_views: int = Field(3, ge=1, description="multiview: views beyond a track's own on each side it may "
                                                    "grow into")
    mv_grow_passes: int = Field(2, ge=1, description="multiview: growing passes (each followed by re-triangulation)")
    mv_scale_ref_px: float = Field(0.0, ge=0, description="multiview: the pixel tolerances (mv_scale_keys) are "
                                                         "for seeds whose median left detection size (mean ellipse "
                                                         "axis) over the scan is this many px; a scan with larger "
                                                         "seeds in the image gets them scaled by (median / this) ** "
                                                         "mv_scale_power (0 = off)")
    mv_scale_power: float = Field(1.0, ge=0, description="multiview: exponent of the size ratio of the tolerance "
                                                        "scaling")
    mv_scale_min: float = Field(1.0, gt=0, description="multiview: smallest tolerance scale factor (1 = never "
                                                      "tighter than configured)")
    mv_scale_max: float = Field(1.6, gt=0, description="multiview: largest tolerance scale factor")
    mv_scale_keys: list[str] = Field(default_factory=lambda: list(SCALED_PX_KEYS),
                                     description="multiview: the pixel tolerances scaled with the seed size")


    calibration: str = Field("auto", description="multiview: calibrated count estimate (seedmap.recon.calibrate): "
                                                 "auto = the shipped calibration of the run's detector when the run "
                                                 "matches its detector and counter settings, none, or a file from "
                                                 "`seedmap train count-calibration`")
    detector_profile: bool = Field(True, description="multiview: apply detector_profiles[detector] on top of these "
                                                     "settings (false = exactly these settings)")
    detector_profiles: dict[str, list[str]] = Field(default_factory=lambda: {k: list(v) for k, v in
                                                                              DETECTOR_PROFILES.items()},
                                                    description="multiview: key=value CountConfig overrides per "
                                                                "detector name")

    def for_detector(self, detector: str) -> CountConfig:
        """These settings with the profile of ``detector`` applied (unless ``detector_profile`` is
        false or the detector has none); the result has ``detector_profile`` false (applied once)."""
        ov = self.detector_profiles.get(detector, []) if self.detector_profile else []
        if not ov:
            return self
        data = apply_overrides(self.model_dump(), list(ov))
        data["detector_profile"] = False
        return type(self).model_validate(data)


class ReconConfig(ConfigModel):
    """Whole reconstruction run (defaults suit the simulated UR5 scan at 0.3 m stand-off)."""

    seed: int = 0
    detector: str = Field("gt", description="detector name (gt = ground-truth ORACLE on simulated data)")
    detector_overrides: list[str] = Field(default_factory=lambda: ["gt.min_area_px=12", "cnn.domain=arm",
                                                                  "cnn.threshold=0.4"],
                                          description="key=value overrides of the detector config (the CNN "
                                                      "of `fast` runs its arm-scan network, session 6, retrained on auto-exposed arm scans in session 7, threshold chosen on validation panicles 140-141); setting "
                                                      "this list replaces all three defaults, so keep the ones "
                                                      "you want")
    sgbm: SgbmConfig = Field(default_factory=SgbmConfig)
    cloud: CloudConfig = Field(default_factory=CloudConfig)
    seeds: SeedCentreConfig = Field(default_factory=SeedCentreConfig)
    registration: RegisterConfig = Field(default_factory=RegisterConfig)
    count: CountConfig = Field(default_factory=CountConfig)
    min_view_points: int = Field(500, ge=0, description="views with fewer valid 3D points are skipped")
    #: how the scan is opened: seedmap layout, or any format seedmap reads (an image folder with a Kalibr /
    #: ROS / OpenCV calibration, a bag...), e.g. ``--set dataset.format=folder`` (see seedmap.io)
    dataset: DatasetOptions = Field(default_factory=DatasetOptions)
    #: measured joint angles, one row per view (``view,q1..q6`` in radians); None = ``joints.csv`` beside the
    #: images (in the dataset folder, or next to a bag file)
    joints: str | None = None
    #: the arm description (UR5 DH, base pose, hand-eye); None = ``arm.yaml`` beside the images
    arm: str | None = None
