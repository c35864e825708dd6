"""Seed detection front-end: one :class:`Detector` interface, several detectors by name.

* ``gt`` — ORACLE reading a simulated dataset's ground-truth masks (:class:`GtDetector`).
* ``fast`` — small CNN on gated tiles + learned refiner, onnxruntime on CPU (:mod:`seedmap.detect.cnn`; the default).
* ``frcnn-pix2pix`` — the paper's Faster R-CNN (VGG16) + pix2pix pipeline; needs the optional
  ``seedmap[learned]`` extra (torch), imported only when asked for.

Use :func:`make_detector` and :meth:`Detector.detect_stereo`. Importing this package never imports
torch.
"""

from seedmap.detect.base import (
    Detector,
    available_detectors,
    default_detector_name,
    detector_label,
    is_oracle_detector,
    detector_help,
    make_detector,
    register_detector,
)
from seedmap.detect.config import DetectConfig
from seedmap.detect.ellipse import draw_ellipses, fit_ellipse_mask, fit_ellipses_labels
from seedmap.detect.cnn import CnnDetector
from seedmap.detect.gt import GtDetector
from seedmap.detect import learned as _learned  # noqa: F401  (registers frcnn-pix2pix; no torch import)

__all__ = [
    "CnnDetector",
    "DetectConfig",
    "Detector",
    "GtDetector",
    "available_detectors",
    "default_detector_name",
    "detector_label",
    "is_oracle_detector",
    "detect_stereo",
    "detector_help",
    "draw_ellipses",
    "fit_ellipse_mask",
    "fit_ellipses_labels",
    "make_detector",
    "register_detector",
]


def detect_stereo(detector: Detector, frame):  # noqa: ANN001, ANN201 - thin alias
    """``detector.detect_stereo(frame)`` -> :class:`~seedmap.records.StereoDetections`."""
    return detector.detect_stereo(frame)
