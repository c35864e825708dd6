"""The renderer's culling is conservative: pixel covers, env culling, the analytic soil and the
leaf sway bounds change which rays are traced, never what a ray hits.

Small renders (scale 0.12-0.15, a 1-3 m range of small panicles) so the file runs in well under a minute.
"""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.sim import SimConfig, build_range_world, render_stereo, right_pose
from seedmap.sim.config import FLASH_OFFSET
from seedmap.sim.range import _rngs, range_trajectory
from seedmap.sim.render import stereo
from seedmap.sim.render.culling import _leaf_spheres
from seedmap.sim.render.rays import _camera_dirs, _rays_tensor, _xf
from seedmap.sim.render.scene import _FrameScene
from seedmap.sim.world import CLS_SOIL


def _world(length: float, scale: float = 0.15, seed: int = 3):
    cfg = SimConfig(seed=seed, world={"length": length, "gap": 0.3}, camera={"scale": scale},
                    panicle={"seeds_min": 300, "seeds_max": 600})
    rw, rt, _ = _rngs(cfg)
    return cfg, build_range_world(cfg, rw), range_trajectory(cfg, rt)


@pytest.fixture(scope="module")
def scene():
    cfg, world, traj = _world(1.0)
    calib = cfg.camera.calib()
    i = len(traj) // 2
    T = traj.poses[i]
    light = T[:3, :3] @ np.asarray(FLASH_OFFSET) + T[:3, 3]
    fs = _FrameScene(world, float(traj.timestamps[i]), [T, right_pose(T, calib.baseline)], calib, light)
    return cfg, world, calib, T, light, fs


def test_pixel_covers_give_the_same_hits_as_tracing_everything(scene):
    cfg, world, calib, T, light, fs = scene
    assert len(fs.active) >= 2
    dc, pix = _camera_dirs(world, calib)
    o = T[:3, 3].astype(np.float32)[None]
    d = _xf(dc, T[:3, :3])
    covers, _ = fs.covers(T, calib, light)
    culled = fs.trace(o, d, pix, covers, grid=True)
    full = fs.trace(o, d)  # every ray against the env BVH, bounding-sphere test per panicle
    assert (culled.seed >= 0).sum() > 1000  # the panicles are in view
    np.testing.assert_array_equal(culled.seed, full.seed)
    np.testing.assert_array_equal(culled.cls, full.cls)
    np.testing.assert_array_equal(culled.t, full.t)
    # the covers skip most rays: env and panicles together trace far fewer than 1 + P rays per pixel
    n_traced = len(covers.env.flat()) + sum(len(c.flat()) for c in covers.pan)
    assert n_traced < 0.6 * (1 + len(fs.active)) * len(d)
    # sub-pixel rays (anti-aliasing) looked up through the covers agree too
    rng = np.random.default_rng(0)
    ps = pix[rng.choice(len(pix), 20000, replace=False)] + rng.uniform(-0.5, 0.5, (20000, 2)).astype(np.float32)
    x = (ps[:, 0] - calib.cx) / calib.fx
    y = (ps[:, 1] - calib.cy) / calib.fy
    ds = np.stack([x, y, np.ones_like(x)], 1)
    ds = _xf(ds / np.linalg.norm(ds, axis=1, keepdims=True), T[:3, :3])
    a, b = fs.trace(o, ds, ps, covers), fs.trace(o, ds)
    np.testing.assert_array_equal(a.seed, b.seed)
    # (Open3D's hit distance may differ in the last bit between two batches of the same rays)
    np.testing.assert_allclose(a.t, b.t, rtol=1e-6)


def test_shadow_covers_give_the_same_occlusion(scene):
    cfg, world, calib, T, light, fs = scene
    dc, pix = _camera_dirs(world, calib)
    o = T[:3, 3].astype(np.float32)[None]
    h = fs.trace(o, _xf(dc, T[:3, :3]))
    hit = np.nonzero(h.t < 3.0)[0]
    p = o + h.t[hit, None] * _xf(dc[hit], T[:3, :3])
    start = p + (light.astype(np.float32) - p) * 1e-3
    _, scovers = fs.covers(T, calib, light)
    culled = fs.occluded(start, light.astype(np.float32) - start, pix[hit], scovers)
    full = fs.occluded(start, light.astype(np.float32) - start)
    assert 0 < culled.sum() < len(hit)  # some shadows, not everything
    np.testing.assert_array_equal(culled, full)


