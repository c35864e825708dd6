"""Speed and memory of the simulator at the default resolution, on a short and a long range.

For each range length (default 1.5 m and 5.0 m, the paper's longest ranges are ~5 m) it builds the
world, renders one warm-up pair (builds the first panicle BVHs) and then ``--frames`` consecutive
pairs from the middle of the range, and reports CPU and wall seconds per stereo pair
(``render_stereo``), the same for pairs at the start of the range, the PNG encoding CPU a written
pair adds (both images and label masks) and the CPU of the whole per-frame write path of
``simulate_range`` (PNGs, instance tables, atomic writes), world build time and peak memory. The render cost should not depend on the
range length (only the geometry near the camera is traced): ``ratio_long_vs_short`` ~ 1.

Baseline measured in the same run, so numbers from loaded machines compare: one bare Open3D
``cast_rays`` of a full image against the frame's env BVH (stalks + leaves near the camera);
``ratio_cpu_pair_vs_bare_cast`` is render CPU per pair over that cast's CPU.

    .venv/bin/python benchmarks/bench_sim.py [--frames 4] [--lengths 1.5 5.0] [--scale 0.35]

Writes benchmarks/results/bench_sim.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import time
from pathlib import Path

import numpy as np


def _bench_range(length: float, seed: int, scale: float, n: int) -> dict:
    from seedmap.sim import SimConfig, build_range_world, render_stereo
    from seedmap.sim.config import FLASH_OFFSET
    from seedmap.sim.range import _rngs, n_frames, range_trajectory
    from seedmap.sim.render import right_pose
    from seedmap.sim.render.rays import _camera_dirs, _rays_tensor, _xf
    from seedmap.sim.render.scene import _FrameScene

    cfg = SimConfig(seed=seed, world={"length": length}, camera={"scale": scale})
    calib = cfg.camera.calib()
    rw, rt, fseeds = _rngs(cfg)
    t0, c0 = time.perf_counter(), time.process_time()
    world = build_range_world(cfg, rw)
    t_world, c_world = time.perf_counter() - t0, time.process_time() - c0
    traj = range_trajectory(cfg, rt)
    frame_ss = fseeds.spawn(len(traj))
    from seedmap.io.images import encode_png

    mid = len(traj) // 2
    frames = list(range(max(0, mid - 1), min(len(traj), mid + n)))
    wall, cpu = [], []

    def render(i: int):
        return render_stereo(world, traj.poses[i], calib, cfg, np.random.default_rng(frame_ss[i]),
                             float(traj.timestamps[i]))

    for k, i in enumerate(frames):
        t0, c0 = time.perf_counter(), time.process_time()
        r = render(i)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if k == 0:
            first = (dt, dc)
        else:
            wall.append(dt)
            cpu.append(dc)
    # what the dataset writer adds per pair: PNG encoding of both images and both label masks
    c0 = time.process_time()
    for img in (r.left, r.right, r.left_labels, r.right_labels):
        encode_png(img)
    png_cpu = time.process_time() - c0
    # ... and the whole per-frame write path of ``simulate_range`` (PNGs, label masks, instance tables,
    # atomic file writes) into a scratch folder
    import tempfile

    from seedmap.io.seedmap_dataset import DatasetWriter

    with tempfile.TemporaryDirectory() as tmp:
        w = DatasetWriter(Path(tmp))
        c0 = time.process_time()
        w.write_frame(i, r.left, r.right)
        w.write_gt_instances(i, "left", r.left_labels, r.left_instances)
        w.write_gt_instances(i, "right", r.right_labels, r.right_instances)
        write_cpu = time.process_time() - c0
    # frames at the start of the range (panicles entering the view; BVHs of the first panicles built
    # by the first of them, which is not counted)
    start = list(range(0, min(len(traj), n + 1)))
    start_cpu = []
    for k, i in enumerate(start):
        c0 = time.process_time()
        render(i)
        if k:
            start_cpu.append(time.process_time() - c0)
    # baseline: one bare cast of a full image against the frame's env BVH
    i = frames[-1]
    T = traj.poses[i]
    light = T[:3, :3] @ np.asarray(FLASH_OFFSET) + T[:3, 3]
    fs = _FrameScene(world, float(traj.timestamps[i]), [T, right_pose(T, calib.baseline)], calib, light)
    dcam, _ = _camera_dirs(world, calib)
    rays = _rays_tensor(T[:3, 3].astype(np.float32)[None], _xf(dcam, T[:3, :3]))
    bare_cpu = float("nan")
    if fs.env is not None:
        fs.env.cast_rays(rays)  # builds the BVH
        bc = []
        for _ in range(3):
            c0 = time.process_time()
            fs.env.cast_rays(rays)
            bc.append(time.process_time() - c0)
        bare_cpu = float(np.median(bc))
    per_cpu = float(np.median(cpu)) if cpu else first[1]
    per_wall = float(np.median(wall)) if wall else first[0]
    return {
        "range_length_m": length,
        "seed": seed,
        "frames_in_range": n_frames(cfg),
        "frames_measured": frames[1:],
        "seeds_in_world": int(len(world.seeds)),
        "panicles_in_world": len(world.panicles),
        "world_build_s": round(t_world, 2),
        "world_build_cpu_s": round(c_world, 2),
        "first_pair_cpu_s": round(first[1], 3),
        "cpu_s_per_pair_median": round(per_cpu, 3),
        "cpu_s_per_pair_all": [round(c, 3) for c in cpu],
        "start_frames_measured": start[1:],
        "start_cpu_s_per_pair_median": round(float(np.median(start_cpu)), 3) if start_cpu else None,
        "start_cpu_s_per_pair_all": [round(c, 3) for c in start_cpu],
        "png_encode_cpu_s_per_pair": round(png_cpu, 3),
        "cpu_s_per_pair_with_png": round(per_cpu + png_cpu, 3),
        "write_cpu_s_per_pair": round(write_cpu, 3),
        "cpu_s_per_pair_rendered_and_written": round(per_cpu + write_cpu, 3),
        "wall_s_per_pair_median": round(per_wall, 3),
        "bare_env_cast_cpu_s_one_image": round(bare_cpu, 4),
        "ratio_cpu_pair_vs_bare_cast": round(per_cpu / bare_cpu, 2) if bare_cpu > 0 else None,
        "estimated_full_range_cpu_s": round(c_world + per_cpu * n_frames(cfg), 1),
        "peak_rss_mb_so_far": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4, help="measured pairs per range (after one warm-up pair)")
    ap.add_argument("--lengths", type=float, nargs="+", default=[1.5, 5.0], help="range lengths (m), short first")
    ap.add_argument("--scale", type=float, default=0.35)
    ap.add_argument("--seed", type=int, default=102, help="world seed (102 = preset paper2)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_sim.json")
    args = ap.parse_args()

    import open3d as o3d

    from seedmap.io.atomic import atomic_write_text

    la0 = os.getloadavg()[0]
    runs = [_bench_range(length, args.seed, args.scale, args.frames) for length in args.lengths]
    from seedmap.sim import SimConfig

    calib = SimConfig(camera={"scale": args.scale}).camera.calib()
    result = {
        "what": "CPU/wall seconds per stereo pair of render_stereo at the default resolution, short vs long range",
        "image_size": [calib.width, calib.height],
        "scale": args.scale,
        "ranges": runs,
        "ratio_long_vs_short_cpu": round(runs[-1]["cpu_s_per_pair_median"] / runs[0]["cpu_s_per_pair_median"], 2),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "cpu_count": os.cpu_count(),
        "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "loadavg_1min_start_end": [round(la0, 2), round(os.getloadavg()[0], 2)],
        "machine": platform.machine(),
        "python": platform.python_version(),
        "open3d": o3d.__version__,
    }
    atomic_write_text(args.out, json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
