"""Panicle reconstruction speed: seconds per view of SGBM, full-cloud ICP and seed-centre ICP,
measured in one run on one simulated arm scan; ICP costs are also given as ratios to SGBM.

Writes JSON (``--out``, default ``benchmarks/results/bench_recon.json``).
Usage: ``python benchmarks/bench_recon.py [--dataset DIR | --views N --seed S]`` -- without
``--dataset`` a scan is simulated into a temporary folder first (not timed).
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", type=Path, default=None, help="existing arm scan dataset")
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results") / "bench_recon.json")
    args = ap.parse_args()

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
