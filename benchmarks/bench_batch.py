"""Field batch speed-up: wall time of ``run_batch`` with N workers relative to 1 worker, same tiny field.

The field is ``--ranges`` copies of one tiny simulated range (rendered once), so every worker does the
same work; the 1-worker run is the baseline measured in the same process, and the result is the ratio
``speedup = wall(1 worker) / wall(N workers)`` (ideal: min(N, ranges, cores)). Process start-up (spawn,
importing GTSAM) is part of the measured cost, as it is for a user.

Writes JSON (``--out``, default ``benchmarks/results/bench_batch.json``).
Usage: ``python benchmarks/bench_batch.py [--ranges 4] [--workers 2] [--frames 4]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

TINY = ["world.length=0.3", "world.gap=0.3", "camera.scale=0.15", "imaging.supersample=1"]


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its finished children (the pool's workers)."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ranges", type=int, default=4, help="ranges in the field (copies of one)")
    ap.add_argument("--workers", type=int, default=2, help="parallel workers compared with 1")
    ap.add_argument("--frames", type=int, default=4, help="SLAM frames per range (max_frames)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_batch.json")
    args = ap.parse_args()

    from seedmap.batch import run_batch
    from seedmap.config import load_config
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig
    from seedmap.slam.config import SlamConfig

    with tempfile.TemporaryDirectory(prefix="bench_batch_") as td:
        td = Path(td)
        t0 = time.perf_counter()
        src = simulate_range(load_config(SimConfig, None, [*TINY, "seed=7"]), td / "src", progress=False)
        t_sim = time.perf_counter() - t0
        field = td / "field"
        for k in range(args.ranges):
            shutil.copytree(src, field / f"range{k}")
        cfg = load_config(SlamConfig, None, [f"max_frames={args.frames}"])
        walls: dict[int, float] = {}
        mdm: dict[int, list] = {}
        cpus: dict[int, float] = {}
        for w in (1, args.workers):
            c0 = _cpu_s()
            t0 = time.perf_counter()
            s = run_batch(field, td / f"out{w}", config=cfg, workers=w, progress=False)
            walls[w] = time.perf_counter() - t0
            cpus[w] = _cpu_s() - c0
            if s.n_failed:
                raise SystemExit(f"{s.n_failed} ranges failed: {[r.error for r in s.ranges if r.error]}")
            mdm[w] = [r.mdm_m for r in s.ranges]
    res = {
        "benchmark": "batch",
        "ranges": args.ranges,
        "frames_per_range": args.frames,
        "workers": args.workers,
        "wall_s_1_worker": round(walls[1], 3),
        f"wall_s_{args.workers}_workers": round(walls[args.workers], 3),
        "speedup": round(walls[1] / walls[args.workers], 3),
        "same_results": mdm[1] == mdm[args.workers],
        # CPU seconds (this process + its workers) / wall seconds = cores actually obtained; on a shared
        # machine a value near 1 for N workers means they were starved, not that the batch is serial
        "cpu_s_1_worker": round(cpus[1], 3),
        f"cpu_s_{args.workers}_workers": round(cpus[args.workers], 3),
        "cores_used_1_worker": round(cpus[1] / walls[1], 2),
        f"cores_used_{args.workers}_workers": round(cpus[args.workers] / walls[args.workers], 2),
        "simulate_s": round(t_sim, 3),
        "cpu_count": os.cpu_count(),
        "load_average_1min_at_end": round(os.getloadavg()[0], 2),  # other work on the machine skews both runs
        "machine": platform.machine(),
        "python": platform.python_version(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
