"""Per-image training targets of the ``fast`` CNN (:class:`TrainImage`): from a simulated image's ground truth
(:func:`image_targets`) or from a user's COCO labels, boxes with or without masks (:func:`labelled_targets`).

:func:`seedmap.detect.train_cnn.crop_batch` cuts crops and their targets from them. A labelled seed becomes:

* its pixels: the annotation's mask (polygon or RLE) where it has one, else the ellipse inscribed in its box
  (seeds are compact ellipsoids; the box edges and keypoint offset are trained on these pixels);
* its keypoint: the mask centroid, else the box centre;
* every labelled seed is a heatmap peak, however small (the user labelled it: no sliver is ignored).

Images listed without annotations train as background. :func:`labels_seed_px` gives the labels' typical seed
size; training resizes every labelled image by ``network seed size / labels' seed size`` (:func:`rescale_targets`)
so that the network learns the seeds at the size it sees them at, and records both sizes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from seedmap.detect.labels import CocoSource, LabelledImage
from seedmap.errors import InputError


@dataclass
class TrainImage:
    """One image with compact per-pixel targets (instance index map + per-instance arrays)."""

    rgb: np.ndarray  # H x W x 3 uint8
    inst: np.ndarray  # H x W int16: row into the per-instance arrays, -1 = background
    boxes: np.ndarray  # (N, 4) float32 GT boxes
    kp: np.ndarray  # (N, 2) float32 keypoint targets (u, v)
    centers: np.ndarray  # (N, 2) int peak pixels
    area: np.ndarray  # (N,) float32 visible pixels of each instance
    arm: bool = False  # from an arm scan (a dataset with arm.yaml: close-up panicle images)
    labelled: bool = False  # from a user's COCO labels (labelled_targets)
    replay: bool = False  # a rehearsal image of a fine-tune (seedmap.detect.replay)


def image_targets(rgb: np.ndarray, labels: np.ndarray, inst, min_area: int = 1) -> TrainImage:
    """Targets of one simulated image from its GT label image and instance table.

    Every instance of at least ``min_area`` visible pixels is kept; ``train_cnn.crop_batch`` decides per
    crop (after scaling) which ones are heatmap positives, ignored slivers or box-only pixels.
    """
    h, w = labels.shape
    lut = np.full(int(max(labels.max(), inst.label.max(initial=0))) + 1, -1, np.int64)
    keep = inst.area >= min_area
    rows = np.flatnonzero(keep)
    lut[inst.label[rows].astype(np.int64)] = np.arange(len(rows))
    idx = lut[labels.astype(np.int64)].astype(np.int16)
    boxes = inst.boxes[rows].astype(np.float32)
    # keypoint: projected centre where visible, else the centroid of the visible mask
    cnt = np.bincount(idx[idx >= 0].astype(np.int64), minlength=len(rows)).astype(np.float64)
    ys, xs = np.nonzero(idx >= 0)
    li = idx[ys, xs].astype(np.int64)
    cx = np.bincount(li, xs, len(rows)) / np.maximum(cnt, 1)
    cy = np.bincount(li, ys, len(rows)) / np.maximum(cnt, 1)
    vis = inst.center_visible[rows].astype(bool)
    kp = np.where(vis[:, None], inst.center_uv[rows], np.c_[cx, cy]).astype(np.float32)
    c = np.round(kp).astype(np.int64)
    c[:, 0] = np.clip(c[:, 0], 0, w - 1)
    c[:, 1] = np.clip(c[:, 1], 0, h - 1)
    return TrainImage(rgb, idx, boxes, kp, c, inst.area[rows].astype(np.float32))


def is_coco_file(path: str | Path) -> bool:
    """True for a ``.json`` path (a COCO label file; datasets are folders)."""
    return Path(path).suffix.lower() == ".json"


def box_ellipse_labels(boxes: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``labels`` with every box that has no mask pixels (value ``k + 1`` absent) filled by its inscribed ellipse
    (pixel centres inside it; at least the centre pixel), on pixels no other seed claims. Returns a new array."""
    out = labels.copy()
    h, w = out.shape
    have = np.zeros(len(boxes) + 1, bool)
    have[np.unique(labels[labels > 0])] = True
    for k, (x0, y0, x1, y1) in enumerate(np.asarray(boxes, np.float64)):
        if have[k + 1]:
            continue
        cx, cy = (x0 + x1) / 2 - 0.5, (y0 + y1) / 2 - 0.5  # pixel k spans [k, k + 1): centres at k
        ax, ay = max((x1 - x0) / 2, 0.5), max((y1 - y0) / 2, 0.5)
        u0, u1 = max(int(np.floor(x0)), 0), min(int(np.ceil(x1)), w)
        v0, v1 = max(int(np.floor(y0)), 0), min(int(np.ceil(y1)), h)
        if u1 <= u0 or v1 <= v0:
            continue
        yy, xx = np.mgrid[v0:v1, u0:u1]
        inside = ((xx - cx) / ax) ** 2 + ((yy - cy) / ay) ** 2 <= 1.0
        ci, cj = int(np.clip(round(cy), v0, v1 - 1)) - v0, int(np.clip(round(cx), u0, u1 - 1)) - u0
        inside[ci, cj] = True
        win = out[v0:v1, u0:u1]
        win[inside & (win == 0)] = k + 1
    return out


