"""Detection files written by ``seedmap detect`` and read by ``seedmap eval detect``.

``DIR/detections.jsonl`` — one JSON object per line, one line per (frame, camera)::

    {"frame": 0, "camera": "left", "timestamp": 0.0, "image": "left/000000.png",
     "width": 1434, "height": 1050, "n": 2,
     "boxes": [[x0, y0, x1, y1], ...],          # px; x1/y1 exclusive pixel-index bounds (GT convention)
     "scores": [s, ...],                          # 0..1
     "ellipses": [[cx, cy, major, minor, angle_deg], ...],   # full axes, angle of the major axis
     "seed_ids": [-1, ...]}                       # GT seed ids (oracle only), else -1

The keypoint of a detection is its ellipse centre ``(cx, cy)``.

A photo's record (``fast`` detector) also carries ``seed_px`` (the seed size estimated in it, px, or the one
``cnn.seed_px`` / ``cnn.scale`` / the network set; null when the estimate found no seeds), ``cnn_scale`` (the
factor the network's input was resized by) and ``seed_px_from`` (``photo``: its own estimate; ``folder``: the
folder's; else how the config set it: ``seed_px`` | ``scale`` | ``network``).

``DIR/detections_coco.json`` — the same detections as a COCO dataset (``images``, with a photo's ``seed_px``,
``cnn_scale`` and ``seed_px_from``; ``annotations``
with ``bbox`` = [x, y, w, h], ``score``, ``keypoints`` = [cx, cy, 2] and ``ellipse`` in seedmap pixel-centre coordinates, a
polygon ``segmentation`` of the ellipse in COCO pixel-edge coordinates (+0.5), ``categories`` = one ``seed`` class), so other tools can
read them and they can serve as (pseudo-)labels for training.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from seedmap.errors import InputError
from seedmap.io.atomic import atomic_write_text
from seedmap.io.text import read_text
from seedmap.records import Detections

JSONL_NAME = "detections.jsonl"
COCO_NAME = "detections_coco.json"


def _r(a: np.ndarray, nd: int = 3) -> list:
    return np.round(np.asarray(a, np.float64), nd).tolist()


def detection_record(frame: int, camera: str, det: Detections, timestamp: float = 0.0, image: str = "",
                     width: int = 0, height: int = 0) -> dict:
    return {
        "frame": int(frame), "camera": camera, "timestamp": float(timestamp), "image": image,
        "width": int(width), "height": int(height), "n": len(det),
        "boxes": _r(det.boxes, 2), "scores": _r(det.scores, 4), "ellipses": _r(det.ellipses, 3),
        "seed_ids": np.asarray(det.seed_ids, np.int64).tolist(),
    }


def record_detections(rec: dict) -> Detections:
    return Detections(boxes=np.asarray(rec["boxes"], np.float32).reshape(-1, 4),
                      scores=np.asarray(rec["scores"], np.float32),
                      ellipses=np.asarray(rec["ellipses"], np.float32).reshape(-1, 5),
                      seed_ids=np.asarray(rec.get("seed_ids") or np.full(len(rec["scores"]), -1), np.int64))


def read_detections(path: str | Path) -> dict[tuple[int, str], Detections]:
    """``{(frame, camera): Detections}`` from a detections folder or its ``detections.jsonl``."""
    p = Path(path)
    if p.is_dir():
        p = p / JSONL_NAME
    if not p.is_file():
        raise InputError(f"no {JSONL_NAME} found (write one with `seedmap detect`)", p)
    out: dict[tuple[int, str], Detections] = {}
    for ln, line in enumerate(read_text(p, JSONL_NAME).splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            out[(int(rec["frame"]), str(rec["camera"]))] = record_detections(rec)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise InputError(f"line {ln}: not a detection record ({type(e).__name__}: {e})", p) from None
    return out


def detection_image_sizes(path: str | Path) -> set[tuple[int, int]]:
    """The ``(width, height)`` pairs the records of a detections folder (or its ``detections.jsonl``) were made on;
    records without a size (0) are left out. Used to refuse scoring detections against another dataset."""
    p = Path(path)
    if p.is_dir():
        p = p / JSONL_NAME
    sizes: set[tuple[int, int]] = set()
    for line in read_text(p, JSONL_NAME).splitlines():
        if line.strip():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue  # read_detections names the bad line
            w, h = int(rec.get("width", 0) or 0), int(rec.get("height", 0) or 0)
            if w > 0 and h > 0:
                sizes.add((w, h))
    return sizes


def _inside_box(poly: np.ndarray, box: tuple[float, float, float, float], area: float) -> tuple[np.ndarray, float]:
    """The ellipse polygon clipped to its box, and its area (px²), so that a COCO annotation's segmentation lies
    inside its bbox and ``area`` <= the bbox's area. Box and ellipse come from different estimates (box head vs
    moment ellipse), and the ellipse sticks out of the box for a few percent of the detections; most are inside,
    and those keep the analytic ellipse area. An ellipse that misses its box entirely keeps the box as its mask."""
    x0, y0, x1, y1 = box
    if poly[:, 0].min() >= x0 and poly[:, 0].max() <= x1 and poly[:, 1].min() >= y0 and poly[:, 1].max() <= y1:
        return poly, area
    rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float32)
    convex = poly[:-1] if len(poly) > 3 and np.allclose(poly[0], poly[-1]) else poly  # ellipse2Poly closes it
    inter, clipped = cv2.intersectConvexConvex(np.ascontiguousarray(convex, np.float32), rect)
    if clipped is None or len(clipped) < 3 or inter <= 0:
        return rect.astype(np.float64), float(max(x1 - x0, 0.0) * max(y1 - y0, 0.0))
    return clipped.reshape(-1, 2).astype(np.float64), float(inter)


def coco_from_records(records: Iterable[dict]) -> dict:
    """A COCO dataset dict holding the detections of ``records`` (see module docstring)."""
    images, anns = [], []
    aid = 1
    for img_id, rec in enumerate(records, 1):
        images.append({"id": img_id, "file_name": rec["image"], "width": rec["width"], "height": rec["height"],
                       "frame": rec["frame"], "camera": rec["camera"],
                       **{k: rec[k] for k in ("seed_px", "cnn_scale", "seed_px_from") if k in rec}})
        for b, s, e, sid in zip(rec["boxes"], rec["scores"], rec["ellipses"], rec["seed_ids"], strict=True):
            x0, y0, x1, y1 = b
            cx, cy, ma, mi, ang = e
            poly = cv2.ellipse2Poly((int(round(cx * 16)), int(round(cy * 16))),
                                    (max(int(round(ma * 8)), 1), max(int(round(mi * 8)), 1)), int(round(ang)), 0,
                                    360, 30).astype(np.float64) / 16.0 + 0.5  # COCO: pixel edges at integers
            poly, area = _inside_box(poly, (x0, y0, x1, y1), float(np.pi * ma * mi / 4.0))
            anns.append({
                "id": aid, "image_id": img_id, "category_id": 1,
                "bbox": [round(x0, 2), round(y0, 2), round(x1 - x0, 2), round(y1 - y0, 2)],
                "area": round(area, 2), "iscrowd": 0, "score": s,
                "keypoints": [cx, cy, 2], "num_keypoints": 1,
                "ellipse": {"cx": cx, "cy": cy, "major": ma, "minor": mi, "angle_deg": ang},
                "segmentation": [np.round(poly.reshape(-1), 2).tolist()], "seed_id": sid,
            })
            aid += 1
    return {"info": {"description": "seedmap seed detections"}, "images": images, "annotations": anns,
            "categories": [{"id": 1, "name": "seed", "supercategory": "grain", "keypoints": ["center"],
                            "skeleton": []}]}


def write_detection_files(out_dir: Path, records: list[dict]) -> None:
    """Write ``detections.jsonl`` and ``detections_coco.json`` into ``out_dir``."""
    out_dir = Path(out_dir)
    atomic_write_text(out_dir / JSONL_NAME, "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in records))
    atomic_write_text(out_dir / COCO_NAME, json.dumps(coco_from_records(records), separators=(",", ":")))
