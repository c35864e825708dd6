"""Detector configuration (one pydantic model, sections per detector)."""

from __future__ import annotations

from typing import Literal, Sequence

from pydantic import Field, field_validator

from seedmap.io.options import DatasetOptions
from seedmap.config import ConfigModel, apply_overrides

#: Smallest visible part of a seed that counts as *detectable*, in pixels at the field camera's full
#: 4096-px width (= 10 px at the default 1434-px rendering; scaled by (width / 4096)^2 for other
#: sizes, see min_visible_seed_px). The ``gt`` oracle emits no keypoint for smaller slivers and
#: ``seedmap eval detect`` ignores them by default. Chosen from what a real detector can do, not from
#: what helps a metric: on held-out range seed 2 (``data/det_s2``, 1434 px) the CNN ``fast`` detector
#: finds 0.1 % of GT instances below 3 px, 2.2 % at 3-6 px, 20 % at 6-10 px, 70 % at 10-15 px and
#: >= 91 % above 15 px (a median seed covers about 19 px); a sliver's mask centre is also biased away
#: from the seed centre, differently in each view. Up to session 3 the oracle kept slivers >= 3 px.
MIN_VISIBLE_SEED_FULLRES_PX = 82.0


def min_visible_seed_px(image_width: int) -> float:
    """The detectable-seed area (pixels) at ``image_width`` (MIN_VISIBLE_SEED_FULLRES_PX scaled)."""
    from seedmap.associate.base import FULL_RES_WIDTH

    return MIN_VISIBLE_SEED_FULLRES_PX * (image_width / FULL_RES_WIDTH) ** 2



class GtConfig(ConfigModel):
    """The ground-truth oracle: ellipse per GT instance mask."""

    #: ``moments`` = mask centroid + second moments (vectorised, least-biased centre for tiny masks);
    #: ``contour`` = cv2.fitEllipse on the mask contour (the paper's fitter).
    ellipse: Literal["moments", "contour"] = "moments"
    #: drop instances with fewer visible pixels (a sliver of an occluded seed is no keypoint);
    #: None = the detectable-seed size scaled to the image (min_visible_seed_px; 10 px at 1434 px)
    min_area_px: float | None = None
    #: keep only instances whose true 3D centre is visible (center_visible = 1)
    only_center_visible: bool = False


class FastConfig(ConfigModel):
    """The classical detector: DoG blob peaks + steepest-ascent regions + moment ellipses.

    Pixel sizes refer to the seed diameter ``seed_px`` at the working resolution; the filters
    scale with it. Defaults tuned on a simulated range (seed 1, ``data/det_s1``) at the default
    1434x1050 for box F1 (IoU >= 0.5, GT >= 6 px): a filter scale of 3.5 px (below the ~5 px seed
    diameter) also finds the partly hidden seeds, whose visible part is smaller than a whole seed.
    """

    #: expected seed diameter (px) at the input resolution; the scale of every filter
    seed_px: float = 3.5
    #: run on the image resized by this factor (< 1 is faster, keypoints are mapped back)
    work_scale: float = 1.0
    #: inner / outer Gaussian of the DoG, as multiples of the seed-matched sigma d / (2 sqrt 2)
    dog_inner: float = 0.6
    dog_outer: float = 1.2
    #: a pixel belongs to a seed region when its DoG response exceeds this (grey levels)
    region_min: float = -12.0
    #: minimum blob (DoG) response of a seed, in grey levels
    min_response: float = 9.0
    #: a seed's smoothed brightness must exceed this (grey levels; flash imaging: dark far field)
    min_brightness: float = 70.0
    #: leaf suppression: f -= (max_green_excess / 16) * max(G - R, 0)
    max_green_excess: float = 15.0
    #: minimum region area in px at the input resolution
    min_area_px: int = 7
    #: reject ridge-like peaks (bright leaf / stalk edges): principal-curvature ratio of the DoG at
    #: the peak must stay below this (SIFT's edge test; 0 = off)
    edge_ratio: float = 8.0
    #: learned second stage (seedmap.detect.refine): seed score + whole-pixel box per candidate;
    #: used at work_scale 1 when its weights exist (shipped: trained on the simulated range)
    refine: bool = True
    #: refiner weights (.safetensors); None = the shipped seedmap/detect/weights/fast_refiner.safetensors
    refine_weights: str | None = None
    #: keep candidates whose refiner seed probability is at least this
    refine_threshold: float = 0.5
    ellipse: Literal["moments", "contour"] = "moments"
    #: ``fast`` runs the small CNN (section ``cnn``, seedmap.detect.cnn; also by name ``fast-cnn``)
    #: instead of the classical pipeline above when its weights exist; ``fast-classic`` always runs the
    #: classical one (held-out F1, GT >= 10 px, session-4 weights: det_s2 0.871 vs 0.855, det_s21
    #: 0.888 vs 0.826, det_s22 0.817 vs 0.721)
    use_cnn: bool = True


