"""Registration of the learned detectors (no torch import here).

* ``frcnn-pix2pix`` — the paper's Faster R-CNN (VGG16) + pix2pix with the user's weights (``--weights``):
  safetensors run in torch (``seedmap[learned]``); a folder that holds only the exported ``detector.onnx`` and
  ``segmenter.onnx`` runs in onnxruntime.
* ``frcnn-pix2pix-lite`` — the same pipeline at reduced width (``seedmap train detector --preset lite``), with
  shipped ONNX weights: runs in onnxruntime, no torch.
"""

from __future__ import annotations

from pathlib import Path

from seedmap.detect.base import register_detector
from seedmap.errors import SeedmapError

INSTALL_HINT = ("the learned detector needs torch: pip install 'seedmap[learned]' "
                "(or torch==2.14.1 torchvision==0.29.1)")

#: the shipped frcnn-pix2pix-lite weights (detector.onnx + segmenter.onnx)
LITE_WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "frcnn_pix2pix_lite"


def require_torch() -> None:
    """Raise a one-line SeedmapError when torch/torchvision are not importable."""
    try:
        import torch  # noqa: F401
        import torchvision  # noqa: F401
    except ImportError:
        raise SeedmapError(INSTALL_HINT) from None


def _has_torch() -> bool:
    try:
        require_torch()
    except SeedmapError:
        return False
    return True


def recommended_threshold(folder: Path) -> float:
    """The score threshold recorded beside a weights folder's files (``recipe.json``), else the default."""
    import json

    from seedmap.detect.config import DEFAULT_SCORE_THRESHOLD

    try:
        t = json.loads((folder / "recipe.json").read_text())["score_threshold"]
        return float(t) if 0.0 <= float(t) <= 1.0 else DEFAULT_SCORE_THRESHOLD
    except (OSError, ValueError, KeyError, TypeError):
        return DEFAULT_SCORE_THRESHOLD


def _build(weights, config, name: str):  # noqa: ANN001, ANN202 - registry factory signature
    from seedmap.detect.config import LearnedConfig
    from seedmap.detect.learned.pipeline import OnnxLearnedDetector, onnx_files

    cfg = config.learned if config is not None else LearnedConfig()
    if cfg.score_threshold is None:
        from seedmap.detect.config import DEFAULT_SCORE_THRESHOLD

        p = Path(weights) if weights is not None else None
        thr = recommended_threshold(p if p.is_dir() else p.parent) if p is not None else DEFAULT_SCORE_THRESHOLD
        cfg = cfg.model_copy(update={"score_threshold": thr})
    if weights is not None:
        p = Path(weights)
        folder = p if p.is_dir() else p.parent
        torch_weights = (folder / "detector.safetensors").is_file() and (folder / "segmenter.safetensors").is_file()
        onnx = onnx_files(folder) if p.exists() and p.suffix != ".safetensors" else None
        if onnx is not None and not (torch_weights and _has_torch()):
            return OnnxLearnedDetector(*onnx, cfg, name=name)
    require_torch()
    from seedmap.detect.learned.detector import LearnedDetector

    det = LearnedDetector.from_weights(weights, cfg)
    det.name = name
    return det


def _factory(dataset=None, weights=None, config=None):  # noqa: ANN001, ANN202
    return _build(weights, config, "frcnn-pix2pix")


def _lite_factory(dataset=None, weights=None, config=None):  # noqa: ANN001, ANN202
    return _build(LITE_WEIGHTS if weights is None else weights, config, "frcnn-pix2pix-lite")


register_detector("frcnn-pix2pix", _factory,
                  "the paper's Faster R-CNN (VGG16) + pix2pix segmenter + ellipse fit, your --weights "
                  "(safetensors need seedmap[learned]; exported .onnx run without torch)")
if (LITE_WEIGHTS / "detector.onnx").is_file():
    register_detector("frcnn-pix2pix-lite", _lite_factory,
                      "the paper's pipeline at 1/4 width, trained on CPU and shipped as ONNX (onnxruntime, no torch)")
