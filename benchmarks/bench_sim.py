"""Speed and memory of the simulator at the default resolution.

Measures, in one run: world build time, seconds per stereo pair (render_stereo, after one warm-up
frame that also builds the panicle BVHs), peak memory (ru_maxrss and tracemalloc), and a baseline:
one bare Open3D ``cast_rays`` of a full image against all geometry of the same frame (env + panicles
merged into one scene). Reports the ratio render / bare cast so numbers from loaded machines compare.

    .venv/bin/python benchmarks/bench_sim.py [--frames 4] [--length 4.0] [--scale 0.35]

Writes benchmarks/results/bench_sim.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--length", type=float, default=4.0)
    ap.add_argument("--scale", type=float, default=0.35)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_sim.json")
    args = ap.parse_args()

    import open3d as o3d

    from seedmap.io.atomic import atomic_write_text
    from seedmap.sim import SimConfig, build_range_world, render_stereo
    from seedmap.sim.meshes import ellipsoids
    from seedmap.sim.range import _rngs, n_frames, range_trajectory
    from seedmap.sim.render import _camera_dirs, _FrameScene, _rays_tensor, right_pose

    cfg = SimConfig(seed=args.seed, world={"length": args.length}, camera={"scale": args.scale})
    calib = cfg.camera.calib()
    tracemalloc.start()
    rw, rt, fseeds = _rngs(cfg)
    t0 = time.perf_counter()
    world = build_range_world(cfg, rw)
    t_world = time.perf_counter() - t0
    traj = range_trajectory(cfg, rt)
    mid = len(traj) // 2
    frames = list(range(mid, min(len(traj), mid + args.frames + 1)))
    times, cpu = [], []
    for k, i in enumerate(frames):
        t0, c0 = time.perf_counter(), time.process_time()
        render_stereo(world, traj.poses[i], calib, cfg, np.random.default_rng(i), float(traj.timestamps[i]))
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if k == 0:
            t_first = dt
        else:
            times.append(dt)
            cpu.append(dc)
    _, tm_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    # baseline: one bare cast of the full image against all the frame's geometry in one scene
    i = frames[-1]
    T = traj.poses[i]
    light = T[:3, :3] @ np.asarray(cfg.imaging.flash_offset) + T[:3, 3]
    fs = _FrameScene(world, float(traj.timestamps[i]), [T, right_pose(T, calib.baseline)], calib, light)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor.from_numpy(fs.V), o3d.core.Tensor.from_numpy(fs.F.astype(np.uint32)))
    for k in fs.active:
        p = world.panicles[int(k)]
        s = slice(p.seed_start, p.seed_stop)
        V, F = ellipsoids(world.seeds.xyz[s], world.seed_axes[s], world.seeds.radii[s])
        scene.add_triangles(o3d.core.Tensor.from_numpy(V.astype(np.float32)),
                            o3d.core.Tensor.from_numpy(F.astype(np.uint32)))
    dc, _ = _camera_dirs(world, calib)
    rays = _rays_tensor(T[:3, 3].astype(np.float32)[None], (dc @ T[:3, :3].T.astype(np.float32)))
    scene.cast_rays(rays)  # builds the BVH
    bare, bare_cpu = [], []
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        scene.cast_rays(rays)
        bare.append(time.perf_counter() - t0)
        bare_cpu.append(time.process_time() - c0)
    t_bare = float(np.median(bare))
    per_pair = float(np.median(times)) if times else t_first
    n = n_frames(cfg)
    result = {
        "what": "seconds per stereo pair of render_stereo at the default resolution",
        "image_size": [calib.width, calib.height],
        "scale": args.scale,
        "range_length_m": args.length,
        "frames_in_range": n,
        "seeds_in_world": int(len(world.seeds)),
        "panicles_in_world": len(world.panicles),
        "world_build_s": round(t_world, 3),
        "first_frame_s_incl_bvh_builds": round(t_first, 3),
        "seconds_per_pair_median": round(per_pair, 3),
        "seconds_per_pair_all": [round(t, 3) for t in times],
        "bare_cast_rays_s_one_image": round(t_bare, 4),
        "ratio_pair_vs_bare_cast": round(per_pair / t_bare, 2),
        "cpu_seconds_per_pair_median": round(float(np.median(cpu)), 3) if cpu else None,
        "bare_cast_cpu_s": round(float(np.median(bare_cpu)), 4),
        "ratio_cpu_pair_vs_bare_cast": round(float(np.median(cpu)) / float(np.median(bare_cpu)), 2) if cpu else None,
        "estimated_full_range_s": round(t_world + t_first + per_pair * (n - 1), 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "tracemalloc_peak_mb": round(tm_peak / 2 ** 20, 1),
        "cpu_count": os.cpu_count(),
        "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "loadavg_1min": round(os.getloadavg()[0], 2),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "open3d": o3d.__version__,
    }
    atomic_write_text(args.out, json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