def labelled_targets(li: LabelledImage) -> TrainImage:
    """The CNN's targets of one labelled image (module docstring)."""
    h, w = li.labels.shape
    n = len(li.boxes)
    lab = box_ellipse_labels(li.boxes, li.labels)
    idx = (lab.astype(np.int64) - 1).astype(np.int16)  # -1 = background
    ys, xs = np.nonzero(lab > 0)
    li_k = lab[ys, xs].astype(np.int64) - 1
    cnt = np.bincount(li_k, minlength=n).astype(np.float64)
    b = np.asarray(li.boxes, np.float64).reshape(-1, 4)
    centre = np.c_[(b[:, 0] + b[:, 2]) / 2 - 0.5, (b[:, 1] + b[:, 3]) / 2 - 0.5]
    cx = np.bincount(li_k, xs, n) / np.maximum(cnt, 1)
    cy = np.bincount(li_k, ys, n) / np.maximum(cnt, 1)
    kp = np.where((cnt > 0)[:, None], np.c_[cx, cy], centre).astype(np.float32)
    c = np.round(kp).astype(np.int64)
    c[:, 0] = np.clip(c[:, 0], 0, w - 1)
    c[:, 1] = np.clip(c[:, 1], 0, h - 1)
    # every labelled seed is a heatmap peak, whatever its size (crop_batch's area thresholds never apply)
    area = np.full(n, np.inf, np.float32)
    return TrainImage(li.image, idx, b.astype(np.float32), kp, c, area, labelled=True)


def pad_to(ti: TrainImage, size: int) -> TrainImage:
    """``ti`` padded with black background at the right and bottom to at least ``size`` x ``size`` px (training
    crops are ``size`` px); larger images are returned as they are."""
    h, w = ti.inst.shape
    if h >= size and w >= size:
        return ti
    ph, pw = max(size - h, 0), max(size - w, 0)
    rgb = np.pad(ti.rgb, ((0, ph), (0, pw), (0, 0)))
    inst = np.pad(ti.inst, ((0, ph), (0, pw)), constant_values=-1)
    return replace(ti, rgb=rgb, inst=inst)


def rescale_targets(ti: TrainImage, s: float) -> TrainImage:
    """``ti`` resized by ``s`` (image: area averaging when shrinking, bilinear when enlarging; instance map: nearest;
    boxes, keypoints and areas scaled; pixel centres at integers)."""
    import cv2

    if s == 1.0:
        return ti
    h, w = ti.inst.shape
    ws, hs = max(1, int(round(w * s))), max(1, int(round(h * s)))
    sx, sy = ws / w, hs / h
    rgb = cv2.resize(ti.rgb, (ws, hs), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    inst = cv2.resize(ti.inst, (ws, hs), interpolation=cv2.INTER_NEAREST)
    boxes = (ti.boxes * np.array([sx, sy, sx, sy], np.float32)).astype(np.float32)
    kp = ((ti.kp + 0.5) * np.array([sx, sy], np.float32) - 0.5).astype(np.float32)
    c = np.round(kp).astype(np.int64)
    c[:, 0] = np.clip(c[:, 0], 0, ws - 1)
    c[:, 1] = np.clip(c[:, 1], 0, hs - 1)
    return replace(ti, rgb=rgb, inst=inst, boxes=boxes, kp=kp, centers=c, area=(ti.area * sx * sy).astype(np.float32))


def coco_image_targets(src: CocoSource, k: int, scale: float = 1.0) -> TrainImage:
    """Targets of image ``k`` of a COCO source; an image whose size differs from the one its labels declare is
    refused (labels made on a rotated or resized copy). ``scale``: resize image and targets (:func:`rescale_targets`)."""
    li = src[k]
    im = src.images[k]
    h, w = li.image.shape[:2]
    if (im.get("width"), im.get("height")) not in ((w, h), (None, None)):
        raise InputError(f"image {im['file_name']!r} is {w}x{h} but its labels say "
                         f"{im.get('width')}x{im.get('height')} (labelled on a rotated or resized copy?)", src.path)
    return rescale_targets(labelled_targets(li), scale)


def labels_seed_px(images: list[TrainImage]) -> float | None:
    """The typical seed size (px) of labelled images: median geometric mean of the box sides (None: no boxes)."""
    b = np.concatenate([im.boxes for im in images]) if images else np.zeros((0, 4))
    if len(b) == 0:
        return None
    return float(np.median(np.sqrt(np.maximum(b[:, 2] - b[:, 0], 0) * np.maximum(b[:, 3] - b[:, 1], 0))))
