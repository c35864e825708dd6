"""Render a rectified stereo pair with exact ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.io.seedmap_dataset import Instances
from seedmap.records import StereoCalib
from seedmap.sim.config import FLASH_OFFSET, SimConfig
from seedmap.sim.render import shadows
from seedmap.sim.render.antialias import _antialias
from seedmap.sim.render.blur import blur_along_motion
from seedmap.sim.render.labels import _instances
from seedmap.sim.render.rays import _O3D_THREADS, _camera_dirs, _object_key, _xf
from seedmap.sim.render.scene import _FrameScene
from seedmap.sim.render.sensor import _develop
from seedmap.sim.render.shading import _shade_parts
from seedmap.sim.world import World

#: threads rendering the two cameras of a pair in parallel (1 = one after the other: the same images)
CAMERA_THREADS = 2

@dataclass
class RenderedStereo:
    """One rendered stereo pair with exact ground truth (labels from pixel-centre rays, no AA)."""

    left: np.ndarray  # H x W x 3 uint8 RGB
    right: np.ndarray
    left_labels: np.ndarray  # H x W uint16, 0 = no seed, else a row of left_instances
    right_labels: np.ndarray
    left_instances: Instances
    right_instances: Instances
    left_depth: np.ndarray  # H x W float32 z-depth (m) of the left pixel-centre ray, NaN where nothing
    panicle_motion: np.ndarray  # (P, 4, 4) wind motion D of every panicle at this instant


def _render_camera(fs: _FrameScene, T_wc: np.ndarray, calib: StereoCalib, cfg: SimConfig,
                   rng: np.random.Generator, light: np.ndarray, light_axes: np.ndarray):
    H, W = calib.height, calib.width
    R = T_wc[:3, :3].astype(np.float32)
    o = T_wc[:3, 3].astype(np.float32)[None, :]
    dc, pix = _camera_dirs(fs.world, calib)
    d = _xf(dc, R)
    covers, scovers = fs.covers(T_wc, calib, light)
    h = fs.trace(o, d, pix, covers, grid=True)
    key = _object_key(h)
    soft = cfg.imaging.shadows
    sparse = soft and shadows.SHADOW_STRIDE > 1
    sh = _shade_parts(fs, o, d, h, light, light_axes, cfg, rng, pix, scovers,
                      shadows._shadow_grid(H, W) if sparse else None)
    vis = np.ones(H * W, np.float32)
    vis[sh.live] = sh.vis
    if sparse:
        vis = shadows._shadows_from_samples(fs, vis.reshape(H, W), key.reshape(H, W), sh.pending, scovers).reshape(-1)
    elif soft:
        vis = shadows._filter_visibility(vis.reshape(H, W), key.reshape(H, W)).reshape(-1)
    rgb = sh.radiance(H * W, vis)
    seed_img = h.seed.reshape(H, W)
    depth = np.where(np.isfinite(h.t), h.t * dc[:, 2], np.nan).reshape(H, W).astype(np.float32)
    if cfg.imaging.supersample > 1:
        _antialias(fs, o, R, calib, cfg, h, key, rgb, covers, scovers, light, light_axes, rng, T_wc, vis)
    return rgb.reshape(H, W, 3), seed_img, depth, h


def right_pose(T_world_left: np.ndarray, baseline: float) -> np.ndarray:
    """Pose of the right camera: ``+baseline`` along the left camera's x axis."""
    T = np.asarray(T_world_left, float).copy()
    T[:3, 3] = T[:3, 3] + T[:3, 0] * baseline
    return T


def render_stereo(world: World, T_world_cam: np.ndarray, calib: StereoCalib, cfg: SimConfig,
                  rng: np.random.Generator, t: float, *, gains: np.ndarray | None = None,
                  exposure_poses: np.ndarray | None = None) -> RenderedStereo:
    """Render the rectified pair whose LEFT camera is at ``T_world_cam`` with the world at time ``t`` (s).

    Works for any pose (range robot, arm around a single panicle). Random effects of this frame
    (exposure jitter, flash sampling, sensor noise) are drawn from ``rng``. Field conditions
    (``seedmap.sim.capture``): ``gains`` (2,) multiply the left and right camera's gain (flash flicker,
    auto-exposure); ``exposure_poses`` (K, 4, 4), the left camera over the exposure interval, blur each image
    along its pixels' motion (``render.blur``).
    """
    T_l = np.asarray(T_world_cam, float)
    T_r = right_pose(T_l, calib.baseline)
    light = T_l[:3, :3] @ np.asarray(FLASH_OFFSET, float) + T_l[:3, 3]
    light_axes = np.stack([T_l[:3, 0], T_l[:3, 1]]).astype(np.float32)
    fs = _FrameScene(world, t, [T_l, T_r], calib, light)
    gain = cfg.imaging.exposure * 1.1 * float(np.exp(rng.normal(0, cfg.imaging.exposure_jitter)))
    centers = world.seed_centers_at(t, fs.D)
    # one generator per camera, so the result does not depend on whether they run in parallel
    cam_rngs = rng.spawn(2)
    jobs = (("left", T_l, cam_rngs[0], 0), ("right", T_r, cam_rngs[1], 1))

    def one(job):
        name, T, crng, c = job
        _O3D_THREADS.n = 1 if CAMERA_THREADS > 1 else 0
        # flash sampling and sensor noise from separate streams: the noise image does not depend on
        # how many flash samples the shading drew
        shade_rng, noise_rng = crng.spawn(2)
        lin, seed_img, depth, _ = _render_camera(fs, T, calib, cfg, shade_rng, light, light_axes)
        if exposure_poses is not None:
            subs = exposure_poses if c == 0 else np.stack([right_pose(P, calib.baseline) for P in exposure_poses])
            lin = blur_along_motion(lin, depth, T, subs, calib)
        g = gain if gains is None else gain * float(gains[c])
        img = _develop(lin, calib, cfg, noise_rng, g, world.cache)
        labels, inst = _instances(fs, seed_img, centers, T, calib)
        return name, (img, labels, inst, depth)

    if CAMERA_THREADS > 1:
        from concurrent.futures import ThreadPoolExecutor

        _camera_dirs(world, calib)  # fill the shared caches before the threads start
        with ThreadPoolExecutor(max_workers=2) as ex:
            out = dict(ex.map(one, jobs))
    else:
        out = dict(one(j) for j in jobs)
    return RenderedStereo(
        left=out["left"][0], right=out["right"][0], left_labels=out["left"][1], right_labels=out["right"][1],
        left_instances=out["left"][2], right_instances=out["right"][2], left_depth=out["left"][3],
        panicle_motion=fs.D)
