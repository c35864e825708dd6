"""Ground truth of the simulator checked against geometry: masks, centres, disparity, wind, determinism.

Tiny renders only (scale 0.12-0.2, one panicle or a 0.3 m range) so the file runs in well under a minute.
"""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.geometry import invert, make_pose, tum_to_pose
from seedmap.io.seedmap_dataset import SeedmapDataset
from seedmap.sim import (
    SimConfig,
    build_panicle_world,
    build_range_world,
    range_length,
    render_stereo,
    right_pose,
    simulate_range,
)
from seedmap.sim.range import n_frames


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """T_world_cam of a camera at ``eye`` looking at ``target`` with image y pointing to world -z."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), eye)


def _silhouette(center, axes, radii, T_world_cam, calib):
    """Exact perspective outline of an ellipsoid (dual quadric projection): centre (u, v) and area (px^2)."""
    H = np.eye(4)
    H[:3, :3] = axes @ np.diag(radii)
    H[:3, 3] = center
    Qd = H @ np.diag([1.0, 1.0, 1.0, -1.0]) @ H.T
    P = calib.K @ invert(T_world_cam)[:3, :]
    Cd = P @ Qd @ P.T
    c = Cd[:2, 2] / Cd[2, 2]
    C = np.linalg.inv(Cd)
    C = C / -C[2, 2] if C[2, 2] < 0 else C
    A = C[:2, :2]
    area = np.pi * abs(np.linalg.det(C)) / np.linalg.det(A) ** 1.5
    return c, area


@pytest.fixture(scope="module")
def panicle_scene():
    cfg = SimConfig(seed=5, camera={"scale": 0.18}, panicle={"seeds_min": 1200, "seeds_max": 1500},
                    imaging={"supersample": 1})
    world = build_panicle_world(cfg, np.random.default_rng(5))
    calib = cfg.camera.calib()
    p = world.panicles[0]
    target = p.center.copy()
    # left camera 0.32 m away (seeds ~5 px across), the pair centred on the panicle
    eye = target + np.array([-cfg.camera.baseline / 2, -0.32, 0.0])
    T = _look_at(eye, target + np.array([-cfg.camera.baseline / 2, 0, 0]))
    r = render_stereo(world, T, calib, cfg, np.random.default_rng(0), t=0.7)
    return cfg, world, calib, T, r


@pytest.fixture(scope="module")
def small_range(tmp_path_factory):
    cfg = SimConfig(seed=11, world={"length": 0.3, "gap": 0.3}, camera={"scale": 0.13},
                    panicle={"seeds_min": 800, "seeds_max": 1200})
    out = simulate_range(cfg, tmp_path_factory.mktemp("sim") / "range", progress=False)
    return cfg, out


def test_masks_tables_and_centres_agree(panicle_scene):
    cfg, world, calib, T, r = panicle_scene
    for labels, inst in ((r.left_labels, r.left_instances), (r.right_labels, r.right_instances)):
        assert labels.dtype == np.uint16
        assert len(inst) > 300  # the panicle fills part of the view
        counts = np.bincount(labels.reshape(-1), minlength=len(inst) + 1)
        assert counts[0] > 0 and np.array_equal(counts[1:], inst.area)
        assert np.array_equal(inst.label, np.arange(1, len(inst) + 1))
        for k in range(0, len(inst), 7):
            rows, cols = np.nonzero(labels == inst.label[k])
            assert (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1) == tuple(inst.boxes[k].astype(int))
        # every centre that is visible projects inside its own mask (pixel [r, c] is (u=c, v=r))
        cv = inst.center_visible
        assert cv.sum() > 0.5 * len(inst)
        uv = np.floor(inst.center_uv[cv] + 0.5).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < calib.width) & (uv[:, 1] >= 0) & (uv[:, 1] < calib.height)
        assert inside.all()
        got = labels[uv[:, 1], uv[:, 0]]
        assert np.array_equal(got, inst.label[cv])


def test_centroids_match_exact_silhouettes_and_disparity(panicle_scene):
    cfg, world, calib, T, r = panicle_scene
    D = r.panicle_motion[0]
    T_r = right_pose(T, calib.baseline)
    li, ri = r.left_instances, r.right_instances
    common, il, ir = np.intersect1d(li.seed_id, ri.seed_id, return_indices=True)
    checked = 0
    errs, derrs = [], []
    for s, a, b in zip(common, il, ir, strict=True):
        c = D[:3, :3] @ world.seeds.xyz[s] + D[:3, 3]
        axes = D[:3, :3] @ world.seed_axes[s]
        rad = world.seeds.radii[s]
        (cl, al), (cr, ar) = _silhouette(c, axes, rad, T, calib), _silhouette(c, axes, rad, T_r, calib)
        # use only seeds seen whole in both views (mask area = silhouette area)
        if not (li.area[a] >= 0.92 * al and ri.area[b] >= 0.92 * ar and al >= 12):
            continue
        rows, cols = np.nonzero(r.left_labels == li.label[a])
        ul, vl = cols.mean(), rows.mean()
        rows_r, cols_r = np.nonzero(r.right_labels == ri.label[b])
        ur = cols_r.mean()
        errs.append(np.hypot(ul - cl[0], vl - cl[1]))
        z = (invert(T) @ np.append(c, 1.0))[2]
        derrs.append((ul - ur) - calib.disparity_of_depth(z))
        checked += 1
    assert checked >= 20
    assert np.max(np.abs(derrs)) <= 1.0
    assert np.median(np.abs(derrs)) < 0.3
    assert np.median(errs) < 0.3 and np.max(errs) < 1.0


def test_depth_image_matches_projection(panicle_scene):
    cfg, world, calib, T, r = panicle_scene
    inst = r.left_instances
    cv = np.nonzero(inst.center_visible)[0]
    D = r.panicle_motion[0]
    c = world.seeds.xyz[inst.seed_id[cv]] @ D[:3, :3].T + D[:3, 3]
    z = (c @ invert(T)[:3, :3].T + invert(T)[:3, 3])[:, 2]
    uv = np.floor(inst.center_uv[cv] + 0.5).astype(int)
    zd = r.left_depth[uv[:, 1], uv[:, 0]]
    # the surface seen at the centre pixel is the front of that seed: nearer than its centre by < 1 radius
    gap = z - zd
    assert np.all(gap > -1e-3) and np.all(gap < world.seeds.radii[inst.seed_id[cv]].max(axis=1) + 1e-3)


def test_wind_moves_panicles_rigidly():
    cfg = SimConfig(seed=2, world={"length": 0.5}, wind={"panicle_amplitude_deg": 2.0})
    world = build_range_world(cfg, np.random.default_rng(2))
    assert len(world.panicles) >= 2
    moved = []
    for t in (0.0, 0.4, 1.3, 2.9):
        D = world.panicle_motion(t)
        now = world.seed_centers_at(t)
        for k, p in enumerate(world.panicles):
            s = slice(p.seed_start, p.seed_stop)
            rest = world.seeds.xyz[s][:200]
            cur = now[s][:200]
            d0 = np.linalg.norm(rest[:, None] - rest[None], axis=2)
            d1 = np.linalg.norm(cur[:, None] - cur[None], axis=2)
            assert np.abs(d0 - d1).max() < 1e-9
            assert np.allclose(D[k, :3, :3] @ D[k, :3, :3].T, np.eye(3))
            assert np.allclose(D[k, :3, :3] @ p.base + D[k, :3, 3], p.base)  # pivot about the base
            moved.append(np.abs(cur - rest).max())
    assert max(moved) > 1e-3  # the wind does move seeds (mm) ...
    assert max(moved) < 0.02  # ... but only mildly


def test_range_dataset_reads_back(small_range):
    cfg, out = small_range
    ds = SeedmapDataset(out)
    assert len(ds) == n_frames(cfg) >= 5
    calib = cfg.camera.calib()
    assert ds.calib == calib
    fr = ds[0]
    assert fr.left.shape == (calib.height, calib.width, 3) and fr.left.dtype == np.uint8
    assert range_length(out) == pytest.approx(0.3)
    traj = ds.gt_trajectory()
    x = traj.positions[:, 0]
    assert x[0] == pytest.approx(0.0, abs=1e-9) and x[-1] == pytest.approx(0.3, abs=1e-9)
    assert np.all(np.diff(x) > 0)
    assert np.allclose(traj.positions[:, 1], -cfg.camera.standoff, atol=0.02)
    # camera looks along world +y with image y = world -z
    R = traj.poses[0][:3, :3]
    assert R[:, 2] @ [0, 1, 0] > 0.99 and R[:, 1] @ [0, 0, -1] > 0.99
    seeds = ds.gt_seeds()
    assert np.array_equal(seeds.seed_id, np.arange(len(seeds)))
    diam = 2 * seeds.radii.mean(axis=1)  # seeds are 3-5 mm
    assert 0.003 - 1e-6 <= diam.min() and diam.max() <= 0.005 + 1e-6
    # plants occupy x in [0, length]
    assert seeds.xyz[:, 0].min() > -0.1 and seeds.xyz[:, 0].max() < 0.4
    poses = ds.gt_panicle_poses()
    assert set(poses) == set(range(len(ds)))
    seen = 0
    for i in range(len(ds)):
        inst = ds.gt_instances(i, "left")
        lab = ds.gt_label_image(i, "left")
        assert lab.shape == (calib.height, calib.width) and lab.dtype == np.uint16
        if len(inst) == 0:
            continue
        seen += 1
        # the recorded centre is the projection of D(frame) * rest centre
        Tcw = invert(traj.poses[i])
        for k in range(0, len(inst), max(1, len(inst) // 20)):
            s = inst.seed_id[k]
            D = poses[i][int(inst.panicle_id[k])]
            c = D[:3, :3] @ seeds.xyz[s] + D[:3, 3]
            (uv,), _ = calib.project((Tcw[:3, :3] @ c + Tcw[:3, 3])[None])
            assert np.allclose(uv, inst.center_uv[k], atol=2e-3)
        cv = inst.center_visible
        uv = np.floor(inst.center_uv[cv] + 0.5).astype(int)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < calib.width) & (uv[:, 1] >= 0) & (uv[:, 1] < calib.height)
        assert np.array_equal(lab[uv[ok, 1], uv[ok, 0]], inst.label[cv][ok])
    assert seen >= 2
    assert (out / "gt" / "config.yaml").is_file()


def test_same_seed_same_data_other_seed_differs(tmp_path):
    def make(seed, name):
        cfg = SimConfig(seed=seed, world={"length": 0.12, "gap": 0.2}, camera={"scale": 0.08}, motion={"speed": 0.6},
                        panicle={"seeds_min": 300, "seeds_max": 400})
        return simulate_range(cfg, tmp_path / name, progress=False)

    a, b, c = make(4, "a"), make(4, "b"), make(5, "c")
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) > 10
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert (a / "left" / "000000.png").read_bytes() != (c / "left" / "000000.png").read_bytes()
    assert (a / "gt" / "seeds.csv").read_bytes() != (c / "gt" / "seeds.csv").read_bytes()


def test_panicle_world_layout():
    cfg = SimConfig(seed=3, panicle={"seeds_min": 1000, "seeds_max": 1000})
    world = build_panicle_world(cfg, np.random.default_rng(3))
    assert len(world.panicles) == 1 and len(world.leaf_vertices) == 0 and not world.has_soil
    p = world.panicles[0]
    assert np.allclose(p.base, 0) and np.allclose(p.axis, [0, 0, 1])
    xyz = world.seeds.xyz
    assert len(xyz) >= 950
    assert xyz[:, 2].min() > 0 and xyz[:, 2].max() < cfg.panicle.length_max * 1.3
    assert np.hypot(xyz[:, 0], xyz[:, 1]).max() < cfg.panicle.width_max
    # seeds do not interpenetrate much: nearest-neighbour distance ~ one diameter
    from scipy.spatial import cKDTree

    d, _ = cKDTree(xyz).query(xyz, k=2)
    assert np.median(d[:, 1] / (2 * world.seeds.radii.mean(axis=1))) > 0.9
    # panicle poses in a dataset use tum rows; the identity sway at rest round-trips
    assert np.allclose(tum_to_pose(np.array([[0, 0, 0, 0, 0, 0, 1.0]]))[0], np.eye(4))


def test_optional_effects_change_pixels_not_ground_truth():
    base = {"seed": 8, "camera": {"scale": 0.1}, "panicle": {"seeds_min": 400, "seeds_max": 500}}
    cfg0 = SimConfig(**base)
    world = build_panicle_world(cfg0, np.random.default_rng(8))
    T = _look_at(world.panicles[0].center + np.array([-0.055, -0.4, 0]),
                 world.panicles[0].center + np.array([-0.055, 0, 0]))
    calib = cfg0.camera.calib()
    plain = render_stereo(world, T, calib, cfg0, np.random.default_rng(1), t=0.0)
    for extra in ({"jpeg_quality": 40}, {"shadows": False}, {"supersample": 1}):
        cfg = SimConfig(**base, imaging=extra)
        r = render_stereo(world, T, calib, cfg, np.random.default_rng(1), t=0.0)
        assert r.left.shape == plain.left.shape and r.left.dtype == np.uint8
        assert not np.array_equal(r.left, plain.left), extra
        assert np.array_equal(r.left_labels, plain.left_labels)
        assert np.array_equal(r.right_instances.seed_id, plain.right_instances.seed_id)
    # the flash lights the panicle, the far background stays dark
    lab = plain.left_labels > 0
    assert plain.left[lab].mean() > 4 * max(plain.left[~lab].mean(), 1.0)
