"""Lazy registration of the torch-based ``frcnn-pix2pix`` detector (no torch import here)."""

from __future__ import annotations

from seedmap.detect.base import register_detector
from seedmap.errors import SeedmapError

INSTALL_HINT = ("the learned detector needs torch: pip install 'seedmap[learned]' "
                "(or torch==2.14.1 torchvision==0.29.1)")


def require_torch() -> None:
    """Raise a one-line SeedmapError when torch/torchvision are not importable."""
    try:
        import torch  # noqa: F401
        import torchvision  # noqa: F401
    except ImportError:
        raise SeedmapError(INSTALL_HINT) from None


def _factory(dataset=None, weights=None, config=None):
    require_torch()
    from seedmap.detect.learned.detector import LearnedDetector

    return LearnedDetector.from_weights(weights, config.learned if config is not None else None)


register_detector("frcnn-pix2pix", _factory,
                  "the paper's Faster R-CNN (VGG16) + pix2pix segmenter + ellipse fit (needs seedmap[learned])")
