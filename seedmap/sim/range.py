"""The range scenario: a robot carrying the stereo rig along the row, written as a seedmap dataset."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from seedmap import outputs
from seedmap.config import config_to_yaml
from seedmap.geometry import pose_to_tum
from seedmap.io.seedmap_dataset import DatasetWriter
from seedmap.progress import Progress
from seedmap.records import Trajectory
from seedmap.sim.config import ALONG_WOBBLE, ANGLE_WOBBLE_DEG, HEIGHT_WOBBLE, LATERAL_WOBBLE, SimConfig
from seedmap.sim.render import render_stereo
from seedmap.sim.stats import dataset_stats, write_preview, write_stats
from seedmap.sim.world import build_range_world

# left camera optical frame in the world at rest: x -> world +x, y -> world -z, z -> world +y
R_WORLD_CAM0 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _smooth_noise(rng: np.random.Generator, x: np.ndarray, amp: float, wavelengths=(0.35, 0.9, 2.3)) -> np.ndarray:
    """Sum of sinusoids in ``x`` (metres travelled) with random phases; peak roughly ``amp``."""
    out = np.zeros_like(x, dtype=float)
    w = rng.uniform(0.5, 1.0, len(wavelengths))
    w = w / w.sum()
    for wl, a in zip(wavelengths, w, strict=True):
        lam = wl * rng.uniform(0.8, 1.25)
        out += amp * a * np.sin(2 * np.pi * x / lam + rng.uniform(0, 2 * np.pi))
    return out


def n_frames(cfg: SimConfig) -> int:
    """Frames needed to cover x in [0, length] at ``speed`` and ``fps`` (both ends included)."""
    step = cfg.motion.speed / cfg.motion.fps
    return int(round(cfg.world.length / step)) + 1


def range_trajectory(cfg: SimConfig, rng: np.random.Generator) -> Trajectory:
    """Left-camera poses ``T_world_cam``: x from 0 to ``length`` at the configured speed/fps, stand-off
    ``camera.standoff`` from the row line, height ``camera.mount_height``, with smooth wobble
    (uneven ground) in height, stand-off, speed and roll/pitch/yaw."""
    mc = cfg.motion
    n = n_frames(cfg)
    ts = np.arange(n) / mc.fps
    s = np.linspace(0.0, 1.0, n)
    x_nom = cfg.world.length * s
    x = x_nom + _smooth_noise(rng, x_nom, ALONG_WOBBLE) * np.sin(np.pi * s)  # ends stay at 0 / length
    y = -cfg.camera.standoff + _smooth_noise(rng, x_nom, LATERAL_WOBBLE)
    z = cfg.camera.mount_height + _smooth_noise(rng, x_nom, HEIGHT_WOBBLE)
    a = np.radians(ANGLE_WOBBLE_DEG)
    ang = np.stack([_smooth_noise(rng, x_nom, a) for _ in range(3)], 1)  # about camera x, y, z
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = R_WORLD_CAM0[None] @ Rotation.from_rotvec(ang).as_matrix()
    poses[:, :3, 3] = np.stack([x, y, z], 1)
    return Trajectory(ts, poses)


def _rngs(cfg: SimConfig) -> tuple[np.random.Generator, np.random.Generator, np.random.SeedSequence]:
    ss = np.random.SeedSequence(cfg.seed)
    w, t, f = ss.spawn(3)
    return np.random.default_rng(w), np.random.default_rng(t), f


def simulate_range(cfg: SimConfig, out: Path, overwrite: bool = False, progress: bool = True, *,
                   preview: bool = False, stats: bool = False, inputs: Sequence[str | Path | None] = ()) -> Path:
    """Render a whole range dataset into ``out`` atomically (nothing is left behind on failure).

    Writes images, calibration, times and the full ground truth (poses, seeds, panicle sway, instance
    masks/tables, the generator config). ``preview`` adds ``preview.png``; ``stats`` adds ``stats.json``.
    """
    out = Path(out)
    outputs.check_output_dir(out, "dataset", inputs, overwrite)  # --overwrite: only a dataset seedmap simulated
    calib = cfg.camera.calib()
    rng_world, rng_traj, frame_ss = _rngs(cfg)
    world = build_range_world(cfg, rng_world)
    traj = range_trajectory(cfg, rng_traj)
    frame_seeds = frame_ss.spawn(len(traj))
    with outputs.output_dir(out, "dataset", inputs, overwrite) as tmp:
        w = DatasetWriter(tmp)
        w.write_calib(calib)
        w.write_times(traj.timestamps)
        w.write_gt_poses(traj)
        w.write_gt_seeds(world.seeds)
        w.write_gt_config(config_to_yaml(cfg))
        frames, pids, rows = [], [], []
        it = range(len(traj))
        bar = Progress(len(traj), f"render {out.name}", "frame", enabled=progress)
        for i in it:
            r = render_stereo(world, traj.poses[i], calib, cfg, np.random.default_rng(frame_seeds[i]),
                              float(traj.timestamps[i]))
            w.write_frame(i, r.left, r.right)
            w.write_gt_instances(i, "left", r.left_labels, r.left_instances)
            w.write_gt_instances(i, "right", r.right_labels, r.right_instances)
            P = len(r.panicle_motion)
            frames.append(np.full(P, i))
            pids.append(np.arange(P))
            rows.append(pose_to_tum(r.panicle_motion) if P else np.zeros((0, 7)))
            bar.advance()
        bar.close()
        if frames:
            w.write_gt_panicle_poses(np.concatenate(frames), np.concatenate(pids), np.vstack(rows))
        else:
            w.write_gt_panicle_poses(np.zeros(0), np.zeros(0), np.zeros((0, 7)))
        if stats:
            st = dataset_stats(tmp)
            st["dataset"] = str(out)
            write_stats(tmp, st)
        if preview:
            write_preview(tmp)
    return out


__all__ = ["n_frames", "range_trajectory", "simulate_range"]
