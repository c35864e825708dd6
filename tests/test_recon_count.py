"""Seed counting (seedmap.recon.count): the paper's ``density`` de-duplication on a synthetic scan whose
per-view centres are precise across the viewing ray and noisy along it (like stereo), the countable
ground-truth reference, and ``seedmap count`` on a results folder."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from seedmap.io.seedmap_dataset import DatasetWriter, Instances
from seedmap.recon.config import CountConfig, ReconConfig
from seedmap.recon.count import count_density
from seedmap.recon.pipeline import gt_countable_seeds, recount

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


def test_density_counts_a_ring_of_touching_seeds_and_empty_input_counts_zero():
    centres, xyz, view, _ = ring_scan(np.random.default_rng(1), 0.0001, 0.0003)
    cnt = count_density(xyz, view, np.full(len(xyz), 0.004), CountConfig(method="density"))
    assert abs(cnt.count - len(centres)) <= 0.1 * len(centres)
    assert np.median(cKDTree(centres).query(cnt.xyz)[0]) < 0.001
    assert count_density(np.zeros((0, 3)), np.zeros(0), np.zeros(0), CountConfig()).count == 0


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


def test_recount_with_density_reads_the_observations_of_the_results_folder(tmp_path):
    _, xyz, view, _ = ring_scan(np.random.default_rng(3), 0.00015, 0.001)
    rows = np.column_stack([view, xyz, np.full(len(xyz), 0.004), np.full(len(xyz), -1), np.zeros(len(xyz))])
    np.savetxt(tmp_path / "observations.csv", rows, delimiter=",", fmt="%.9g",
               header="view,x,y,z,diameter_m,gt_seed_id,seed", comments="")
    cfg = ReconConfig()
    cfg.count.method = "density"
    direct = count_density(xyz, view, np.full(len(xyz), 0.004), cfg.count).count
    assert direct > 0 and recount(tmp_path, cfg).count == direct
    cfg.count.method = "multiview"
    from seedmap.errors import InputError

    with pytest.raises(InputError, match="poses_tum.txt"):
        recount(tmp_path, cfg)
