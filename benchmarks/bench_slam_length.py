"""SLAM cost along a row: per-frame CPU time and memory against the distance driven (no renderer).

Synthetic seed geometry (seedmap.slam.synthetic: panicles every 0.15 m, 150 seeds each, a frame every 0.04 m)
for each ``--lengths`` row; per frame the association + motion + back-end CPU time of the main thread, and the
process's resident memory. Reported: the mean CPU ms of the first and the last 10 % of the frames (a flat cost
has a ratio of 1; the first tenth includes the ramp-up while the view fills with landmarks) and of every tenth,
the final batch optimisation, the memory growth per metre, and the position RMSE of the online (per-frame) and
the final trajectory. Each row runs with every online back-end (``backend.online``): ``isam2``
(the whole graph), ``fixed_lag`` (the bounded smoother) and ``none`` (motion estimate only, the final batch
still runs), the baseline of the same run, which separates the back-end's growth from the front-end's.

Writes benchmarks/results/bench_slam_length.json. Run: ``python benchmarks/bench_slam_length.py --lengths 5 20 50``
(iSAM2 keeps every pose and landmark, ~60 MB per metre of row here: mind the machine's memory for long rows).
``--online`` picks some of the back-ends.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from seedmap.associate import make_matcher
from seedmap.slam.config import SlamConfig
from seedmap.slam.backends import ONLINE_BACKENDS
from seedmap.slam.core import SemanticSlam
from seedmap.slam.synthetic import make_range, observe

OUT = Path(__file__).parent / "results" / "bench_slam_length.json"


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


def row(length: float, online: str) -> dict:
    """One synthetic row of ``length`` m with the online back-end ``online`` (isam2 | fixed_lag | none)."""
    rng = np.random.default_rng(0)
    rg = make_range(rng, length=length, seeds_per_panicle=150)
    cfg = SlamConfig()
    cfg.backend.online = online
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    cpu, rss, size = [], [], []
    smoother_size = getattr(slam.backend, "size", None)
    rss0 = _rss_mb()
    for i in range(len(rg.gt)):
        d = observe(rg, i, rng)
        t0 = time.thread_time()
        r = slam.register_frame(m.features_from_detections(d))
        cpu.append((time.thread_time() - t0) * 1e3)
        rss.append(_rss_mb())
        if smoother_size is not None:
            size.append(smoother_size())
        if not r.ok:
            break
    online_traj = slam.online_trajectory()
    t0 = time.thread_time()
    traj, _, _ = slam.finalize()
    t_final = time.thread_time() - t0
    k = max(1, len(cpu) // 10)
    err = np.linalg.norm(traj.positions - rg.gt.positions[: len(traj)], axis=1)
    err_on = np.linalg.norm(online_traj.positions - rg.gt.positions[: len(online_traj)], axis=1)
    out = {"length_m": length, "online": online, "frames": len(rg.gt), "frames_tracked": len(cpu),
           "cpu_ms_first_10pct": float(np.mean(cpu[:k])), "cpu_ms_last_10pct": float(np.mean(cpu[-k:])),
           "last_vs_first_ratio": float(np.mean(cpu[-k:]) / np.mean(cpu[:k])),
           "cpu_ms_tenths": [float(np.mean(c)) for c in np.array_split(np.asarray(cpu), 10)],
           "final_batch_cpu_s": t_final, "rss_start_mb": rss0, "rss_end_mb": rss[-1],
           "rss_growth_mb_per_m": (rss[-1] - rss[k - 1]) / (length * (len(cpu) - k) / len(rg.gt)),
           "position_rmse_mm": float(1e3 * np.sqrt(np.mean(err**2))),
           "online_position_rmse_mm": float(1e3 * np.sqrt(np.mean(err_on**2))),
           "smoother_variables_max": max(size) if size else None}
    print(out, flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--lengths", type=float, nargs="+", default=[2.0, 5.0], help="row lengths (m)")
    ap.add_argument("--online", nargs="+", default=["none", "isam2", "fixed_lag"], choices=sorted(ONLINE_BACKENDS),
                    help="online back-ends (backend.online) to run on each row")
    args = ap.parse_args()
    rows = []
    for length in args.lengths:
        for online in args.online:
            # a fresh process per row: memory another row freed would hide this row's growth
            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
                rows.append(pool.submit(row, length, online).result())
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"rows": rows}, indent=2) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
