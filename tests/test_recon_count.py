"""Seed counting (seedmap.recon.count): the ray-aware ``rays`` de-duplication on synthetic scans whose
per-view centres are precise across the viewing ray and noisy along it (like stereo), the countable
ground-truth reference, and ``seedmap count`` on a results folder."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from seedmap.io.seedmap_dataset import DatasetWriter, Instances
from seedmap.io.trajectory import write_tum
from seedmap.recon.config import CountConfig, ReconConfig
from seedmap.recon.count import count_seeds
from seedmap.recon.pipeline import gt_countable_seeds, recount
from seedmap.records import Trajectory

VIEWS = 24


def ring_scan(rng: np.random.Generator, lateral: float, depth: float, heavy_tail: float = 0.0):
    """Touching seeds (4 mm lattice) on a 12.7 mm cylinder around z; view v looks at it from angle
    2 pi v / 24 at 0.3 m and sees every seed whose outward normal faces it (a contiguous arc of
    views). Each observation = true centre + ``lateral`` noise across the ray + ``depth`` noise
    along it (+ a ``heavy_tail`` fraction of 5 mm depth outliers). Returns (centres, xyz, view, origin)."""
    k = np.arange(400)
    z = 0.004 * (k // 20)
    phi = (k % 20) * (2 * np.pi / 20) + 0.5 * (k // 20 % 2) * (2 * np.pi / 20)
    centres = np.column_stack([0.0127 * np.cos(phi), 0.0127 * np.sin(phi), z])
    normals = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(len(k))])
    xyz, view, origin = [], [], []
    for v in range(VIEWS):
        a = 2 * np.pi * v / VIEWS
        cam = np.array([0.3 * np.cos(a), 0.3 * np.sin(a), 0.02])
        ray = cam - centres
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        seen = np.flatnonzero(np.sum(normals * ray, axis=1) > 0.35)
        r = -ray[seen]  # camera -> seed
        e = rng.normal(0, lateral, (len(seen), 3))
        e -= np.sum(e * r, axis=1, keepdims=True) * r
        dz = rng.normal(0, depth, len(seen))
        dz[rng.random(len(seen)) < heavy_tail] = 0.005
        xyz.append(centres[seen] + e + dz[:, None] * r)
        view.append(np.full(len(seen), v))
        origin.append(np.repeat(cam[None], len(seen), 0))
    return centres, np.concatenate(xyz), np.concatenate(view), np.concatenate(origin)


def test_rays_counts_seeds_whose_depth_scatter_breaks_the_density_method():
    centres, xyz, view, origin = ring_scan(np.random.default_rng(0), lateral=0.00015, depth=0.001)
    d = np.full(len(xyz), 0.004)
    n_true = len(centres)
    rays = count_seeds(xyz, view, d, CountConfig(method="rays"), origin=origin)
    dens = count_seeds(xyz, view, d, CountConfig(method="density"))
    assert abs(rays.count - n_true) <= 0.05 * n_true
    assert abs(rays.count - n_true) < abs(dens.count - n_true)
    # one view never contributes two observations to one counted seed (cannot-link)
    a = rays.assignment
    kept = a >= 0
    pairs = np.column_stack([a[kept], view[kept]])
    assert len(np.unique(pairs, axis=0)) == kept.sum()
    # information-weighted positions: well inside a seed radius of the truth, better than the
    # stereo depth scatter of one observation
    dist, _ = cKDTree(centres).query(rays.xyz)
    assert np.median(dist) < 0.0005
    assert np.all(rays.n_views >= 2)


def test_rays_without_camera_centres_is_an_error_and_empty_input_counts_zero():
    centres, xyz, view, _ = ring_scan(np.random.default_rng(1), 0.0001, 0.0005)
    with pytest.raises(ValueError, match="origin"):
        count_seeds(xyz, view, np.full(len(xyz), 0.004), CountConfig(method="rays"))
    assert count_seeds(np.zeros((0, 3)), np.zeros(0), np.zeros(0), CountConfig(method="rays"), origin=np.zeros((0, 3))).count == 0


def test_rays_depth_outliers_do_not_create_seeds():
    # 10 % of the observations 5 mm too deep: they stay unlinked singletons instead of new seeds
    centres, xyz, view, origin = ring_scan(np.random.default_rng(2), 0.00015, 0.0008, heavy_tail=0.1)
    c = count_seeds(xyz, view, np.full(len(xyz), 0.004), CountConfig(method="rays"), origin=origin)
    assert abs(c.count - len(centres)) <= 0.05 * len(centres)


def test_countable_reference_needs_both_images_and_two_views(tmp_path):
    w = DatasetWriter(tmp_path)
    H, W = 8, 8
    # seed 1: big in left+right of views 0 and 1 -> countable; seed 2: left only -> not;
    # seed 3: both images but one view only -> not; seed 4: both images, 2 views, but 5 px -> not
    table = {0: {"left": [(1, 40), (2, 40), (3, 40), (4, 5)], "right": [(1, 40), (3, 40), (4, 5)]},
             1: {"left": [(1, 30), (2, 40), (4, 5)], "right": [(1, 30), (4, 5)]}}
    for v, cams in table.items():
        for cam, rows in cams.items():
            n = len(rows)
            inst = Instances(np.arange(1, n + 1, dtype=np.uint16), np.array([r[0] for r in rows], np.int64),
                             np.zeros(n, np.int64), np.zeros((n, 4)), np.zeros((n, 2)),
                             np.array([r[1] for r in rows], np.int64), np.ones(n, bool))
            w.write_gt_instances(v, cam, np.zeros((H, W), np.uint16), inst)
    w.write_times(np.arange(2, dtype=float))
    for v in range(2):
        w.write_frame(v, np.zeros((H, W, 3), np.uint8), np.zeros((H, W, 3), np.uint8))
    from seedmap.records import StereoCalib

    w.write_calib(StereoCalib(fx=10.0, fy=10.0, cx=4.0, cy=4.0, baseline=0.1, width=W, height=H))
    np.testing.assert_array_equal(gt_countable_seeds(tmp_path, 12), [1])
    np.testing.assert_array_equal(gt_countable_seeds(tmp_path, 3), [1, 4])


def test_recount_with_rays_reads_the_poses_of_the_results_folder(tmp_path):
    centres, xyz, view, origin = ring_scan(np.random.default_rng(3), 0.00015, 0.001)
    rows = np.column_stack([view, xyz, np.full(len(xyz), 0.004), np.full(len(xyz), -1), np.zeros(len(xyz))])
    np.savetxt(tmp_path / "observations.csv", rows, delimiter=",", fmt="%.9g",
               header="view,x,y,z,diameter_m,gt_seed_id,seed", comments="")
    poses = np.repeat(np.eye(4)[None], VIEWS, 0)
    for v in range(VIEWS):
        poses[v, :3, 3] = origin[view == v][0]
    write_tum(tmp_path / "poses_tum.txt", Trajectory(np.arange(VIEWS, dtype=float), poses))
    cfg = ReconConfig()
    cfg.count.method = "rays"
    direct = count_seeds(xyz, view, np.full(len(xyz), 0.004), cfg.count, origin=origin).count
    assert recount(tmp_path, cfg).count == direct
    (tmp_path / "poses_tum.txt").unlink()
    from seedmap.errors import InputError

    with pytest.raises(InputError, match="poses_tum.txt"):
        recount(tmp_path, cfg)
    cfg.count.method = "density"
    assert recount(tmp_path, cfg).count > 0


def test_merging_joins_a_seed_seen_from_two_separate_arcs_of_views():
    # no observations from views 3..7 (e.g. hidden by a leaf): seeds seen on both sides of the gap
    # give two groups that share no view; the group-level merge makes them one seed again
    centres, xyz, view, origin = ring_scan(np.random.default_rng(4), 0.00015, 0.001)
    keep = (view < 3) | (view > 7)
    xyz, view, origin = xyz[keep], view[keep], origin[keep]
    d = np.full(len(xyz), 0.004)
    n_seen = len(centres)
    split = count_seeds(xyz, view, d, CountConfig(method="rays", merge_passes=0), origin=origin).count
    merged = count_seeds(xyz, view, d, CountConfig(method="rays", merge_passes=1), origin=origin).count
    assert split - n_seen >= 10  # measured: 420 of 400
    assert abs(merged - n_seen) <= 4
