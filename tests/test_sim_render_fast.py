"""The renderer's cheaper image model: sparse flash-shadow rays, and anti-aliasing sub-samples decided
by the seeds' analytic image outlines instead of rays.

Small renders (scale 0.15, a 1 m range of small panicles) so the file runs in well under a minute.
"""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.sim.render import shadows
from seedmap.sim.render.antialias import _antialias, _inside_outline, _seed_conics, _seed_entry
from seedmap.sim.render.culling import _cover_from_boxes
from seedmap.sim.render.rays import ENV_CODE, _camera_dirs, _Hits, _object_key, _put_rows, _rays_tensor, _unit_dirs, _xf
from seedmap.sim.render.scene import _FrameScene
from seedmap.sim.render.shading import _shade, _shade_parts
from seedmap.sim.render.shadows import _filter_visibility
from seedmap.sim import SimConfig, build_range_world, render_stereo, right_pose
from seedmap.sim.config import FLASH_OFFSET, LIGHT_CUTOFF
from seedmap.sim.meshes import ellipsoids
from seedmap.sim.range import _rngs, range_trajectory


@pytest.fixture(scope="module")
def scene():
    cfg = SimConfig(seed=3, world={"length": 1.0, "gap": 0.3}, camera={"scale": 0.15},
                    panicle={"seeds_min": 300, "seeds_max": 600})
    rw, rt, _ = _rngs(cfg)
    world = build_range_world(cfg, rw)
    traj = range_trajectory(cfg, rt)
    calib = cfg.camera.calib()
    i = len(traj) // 2
    T = traj.poses[i]
    light = T[:3, :3] @ np.asarray(FLASH_OFFSET) + T[:3, 3]
    fs = _FrameScene(world, float(traj.timestamps[i]), [T, right_pose(T, calib.baseline)], calib, light)
    return cfg, world, calib, T, float(traj.timestamps[i]), fs


def test_seed_outlines_match_the_seed_meshes(scene):
    """The analytic image outline of a seed (``_seed_conics``, ellipsoid scaled by ``SEED_AA_SCALE``)
    agrees with casting rays at its triangle mesh at this frame's wind pose, and the analytic entry
    distance (``_seed_entry``) is within the mesh's sag of the mesh hit."""
    import open3d as o3d

    cfg, world, calib, T, t, fs = scene
    rng = np.random.default_rng(0)
    o = T[:3, 3].astype(np.float32)
    conics = _seed_conics(fs, T, calib)
    sids = rng.choice(fs.active_seed_ids, 40, replace=False)
    stops = np.array([p.seed_stop for p in world.panicles])
    agree = tot = n_hit = 0
    for sid in sids:
        k = int(np.searchsorted(stops, sid, side="right"))
        V, F = ellipsoids(world.seeds.xyz[sid][None], world.seed_axes[sid][None], world.seeds.radii[sid][None])
        V = V @ fs.D[k, :3, :3].T + fs.D[k, :3, 3]  # the mesh at this instant
        sc = o3d.t.geometry.RaycastingScene()
        sc.add_triangles(o3d.core.Tensor.from_numpy(V.astype(np.float32)),
                         o3d.core.Tensor.from_numpy(F.astype(np.uint32)))
        uv = (conics[sid, :2][None] + rng.uniform(-3, 3, (400, 2))).astype(np.float32)
        d = _xf(_unit_dirs(calib, uv), T[:3, :3])
        t_mesh = sc.cast_rays(_rays_tensor(np.repeat(o[None], len(d), 0), d))["t_hit"].numpy()
        hit = np.isfinite(t_mesh)
        inside = _inside_outline(conics, np.full(len(d), sid), uv[:, 0], uv[:, 1])
        agree += int((hit == inside).sum())
        tot += len(d)
        n_hit += int(hit.sum())
        t_an = _seed_entry(fs, o, d[hit], np.full(int(hit.sum()), sid))
        r = float(world.seeds.radii[sid].max())
        err = np.abs(t_an - t_mesh[hit])
        assert np.median(err) < 0.1 * r and err.max() < r  # larger only at grazing rays near the outline
    assert n_hit > 1000
    assert agree > 0.985 * tot, agree / tot  # only a sliver along the outline differs


