"""Procedural sorghum world and ground-truth stereo renderer (the data every other module is measured on).

Public API::

    build_range_world(cfg, rng) -> World        a sorghum range (plants over x in [0, length])
    build_panicle_world(cfg, rng) -> World      one panicle, rachis along +z, base at the origin
    render_stereo(world, T_world_cam, calib, cfg, rng, t, *, gains=None, exposure_poses=None) -> RenderedStereo
    simulate_range(cfg, out, overwrite=False, progress=True) -> Path   a whole dataset, atomically
                                                (field conditions: ``cfg.conditions``, seedmap.sim.conditions)
    range_length(dataset_path) -> float | None  the range length recorded in gt/config.yaml

The world model, the renderer and the ground truth are described in docs/method/simulator.md, the field
conditions (wind, vibration, blur, flicker, wet leaves, frame drops) in docs/method/conditions.md.
Open3D is imported only when rendering.
"""

from seedmap.sim.config import PRESETS, SimConfig, preset_dict
from seedmap.sim.range import range_trajectory, simulate_range
from seedmap.sim.render import RenderedStereo, render_stereo, right_pose
from seedmap.sim.stats import range_length
from seedmap.sim.world import World, build_panicle_world, build_range_world

__all__ = [
    "PRESETS",
    "RenderedStereo",
    "SimConfig",
    "World",
    "build_panicle_world",
    "build_range_world",
    "preset_dict",
    "range_length",
    "range_trajectory",
    "render_stereo",
    "right_pose",
    "simulate_range",
]
