"""Session-10 (issue #3) evaluation of ``fast`` CNN candidates: held-out box F1 per range and pooled, plus the
validation F1 and the CPU ratio that chose them, in one JSON (benchmarks/results/detect_heldout_s10.json).

Why one script: the adoption rule compares the pooled held-out F1 (IoU >= 0.5, GT >= the detectable-seed size,
greedy one-to-one, as ``seedmap eval detect``) of a frozen candidate with the shipped network's, measured in the
same run with the same code, and needs the CPU ratio of the two measured in one bench run. Pooled = the sums of
true positives, detections and counted GT over the ranges (not a mean of per-range F1s).

    .venv/bin/python benchmarks/detect_heldout_s10.py --network shipped=seedmap/detect/weights/fast_cnn.onnx \\
        --network fast_cnn_s10=seedmap/detect/weights/fast_cnn_s10.onnx \\
        [--dataset data/det_s2 ...]  (default: det_s2, s21, s2_new, s22, s23, s24; pooled_5 = the first five)
        [--thresholds 0.45,0.5] [--validation NAME=val.json ...] [--bench bench.json] [--out FILE]

``--validation`` copies the per-dataset F1 of ``benchmarks/detect_errors.py --out`` files (the numbers the
candidate was chosen on); ``--bench`` reads ``benchmarks/bench_detect.py --cnn-weights ... --out`` and reports each
network's CPU ms per image (one thread, gated tiles and whole image, timed round-robin with ``--interleave``) and
its ratio to the shipped one.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HELDOUT = ["data/det_s2", "data/det_s21", "data/det_s2_new", "data/det_s22", "data/det_s23", "data/det_s24"]


def pooled(per_range: dict, names: list[str]) -> dict:
    """Precision / recall / F1 from the summed counts of ``names`` (keys of ``per_range``)."""
    tp = sum(per_range[n]["tp"] for n in names)
    nd = sum(per_range[n]["n_det"] for n in names)
    ng = sum(per_range[n]["n_gt"] for n in names)
    p, r = tp / max(nd, 1), tp / max(ng, 1)
    return {"precision": p, "recall": r, "f1": 2 * p * r / max(p + r, 1e-12), "tp": tp, "n_det": nd, "n_gt": ng}


def evaluate_network(weights: str, datasets: list[str], thresholds: list[float]) -> dict:
    """Per-range and pooled metrics of one network at every threshold (the network runs once per image)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from detect_errors import detect_all

    from seedmap.detect.config import min_visible_seed_px
    from seedmap.eval.detect_metrics import evaluate_detections
    from seedmap.io.seedmap_dataset import SeedmapDataset

    out = {str(t): {"per_range": {}} for t in thresholds}
    cpu = {}
    for d in datasets:
        ds = SeedmapDataset(d)
        mga = min_visible_seed_px(ds.calib.width)
        # the networks alone, as in session 10 (the session-12 refiner belongs to the shipped network only)
        dets, cpu[Path(d).name] = detect_all(d, weights, min(thresholds), ["cnn.refiner=none"])
        for t in thresholds:
            dt = {k: v.subset(v.scores >= t) for k, v in dets.items()}
            m = evaluate_detections(ds, dt, 0.5, "greedy", mga)
            out[str(t)]["per_range"][Path(d).name] = {
                "precision": m.precision, "recall": m.recall, "f1": m.f1, "kp_median_px": m.kp_err_median_px,
                "kp_p90_px": m.kp_err_p90_px, "n_det": m.n_det, "n_gt": m.n_gt, "tp": m.tp}
            print(f"{weights} {d} t={t:.2f}: P {m.precision:.4f} R {m.recall:.4f} F1 {m.f1:.4f} "
                  f"kp med {m.kp_err_median_px:.3f} px", flush=True)
    names = [Path(d).name for d in datasets]
    for t in thresholds:
        pr = out[str(t)]["per_range"]
        out[str(t)]["pooled_all"] = pooled(pr, names)
        if len(names) == 6 and names == [Path(d).name for d in HELDOUT]:
            out[str(t)]["pooled_5"] = pooled(pr, names[:5])
    out["cpu_s_detect"] = cpu
    return out


def bench_ratios(path: str) -> dict:
    """CPU ms per 1434x1050 image (1 onnxruntime thread) of each network timed in one ``bench_detect.py
    --interleave N --cnn-weights ...`` run, and its ratio to the shipped network (keyed as bench_detect names them:
    ``shipped`` or the --cnn-weights path)."""
    d = json.loads(Path(path).read_text())
    if not d.get("interleaved"):
        raise SystemExit(f"{path}: no interleaved timings (run bench_detect.py with --interleave N)")
    return {"file": path, "rounds": d["interleaved"]["rounds"], "load_avg_1m": d.get("load_avg_1m"),
            **d["interleaved"]["networks"]}


def validation_f1(path: str) -> dict:
    d = json.loads(Path(path).read_text())
    return {k: {t: round(v["f1"], 4) for t, v in r["by_threshold"].items()} for k, r in d["datasets"].items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--network", action="append", required=True, help="NAME=ONNX path (the first is the reference)")
    ap.add_argument("--dataset", action="append", default=None)
    ap.add_argument("--thresholds", default="0.45,0.5")
    ap.add_argument("--validation", action="append", default=[], help="NAME=detect_errors JSON")
    ap.add_argument("--bench", default=None, help="bench_detect.py JSON with every network's --cnn-weights")
    ap.add_argument("--note", default="")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "detect_heldout_s10.json"))
    a = ap.parse_args()
    nets = dict(n.split("=", 1) for n in a.network)
    ths = sorted(float(t) for t in a.thresholds.split(","))
    datasets = a.dataset or HELDOUT
    t0 = time.process_time()
    res = {"what": "session 10 (issue #3): fast-CNN candidates; default eval (IoU >= 0.5, greedy, GT >= detectable "
                   "size 10 px at 1434 px); pooled = summed counts", "note": a.note, "networks": nets,
           "datasets": datasets, "command": " ".join(sys.argv), "heldout": {}}
    for name, w in nets.items():
        res["heldout"][name] = evaluate_network(w, datasets, ths)
    ref = next(iter(nets))
    res["pooled_f1_gain_vs_" + ref] = {
        name: {t: {k: r[t][k]["f1"] - res["heldout"][ref][t][k]["f1"] for k in ("pooled_all", "pooled_5")
                   if k in r[t]} for t in map(str, ths)}
        for name, r in res["heldout"].items() if name != ref}
    if a.validation:
        res["validation_f1"] = {}
        for v in a.validation:
            name, path = v.split("=", 1)
            res["validation_f1"][name] = validation_f1(path)
    if a.bench:
        res["cpu"] = bench_ratios(a.bench)
    res["cpu_s_this_script"] = time.process_time() - t0
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(Path(a.out), json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