def test_trace_only_restricts_objects_and_keeps_hits(scene):
    """``trace(only=...)`` with every object allowed equals the unrestricted trace; with only the env
    allowed no ray reports a panicle hit."""
    cfg, world, calib, T, t, fs = scene
    dc, pix = _camera_dirs(world, calib)
    o = T[:3, 3].astype(np.float32)[None]
    d = _xf(dc, T[:3, :3])
    covers, _ = fs.covers(T, calib, np.asarray(T[:3, 3]))
    rng = np.random.default_rng(1)
    pick = rng.choice(len(pix), 30000, replace=False)
    ps, ds = pix[pick], d[pick]
    every = np.tile(np.r_[ENV_CODE, fs.active].astype(np.int32), (len(ps), 1))
    a, b = fs.trace(o, ds, ps, covers), fs.trace(o, ds, ps, covers, only=every)
    assert (a.seed >= 0).sum() > 500
    np.testing.assert_array_equal(a.seed, b.seed)
    np.testing.assert_array_equal(a.t, b.t)
    env_only = fs.trace(o, ds, ps, covers, only=np.full((len(ps), 1), ENV_CODE, np.int32))
    assert (env_only.seed < 0).all() and (env_only.obj < 0).all()


def test_sparse_shadows_match_dense_shadows(scene, monkeypatch):
    """Shadow rays on a quarter of the pixels change no label and move the image by well under one
    grey level on average (same flash samples and sensor noise)."""
    cfg, world, calib, T, t, fs = scene
    sparse = render_stereo(world, T, calib, cfg, np.random.default_rng(7), t)
    monkeypatch.setattr(shadows, "SHADOW_STRIDE", 1)
    dense = render_stereo(world, T, calib, cfg, np.random.default_rng(7), t)
    assert np.array_equal(sparse.left_labels, dense.left_labels)
    assert np.array_equal(sparse.right_labels, dense.right_labels)
    for a, b in ((sparse.left, dense.left), (sparse.right, dense.right)):
        diff = np.abs(a.astype(np.int32) - b.astype(np.int32))
        assert 0 < diff.mean() < 1.0, diff.mean()
        assert abs(float(a.mean()) - float(b.mean())) < 0.3
    # shadows are really there (a render without them is brighter)
    no_shadows = cfg.model_copy(update={"imaging": cfg.imaging.model_copy(update={"shadows": False})})
    lit = render_stereo(world, T, calib, no_shadows, np.random.default_rng(7), t)
    assert lit.left.mean() > sparse.left.mean() + 0.3


def _edge_pixels(key: np.ndarray, t: np.ndarray, H: int, W: int, far: float) -> np.ndarray:
    """Pixels the anti-aliasing works on: a 4-neighbour sees another object or depth, one of them lit."""
    k, tt = key.reshape(H, W), np.minimum(t, 1e3).reshape(H, W)
    lit = tt < far
    edge = np.zeros((H, W), bool)
    for a, b in (((slice(None), slice(1, None)), (slice(None), slice(0, -1))),
                 ((slice(1, None), slice(None)), (slice(0, -1), slice(None)))):
        e = ((k[a] != k[b]) | (np.abs(tt[a] - tt[b]) > 0.05 * np.minimum(tt[a], tt[b]))) & (lit[a] | lit[b])
        edge[a] |= e
        edge[b] |= e
    return np.nonzero(edge.reshape(-1))[0]


