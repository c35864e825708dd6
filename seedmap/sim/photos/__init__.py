"""Simulated grain photos with ground truth: loose grain, piles and panicles on varied backgrounds and light.

``seedmap simulate photos`` writes a folder a user's own labelled photos would look like: the images
(``00000.jpg`` ...; flatbed scans as PNG) and ``labels.json``, COCO with one annotation per visible seed (box,
compressed-RLE mask, area). Each image entry also carries ``seed_px`` (median geometric mean of its seeds' box
sides) and the ``conditions`` it was drawn with. ``split=validation`` and ``split=heldout`` draw backgrounds, lights
and varieties that ``split=train`` never uses (two disjoint sets: one to choose with, one to measure).
Method: docs/method/photos.md.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal, Sequence

import cv2
import numpy as np
from pydantic import Field
from scipy import ndimage

from seedmap import outputs
from seedmap.config import ConfigModel, config_to_yaml
from seedmap.detect.labels import rle_counts_to_string
from seedmap.io.atomic import atomic_write_text
from seedmap.progress import track
from seedmap.sim.photos.compose import Photo, draw_conditions, render_photo

__all__ = ["PhotoSimConfig", "simulate_photos", "render_photo", "coco_annotations"]


class PhotoSimConfig(ConfigModel):
    """``seedmap simulate photos``: how many photos, of which split, how large, with how large seeds."""

    #: random seed; photo i depends only on it and i
    seed: int = 0
    #: number of photos
    count: int = Field(20, ge=1)
    #: ``train`` conditions; ``validation`` or ``heldout``: backgrounds, lights and varieties never used for training,
    #: the first for choosing between networks and settings, the second for measuring them
    split: Literal["train", "validation", "heldout"] = "train"
    #: long side of a photo (px), drawn uniformly from this range
    long_side: tuple[int, int] = (640, 1280)
    #: seed diameter (px), drawn log-uniformly from this range per photo
    seed_px: tuple[float, float] = (10.0, 40.0)
    #: fraction of photos with no seeds at all (only background and look-alikes)
    empty_fraction: float = Field(0.08, ge=0, le=1)
    #: all photos of one setup, as a user's own photos are: one background, light and set of grain varieties drawn
    #: from ``seed`` (and ``split``), the seed size varying by +-10 % around one drawn from ``seed_px``
    setup: bool = False


#: random stream of a setup's conditions (apart from every photo's own)
SETUP_STREAM = 1


def _rle(pos: np.ndarray, h: int, w: int) -> dict:
    """Compressed COCO RLE of the mask whose pixels have the sorted column-major indices ``pos`` (x * h + y)."""
    if len(pos) == 0:
        return {"counts": rle_counts_to_string([h * w]), "size": [h, w]}
    brk = np.flatnonzero(np.diff(pos) != 1) + 1
    starts = pos[np.concatenate([[0], brk])]
    ends = pos[np.concatenate([brk - 1, [len(pos) - 1]])] + 1
    zeros = starts - np.concatenate([[0], ends[:-1]])
    runs = np.empty(2 * len(starts) + 1, np.int64)
    runs[0:-1:2] = zeros
    runs[1::2] = ends - starts
    runs[-1] = h * w - ends[-1]
    return {"counts": rle_counts_to_string(runs.tolist()), "size": [h, w]}


def coco_annotations(photo: Photo, image_id: int, first_id: int) -> tuple[list[dict], float | None]:
    """COCO annotations of a photo's labelled seeds and their median size (px; None without seeds)."""
    anns, sizes = [], []
    h, w = photo.ids.shape
    slices = ndimage.find_objects(photo.ids)
    for k in photo.seeds:
        sy, sx = slices[k - 1]
        ys, xs = np.nonzero(photo.ids[sy, sx] == k)
        ys, xs = ys + sy.start, xs + sx.start
        x0, x1, y0, y1 = int(xs.min()), int(xs.max()) + 1, int(ys.min()), int(ys.max()) + 1
        sizes.append(np.sqrt((x1 - x0) * (y1 - y0)))
        anns.append({"id": first_id + len(anns), "image_id": image_id, "category_id": 1,
                     "bbox": [x0, y0, x1 - x0, y1 - y0], "area": int(len(xs)), "iscrowd": 0,
                     "segmentation": _rle(np.sort(xs.astype(np.int64) * h + ys), h, w)})
    return anns, (round(float(np.median(sizes)), 3) if sizes else None)


def simulate_photos(cfg: PhotoSimConfig, out: str | Path, overwrite: bool = False, progress: bool = True,
                    inputs: Sequence[str | Path | None] = ()) -> Path:
    """Render ``cfg.count`` photos with COCO labels into ``out`` atomically (nothing left behind on failure)."""
    out = Path(out)
    lo, hi = cfg.long_side
    if not 64 <= lo <= hi <= 8192:
        raise ValueError(f"long_side must satisfy 64 <= low <= high <= 8192, got {cfg.long_side}")
    if not 3.0 <= cfg.seed_px[0] <= cfg.seed_px[1] <= lo / 8:
        raise ValueError(f"seed_px must satisfy 3 <= low <= high <= long_side low / 8, got {cfg.seed_px}")
    seqs = np.random.SeedSequence(cfg.seed).spawn(cfg.count)
    setup = None
    if cfg.setup:
        setup = draw_conditions(np.random.default_rng([cfg.seed, SETUP_STREAM]), cfg.split, cfg.long_side, cfg.seed_px)
    images, anns = [], []
    with outputs.output_dir(out, "photos", inputs, overwrite) as tmp:
        for i in track(range(cfg.count), f"render {out.name}", "photo", enabled=progress):
            rng = np.random.default_rng(seqs[i])
            ph = render_photo(rng, cfg.split, cfg.long_side, cfg.seed_px, cfg.empty_fraction, setup)
            name = f"{i:05d}.png" if ph.lossless else f"{i:05d}.jpg"
            bgr = cv2.cvtColor(ph.image, cv2.COLOR_RGB2BGR)
            q = int(rng.integers(50, 96))
            params = [] if ph.lossless else [cv2.IMWRITE_JPEG_QUALITY, q]
            if not cv2.imwrite(str(tmp / name), bgr, params):
                raise OSError(f"cannot write {name}")
            a, spx = coco_annotations(ph, i + 1, len(anns) + 1)
            anns += a
            cond = {**ph.conditions, **({} if ph.lossless else {"jpeg_quality": q})}
            images.append({"id": i + 1, "file_name": name, "width": int(ph.image.shape[1]),
                           "height": int(ph.image.shape[0]), "seed_px": spx, "conditions": cond})
        coco = {"info": {"description": "seedmap simulated grain photos", "split": cfg.split, "seed": cfg.seed,
                         **({"setup": {k: setup[k] for k in ("bg", "light", "varieties")}} if setup else {})},
                "images": images, "annotations": anns, "categories": [{"id": 1, "name": "seed"}]}
        atomic_write_text(tmp / "labels.json", json.dumps(coco))
        atomic_write_text(tmp / "config.yaml", config_to_yaml(cfg))
    return out
