"""Detector configuration (one pydantic model, sections per detector)."""

from __future__ import annotations

from typing import Literal, Sequence, Union

from pydantic import Field, field_validator

from seedmap.io.options import DatasetOptions
from seedmap.config import ConfigModel, apply_overrides

#: Smallest visible part of a seed that counts as *detectable*, in pixels at the field camera's full 4096-px width
#: (10 px at the default 1434-px rendering; see min_visible_seed_px). Chosen from what a real detector can find
#: (docs/method/detection.md): the ``gt`` oracle emits no keypoint for smaller slivers, ``seedmap eval detect``
#: ignores them.
MIN_VISIBLE_SEED_FULLRES_PX = 82.0


def min_visible_seed_px(image_width: int) -> float:
    """The detectable-seed area (pixels) at ``image_width`` (MIN_VISIBLE_SEED_FULLRES_PX scaled)."""
    from seedmap.associate.base import FULL_RES_WIDTH

    return MIN_VISIBLE_SEED_FULLRES_PX * (image_width / FULL_RES_WIDTH) ** 2



class GtConfig(ConfigModel):
    """The ground-truth ORACLE: one ellipse per GT instance mask."""

    #: ``moments`` = mask centroid + second moments (least-biased centre for tiny masks); ``contour`` =
    #: cv2.fitEllipse on the mask contour (the paper's fitter)
    ellipse: Literal["moments", "contour"] = "moments"
    #: drop instances with fewer visible pixels; None = the detectable-seed size at the image width (min_visible_seed_px)
    min_area_px: float | None = None


#: typical seed diameter (px, median geometric mean of the GT box sides of detectable seeds) the shipped networks were
#: trained on: field ranges at 1434x1050 (measured 5.0); arm scans show seeds of about twice the area; the photo network
#: was trained on grain photos each resized so that its seeds measure 8.0 px
TRAINED_SEED_PX = {"field": 5.0, "arm": 7.0, "photo": 8.0}

#: what ``seedmap detect`` uses on image files and folders: the photo network on the whole image in one pass (a photo
#: resized to its seeds' scale is small, and the tile gate's brightness test would skip dark seeds on a light surface)
PHOTO_DEFAULTS = {"cnn": {"domain": "photo", "tile": 0}}

#: the fast CNN's heatmap peak threshold without a refiner (both shipped networks)
CNN_THRESHOLD = 0.45


#: the ``cnn.scale`` values that estimate the seed size from the images (a number sets the scale)
ESTIMATED_SCALES = ("auto", "folder")


class CnnConfig(ConfigModel):
    """The ``fast`` detector (seedmap.detect.cnn): the small CNN on gated tiles, in onnxruntime, and its refiner."""

    #: ONNX weights; None = the shipped network of ``domain``; a bare file name that is no file in the working
    #: directory names a file in seedmap/detect/weights/
    weights: str | None = None
    #: shipped network for ``weights = None``: ``field`` (fast_cnn.onnx, row ranges), ``arm`` (fast_cnn_arm.onnx,
    #: close-up arm scans; the panicle reconstruction sets it) or ``photo`` (fast_cnn_photo.onnx, grain photos and
    #: scans; ``seedmap detect`` sets it for images)
    domain: Literal["field", "arm", "photo"] = "field"
    #: seed probability a heatmap peak needs when no refiner runs
    threshold: float = CNN_THRESHOLD
    #: tile side (px, even) the gated network runs on; 0 = the whole image in one pass
    tile: int = 48
    #: ``auto`` = estimate the seeds' size on the first image of a sequence (each photo of a folder, then one size
    #: for the folder when its photos agree: autoscale.folder_agreement) and resize the images to it; ``folder`` =
    #: one size for a whole folder of photos without that check (a fixed camera or scanner): the median estimate of
    #: up to FOLDER_SAMPLE photos spread over it; a number = run the network on the image resized by it (0-4]
    scale: Union[Literal["auto", "folder"], float] = "auto"
    #: the seeds' typical diameter (px, geometric mean of a seed's box sides) in your images: sets the scale to the
    #: network's training seed size / seed_px (TRAINED_SEED_PX, or the size a ``seedmap train fast-cnn`` network
    #: records); None = use ``scale``
    seed_px: float | None = Field(None, gt=0)
    #: refiner: ``auto`` = the shipped one with the shipped field network (else off), ``none`` = off, or a refiner
    #: file trained for the network in use (``seedmap train cnn-refiner``)
    refiner: str = "auto"
    #: with a refiner: the network's peak threshold that makes the candidates ...
    refine_candidates: float = Field(0.25, gt=0, lt=1)
    #: ... and the refined seed probability a detection needs (replaces ``threshold``)
    refine_threshold: float = Field(0.30, gt=0, lt=1)
    #: onnxruntime intra-op threads (0 = all cores, which spin-wait on a busy machine)
    threads: int = 1
    #: stereo frames: left and right run concurrently on this many threads (1 or 2)
    stereo_threads: int = 2

    @field_validator("scale", mode="before")
    @classmethod
    def _scale(cls, v: object) -> object:
        """``auto``, ``folder`` or a number in (0, 4]."""
        if isinstance(v, str) and v.strip().lower() in ESTIMATED_SCALES:
            return v.strip().lower()
        try:
            if isinstance(v, bool):
                raise TypeError
            f = float(v)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise ValueError(f"must be auto, folder or a number in (0, 4], got {v!r}") from None
        if not 0.0 < f <= 4.0:
            raise ValueError(f"must be auto, folder or a number in (0, 4], got {v!r}")
        return f


#: the learned detector's box score threshold when neither the settings nor its weights give one
DEFAULT_SCORE_THRESHOLD = 0.5


class LearnedConfig(ConfigModel):
    """The paper's Faster R-CNN (VGG16) + pix2pix detector (seedmap.detect.learned)."""

    #: the detector runs on the image upscaled by this factor; None = the factor the weights were trained at
    upscale: Union[float, None] = None
    #: Faster R-CNN box score a detection needs; None = the weights' own (``score_threshold`` of the recipe.json
    #: beside them, chosen on validation data), else DEFAULT_SCORE_THRESHOLD
    score_threshold: Union[float, None] = None
    #: box non-maximum suppression IoU
    nms_iou: float = 0.3
    #: at most this many detections per image
    max_detections: int = 3000


class DetectConfig(ConfigModel):
    """Detector settings, one section per detector."""

    gt: GtConfig = GtConfig()
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
