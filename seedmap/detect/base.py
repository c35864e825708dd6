"""The detector interface and the registry every stage uses to get one by name.

A detector turns one RGB ``uint8`` image into :class:`~seedmap.records.Detections` (boxes, scores,
ellipses, keypoints = ellipse centres) and a stereo frame into
:class:`~seedmap.records.StereoDetections` via :meth:`Detector.detect_stereo`. Downstream code
(association, SLAM, reconstruction) only ever calls these two methods, so the oracle, the fast CNN
and the learned Faster R-CNN + pix2pix pipeline are interchangeable. Detectors register a factory by name
(:func:`register_detector`); :func:`make_detector` builds one by name.

The ``gt`` oracle reads ground truth instead of pixels, so it needs the dataset and the frame
index; it implements :meth:`detect_stereo` from ``frame.index`` and :meth:`GtDetector.detect_frame`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from seedmap.errors import InputError, SeedmapError
from seedmap.records import Detections, StereoDetections, StereoFrame


def logit(p: float) -> float:
    """The logit whose sigmoid is the probability ``p`` (clipped to [1e-6, 1 - 1e-6]): ``sigmoid(z) >= p`` iff
    ``z >= logit(p)``, so score thresholds apply to raw network outputs."""
    t = min(max(float(p), 1e-6), 1 - 1e-6)
    return float(np.log(t / (1 - t)))


def check_image(image: np.ndarray, what: str = "image") -> np.ndarray:
    """Refuse anything that is not an ``H x W x 3`` ``uint8`` RGB array (one-line error)."""
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise InputError(f"{what} is {a.dtype}; detectors expect 8-bit RGB (uint8)")
    if a.ndim != 3 or a.shape[2] != 3:
        raise InputError(f"{what} has shape {a.shape}; detectors expect H x W x 3 RGB")
    if a.size == 0:
        raise InputError(f"{what} is empty")
    return a


class Detector:
    """Base class: subclasses implement :meth:`detect`; stereo is two monocular calls by default."""

    name: str = "base"
    #: True for detectors that read ground truth instead of pixels (never for real data).
    is_oracle: bool = False

    def detect(self, image: np.ndarray) -> Detections:  # pragma: no cover - interface
        raise SeedmapError(f"detector {self.name!r} does not detect on plain images")

    def settings(self) -> dict:
        """Settings a result's meta.json records beside the detector's name (none by default)."""
        return {}

    def detect_stereo(self, frame: StereoFrame) -> StereoDetections:
        """Detections in the left and right images of one rectified stereo frame."""
        return StereoDetections(index=frame.index, timestamp=frame.timestamp,
                                left=self.detect(frame.left), right=self.detect(frame.right))

    def __call__(self, image: np.ndarray) -> Detections:
        return self.detect(image)


def map_to_input(boxes: np.ndarray, ellipses: np.ndarray, sx: float, sy: float,
                 s_axes: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes and ellipses found on an image resized by ``(sx, sy)`` in the input image's pixels.

    Pixel-centre convention for the centres, ``u_in = (u_small + 0.5) / sx - 0.5``; box edges are pixel
    edges (divided by the factor); the ellipse axes are divided by ``s_axes``. Returns new arrays."""
    ell = ellipses.copy()
    ell[:, 0] = (ell[:, 0] + 0.5) / sx - 0.5
    ell[:, 1] = (ell[:, 1] + 0.5) / sy - 0.5
    ell[:, 2:4] /= s_axes
    return boxes / np.array([sx, sy, sx, sy]), ell


# name -> factory(**kwargs) -> Detector ; factories import their heavy modules lazily
_REGISTRY: dict[str, Callable[..., Detector]] = {}
_HELP: dict[str, str] = {}
_ORACLES: set[str] = set()


def register_detector(name: str, factory: Callable[..., Detector], help: str = "", oracle: bool = False) -> None:
    """Make ``factory(dataset=, weights=, config=)`` available as detector ``name`` (``help``: one line;
    ``oracle``: it reads ground truth instead of pixels, like its detectors' ``is_oracle``)."""
    _REGISTRY[name] = factory
    _HELP[name] = help
    if oracle:
        _ORACLES.add(name)


def is_oracle_detector(name: str) -> bool:
    """Whether the detector registered as ``name`` reads ground truth instead of pixels."""
    return name in _ORACLES


def available_detectors() -> list[str]:
    """Registered detector names (``gt`` is the ground-truth oracle)."""
    return list(_REGISTRY)


def detector_help() -> dict[str, str]:
    """One line of help per registered detector name."""
    return dict(_HELP)


def default_weights_path() -> Path:
    """Where shipped weights of the learned pipeline live (detector.safetensors + segmenter.safetensors)."""
    return Path(__file__).with_name("weights") / "detector.safetensors"


def detector_label(name: str, oracle: bool | None = None) -> str:
    """The detector's name as reports and the console show it: ``gt (ORACLE)`` for the ground-truth oracle."""
    if oracle is None:
        oracle = is_oracle_detector(name)
    return f"{name} (ORACLE)" if oracle else name


def default_detector_name() -> str:
    """``frcnn-pix2pix`` when torch and shipped trained weights are present, else ``fast``."""
    if default_weights_path().is_file() and default_weights_path().with_name("segmenter.safetensors").is_file():
        try:
            import torch  # noqa: F401
            import torchvision  # noqa: F401
        except ImportError:
            return "fast"
        return "frcnn-pix2pix"
    return "fast"


def make_detector(name: str, *, dataset: str | Path | object | None = None, weights: str | Path | None = None,
                  config: object | None = None, overrides: tuple[str, ...] | list[str] = ()) -> Detector:
    """Build a detector by name.

    ``dataset`` (path or an opened :class:`~seedmap.io.seedmap_dataset.SeedmapDataset`) is needed by
    the ``gt`` oracle only; ``weights`` by the learned detector (defaults to shipped weights);
    ``config`` is a :class:`~seedmap.detect.config.DetectConfig` (defaults otherwise) and
    ``overrides`` are ``key=value`` strings applied on top of it. ``"default"`` picks
    :func:`default_detector_name`.
    """
    from seedmap.detect.config import DetectConfig, resolve_config

    if name in ("default", "auto"):
        name = default_detector_name()
    if name not in _REGISTRY:
        raise SeedmapError(f"unknown detector {name!r} (known: {', '.join(available_detectors())})")
    cfg = resolve_config(config if isinstance(config, DetectConfig) else None, overrides)
    return _REGISTRY[name](dataset=dataset, weights=weights, config=cfg)