def test_antialiasing_matches_tracing_every_subsample(scene):
    """The anti-aliasing that decides most sub-samples without rays (seed outlines, neighbouring
    pixels' shading) gives nearly the image of tracing and shading all 2 x 2 sub-samples of the edge
    pixels (a sub-sample that sees another object than its pixel shaded on its own, with its own
    shadow ray): small per-pixel differences, about the same brightness."""
    cfg, world, calib, T, t, fs = scene
    H, W = calib.height, calib.width
    R, o = T[:3, :3], T[:3, 3].astype(np.float32)[None]
    light = T[:3, :3] @ np.asarray(FLASH_OFFSET) + T[:3, 3]
    light_axes = np.stack([T[:3, 0], T[:3, 1]]).astype(np.float32)
    dc, pix = _camera_dirs(world, calib)
    d = _xf(dc, R)
    covers, scovers = fs.covers(T, calib, light)
    h = fs.trace(o, d, pix, covers, grid=True)
    key = _object_key(h)
    sh = _shade_parts(fs, o, d, h, light, light_axes, cfg, np.random.default_rng(1), pix, scovers)
    vis = np.ones(H * W, np.float32)
    vis[sh.live] = sh.vis
    vis = _filter_visibility(vis.reshape(H, W), key.reshape(H, W)).reshape(-1)
    base = sh.radiance(H * W, vis)
    fast = base.copy()
    _antialias(fs, o, R, calib, cfg, h, key, fast, covers, scovers, light, light_axes,
                      np.random.default_rng(2), T, vis)
    # reference: every sub-sample of every edge pixel traced; another object than the pixel's is shaded
    idx = _edge_pixels(key, h.t, H, W, LIGHT_CUTOFF + 0.3)
    offs = [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)]
    ref_sum = np.zeros((len(idx), 3), np.float32)
    rng = np.random.default_rng(3)
    for du, dv in offs:
        ps = pix[idx] + np.float32([du, dv])
        ds = _xf(_unit_dirs(calib, ps), R)
        hs = fs.trace(o, ds, ps, covers)
        sub = base[idx].copy()
        other = np.nonzero(_object_key(hs) != key[idx])[0]
        hh = _Hits(hs.t[other], hs.cls[other], hs.obj[other], hs.prim[other], hs.bary[other], hs.seed[other])
        sub[other] = _shade(fs, o, ds[other], hh, light, light_axes, cfg, rng, ps[other], scovers)
        ref_sum += sub
    ref = base.copy()
    ref[idx] = ref_sum / 4
    assert len(idx) > 5000
    assert not np.allclose(ref[idx], base[idx])  # anti-aliasing changes the edge pixels
    err = np.abs(fast[idx] - ref[idx]).mean()
    change = np.abs(ref[idx] - base[idx]).mean()
    # measured: err / change = 0.35 (part of it the reference's own random flash and shadow samples)
    assert err < 0.45 * change, (err, change)
    # about the same brightness on the edge pixels (seed rims are a little brighter: the reference's
    # shadow rays from mesh points on a grazing rim partly hit the seed's own triangles)
    # (measured +2.5 %)
    assert abs(fast[idx].mean() - ref[idx].mean()) < 0.04 * ref[idx].mean(), (fast[idx].mean(), ref[idx].mean())


def test_put_rows_and_integer_covers_equal_the_plain_numpy_forms():
    """The row scatter and the int32 difference-array covers used by the renderer give exactly what
    fancy assignment and painting every box pixel by pixel give."""
    rng = np.random.default_rng(7)
    for k in (2, 3):
        out = rng.random((500, k), np.float32)
        ref = out.copy()
        idx = rng.choice(500, 200, replace=False)
        rows = rng.random((k, 200), np.float32).T  # a transposed (non-contiguous) source, as in radiance
        ref[idx] = rows
        _put_rows(out, idx, rows)
        assert np.array_equal(out, ref)
    H, W = 60, 80
    boxes = np.column_stack([rng.uniform(-10, W, 40), rng.uniform(-10, H, 40), np.zeros(40), np.zeros(40)])
    boxes[:, 2] = boxes[:, 0] + rng.uniform(-2, 25, 40)  # some empty (u1 < u0), some past the border
    boxes[:, 3] = boxes[:, 1] + rng.uniform(0, 25, 40)
    cov = _cover_from_boxes(boxes, H, W)
    painted = np.zeros((H, W), bool)
    vv, uu = np.mgrid[0:H, 0:W]
    for u0, v0, u1, v1 in boxes:
        painted |= (uu >= u0) & (uu <= u1) & (vv >= v0) & (vv <= v1)
    got = np.zeros((H, W), bool)
    got[cov.r0:cov.r0 + cov.mask.shape[0], cov.c0:cov.c0 + cov.mask.shape[1]] = cov.mask
    assert np.array_equal(got, painted)