def test_analytic_soil_matches_ray_casting_the_soil_triangles(scene):
    import open3d as o3d

    cfg, world, calib, T, light, fs = scene
    soil = fs.F[fs.tri_cls == CLS_SOIL]
    assert len(soil) == 2
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor.from_numpy(fs.V), o3d.core.Tensor.from_numpy(soil.astype(np.uint32)))
    rng = np.random.default_rng(1)
    o = np.column_stack([rng.uniform(-8, 10, 5000), rng.uniform(-9, 9, 5000), rng.uniform(0.05, 2, 5000)])
    d = rng.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, d = o.astype(np.float32), d.astype(np.float32)
    ref = sc.cast_rays(_rays_tensor(o, d))["t_hit"].numpy()
    idx, ts = fs._soil_hits(o, d, np.full(len(d), np.inf, np.float32))
    got = np.full(len(d), np.inf, np.float32)
    got[idx] = ts
    ok = np.isfinite(ref)
    assert ok.sum() > 500 and (~ok).sum() > 500
    # identical hit/miss except rays grazing the rectangle's border
    far_from_edge = np.ones(len(d), bool)
    xy = o[:, :2] + np.where(np.isfinite(ref), ref, 0)[:, None] * d[:, :2]
    far_from_edge &= ~np.isclose(np.abs(xy[:, 1]), 6.0, atol=1e-3)
    np.testing.assert_array_equal(np.isfinite(got)[far_from_edge], ok[far_from_edge])
    np.testing.assert_allclose(got[ok & far_from_edge], ref[ok & far_from_edge], rtol=1e-5)


def test_leaf_spheres_hold_the_swaying_leaves():
    cfg, world, _ = _world(0.6, seed=4)
    c, r = _leaf_spheres(world)
    for t in np.linspace(0, 20, 41):
        M = world.leaf_motion(t)
        v = np.einsum("lij,lvj->lvi", M[:, :3, :3], world.leaf_vertices) + M[:, None, :3, 3]
        assert (np.linalg.norm(v - c[:, None, :], axis=2) <= r[:, None]).all()


def test_frame_geometry_does_not_grow_with_the_range():
    """A frame builds only what its cameras can see: the same camera pose sees about the same number
    of env triangles and panicles in a 2 m and a 4 m range."""
    counts = []
    for length in (2.0, 4.0):
        cfg, world, traj = _world(length, seed=5)
        calib = cfg.camera.calib()
        T = traj.poses[len(traj) // 2].copy()
        T[:3, 3] = (0.8, -cfg.camera.standoff, cfg.camera.mount_height)
        light = T[:3, :3] @ np.asarray(FLASH_OFFSET) + T[:3, 3]
        fs = _FrameScene(world, 0.0, [T, right_pose(T, calib.baseline)], calib, light)
        n_env = len(world.stalk_triangles) + len(world.leaf_vertices) * len(world.leaf_triangles)
        counts.append((len(fs.F), len(fs.active), n_env))
    (f1, a1, n1), (f3, a3, n3) = counts
    assert n3 > 1.6 * n1, counts  # the long world really is bigger
    assert f3 < 1.3 * f1 and a3 <= a1 + 2, counts


def test_render_is_deterministic_with_threads(scene, monkeypatch):
    cfg, world, calib, T, light, fs = scene
    a = render_stereo(world, T, calib, cfg, np.random.default_rng(7), 0.4)
    monkeypatch.setattr(stereo, "CAMERA_THREADS", 1)
    b = render_stereo(world, T, calib, cfg, np.random.default_rng(7), 0.4)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert np.array_equal(a.left_labels, b.left_labels) and np.array_equal(a.right_labels, b.right_labels)
