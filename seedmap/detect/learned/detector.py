"""``frcnn-pix2pix``: Faster R-CNN boxes -> pix2pix masks -> cv2.fitEllipse -> keypoints.

Weights: ``detector.safetensors`` and ``segmenter.safetensors`` (as written by ``seedmap train``).
``--weights`` may name either file or their folder; the other file is looked up beside it. When a
``segmenter.onnx`` sits next to the segmenter weights, the segmenter runs
in onnxruntime; likewise the detector when a ``detector.onnx`` (``seedmap train export``) sits next to
the detector weights and its baked-in post-processing (score threshold, NMS IoU, box cap) fits the config. A mask that comes out empty falls back to the box's inscribed ellipse (its centre is
the box centre), so the detection is kept.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from seedmap.detect.base import Detector, check_image
from seedmap.detect.config import LearnedConfig
from seedmap.detect.learned.models import (
    DetectorArch,
    SegmenterArch,
    UNetGenerator,
    build_frcnn,
    set_input_scale,
)
from seedmap.detect.learned.pipeline import boxes_to_detections, graph_gives
from seedmap.detect.learned.weights import load_into, read_weights
from seedmap.errors import InputError, SeedmapError
from seedmap.records import Detections

def find_weight_files(weights: str | Path | None) -> tuple[Path, Path]:
    """``(detector.safetensors, segmenter.safetensors)`` from a file or folder (or shipped defaults)."""
    from seedmap.detect.base import default_weights_path

    if weights is None:
        p = default_weights_path().parent
        if not (p / "detector.safetensors").is_file():
            raise SeedmapError("no trained weights for frcnn-pix2pix: train them with `seedmap train detector` and "
                               "`seedmap train segmenter` and pass --weights FOLDER, or use --detector "
                               "frcnn-pix2pix-lite (shipped) or fast")
    else:
        p = Path(weights)
        if not p.exists():
            raise InputError("weights not found", p)
    folder = p if p.is_dir() else p.parent
    det = p if p.is_file() and "segmenter" not in p.name else folder / "detector.safetensors"
    seg = p if p.is_file() and "segmenter" in p.name else folder / "segmenter.safetensors"
    for f in (det, seg):
        if not f.is_file():
            raise InputError(f"{f.name} not found (frcnn-pix2pix needs detector and segmenter weights)", folder)
    return det, seg


class LearnedDetector(Detector):
    name = "frcnn-pix2pix"

    def __init__(self, det_model: torch.nn.Module, det_arch: DetectorArch, gen: torch.nn.Module,
                 seg_arch: SegmenterArch, config: LearnedConfig | None = None, onnx_path: Path | None = None,
                 det_onnx_path: Path | None = None) -> None:
        self.cfg = config or LearnedConfig()
        if self.cfg.score_threshold is None:
            from seedmap.detect.config import DEFAULT_SCORE_THRESHOLD

            self.cfg = self.cfg.model_copy(update={"score_threshold": DEFAULT_SCORE_THRESHOLD})
        self.det = det_model.eval()
        self.det_arch = det_arch
        self.gen = gen.eval()
        self.seg_arch = seg_arch
        self.crop_size = seg_arch.crop_size
        self.det.roi_heads.score_thresh = self.cfg.score_threshold
        self.det.roi_heads.nms_thresh = self.cfg.nms_iou
        self.det.roi_heads.detections_per_img = self.cfg.max_detections
        self.ort = None
        if onnx_path is not None and onnx_path.is_file():
            import onnxruntime as ort

            so = ort.SessionOptions()
            so.intra_op_num_threads = max(1, torch.get_num_threads())
            self.ort = ort.InferenceSession(str(onnx_path), so, providers=["CPUExecutionProvider"])
        self.ort_det = None
        if det_onnx_path is not None and det_onnx_path.is_file():
            from seedmap.detect.learned.export import onnx_post_params

            post = onnx_post_params(det_onnx_path)
            if graph_gives(post, self.cfg) and self.cfg.upscale in (None, det_arch.upscale):
                import onnxruntime as ort

                so = ort.SessionOptions()
                so.intra_op_num_threads = max(1, torch.get_num_threads())
                self.ort_det = ort.InferenceSession(str(det_onnx_path), so, providers=["CPUExecutionProvider"])

    @classmethod
    def from_weights(cls, weights: str | Path | None, config: LearnedConfig | None = None) -> LearnedDetector:
        det_p, seg_p = find_weight_files(weights)
        td, md = read_weights(det_p, "detector")
        ts, ms = read_weights(seg_p, "segmenter")
        try:
            darch = DetectorArch.model_validate(json.loads(md["arch"]))
            sarch = SegmenterArch.model_validate(json.loads(ms["arch"]))
        except (KeyError, ValueError) as e:
            raise InputError(f"weights metadata lacks a valid architecture ({type(e).__name__})", det_p) from None
        model = build_frcnn(darch)
        load_into(model, td, det_p)
        gen = UNetGenerator(sarch.crop_size, sarch.ngf)
        load_into(gen, ts, seg_p)
        return cls(model, darch, gen, sarch, config, seg_p.with_suffix(".onnx"), det_p.with_suffix(".onnx"))

    def boxes(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Faster R-CNN boxes (x0, y0, x1, y1) and scores on the upscaled image."""
        img = check_image(image)
        h, w = img.shape[:2]
        set_input_scale(self.det, h, w, self.det_arch.upscale if self.cfg.upscale is None else self.cfg.upscale)
        x = torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float().div_(255.0)
        if self.ort_det is not None:
            b, s = self.ort_det.run(None, {"image": x.numpy()})
            keep = np.flatnonzero(s >= self.cfg.score_threshold)
            keep = keep[np.argsort(-s[keep], kind="stable")][: self.cfg.max_detections]
            return b[keep].astype(np.float64), s[keep]
        with torch.no_grad():
            out = self.det([x])[0]
        return out["boxes"].numpy().astype(np.float64), out["scores"].numpy()

    def masks(self, crops: np.ndarray) -> np.ndarray:
        """pix2pix masks (K, N, N) bool for uint8 crops (K, N, N, 3)."""
        if len(crops) == 0:
            return np.zeros((0,) + crops.shape[1:3], bool)
        x = crops.transpose(0, 3, 1, 2).astype(np.float32) / 127.5 - 1.0
        if self.ort is not None:
            y = self.ort.run(None, {"crop": x})[0]
        else:
            with torch.no_grad():
                y = self.gen(torch.from_numpy(x)).numpy()
        return y[:, 0] > 0

    def detect(self, image: np.ndarray) -> Detections:
        boxes, scores = self.boxes(image)
        return boxes_to_detections(image, boxes, scores, self.masks, self.crop_size)
