"""The paper's pipeline at reduced width (``frcnn-pix2pix-lite``) beside ``fast`` on held-out simulated ranges.

For each detector: box precision / recall / F1 (IoU >= 0.5, greedy one-to-one, GT below the detectable size ignored
— the ``seedmap eval detect`` scorer), the keypoint error (ellipse centre to the true seed centre), CPU and wall ms
per image (one thread each, the same images in the same run), pooled over ``--dataset`` and per dataset. For the
learned pipeline also the pix2pix masks' IoU against the GT masks: for every detection matched to a counted GT seed,
its predicted mask and the GT instance's mask in the same box crop (the segmenter's own N x N grid).

The learned detector's score threshold is chosen on ``--val`` (best F1), never on the held-out ranges; ``fast`` runs
with its shipped settings.

    python benchmarks/bench_learned.py --val data/det_s36 --dataset data/det_s2 ... --out benchmarks/results/learned.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from seedmap.progress import track

#: candidate score thresholds of the learned detector (chosen on --val)
THRESHOLDS = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
#: the lowest threshold the learned detector runs at (a higher one filters its detections by score)
RUN_THRESHOLD = min(THRESHOLDS)


def run_fast(ds, frames: list[int]) -> tuple[dict, list[float], list[float]]:  # noqa: ANN001 - SeedmapDataset
    """``{(frame, cam): Detections}`` of the shipped ``fast`` detector, wall and CPU seconds per image."""
    from seedmap.detect import make_detector

    det = make_detector("fast")
    det.detect(ds[frames[0]].left)  # warm-up: the networks are loaded and the kernels compiled before timing
    out, wall, cpu = {}, [], []
    for i in track(frames, f"fast {Path(ds.root).name}", "frame"):
        fr = ds[i]
        for cam, img in (("left", fr.left), ("right", fr.right)):
            w0, c0 = time.perf_counter(), time.process_time()
            out[(i, cam)] = det.detect(img)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
    return out, wall, cpu


def run_learned(ds, frames: list[int], name: str, weights: str | None):  # noqa: ANN001, ANN201
    """Detections of the learned pipeline at RUN_THRESHOLD, timings, and per image the masks of its box crops."""
    from seedmap.detect import make_detector
    from seedmap.detect.learned.crops import CROP_PAD, extract_crops
    from seedmap.detect.learned.pipeline import boxes_to_detections

    det = make_detector(name, weights=weights, overrides=[f"learned.score_threshold={RUN_THRESHOLD}"])
    det.detect(ds[frames[0]].left)  # warm-up
    out, masks, wall, cpu = {}, {}, [], []
    for i in track(frames, f"{name} {Path(ds.root).name}", "frame"):
        fr = ds[i]
        for cam, img in (("left", fr.left), ("right", fr.right)):
            w0, c0 = time.perf_counter(), time.process_time()
            boxes, scores = det.boxes(img)
            crops, _, _ = extract_crops(img, boxes, det.crop_size, CROP_PAD)
            m = det.masks(crops)
            out[(i, cam)] = boxes_to_detections(img, boxes, scores, lambda _c, m=m: m, det.crop_size)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
            masks[(i, cam)] = m
    return out, masks, wall, cpu, det.crop_size


def score(items: list[tuple], min_area: float) -> dict:  # noqa: ANN001
    """Pooled P / R / F1 / keypoint error of ``[(dataset, {(frame, cam): Detections})]``."""
    from seedmap.eval.detect_metrics import aggregate, frame_metrics

    rows, errs = [], []
    for ds, dets in items:
        for (frame, cam), d in sorted(dets.items()):
            m, e = frame_metrics(d, ds.gt_instances(frame, cam), frame, cam, 0.5, "greedy", min_area)
            rows.append(m)
            errs.append(e)
    a = aggregate(rows, errs, 0.5, "greedy")
    return {"precision": a.precision, "recall": a.recall, "f1": a.f1, "kp_median_px": a.kp_err_median_px,
            "kp_p90_px": a.kp_err_p90_px, "n_det": a.n_det, "n_gt": a.n_gt, "tp": a.tp}


def mask_ious(ds, dets: dict, masks: dict, crop_size: int, min_area: float) -> list[float]:  # noqa: ANN001
    """IoU of each matched detection's predicted mask with its GT seed's mask, in the detection's box crop."""
    from seedmap.detect.learned.crops import CROP_PAD, extract_crops
    from seedmap.eval.detect_metrics import match_boxes

    out = []
    for (frame, cam), d in sorted(dets.items()):
        gt = ds.gt_instances(frame, cam)
        md, mg, _ = match_boxes(d.boxes, gt.boxes, 0.5, "greedy")
        ok = gt.area[mg] >= min_area
        md, mg = md[ok], mg[ok]
        if not len(md):
            continue
        img = ds[frame].left if cam == "left" else ds[frame].right
        lab = ds.gt_label_image(frame, cam).astype(np.int32)
        _, _, gm = extract_crops(img, d.boxes[md], crop_size, CROP_PAD, lab, gt.label[mg].astype(np.int64))
        pm = masks[(frame, cam)][md]
        g = gm > 0
        inter = (pm & g).sum(axis=(1, 2))
        union = (pm | g).sum(axis=(1, 2))
        out.extend((inter / np.maximum(union, 1)).tolist())
    return out


