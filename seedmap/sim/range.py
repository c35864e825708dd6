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
from seedmap.sim.capture import RobotShake, condition_streams, exposure_gains, exposure_offsets, frame_schedule
from seedmap.sim.render import render_stereo
from seedmap.sim.stats import dataset_stats, write_preview, write_stats
from seedmap.sim.wind import WindField
from seedmap.sim.world import World, build_range_world

# left camera optical frame in the world at rest: x -> world +x, y -> world -z, z -> world +y
R_WORLD_CAM0 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


class _Sines:
    """A sum of sinusoids in ``x`` (metres travelled) with random wavelengths and phases; peak roughly ``amp``."""

    def __init__(self, rng: np.random.Generator, amp: float, wavelengths=(0.35, 0.9, 2.3)) -> None:
        w = rng.uniform(0.5, 1.0, len(wavelengths))
        w = w / w.sum()
        self.terms = []
        for wl, a in zip(wavelengths, w, strict=True):
            lam = wl * rng.uniform(0.8, 1.25)
            self.terms.append((amp * a, lam, rng.uniform(0, 2 * np.pi)))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = np.zeros_like(x, dtype=float)
        for c, lam, ph in self.terms:
            out += c * np.sin(2 * np.pi * x / lam + ph)
        return out


def n_frames(cfg: SimConfig) -> int:
    """Frames needed to cover x in [0, length] at ``speed`` and ``fps`` (both ends included)."""
    step = cfg.motion.speed / cfg.motion.fps
    return int(round(cfg.world.length / step)) + 1


class RangePath:
    """The rig's path along the row as a function of ``s`` in [0, 1] (the share of the range travelled): x from
    0 to ``length``, stand-off ``camera.standoff`` from the row line, height ``camera.mount_height``, with smooth
    wobble (uneven ground) in height, stand-off, speed and roll/pitch/yaw."""

    def __init__(self, cfg: SimConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.n = n_frames(cfg)
        # drawn in this order from ``rng``: along, lateral, height, three angles
        self.along = _Sines(rng, ALONG_WOBBLE)
        self.lateral = _Sines(rng, LATERAL_WOBBLE)
        self.height = _Sines(rng, HEIGHT_WOBBLE)
        a = np.radians(ANGLE_WOBBLE_DEG)
        self.angles = [_Sines(rng, a) for _ in range(3)]  # about camera x, y, z

    def nominal_x(self, s: np.ndarray) -> np.ndarray:
        """Distance travelled (m) at ``s`` without the wobble."""
        return self.cfg.world.length * s

    def poses(self, s: np.ndarray) -> np.ndarray:
        """(len(s), 4, 4) left-camera poses ``T_world_cam`` at ``s``."""
        x_nom = self.nominal_x(s)
        x = x_nom + self.along(x_nom) * np.sin(np.pi * s)  # ends stay at 0 / length
        y = -self.cfg.camera.standoff + self.lateral(x_nom)
        z = self.cfg.camera.mount_height + self.height(x_nom)
        ang = np.stack([f(x_nom) for f in self.angles], 1)
        poses = np.tile(np.eye(4), (len(s), 1, 1))
        poses[:, :3, :3] = R_WORLD_CAM0[None] @ Rotation.from_rotvec(ang).as_matrix()
        poses[:, :3, 3] = np.stack([x, y, z], 1)
        return poses

    def frame_s(self) -> np.ndarray:
        """``s`` of the frames (both ends included)."""
        return np.linspace(0.0, 1.0, self.n)


def range_trajectory(cfg: SimConfig, rng: np.random.Generator) -> Trajectory:
    """Left-camera poses ``T_world_cam`` of the frames along the range (see ``RangePath``), at ``motion.fps``."""
    path = RangePath(cfg, rng)
    return Trajectory(np.arange(path.n) / cfg.motion.fps, path.poses(path.frame_s()))


def _rngs(cfg: SimConfig) -> tuple[np.random.Generator, np.random.Generator, np.random.SeedSequence]:
    ss = np.random.SeedSequence(cfg.seed)
    w, t, f = ss.spawn(3)
    return np.random.default_rng(w), np.random.default_rng(t), f


class _Capture:
    """The frames a range writes under ``cfg.conditions``: the (shaken) camera poses, the written frames' time
    stamps and sources (drops, duplicates), and per frame the gains and exposure-interval poses. With every
    condition off: the nominal frames, nothing else drawn."""

    def __init__(self, cfg: SimConfig, world: World, path: RangePath) -> None:
        cond = cfg.conditions
        self.cfg, self.path = cfg, path
        n = path.n
        s = path.frame_s()
        self.times = np.arange(n) / cfg.motion.fps
        self.poses = path.poses(s)
        self.stamp = self.source = np.arange(n)
        self.gains = self.shake = None
        self.offsets = exposure_offsets(cond)
        if not cond.any:
            return
        streams = condition_streams(cfg.seed)
        if cond.wind > 0:
            world.wind_field = WindField.draw(world, cond.wind, streams["wind"])
        if cond.vibration > 0:
            self.shake = RobotShake.draw(cond.vibration, streams["vibration"])
            self.poses = self.shake.apply(self.poses, path.nominal_x(s), self.times)
        if cond.flicker > 0:
            self.gains = exposure_gains(n, cond.flicker, streams["flicker"])
        if cond.drops > 0:
            self.stamp, self.source = frame_schedule(n, cond.drops, streams["drops"])

    def trajectory(self) -> Trajectory:
        """Ground truth of the written frames: each one's time stamp and the pose its image was taken from."""
        return Trajectory(self.times[self.stamp], self.poses[self.source])

    def frame_conditions(self, i: int) -> dict:
        """Keyword arguments of ``render_stereo`` for capture ``i``: gains and exposure-interval poses."""
        out: dict = {}
        if self.gains is not None:
            out["gains"] = self.gains[i]
        if len(self.offsets):
            t = self.times[i] + self.offsets
            s = t * self.cfg.motion.fps / max(self.path.n - 1, 1)
            P = self.path.poses(s)
            if self.shake is not None:
                P = self.shake.apply(P, self.path.nominal_x(s), t)
            out["exposure_poses"] = P
        return out


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
    cap = _Capture(cfg, world, RangePath(cfg, rng_traj))
    traj = cap.trajectory()
    frame_seeds = frame_ss.spawn(cap.path.n)
    with outputs.output_dir(out, "dataset", inputs, overwrite) as tmp:
        w = DatasetWriter(tmp)
        w.write_calib(calib)
        w.write_times(traj.timestamps)
        w.write_gt_poses(traj)
        w.write_gt_seeds(world.seeds)
        w.write_gt_config(config_to_yaml(cfg))
        frames, pids, rows = [], [], []
        bar = Progress(len(traj), f"render {out.name}", "frame", enabled=progress)
        r, last = None, -1
        for j, i in enumerate(cap.source):
            if i != last:  # a duplicated frame repeats the image written before it
                r = render_stereo(world, cap.poses[i], calib, cfg, np.random.default_rng(frame_seeds[i]),
                                  float(cap.times[i]), **cap.frame_conditions(i))
                last = i
            w.write_frame(j, r.left, r.right)
            w.write_gt_instances(j, "left", r.left_labels, r.left_instances)
            w.write_gt_instances(j, "right", r.right_labels, r.right_instances)
            P = len(r.panicle_motion)
            frames.append(np.full(P, j))
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


__all__ = ["RangePath", "n_frames", "range_trajectory", "simulate_range"]
