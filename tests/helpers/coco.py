"""COCO label files (polygons and RLE masks) exported from a simulated dataset's ground truth."""

from __future__ import annotations

import copy
from pathlib import Path
import cv2
import numpy as np


def coco_rle(m: np.ndarray) -> dict:
    """Uncompressed COCO RLE: run lengths of the column-major mask, starting with a run of zeros."""
    f = m.flatten(order="F").astype(np.int8)
    change = np.flatnonzero(np.diff(f)) + 1
    bounds = np.concatenate([[0], change, [f.size]])
    runs = np.diff(bounds).tolist()
    if f[0] == 1:
        runs = [0, *runs]
    return {"counts": runs, "size": list(m.shape)}


_EXPORTS: dict = {}


def export_coco(root: Path, frames=(0, 1), min_area: int = 6) -> tuple[dict, dict]:
    """COCO of the left GT instances of ``frames``: every other seed as a polygon (pixel-edge
    coordinates) or an RLE mask. Returns the COCO dict and {annotation id: GT mask} (computed once)."""
    key = (str(root), tuple(frames), min_area)
    if key not in _EXPORTS:
        _EXPORTS[key] = _export_coco_uncached(root, frames, min_area)
    return copy.deepcopy(_EXPORTS[key][0]), _EXPORTS[key][1]


def _export_coco_uncached(root: Path, frames, min_area: int) -> tuple[dict, dict]:
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(root)
    images, anns, masks = [], [], {}
    for i in frames:
        lab = ds.gt_label_image(i, "left")
        inst = ds.gt_instances(i, "left")
        h, w = lab.shape
        images.append({"id": i + 1, "file_name": f"left/{i:06d}.png", "width": w, "height": h})
        for lbl in inst.label:
            m = (lab == lbl).astype(np.uint8)
            if m.sum() < min_area:
                continue
            ys, xs = np.nonzero(m)
            bbox = [float(xs.min()), float(ys.min()), float(np.ptp(xs) + 1), float(np.ptp(ys) + 1)]
            aid = len(anns) + 1
            if aid % 2:
                seg = coco_rle(m)
            else:
                # the pixel-edge outline of a convex-ish blob: contour of the 2x upsampled mask, halved
                big = cv2.resize(m, (2 * w, 2 * h), interpolation=cv2.INTER_NEAREST)
                cs, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
                c = max(cs, key=len).reshape(-1, 2).astype(float)
                seg = [((c + 0.5) / 2.0).ravel().tolist()]
            anns.append({"id": aid, "image_id": i + 1, "category_id": 1, "bbox": bbox, "area": float(m.sum()),
                         "iscrowd": 0, "segmentation": seg})
            masks[aid] = m
    return {"images": images, "annotations": anns, "categories": [{"id": 1, "name": "seed"}]}, masks