def timing(wall: list[float], cpu: list[float]) -> dict:
    return {"wall_ms_median": 1000 * float(np.median(wall)), "cpu_ms_median": 1000 * float(np.median(cpu)),
            "images": len(wall)}


def main() -> None:
    from seedmap.detect.config import min_visible_seed_px
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", action="append", required=True, help="held-out simulated dataset(s) with GT")
    ap.add_argument("--val", required=True, help="simulated dataset that chooses the learned score threshold")
    ap.add_argument("--detector", default="frcnn-pix2pix-lite", help="the learned detector's registry name")
    ap.add_argument("--weights", default=None, help="its weights folder (default: the shipped ones)")
    ap.add_argument("--frames", type=int, default=None, help="the first N frames of each dataset (default: all)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "learned.json"))
    a = ap.parse_args()
    import cv2

    cv2.setNumThreads(1)

    def frames(ds):  # noqa: ANN001, ANN202
        return list(range(len(ds) if a.frames is None else min(a.frames, len(ds))))

    vds = SeedmapDataset(a.val)
    vmin = min_visible_seed_px(vds.calib.width)
    vd, _, _, _, _ = run_learned(vds, frames(vds), a.detector, a.weights)
    sweep = {}
    for t in THRESHOLDS:
        sweep[str(t)] = score([(vds, {k: v.subset(v.scores >= t) for k, v in vd.items()})], vmin)
    best = max(THRESHOLDS, key=lambda t: sweep[str(t)]["f1"])
    print(f"threshold chosen on {a.val}: {best} (F1 {sweep[str(best)]['f1']:.4f})")

    res = {"detector": a.detector, "weights": a.weights or "shipped", "val": a.val, "val_sweep": sweep,
           "threshold": best, "datasets": {}, "pooled": {}}
    pooled = {"fast": [], a.detector: []}
    times = {"fast": ([], []), a.detector: ([], [])}
    ious: list[float] = []
    for dname in a.dataset:
        ds = SeedmapDataset(dname)
        mga = min_visible_seed_px(ds.calib.width)
        fr = frames(ds)
        fd, fw, fc = run_fast(ds, fr)
        ld, lm, lw, lc, n = run_learned(ds, fr, a.detector, a.weights)
        keep = {k: v.scores >= best for k, v in ld.items()}
        ld = {k: v.subset(keep[k]) for k, v in ld.items()}
        lm = {k: v[keep[k]] for k, v in lm.items()}
        di = mask_ious(ds, ld, lm, n, mga)
        ious.extend(di)
        r = {"fast": {**score([(ds, fd)], mga), **timing(fw, fc)},
             a.detector: {**score([(ds, ld)], mga), **timing(lw, lc),
                          "mask_iou_mean": float(np.mean(di)) if di else None,
                          "mask_iou_median": float(np.median(di)) if di else None}}
        res["datasets"][dname] = r
        pooled["fast"].append((ds, fd))
        pooled[a.detector].append((ds, ld))
        for key, (w, c) in (("fast", (fw, fc)), (a.detector, (lw, lc))):
            times[key][0].extend(w)
            times[key][1].extend(c)
        print(f"{dname}: fast F1 {r['fast']['f1']:.4f}, {a.detector} F1 {r[a.detector]['f1']:.4f} "
              f"(mask IoU {r[a.detector]['mask_iou_mean']})")
    for key in pooled:
        res["pooled"][key] = {**score(pooled[key], mga), **timing(*times[key])}
    res["pooled"][a.detector]["mask_iou_mean"] = float(np.mean(ious)) if ious else None
    res["pooled"][a.detector]["mask_iou_median"] = float(np.median(ious)) if ious else None
    res["pooled"]["cpu_ratio"] = (res["pooled"][a.detector]["cpu_ms_median"] / res["pooled"]["fast"]["cpu_ms_median"])
    print(json.dumps(res["pooled"], indent=1))
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from provenance import stamp

    from seedmap.io.atomic import atomic_write_text

    cmd = "python benchmarks/bench_learned.py " + " ".join(
        [f"--val {a.val}"] + [f"--dataset {d}" for d in a.dataset]
        + ([f"--weights {a.weights}"] if a.weights else []) + ([f"--frames {a.frames}"] if a.frames else []))
    atomic_write_text(Path(a.out), json.dumps({**stamp(cmd), **res}, indent=1))


if __name__ == "__main__":
    main()
