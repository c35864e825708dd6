"""Where the ``fast`` CNN's detection errors are: false positives and misses in buckets, plus a threshold sweep.

Why: choosing training changes needs to know which errors dominate. The buckets follow the default
``seedmap eval detect`` rule (box IoU >= 0.5, greedy one-to-one, GT below the detectable-seed size ignored,
a detection matched to an ignored GT counts neither way); each unmatched detection is filed by the GT
instance under its keypoint pixel (GT label image):

* ``sliver``: under a GT sliver below the detectable size (its box missed IoU 0.5 with it);
* ``duplicate``: under a counted GT that another detection already matched;
* ``poor_box``: under a counted GT that no detection matched (right seed, box IoU < 0.5);
* ``background``: on no GT pixel and IoU < 0.1 with every GT box;
* ``near``: on no GT pixel but overlapping some GT box (IoU >= 0.1).

Misses (counted GT left unmatched) by visible area (10-15, 15-25, >= 25 px) and whether the seed's centre is
visible. The network runs once per image at the lowest threshold of ``--thresholds``; a higher threshold is
the same detections filtered by score (a peak does not depend on the threshold), so a sweep costs one run.

    .venv/bin/python benchmarks/bench_detect_accuracy.py --dataset data/det_s36 [--weights W.onnx]
        [--thresholds 0.35,0.4,0.45,0.5,0.55] [--out results/x.json]

The shipped network runs with its refiner (``cnn.refiner=auto``; the sweep is then over the refined score);
``--set cnn.refiner=none`` measures the network alone. Prints one line per threshold (P / R / F1 / keypoint
median) and the buckets at ``--bucket-threshold``
(default 0.45, the shipped one); writes everything as JSON with ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from seedmap.progress import track



def detect_all(dataset: str | Path, weights: str | None, threshold: float, overrides: list[str] | None = None,
               progress: bool = True) -> tuple[dict, float]:
    """``{(frame, cam): Detections}`` of the ``fast`` CNN on every image of ``dataset`` and the CPU seconds."""
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.config import resolve_config
    from seedmap.io.seedmap_dataset import SeedmapDataset

    # the lowest threshold of the sweep: the network's own, or the refined score's when a refiner runs
    cfg = resolve_config(None, [f"cnn.threshold={threshold}", f"cnn.refine_threshold={threshold}", *(overrides or [])])
    det = CnnDetector(cfg.cnn, weights=weights)
    ds = SeedmapDataset(dataset)
    out = {}
    it = track(range(len(ds)), f"detect {Path(dataset).name}", "frame", enabled=progress)
    t0 = time.process_time()
    for i in it:
        fr = ds[i]
        out[(i, "left")] = det.detect(fr.left)
        out[(i, "right")] = det.detect(fr.right)
    return out, time.process_time() - t0


def error_buckets(ds, dets: dict, min_gt_area: float, iou: float = 0.5) -> dict:  # noqa: ANN001 - SeedmapDataset
    """Counts of the false-positive and miss buckets (module docstring) over all images in ``dets``."""
    from seedmap.eval.detect_metrics import box_iou_pairs, match_boxes

    fp = {"sliver": 0, "duplicate": 0, "poor_box": 0, "background": 0, "near": 0}
    sliver_ratio, sliver_iou, poor_iou = [], [], []
    bins = [(10, 15), (15, 25), (25, 1e9)]
    miss = {f"{a}-{b if b < 1e9 else 'inf'}px_{v}": 0 for a, b in bins for v in ("center_visible", "center_hidden")}
    tot = dict.fromkeys(miss, 0)
    n_ignored_match = 0
    for (frame, cam), d in dets.items():
        gt = ds.gt_instances(frame, cam)
        lab = ds.gt_label_image(frame, cam).astype(np.int64)
        lut = np.full(int(max(lab.max(), gt.label.max(initial=0))) + 1, -1, np.int64)
        lut[gt.label.astype(np.int64)] = np.arange(len(gt))
        counted = gt.area >= min_gt_area
        md, mg, _ = match_boxes(d.boxes, gt.boxes, iou, "greedy")
        n_ignored_match += int((~counted[mg]).sum())
        gt_matched = np.zeros(len(gt), bool)
        gt_matched[mg[counted[mg]]] = True
        unmatched = np.setdiff1d(np.arange(len(d)), md)
        h, w = lab.shape
        kp = d.keypoints
        for k in unmatched:
            x = int(np.clip(np.round(kp[k, 0]), 0, w - 1))
            y = int(np.clip(np.round(kp[k, 1]), 0, h - 1))
            g = int(lut[lab[y, x]]) if lab[y, x] > 0 else -1
            if g >= 0 and not counted[g]:
                fp["sliver"] += 1
                ga = (gt.boxes[g, 2] - gt.boxes[g, 0]) * (gt.boxes[g, 3] - gt.boxes[g, 1])
                da = (d.boxes[k, 2] - d.boxes[k, 0]) * (d.boxes[k, 3] - d.boxes[k, 1])
                sliver_ratio.append(da / max(ga, 1.0))
                sliver_iou.append(float(box_iou_pairs(d.boxes, gt.boxes, np.array([k]), np.array([g]))[0]))
            elif g >= 0 and gt_matched[g]:
                fp["duplicate"] += 1
            elif g >= 0:
                fp["poor_box"] += 1
                poor_iou.append(float(box_iou_pairs(d.boxes, gt.boxes, np.array([k]), np.array([g]))[0]))
            else:
                best = box_iou_pairs(d.boxes, gt.boxes, np.full(len(gt), k), np.arange(len(gt))).max(initial=0.0)
                fp["background" if best < 0.1 else "near"] += 1
        for g in np.flatnonzero(counted):
            a = gt.area[g]
            for lo, hi in bins:
                if lo <= a < hi:
                    key = f"{lo}-{hi if hi < 1e9 else 'inf'}px_{'center_visible' if gt.center_visible[g] else 'center_hidden'}"
                    tot[key] += 1
                    miss[key] += int(not gt_matched[g])
    q = (lambda a: {"median": float(np.median(a)), "p25": float(np.percentile(a, 25)),
                    "p75": float(np.percentile(a, 75))} if len(a) else None)
    return {"false_positives": fp, "false_positives_total": int(sum(fp.values())),
            "detections_on_ignored_gt": n_ignored_match,
            "sliver_fp_box_area_ratio": q(sliver_ratio), "sliver_fp_iou": q(sliver_iou), "poor_box_iou": q(poor_iou),
            "misses": miss, "gt_counted": tot,
            "miss_rate": {k: (miss[k] / tot[k] if tot[k] else None) for k in miss}}


def main() -> None:
    from seedmap.detect.config import min_visible_seed_px
    from seedmap.eval.detect_metrics import evaluate_detections
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", action="append", required=True, help="simulated dataset(s) with GT")
    ap.add_argument("--weights", default=None, help="fast_cnn ONNX (default: the shipped field network)")
    ap.add_argument("--thresholds", default="0.35,0.4,0.45,0.5,0.55")
    ap.add_argument("--bucket-threshold", type=float, default=0.45)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="detector config key=value")
    ap.add_argument("--no-buckets", action="store_true")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    ths = sorted(float(t) for t in a.thresholds.split(","))
    res = {"weights": a.weights or "shipped", "thresholds": ths, "datasets": {}}
    for dname in a.dataset:
        ds = SeedmapDataset(dname)
        mga = min_visible_seed_px(ds.calib.width)
        dets, cpu = detect_all(dname, a.weights, min(ths + [a.bucket_threshold]), a.overrides)
        r = {"cpu_s_detect": cpu, "images": len(dets), "min_gt_area_px": mga, "by_threshold": {}}
        for t in ths:
            dt = {k: v.subset(v.scores >= t) for k, v in dets.items()}
            m = evaluate_detections(ds, dt, 0.5, "greedy", mga)
            r["by_threshold"][str(t)] = {"precision": m.precision, "recall": m.recall, "f1": m.f1,
                                         "kp_median_px": m.kp_err_median_px, "kp_p90_px": m.kp_err_p90_px,
                                         "n_det": m.n_det, "n_gt": m.n_gt, "tp": m.tp}
            print(f"{dname} t={t:.2f}: P {m.precision:.4f} R {m.recall:.4f} F1 {m.f1:.4f} "
                  f"kp med {m.kp_err_median_px:.3f} px (det {m.n_det}, gt {m.n_gt}, tp {m.tp})")
        if not a.no_buckets:
            dt = {k: v.subset(v.scores >= a.bucket_threshold) for k, v in dets.items()}
            r["buckets"] = error_buckets(ds, dt, mga)
            print(json.dumps(r["buckets"], indent=1))
        res["datasets"][dname] = r
    if a.out:
        from seedmap.io.atomic import atomic_write_text

        atomic_write_text(Path(a.out), json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