#: The CNN's peak threshold (both shipped networks). Field network: chosen on det_s36 (session 4, F1 0.898). Session 7
#: fine-tuned it and chose 0.50 on validation (F1 0.902 / 0.884 on det_s36 / det_s45), but at 0.50 `seedmap slam
#: --detector fast` lost track on two of the eight hard scenes (paper2-hard at frame 63, paper6-hard at frame 11),
#: which the session-4 weights at 0.45 map in full, so the session-4 network and 0.45 stayed (see
#: seedmap.detect.train_cnn, run C). Session 7 briefly let ``None`` mean a per-domain value; both were 0.45, so
#: since session 8 the default is the plain number and ``None`` (in configs written then) reads as it.
CNN_THRESHOLD = 0.45


class CnnConfig(ConfigModel):
    """The ``fast`` detector's small CNN (seedmap.detect.cnn): heatmap peaks + box per pixel, onnxruntime.

    Runs only on tiles where seeds can be: a tile is kept when its bright, blob-like pixels (the
    classical seediness DoG at half resolution, above ``gate_response``) number at least
    ``gate_min_px``; ``tile = 0`` runs on the whole image. Gate defaults chosen on ``data/det_s1``
    (8 images): 24 % of the image area (margins included) holds 99.5 % of the GT seeds >= 6 px.
    """

    #: ONNX weights; None = the shipped network of ``domain``; a bare file name that is no file in the working
    #: directory names a file in seedmap/detect/weights/ (opt-in networks, e.g. ``fast_cnn_s9.onnx``)
    weights: str | None = None
    #: which shipped network ``weights = None`` means: ``field`` = seedmap/detect/weights/fast_cnn.onnx (trained on
    #: simulated row ranges), ``arm`` = fast_cnn_arm.onnx (trained on ranges + close-up arm scans of panicles,
    #: whose seeds are ~2x larger; retrained on auto-exposed scans in session 7; the panicle reconstruction sets it)
    domain: Literal["field", "arm"] = "field"
    #: keep heatmap peaks with seed probability at least this when no refiner runs (CNN_THRESHOLD: session 4, det_s36
    #: F1 0.898; the panicle reconstruction runs the arm network at 0.40, ReconConfig.detector_overrides); with a
    #: refiner the candidates are ``refine_candidates`` and the detections ``refine_threshold``
    threshold: float = CNN_THRESHOLD

    @field_validator("threshold", mode="before")
    @classmethod
    def _null_threshold_is_the_default(cls, v: object) -> object:
        # configs written in session 7 say ``threshold: null`` (it meant 0.45 for both networks)
        return CNN_THRESHOLD if v is None else v

    #: tile side (px) at the input resolution; 0 = whole image in one pass
    tile: int = 48
    #: context added around every tile (px). The receptive-field radius is 9 px (+1 for the 3x3
    #: smoothing), but 8 px gives the same F1 on det_s36 (-0.0003) for 9 % less CPU (session 4)
    margin: int = 8
    #: gate: half-resolution DoG of the seediness image must exceed this (grey levels) ...
    gate_response: float = 18.0
    #: ... and its smoothed brightness this (grey levels) ...
    gate_brightness: float = 60.0
    #: ... on at least this many half-resolution pixels of the tile (0 = no gate, every tile)
    gate_min_px: int = 4
    #: box edges and keypoint averaged over the peak's 3x3 neighbours weighted by
    #: sigmoid(heat) ** smooth (0 = the peak pixel's own prediction)
    smooth: float = 4.0
    #: peak test: heat logit maximal over the 3x3 square (3) or the 5x5 disk (5)
    peak_window: int = 3
    #: box non-maximum suppression of the peaks: a peak whose box overlaps a stronger peak's box with IoU above
    #: this is dropped (cv2.dnn.NMSBoxes; 0 = off). Arm scans: a second peak on one seed is the main source of
    #: ghost seeds in the count, and a low threshold with NMS finds more seeds at the same duplicate rate
    nms_iou: float = Field(0.0, ge=0, le=1)
    #: run the network on the image resized by this factor (seeds larger than the ~5 px training seeds,
    #: e.g. close-up arm scans, brought to the training size); outputs mapped back to input pixels
    scale: float = Field(1.0, gt=0, le=4)
    #: learned second stage (seedmap.detect.cnn_refine: every peak rescored and its box corrected): ``auto`` = the
    #: shipped refiner when the shipped field network runs (off for other networks, e.g. ``domain=arm``), ``none`` =
    #: off, or a refiner file trained for the network in use (``seedmap train cnn-refiner``; a bare shipped file name
    #: works too). Session 12: held-out box F1 0.870 -> 0.917 pooled over five ranges, 1.33x the CPU per image
    refiner: str = "auto"
    #: with a refiner: the network's peak threshold that makes the candidates ...
    refine_candidates: float = Field(0.25, gt=0, lt=1)
    #: ... and the refined seed probability a detection needs (replaces ``threshold``)
    refine_threshold: float = Field(0.30, gt=0, lt=1)
    #: test-time augmentation: the network also runs on the tiles mirrored left-right and the two outputs are
    #: averaged (heat logits, box edges with left and right swapped, keypoint offsets): 2x the network's CPU.
    #: Up-down mirroring is not offered: training mirrors left-right only, and the keypoint error grew with it
    flip_tta: bool = False
    #: tiles per onnxruntime call
    batch: int = 32
    #: onnxruntime intra-op threads (0 = onnxruntime's default: all cores, which spin-wait and cost
    #: ~3x the CPU on a busy 2-core machine)
    threads: int = 1
    #: detect_stereo runs the left and the right image concurrently on this many threads (1 or 2). Session 12, quiet
    #: 2-core host, with the refiner: 60.5 ms per stereo pair in sequence, 36.0 ms concurrently (28 pairs/s)
    stereo_threads: int = 2


