"""ONNX export of the learned pipeline: the Faster R-CNN detector and the pix2pix segmenter.

Why: onnxruntime runs the exported graphs on CPU without the Python-level overhead of torchvision's
detection code, and other tools (C++, mobile) can run them without torch.

The detector is exported with the legacy TorchScript-tracing exporter (``dynamo=False``), which
needs no ``onnxscript``. torchvision's transform computes its resize factor from
``min_size / short side``, a constant baked in at trace time, so an image of another size would be
scaled by the wrong factor; the exported graph therefore swaps in :class:`FixedScaleTransform`,
which always scales by the architecture's ``upscale``. The exported graph takes one image
``image`` (float32, 3 x H x W, RGB in [0, 1], any H, W) and returns ``boxes`` (N x 4, x0, y0, x1, y1
in input pixels) and ``scores`` (N,), every box scoring at least the score threshold given at export.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn
from torchvision.models.detection.transform import GeneralizedRCNNTransform

from seedmap.detect.learned.models import DetectorArch, SegmenterArch, UNetGenerator, build_frcnn
from seedmap.detect.learned.weights import load_into, read_weights
from seedmap.errors import InputError
from seedmap.io.atomic import atomic_write_bytes

#: ONNX opset of every exported graph (onnxruntime >= 1.17 runs it)
OPSET = 17


class FixedScaleTransform(GeneralizedRCNNTransform):
    """torchvision's detection transform with a resize by a fixed factor (traceable for any size)."""

    def __init__(self, base: GeneralizedRCNNTransform, scale: float) -> None:
        super().__init__(base.min_size, base.max_size, base.image_mean, base.image_std,
                         size_divisible=base.size_divisible, fixed_size=base.fixed_size)
        self.scale = float(scale)

    def resize(self, image, target=None):
        # same call as torchvision's own resize (bilinear, recompute_scale_factor) with our factor
        out = F.interpolate(image[None], scale_factor=self.scale, mode="bilinear", recompute_scale_factor=True,
                            align_corners=False)[0]
        return out, target


class _DetectorGraph(nn.Module):
    """One image in, ``(boxes, scores)`` out: the part of Faster R-CNN that gets exported."""

    def __init__(self, model: nn.Module, upscale: float) -> None:
        super().__init__()
        self.model = model
        self.model.transform = FixedScaleTransform(model.transform, upscale)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.model([image])[0]
        return out["boxes"], out["scores"]


def export_frcnn_onnx(model: nn.Module, arch: DetectorArch, path: Path, score_threshold: float = 0.05,
                      nms_iou: float = 0.3, max_detections: int | None = None,
                      sample_hw: tuple[int, int] = (96, 128)) -> Path:
    """Write ``model`` (a :func:`build_frcnn` network) as ONNX to ``path`` (atomically).

    ``score_threshold``, ``nms_iou`` and ``max_detections`` are baked into the graph's
    post-processing; ``sample_hw`` is only the size of the tracing image (the graph takes any size).
    """
    import copy
    import warnings

    m = copy.deepcopy(model).eval()
    m.roi_heads.score_thresh = float(score_threshold)
    m.roi_heads.nms_thresh = float(nms_iou)
    if max_detections is not None:
        m.roi_heads.detections_per_img = int(max_detections)
    g = _DetectorGraph(m, arch.upscale).eval()
    x = torch.rand(3, *sample_hw, generator=torch.Generator().manual_seed(0))
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about python scalars in torchvision's code
        torch.onnx.export(g, (x,), buf, input_names=["image"], output_names=["boxes", "scores"], dynamo=False,
                          opset_version=OPSET, dynamic_axes={"image": {1: "height", 2: "width"},
                                                             "boxes": {0: "n"}, "scores": {0: "n"}})
    atomic_write_bytes(Path(path), _with_metadata(buf.getvalue(), {
        "seedmap_kind": "detector", "arch": arch.model_dump_json(),
        "post": json.dumps({"score_threshold": score_threshold, "nms_iou": nms_iou,
                            "max_detections": int(m.roi_heads.detections_per_img)})}))
    return Path(path)


def export_segmenter_onnx(gen: nn.Module, arch: SegmenterArch, path: Path) -> Path:
    """ONNX export (dynamic batch) of the pix2pix generator: ``crop`` (N, 3, S, S) in [-1, 1] -> ``mask``."""
    import copy

    g = copy.deepcopy(gen).eval()
    buf = io.BytesIO()
    x = torch.zeros(2, 3, arch.crop_size, arch.crop_size)
    torch.onnx.export(g, (x,), buf, input_names=["crop"], output_names=["mask"], dynamo=False,
                      dynamic_axes={"crop": {0: "n"}, "mask": {0: "n"}}, opset_version=OPSET)
    atomic_write_bytes(Path(path), _with_metadata(buf.getvalue(), {"seedmap_kind": "segmenter",
                                                                   "arch": arch.model_dump_json()}))
    return Path(path)


def _with_metadata(model_bytes: bytes, meta: dict[str, str]) -> bytes:
    """The serialised ONNX model with ``meta`` as metadata_props (read back by onnxruntime)."""
    import onnx

    mp = onnx.load_from_string(model_bytes)
    for k, v in meta.items():
        p = mp.metadata_props.add()
        p.key, p.value = k, v
    return mp.SerializeToString()


def export_weights(weights: str | Path, out_dir: str | Path | None = None, score_threshold: float = 0.05,
                   nms_iou: float = 0.3, max_detections: int = 3000) -> list[Path]:
    """Export ``detector.onnx`` / ``segmenter.onnx`` for the safetensors weights in ``weights``.

    ``weights`` is a weights folder or one ``.safetensors`` file; every ``detector.safetensors`` /
    ``segmenter.safetensors`` found is exported next to it (or into ``out_dir``). Returns the
    written paths. The detector's post-processing defaults match :class:`LearnedConfig`'s (NMS IoU
    0.3, up to 3000 boxes). Raises :class:`InputError` when there is nothing to export.
    """
    p = Path(weights)
    if not p.exists():
        raise InputError("weights not found", p)
    files = [p] if p.is_file() else [f for f in (p / "detector.safetensors", p / "segmenter.safetensors")
                                      if f.is_file()]
    if not files:
        raise InputError("no detector.safetensors or segmenter.safetensors to export", p)
    out: list[Path] = []
    for f in files:
        tensors, meta = read_weights(f)
        kind = meta.get("seedmap_kind")
        try:
            arch_d = json.loads(meta["arch"])
        except (KeyError, ValueError):
            raise InputError("weights metadata lacks a valid architecture", f) from None
        dest = (Path(out_dir) if out_dir else f.parent) / f.with_suffix(".onnx").name
        if kind == "detector":
            arch = DetectorArch.model_validate(arch_d)
            model = build_frcnn(arch)
            load_into(model, tensors, f)
            out.append(export_frcnn_onnx(model, arch, dest, score_threshold, nms_iou, max_detections))
        elif kind == "segmenter":
            sarch = SegmenterArch.model_validate(arch_d)
            gen = UNetGenerator(sarch.crop_size, sarch.ngf)
            load_into(gen, tensors, f)
            out.append(export_segmenter_onnx(gen, sarch, dest))
        else:
            raise InputError(f"holds {kind or 'unknown'} weights, expected detector or segmenter weights", f)
    return out


def onnx_post_params(path: str | Path) -> dict:
    """The post-processing parameters baked into an exported detector graph (``{}`` if unknown)."""
    import onnx

    mp = onnx.load(str(path), load_external_data=False)
    for p in mp.metadata_props:
        if p.key == "post":
            return json.loads(p.value)
    return {}
