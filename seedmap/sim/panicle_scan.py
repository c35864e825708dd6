"""``seedmap simulate panicle``: a UR5 arm scan of one simulated panicle, written as a seedmap dataset.

Besides the standard layout (seedmap.io.seedmap_dataset) the folder holds

* ``joints.csv``          commanded and measured joint angles per view (rad)
* ``arm.yaml``            the nominal arm description (DH table, base pose, hand-eye, capture config)
* ``gt/poses_tum.txt``    TRUE left-camera poses T_world_cam
* ``gt/poses_fk_tum.txt`` nominal FK poses (what the robot believes)
* ``gt/panicle_poses.csv`` the panicle sway D per view (p_world = D p_rest)
* ``gt/surface_points.npy`` points sampled on the seed ellipsoids at rest (GT surface, m)
* ``gt/scan.yaml``        the generator config (scan + simulator)

Panicle sway is applied by rendering the panicle at rest from ``D^-1 T_world_cam`` (the scene holds
nothing else), so the simulator's own wind is off for these scans. ``exposure="auto"`` scales the
flash gain for the scan's stand-off (docs/method/simulator.md); the gain used is written to
``gt/config.yaml`` (``imaging.exposure``).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, Union

import numpy as np
import yaml
from pydantic import Field, field_validator, model_validator

from seedmap import outputs
from seedmap.config import ConfigModel, config_to_yaml, deep_merge
from seedmap.errors import ConfigError
from seedmap.geometry import invert, pose_to_tum
from seedmap.io.atomic import atomic_write_bytes, atomic_write_text
from seedmap.io.seedmap_dataset import DatasetWriter, SeedmapDataset
from seedmap.io.trajectory import write_tum
from seedmap.progress import Progress
from seedmap.records import Trajectory
from seedmap.sim.arm import ArmConfig, arm_yaml_dict, simulate_capture, write_joints_csv
from seedmap.sim.config import SimConfig, drop_retired
from seedmap.sim.render import REF_DISTANCE, render_stereo
from seedmap.sim.world import build_panicle_world


#: the arm scan's departures from the field simulator's defaults: a quarter-resolution camera and no
#: simulator wind (sway is the scan's own). A partial ``sim:`` section (YAML or ``--set sim.X=...``) is
#: merged over these, so overriding one key never brings back the field camera or the wind.
SCAN_SIM_DEFAULTS: dict = {"camera": {"scale": 0.25}, "wind": {"enabled": False}}
#: points sampled on each seed ellipsoid for the GT surface
SURFACE_SAMPLES_PER_SEED = 60


def _default_sim() -> SimConfig:
    return SimConfig.model_validate(SCAN_SIM_DEFAULTS)


class PanicleScanConfig(ConfigModel):
    """An arm scan: one ``seed`` drives the panicle, the arm errors and the image noise."""

    #: random seed of the panicle, the arm errors and the image noise
    seed: int = 0
    arm: ArmConfig = Field(default_factory=ArmConfig)
    sim: SimConfig = Field(default_factory=_default_sim)
    #: "auto": gain x (scan distance / 0.7 m)^2, seeds facing the camera exposed as in the field; a number > 0
    #: multiplies sim.imaging.exposure (1.0 = the field gain: flash-saturated close-ups)
    exposure: Union[Literal["auto"], float] = "auto"

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        return drop_retired(data, {"surface_samples_per_seed": SURFACE_SAMPLES_PER_SEED})

    @field_validator("sim", mode="before")
    @classmethod
    def _scan_sim_defaults(cls, v):  # noqa: ANN001, ANN206 - pydantic validator
        if isinstance(v, dict):
            return deep_merge(SCAN_SIM_DEFAULTS, v)
        return v

    @field_validator("sim")
    @classmethod
    def _no_field_conditions(cls, v):  # noqa: ANN001, ANN206 - pydantic validator
        if v.conditions.any:
            raise ValueError("conditions are those of a field row (seedmap simulate range); an arm scan has its "
                             "own error model (arm.errors)")
        return v

    @field_validator("exposure")
    @classmethod
    def _positive(cls, v):  # noqa: ANN001, ANN206 - pydantic validator
        if v != "auto" and not v > 0:
            raise ValueError(f"must be 'auto' or a number > 0, got {v}")
        return v


def scan_distance(world, arm_radius: float, quantile: float = 0.9) -> float:
    """Typical distance (m) from the arm camera to the seed surfaces it faces: the stand-off from the
    rachis axis minus the panicle's radius, taken as the ``quantile`` of the seeds' outer surface
    distance from the axis (centre distance + largest semi-axis) -- the seeds on the outside of the
    panicle are the ones facing the camera. Clipped to >= 0.05 m."""
    xy = world.seeds.xyz[:, :2]
    outer = np.hypot(xy[:, 0], xy[:, 1]) + world.seeds.radii.max(axis=1)
    r_pan = float(np.quantile(outer, quantile)) if len(outer) else 0.0
    return max(float(arm_radius) - r_pan, 0.05)


def exposure_factor(cfg: PanicleScanConfig, world) -> float:
    """Multiplier of ``sim.imaging.exposure`` for this scan (see the module docstring)."""
    if cfg.exposure == "auto":
        return (scan_distance(world, cfg.arm.radius) / REF_DISTANCE) ** 2
    if not cfg.exposure > 0:
        raise ConfigError(f"exposure must be 'auto' or a number > 0, got {cfg.exposure}")
    return float(cfg.exposure)


def seed_surface_points(world, per_seed: int, rng: np.random.Generator) -> np.ndarray:
    """Points uniformly-ish on every seed ellipsoid at rest (world frame, m) -- the GT surface."""
    c = world.seeds.xyz
    r = world.seeds.radii
    v = rng.normal(size=(len(c), per_seed, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    local = v * r[:, None, :]
    return (np.einsum("nij,nkj->nki", world.seed_axes, local) + c[:, None, :]).reshape(-1, 3).astype(np.float32)


def simulate_panicle(cfg: PanicleScanConfig, out: Path, overwrite: bool = False, progress: bool = True,
                     inputs: Sequence[str | Path | None] = ()) -> Path:
    """Build one panicle, plan and 'execute' the arm scan, render every view and write the dataset.

    ``--overwrite`` replaces only a panicle scan seedmap simulated, never one of ``inputs`` (``--config``)."""
    out = Path(out)
    outputs.check_output_dir(out, "panicle-scan", inputs, overwrite)
    sim = cfg.sim.model_copy(update={"seed": cfg.seed})
    ss = np.random.SeedSequence(cfg.seed)
    s_world, s_arm, s_surf, s_frames = ss.spawn(4)
    world = build_panicle_world(sim, np.random.default_rng(s_world))
    factor = exposure_factor(cfg, world)
    if factor != 1.0:  # (1.0: the config object untouched, the field gain exactly)
        sim = sim.model_copy(update={"imaging": sim.imaging.model_copy(
            update={"exposure": sim.imaging.exposure * factor})})
    z = world.seeds.xyz[:, 2]
    heights = cfg.arm.heights if cfg.arm.heights else [float(0.5 * (z.min() + z.max()))]
    cap = simulate_capture(cfg.arm, heights, np.random.default_rng(s_arm))
    calib = sim.camera.calib()
    frame_seeds = s_frames.spawn(cfg.arm.views)
    T_render = invert(cap.panicle_motion) @ cap.T_world_cam_true
    with outputs.output_dir(out, "panicle-scan", inputs, overwrite) as tmp:
        w = DatasetWriter(tmp)
        w.write_calib(calib)
        w.write_times(cap.times)
        w.write_gt_poses(Trajectory(cap.times, cap.T_world_cam_true))
        write_tum(tmp / "gt" / "poses_fk_tum.txt", Trajectory(cap.times, cap.T_world_cam_fk))
        w.write_gt_seeds(world.seeds)
        w.write_gt_panicle_poses(np.arange(cfg.arm.views), np.zeros(cfg.arm.views, int), pose_to_tum(cap.panicle_motion))
        w.write_gt_config(config_to_yaml(sim))
        # (the resolved values as a comment: the file stays loadable as a PanicleScanConfig)
        atomic_write_text(tmp / "gt" / "scan.yaml", config_to_yaml(cfg) + (
            f"# resolved_exposure: {sim.imaging.exposure!r} (sim.imaging.exposure used for the images)\n"
            f"# scan_distance_m: {scan_distance(world, cfg.arm.radius):.4f}\n"))
        buf = io.BytesIO()
        np.save(buf, seed_surface_points(world, SURFACE_SAMPLES_PER_SEED, np.random.default_rng(s_surf)))
        atomic_write_bytes(tmp / "gt" / "surface_points.npy", buf.getvalue())
        write_joints_csv(tmp / "joints.csv", cap)
        atomic_write_text(tmp / "arm.yaml", yaml.safe_dump(arm_yaml_dict(cap, cfg.arm), sort_keys=False))
        bar = Progress(cfg.arm.views, f"render {out.name}", "view", enabled=progress)
        for k in range(cfg.arm.views):
            r = render_stereo(world, T_render[k], calib, sim, np.random.default_rng(frame_seeds[k]), 0.0)
            w.write_frame(k, r.left, r.right)
            w.write_gt_instances(k, "left", r.left_labels, r.left_instances)
            w.write_gt_instances(k, "right", r.right_labels, r.right_instances)
            bar.advance()
        bar.close()
    return out


def gt_rest_poses(root: Path) -> np.ndarray | None:
    """True camera poses in the panicle rest frame (``D^-1 T_world_cam``) of an arm scan dataset."""
    ds = SeedmapDataset(root)
    tr = ds.gt_trajectory()
    if tr is None:
        return None
    D = ds.gt_panicle_poses()
    out = tr.poses.copy()
    for k in range(len(out)):
        Dk = D.get(k, {}).get(0)
        if Dk is not None:
            out[k] = invert(Dk) @ out[k]
    return out


def gt_surface_points(root: Path) -> np.ndarray | None:
    """The GT seed surface points (m) of an arm scan dataset, None without them."""
    p = Path(root) / "gt" / "surface_points.npy"
    return np.load(p).astype(np.float64) if p.is_file() else None