class LearnedConfig(ConfigModel):
    """Faster R-CNN (VGG16) + pix2pix; see seedmap.detect.learned."""

    #: the detector runs on the image upscaled by this factor (seeds are 4-8 px at 1434x1050)
    upscale: float = 2.0
    score_threshold: float = 0.5
    nms_iou: float = 0.3
    max_detections: int = 3000
    #: crop padding around a box, as a fraction of the box size
    crop_pad: float = 0.5
    crop_size: int = 32
    #: use onnxruntime for the segmenter when an exported .onnx sits next to the weights
    use_onnx: bool = True
    ellipse: Literal["moments", "contour"] = "contour"


class ExposureConfig(ConfigModel):
    """Opt-in exposure normalisation before an image-based detector (``--set exposure.enabled=true``).

    Why: the classical detector's thresholds (``fast.min_brightness``, ``fast.min_response``) and the
    CNN's tile gate are grey levels, tuned at the simulator's flash exposure. A frame far darker or
    brighter than that loses its seeds: on the hard scene paper8-hard, frame 1 (exposure jitter
    0.25) has a 99th grey percentile of 102 against 131-238 in the other frames, and ``fast-classic``
    finds 273 keypoints there instead of ~2,600, so SLAM is lost. A frame whose 99th grey percentile
    lies more than ``tolerance`` times away from ``ref_p99`` is scaled towards it (gain clipped to
    ``1 / max_gain``..``max_gain``); frames inside the band are passed on untouched, so normally
    exposed data give identical detections. ``ref_p99`` = 165 is the median over the training range
    det_s1 (on the eight default paper ranges no left image leaves the band except five of paper7's;
    the hard scenes have 3-16 per range). Opt-in because the statistic also depends on the content: a frame with little panicle
    in view reads as dark (a 0.12 m test range: 87) and would be brightened, so calibrate ``ref_p99``
    on your own normally exposed frames.
    """

    enabled: bool = False
    ref_p99: float = Field(165.0, gt=0, le=255)
    tolerance: float = Field(1.3, ge=1.0)
    max_gain: float = Field(2.0, ge=1.0)


class DetectConfig(ConfigModel):
    seed: int = 0
    exposure: ExposureConfig = ExposureConfig()
    gt: GtConfig = GtConfig()
    fast: FastConfig = FastConfig()
    cnn: CnnConfig = CnnConfig()
    learned: LearnedConfig = LearnedConfig()
    #: how the input is opened (format, bag topics, calibration file...)
    dataset: DatasetOptions = DatasetOptions()


def resolve_config(cfg: DetectConfig | None, overrides: Sequence[str] = ()) -> DetectConfig:
    """``cfg`` (or defaults) with ``key=value`` overrides applied and validated."""
    from seedmap.config import load_config

    base = (cfg or DetectConfig()).model_dump()
    if not overrides:
        return DetectConfig.model_validate(base)
    return load_config(DetectConfig, None, overrides, base=apply_overrides(base, []))
