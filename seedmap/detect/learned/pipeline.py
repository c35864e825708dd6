"""The learned pipeline's shared last steps, and its torch-free onnxruntime form.

Boxes -> pix2pix masks of padded box crops -> ``cv2.fitEllipse`` on each mask's contour -> keypoints
(:func:`boxes_to_detections`). :class:`OnnxLearnedDetector` runs both networks from their exported graphs
(``detector.onnx``, ``segmenter.onnx``, written by ``seedmap train export`` or shipped), so inference needs
onnxruntime only, no torch.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from seedmap.detect.base import Detector, check_image
from seedmap.detect.config import LearnedConfig
from seedmap.detect.ellipse import fit_ellipse_mask
from seedmap.detect.learned.crops import CROP_PAD, crop_to_full, extract_crops
from seedmap.errors import InputError
from seedmap.records import Detections

#: onnxruntime intra-op threads of each network (one per detector, as ``fast``'s default)
ONNX_THREADS = 1
#: the ellipse fitter of a mask (cv2.fitEllipse on its contour, the paper's)
ELLIPSE = "contour"


def boxes_to_detections(image: np.ndarray, boxes: np.ndarray, scores: np.ndarray,
                        masks: Callable[[np.ndarray], np.ndarray], crop_size: int) -> Detections:
    """Ellipses from the masks of the box crops. A mask that comes out empty falls back to the box's inscribed
    ellipse (its centre is the box centre), so the detection is kept."""
    if len(boxes) == 0:
        return Detections()
    n = crop_size
    crops, wins, _ = extract_crops(image, boxes, n, CROP_PAD)
    m = masks(crops)
    ell = np.zeros((len(boxes), 5))
    for k in range(len(boxes)):
        e = fit_ellipse_mask(m[k], ELLIPSE)
        if e is None:
            b = boxes[k]
            ell[k] = [(b[0] + b[2]) / 2 - 0.5, (b[1] + b[3]) / 2 - 0.5, b[2] - b[0], b[3] - b[1], 0.0]
            continue
        a = n / wins[k, 2]
        ell[k, :2] = crop_to_full(e[:2], wins[k], n)
        ell[k, 2:4] = e[2:4] / a
        ell[k, 4] = e[4]
        if ell[k, 2] < ell[k, 3]:
            ell[k, 2], ell[k, 3] = ell[k, 3], ell[k, 2]
    return Detections(boxes=boxes, scores=scores, ellipses=ell)


def graph_gives(post: dict, cfg: LearnedConfig) -> bool:
    """Whether a detector graph's baked-in post-processing (``post``: score threshold, NMS IoU, box cap) keeps
    everything the settings ``cfg`` ask for."""
    return (post.get("score_threshold", 1.0) <= cfg.score_threshold
            and abs(post.get("nms_iou", -1.0) - cfg.nms_iou) < 1e-9
            and post.get("max_detections", 0) >= cfg.max_detections)


def onnx_files(folder: Path) -> tuple[Path, Path] | None:
    """``(detector.onnx, segmenter.onnx)`` in ``folder`` when both exist, else None."""
    det, seg = folder / "detector.onnx", folder / "segmenter.onnx"
    return (det, seg) if det.is_file() and seg.is_file() else None


def _meta_json(sess, key: str, path: Path) -> dict:  # noqa: ANN001 - ort.InferenceSession
    try:
        d = json.loads(sess.get_modelmeta().custom_metadata_map[key])
    except (KeyError, ValueError):
        raise InputError(f"the ONNX file lacks its {key!r} metadata (export it with `seedmap train export`)",
                         path) from None
    if not isinstance(d, dict):
        raise InputError(f"the ONNX file's {key!r} metadata is not a JSON object", path)
    return d


class OnnxLearnedDetector(Detector):
    """Faster R-CNN boxes -> pix2pix masks -> ellipses, both networks in onnxruntime (no torch)."""

    def __init__(self, det_onnx: Path, seg_onnx: Path, config: LearnedConfig | None = None,
                 name: str = "frcnn-pix2pix") -> None:
        from seedmap.detect.runtime import load_session

        self.name = name
        self.cfg = config or LearnedConfig()
        if self.cfg.score_threshold is None:
            from seedmap.detect.config import DEFAULT_SCORE_THRESHOLD

            self.cfg = self.cfg.model_copy(update={"score_threshold": DEFAULT_SCORE_THRESHOLD})
        self.det = load_session(det_onnx, ONNX_THREADS, kind="detector")
        self.seg = load_session(seg_onnx, ONNX_THREADS, kind="segmenter")
        self.det_arch = _meta_json(self.det, "arch", det_onnx)
        self.seg_arch = _meta_json(self.seg, "arch", seg_onnx)
        post = _meta_json(self.det, "post", det_onnx)
        up = float(self.det_arch.get("upscale", 2.0))
        if self.cfg.upscale is not None and abs(self.cfg.upscale - up) > 1e-9:
            raise InputError(f"the detector graph runs at upscale {up:g}; learned.upscale={self.cfg.upscale:g} needs "
                             "the safetensors weights and torch", det_onnx)
        if not graph_gives(post, self.cfg):
            raise InputError(
                f"the detector graph was exported with score >= {post.get('score_threshold')}, NMS IoU "
                f"{post.get('nms_iou')}, at most {post.get('max_detections')} boxes, which cannot give "
                f"learned.score_threshold={self.cfg.score_threshold:g}, nms_iou={self.cfg.nms_iou:g}, "
                f"max_detections={self.cfg.max_detections}: re-export with `seedmap train export`", det_onnx)
        self.crop_size = int(self.seg_arch.get("crop_size", 32))

    def boxes(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Boxes (x0, y0, x1, y1, input pixels) and scores, best first, at most ``max_detections``."""
        img = check_image(image)
        x = np.ascontiguousarray(img.transpose(2, 0, 1), np.float32) / np.float32(255.0)
        b, s = self.det.run(None, {"image": x})
        keep = np.flatnonzero(s >= self.cfg.score_threshold)
        keep = keep[np.argsort(-s[keep], kind="stable")][: self.cfg.max_detections]
        return b[keep].astype(np.float64), s[keep]

    def masks(self, crops: np.ndarray) -> np.ndarray:
        """pix2pix masks (K, N, N) bool for uint8 crops (K, N, N, 3)."""
        if len(crops) == 0:
            return np.zeros((0,) + crops.shape[1:3], bool)
        x = crops.transpose(0, 3, 1, 2).astype(np.float32) / np.float32(127.5) - np.float32(1.0)
        return self.seg.run(None, {"crop": x})[0][:, 0] > 0

    def detect(self, image: np.ndarray) -> Detections:
        boxes, scores = self.boxes(image)
        return boxes_to_detections(image, boxes, scores, self.masks, self.crop_size)
