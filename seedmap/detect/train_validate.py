"""The held-out split and the held-out detection F1 of ``seedmap train fast-cnn``.

A COCO label file without ``--val`` keeps a seeded fraction of its labelled images for validation
(:func:`split_coco`). After training, :func:`heldout_f1` runs a network the way ``seedmap detect`` does
(onnxruntime, :class:`seedmap.detect.cnn.CnnDetector`, refiner off, at the scale the network stores) on the held-out
images and scores its boxes with the rule of ``seedmap eval detect`` (IoU >= 0.5, greedy one-to-one): every labelled
seed of a COCO image counts; a simulated frame's GT slivers below the detectable-seed size are ignored.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seedmap.errors import InputError


@dataclass
class HeldOut:
    """Held-out images of one training source: COCO image indices (``coco`` = the :class:`CocoSource`) or the
    frames of a simulated dataset (``dataset`` = its folder)."""

    coco: object | None = None
    dataset: Path | None = None
    indices: tuple[int, ...] = ()


def split_coco(labelled: list[int], unlabelled: list[int], fraction: float, seed: int, path: Path
               ) -> tuple[list[int], list[int]]:
    """``(train, val)`` image indices: ``max(1, round(fraction x labelled))`` labelled images, drawn with ``seed``,
    are held out (at least one labelled image is left to train on); images without labels train as background.
    Fewer than 2 labelled images: one-line :class:`InputError` naming ``path``."""
    if len(labelled) < 2:
        raise InputError(f"has {len(labelled)} labelled image{'s' if len(labelled) != 1 else ''}; training needs at "
                         "least 2 (one for the held-out check of the network; or pass --val LABELS.json)", path)
    n_val = min(max(1, int(round(fraction * len(labelled)))), len(labelled) - 1)
    order = np.random.default_rng(seed).permutation(len(labelled))
    val = sorted(labelled[k] for k in order[:n_val])
    train = sorted([labelled[k] for k in order[n_val:]] + list(unlabelled))
    return train, val


def _coco_items(src, indices):  # noqa: ANN001, ANN202 - a CocoSource
    for k in indices:
        li = src[k]
        yield li.image, np.asarray(li.boxes, np.float64).reshape(-1, 4), None


def _sim_items(root: Path, frames):  # noqa: ANN001, ANN202
    from seedmap.io.images import read_rgb
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(root)
    for i in frames:
        for cam in ("left", "right"):
            yield read_rgb(ds.image_path(i, cam)), None, ds.gt_instances(i, cam)


def heldout_f1(weights: str | Path, heldout: list[HeldOut], images_seed_px: float | None = None,
               threads: int = 1) -> dict | None:
    """Box precision, recall and F1 of the network ``weights`` on the held-out images (module docstring), pooled
    over all of them: ``{"precision", "recall", "f1", "tp", "n_det", "n_gt", "images", "threshold"}`` (None without
    held-out images). COCO images run at ``network seed size / images_seed_px`` (the scale the trained network
    stores), or, without it, at the scale estimated on each image; simulated frames at their own size."""
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.config import PHOTO_DEFAULTS, CnnConfig, min_visible_seed_px
    from seedmap.eval.detect_metrics import frame_metrics, match_boxes, prf

    if not heldout:
        return None
    tp = nd = ng = n_img = 0
    thr = None
    for h in heldout:
        coco = h.coco is not None
        # COCO images run as `seedmap detect` runs photos (PHOTO_DEFAULTS: the whole image in one pass)
        cfg = CnnConfig(refiner="none", threads=threads, seed_px=images_seed_px if coco else None,
                        tile=PHOTO_DEFAULTS["cnn"]["tile"] if coco else CnnConfig().tile)
        det = CnnDetector(cfg, weights)
        thr = det.threshold
        items = _coco_items(h.coco, h.indices) if coco else _sim_items(h.dataset, h.indices)
        for img, boxes, inst in items:
            if coco and images_seed_px is None:
                det.reset_scale()  # photos of several seed sizes: each one's own estimate, as seedmap detect does
            d = det.detect(img)
            n_img += 1
            if inst is None:
                md, _, _ = match_boxes(d.boxes, boxes, 0.5, "greedy")
                tp, nd, ng = tp + len(md), nd + len(d), ng + len(boxes)
            else:
                m, _ = frame_metrics(d, inst, iou_threshold=0.5, min_gt_area=min_visible_seed_px(img.shape[1]))
                tp, nd, ng = tp + m.tp, nd + m.n_det, ng + m.n_gt
    p, r, f = prf(tp, nd, ng)
    return {"precision": p, "recall": r, "f1": f, "tp": tp, "n_det": nd, "n_gt": ng, "images": n_img,
            "threshold": thr}


def network_seed_px(weights: str | Path | None, default: float) -> float:
    """The seed size (px) a fast_cnn ONNX file says its network expects in its input (``info["seed_px"]``), else
    ``default`` (the shipped networks' training size)."""
    from seedmap.detect.runtime import network_info

    if weights is None:
        return float(default)
    from seedmap.detect.config import TRAINED_SEED_PX

    if Path(weights).name == "fast_cnn_arm.onnx":  # the shipped arm network (no seed_px recorded)
        default = TRAINED_SEED_PX["arm"]
    info = network_info(weights)
    v = info.get("seed_px")
    return float(v) if isinstance(v, (int, float)) and v > 0 else float(default)


@dataclass
class TrainPlan:
    """Which images of each training source train and which are held out, and the COCO labels' scale."""

    #: ``{str(source): image indices / frames}`` that train (None = all of every source)
    train: dict | None
    #: the same for the held-out images (None = the ``--val`` sources, all of them)
    val: dict | None
    heldout: list[HeldOut]
    #: the labels' typical seed size in the user's images (px; None without COCO labels)
    images_seed_px: float | None
    #: COCO images are resized by this factor (network seed size / images_seed_px) ...
    scale: float
    #: ... or, an image with at least PER_IMAGE_MIN_SEEDS labels, by network seed size / its own median seed size:
    #: ``{(str(source), image index): factor}`` (photos of seeds at several sizes all train at the network's size)
    image_scales: dict | None = None
    #: the labelled images show seeds of one size (per-image medians within SIZE_SPREAD): the trained network
    #: records images_seed_px and runs at that fixed scale; else it estimates every image's scale (cnn.scale=auto)
    fixed_scale: bool = True


#: largest ratio between the per-image median seed sizes of labels that still count as one seed size
SIZE_SPREAD = 1.5
#: labelled seeds an image needs to be resized by its own median seed size (fewer: the median of all labels)
PER_IMAGE_MIN_SEEDS = 5


def plan_training(train_sets: list, val_sets: list | None, images_root, val_fraction: float, seed: int,
                  net_seed_px: float) -> TrainPlan:
    """The split (without ``val_sets``: the last frame of a simulated dataset, a seeded ``val_fraction`` of a COCO
    file's labelled images, :func:`split_coco`) and the scale that brings the COCO labels' median seed size to
    ``net_seed_px`` (per image where it has enough labels: :class:`TrainPlan`). Reads the label files only."""
    from seedmap.detect.cnn_targets import is_coco_file
    from seedmap.detect.labels import CocoSource
    from seedmap.io.seedmap_dataset import SeedmapDataset

    tr: dict = {}
    va: dict = {}
    heldout: list[HeldOut] = []
    sides = []
    per_image: dict = {}
    for d in train_sets:
        if is_coco_file(d):
            src = CocoSource(d, images_root)
            lab = src.labelled_indices()
            if val_sets:
                tr[str(d)] = list(range(len(src)))
            else:
                unl = sorted(set(range(len(src))) - set(lab))
                tr[str(d)], va[str(d)] = split_coco(lab, unl, val_fraction, seed, Path(d))
                heldout.append(HeldOut(coco=src, indices=tuple(va[str(d)])))
            sides.append(src.seed_sides(tr[str(d)]))
            for k in set(tr[str(d)]) | set(va.get(str(d), [])):
                own = src.seed_sides([k])
                if len(own) >= PER_IMAGE_MIN_SEEDS:
                    per_image[(str(d), k)] = float(np.median(own))
        else:
            n = len(SeedmapDataset(d))
            if val_sets:
                tr[str(d)] = list(range(n))
                continue
            if n < 2:
                raise InputError("needs at least 2 frames for a held-out split (or pass --val)", d)
            tr[str(d)], va[str(d)] = list(range(n - 1)), [n - 1]
            heldout.append(HeldOut(dataset=Path(d), indices=(n - 1,)))
    val_sizes: dict = {}
    for d in val_sets or []:
        if is_coco_file(d):
            src = CocoSource(d, images_root)
            heldout.append(HeldOut(coco=src, indices=tuple(range(len(src)))))
            for k in range(len(src)):  # held-out photos at their own seed size too, as the training photos
                own = src.seed_sides([k])
                if len(own) >= PER_IMAGE_MIN_SEEDS:
                    val_sizes[(str(d), k)] = float(np.median(own))
        else:
            heldout.append(HeldOut(dataset=Path(d), indices=tuple(range(len(SeedmapDataset(d))))))
    allsides = np.concatenate(sides) if sides else np.zeros(0)
    images_seed_px = float(np.median(allsides)) if len(allsides) else None
    scale = 1.0
    if images_seed_px is not None:
        scale = float(net_seed_px) / images_seed_px
        if scale > 4.0:
            coco = next(d for d in train_sets if is_coco_file(d))
            raise InputError(f"the labelled seeds are {images_seed_px:.2g} px (median box side); the network needs "
                             f"seeds of at least {net_seed_px / 4.0:g} px (it would enlarge the images "
                             f"{scale:.1f}x, at most 4x)", coco)
    scales = {key: float(net_seed_px) / v for key, v in {**val_sizes, **per_image}.items()}
    for (d, k), f in scales.items():
        if f > 4.0:
            raise InputError(f"image {k}: its labelled seeds are {net_seed_px / f:.2g} px (median box side); the "
                             f"network needs seeds of at least {net_seed_px / 4.0:g} px", d)
    sizes = list(per_image.values())
    fixed = not sizes or max(sizes) <= SIZE_SPREAD * min(sizes)
    return TrainPlan(tr, None if val_sets else va, heldout, images_seed_px, scale, scales, fixed)


#: held-out COCO images (each with at least PER_IMAGE_MIN_SEEDS labels) the seed-size calibration needs
CALIBRATION_MIN_IMAGES = 5


def calibrate_seed_px(weights: str | Path, heldout: list[HeldOut], threads: int = 1) -> dict | None:
    """The seed size (px) a ``score``-cue network should declare so that its seed-size estimates centre on labelled
    sizes: its recorded ``seed_px`` x the median over the held-out COCO images of (their labels' median box side /
    the network's estimate). The input scale the network runs at (its ``score_size`` over the scale where its
    scores peak) does not depend on it. Only images with at least PER_IMAGE_MIN_SEEDS labels count; with fewer
    than CALIBRATION_MIN_IMAGES of them: None. Returns ``{"seed_px", "images", "median_ratio_before"}``."""
    from seedmap.detect.autoscale import estimate_seed_px
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.config import PHOTO_DEFAULTS, CnnConfig

    # as `seedmap detect` runs photos (PHOTO_DEFAULTS: the whole image in one pass)
    det = CnnDetector(CnnConfig(refiner="none", threads=threads, tile=PHOTO_DEFAULTS["cnn"]["tile"]), weights)
    ratios = []
    for h in heldout:
        for k in h.indices if h.coco is not None else ():
            own = h.coco.seed_sides([k])  # the measure plan_training sizes images by; no image read below the minimum
            if len(own) < PER_IMAGE_MIN_SEEDS:
                continue
            est = estimate_seed_px(det.peaks, h.coco[k].image, det.trained_seed_px, det.scale_cue,
                                   det.score_size).seed_px
            if est:
                ratios.append(float(np.median(own)) / est)
    if len(ratios) < CALIBRATION_MIN_IMAGES:
        return None
    r = float(np.median(ratios))
    return {"seed_px": round(det.trained_seed_px * r, 3), "images": len(ratios), "median_ratio_before": round(1 / r, 4)}


def heldout_report(weights: Path, init: str | Path | None, plan: TrainPlan, threads: int = 1,
                   progress: bool = False) -> dict:
    """The held-out F1 of the trained network ``weights`` and of the network it started from (``init``; None = a
    random start, no F1 before) on ``plan``'s held-out images, as the ``val_*`` keys of train_metrics.json."""
    from seedmap.progress import track

    out: dict = {}
    runs = [("", weights)] + ([("_before", init)] if init else [])
    for suffix, w in track(runs, "held-out F1", "network", enabled=progress):
        r = heldout_f1(w, plan.heldout, plan.images_seed_px if plan.fixed_scale else None, threads)
        if r is None:
            continue
        out.update({f"val_f1{suffix}": r["f1"], f"val_precision{suffix}": r["precision"],
                    f"val_recall{suffix}": r["recall"], f"val_counts{suffix}": {k: r[k] for k in
                                                                               ("tp", "n_det", "n_gt", "images")}})
        out.setdefault("val_threshold", r["threshold"])
    return out
