"""Panicle reconstruction speed: seconds per view of SGBM, full-cloud ICP and seed-centre ICP,
measured in one run on one simulated arm scan; ICP costs are also given as ratios to SGBM.

Writes JSON (``--out``, default ``benchmarks/results/bench_recon.json``).
Usage: ``python benchmarks/bench_recon.py [--dataset DIR | --views N --seed S]`` -- without
``--dataset`` a scan is simulated into a temporary folder first (not timed).

``--eval 100 101 ... 110`` instead runs the accuracy evaluation: simulates the missing scans
(24 views, default errors) into ``data/recon_eval/pSEED``, reconstructs each in the modes fk, full
and seeds, and writes per-panicle JSON and ``summary.json`` into ``results/recon_eval_bench/``. The first
seed is the tuning panicle (it calibrates the naive 2D baseline and is left out of the means).
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np


def run_eval(seeds: list[int], views: int = 24) -> dict:
    """Accuracy of fk / full / seeds registration and of seed counting on simulated scans."""
    from seedmap.eval.recon_metrics import summarize_scan_rows
    from seedmap.recon.config import CountConfig, ReconConfig
    from seedmap.recon.count import count_seeds
    from seedmap.recon.pipeline import gt_metrics, gt_visible_seeds, prepare_scan, reconstruct
    from seedmap.sim.arm import ArmConfig
    from seedmap.sim.panicle_scan import PanicleScanConfig, simulate_panicle

    out = Path("results/recon_eval_bench")
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for s in seeds:
        root = Path(f"data/recon_eval/p{s}")
        if not root.exists():
            simulate_panicle(PanicleScanConfig(seed=s, arm=ArmConfig(views=views)), root, progress=True)
        cfg = ReconConfig()
        prep = prepare_scan(root, cfg, progress=True)
        gt_vis = int(len(gt_visible_seeds(root, 12)))
        row = {"panicle": s, "gt_visible": gt_vis, "sgbm_s_per_view": float(np.mean(prep.seconds_sgbm)),
               "detections": int(sum(v.n_detections for v in prep.views if v is not None)), "modes": {}}
        for mode in ("fk", "full", "seeds"):
            cfg.registration.mode = mode
            t0 = time.perf_counter()
            rec = reconstruct(prep, cfg)
            m = gt_metrics(rec, root, 12)
            m["quality"] = rec.quality
            m["icp_s_per_view"] = float(np.mean(rec.registration.seconds[1:]))
            m["reconstruct_s"] = time.perf_counter() - t0
            for meth in ("density", "tracks"):
                n = count_seeds(rec.obs_xyz, rec.obs_view, rec.obs_diam, CountConfig(method=meth)).count
                m[f"count_{meth}"] = n
                m[f"count_{meth}_ape"] = abs(n - gt_vis) / max(gt_vis, 1) * 100
            row["modes"][mode] = m
        (out / f"p{s}.json").write_text(json.dumps(row, indent=1))
        rows.append(row)
    tune = rows[0]
    views_per_seed = tune["detections"] / max(tune["gt_visible"], 1)
    held = rows[1:]
    summary = summarize_scan_rows(rows, ["fk", "full", "seeds"], (tune["panicle"],))
    for mode in ("fk", "full", "seeds"):
        for meth in ("density", "tracks"):
            summary["modes"][mode][f"count_{meth}_mape"] = float(np.mean([r["modes"][mode][f"count_{meth}_ape"]
                                                                         for r in held]))
    summary["naive_2d"] = {"views_per_seed": views_per_seed, "mape": float(np.mean(
        [abs(r["detections"] / views_per_seed - r["gt_visible"]) / r["gt_visible"] * 100 for r in held]))}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--eval", type=int, nargs="+", default=None, help="accuracy evaluation on these scan seeds")
    ap.add_argument("--dataset", type=Path, default=None, help="existing arm scan dataset")
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results") / "bench_recon.json")
    args = ap.parse_args()
    if args.eval:
        print(json.dumps(run_eval(args.eval), indent=1))
        return

    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import prepare_scan
    from seedmap.recon.register import register_views

    with tempfile.TemporaryDirectory() as tmp:
        root = args.dataset
        if root is None:
            from seedmap.sim.arm import ArmConfig
            from seedmap.sim.panicle_scan import PanicleScanConfig, simulate_panicle

            root = Path(tmp) / "scan"
            simulate_panicle(PanicleScanConfig(seed=args.seed, arm=ArmConfig(views=args.views)), root, progress=True)
        cfg = ReconConfig()
        t0 = time.perf_counter()
        prep = prepare_scan(root, cfg, progress=True)
        prep_s = time.perf_counter() - t0
        geoms = [v.geometry if v is not None else None for v in prep.views]
        res = {}
        for mode in ("full", "seeds"):
            cfg.registration.mode = mode
            t0 = time.perf_counter()
            reg = register_views(geoms, prep.T_fk, cfg.registration)
            res[mode] = {"icp_s_per_view": float(np.mean(reg.seconds[1:])),
                         "register_total_s": time.perf_counter() - t0}
        sgbm = float(np.mean(prep.seconds_sgbm))
        n_views = len(prep.views)
        geo0 = next(g for g in geoms if g is not None)
        out = {
            "dataset": str(args.dataset) if args.dataset else f"simulated seed {args.seed}, {args.views} views",
            "image_size": [prep.calib.width, prep.calib.height],
            "views": n_views,
            "sgbm_s_per_view": sgbm,
            "full_icp_s_per_view": res["full"]["icp_s_per_view"],
            "seed_icp_s_per_view": res["seeds"]["icp_s_per_view"],
            "full_icp_over_sgbm": res["full"]["icp_s_per_view"] / sgbm,
            "seed_icp_over_sgbm": res["seeds"]["icp_s_per_view"] / sgbm,
            "full_over_seed_icp": res["full"]["icp_s_per_view"] / max(res["seeds"]["icp_s_per_view"], 1e-9),
            "points_per_view_full_icp": int(len(geo0.cloud_xyz)),
            "points_per_view_seed_icp": int(len(geo0.seeds_xyz)),
            "prepare_total_s": prep_s,
            "machine": platform.processor() or platform.machine(),
        }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
