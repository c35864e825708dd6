"""The fast paths of the association and the motion RANSAC must not change any result: each
fast path is checked against the straightforward computation it replaced (same pairs, same
medians bit for bit, same sums, same RANSAC inliers)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.associate.cost import neighbour_sums
from seedmap.associate.field import _median_rows, box_pairs, local_field, loo_local_median
from seedmap.records import Matches, StereoCalib
from seedmap.slam.motion import _translation_inliers, ransac_translation, stereo_reproj_error


def _kdtree_box_pairs(pa, pb, half):
    """The straightforward search: two KD-trees, max-norm sparse distance matrix."""
    h = np.maximum(np.asarray(half, np.float64), 1e-9)
    r = cKDTree(pa / h).sparse_distance_matrix(cKDTree(pb / h), 1.0, p=np.inf, output_type="ndarray")
    return set(zip(r["i"].tolist(), r["j"].tolist(), strict=True))


def test_box_pairs_match_the_kdtree_search_on_boundaries_duplicates_and_wide_boxes():
    rng = np.random.default_rng(1)
    grid = rng.integers(0, 40, (300, 2)).astype(float)  # many pairs exactly on the box boundary
    pts = rng.uniform(-50, 900, (400, 2))
    for pa, pb, half in ((grid, grid[::-1] + 0.0, [2.0, 1.0]), (grid, grid, [0.5, 0.5]),
                         (pts, pts[:250] + [30.0, 1.0], [262.0, 4.2]), (pts, pts * 1.01, [3.0, 7.0]),
                         (pts[:1], pts, [1e4, 1e4])):
        i, j = box_pairs(pa, pb, np.array(half))
        assert np.all(np.diff(i) >= 0)  # grouped by i
        got = set(zip(i.tolist(), j.tolist(), strict=True))
        assert len(got) == len(i)  # no pair twice
        assert got == _kdtree_box_pairs(pa, pb, np.array(half))


def test_median_rows_is_np_median_bit_for_bit():
    rng = np.random.default_rng(2)
    for k in (1, 2, 11, 12, 25):
        v = rng.normal(size=(3, 50, k)) * 10 ** rng.uniform(-3, 3, (3, 50, 1))
        assert np.array_equal(_median_rows(v), np.median(v, axis=-1))
    v = rng.normal(size=(20, 12))
    v[3, 4] = np.nan
    assert np.array_equal(_median_rows(v), np.median(v, axis=-1), equal_nan=True)


def test_loo_local_median_and_local_field_match_the_direct_computation():
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, 300, (500, 2))
    pos[10] = pos[11]  # a repeated position: the KD-tree decides which point is dropped
    val = rng.normal(size=(500, 2))
    k = 9
    got = loo_local_median(pos, val, k)
    _, nn = cKDTree(pos).query(pos, k + 1)
    for p in range(500):
        others = [q for q in nn[p] if q != p][:k] if p in nn[p] else list(nn[p][:k])
        assert np.array_equal(got[p], np.median(val[others], axis=0))
    # local_field: every keypoint takes the field of its nearest seed match
    ka = rng.uniform(0, 300, (800, 2))
    sel = rng.choice(800, 300, replace=False)
    kb = ka + [5.0, 0.5] + rng.normal(0, 0.3, (800, 2))
    m = Matches(sel, sel, np.zeros(300))
    f = local_field(ka, m, kb, k, np.zeros((800, 2)))
    at_seed = loo_local_median(ka[sel], kb[sel] - ka[sel], k)
    _, near = cKDTree(ka[sel]).query(ka, 1)
    assert np.array_equal(f, at_seed[near])


def test_neighbour_sums_match_brute_force():
    rng = np.random.default_rng(4)
    kp = np.r_[rng.uniform(0, 400, (300, 2)), rng.integers(0, 60, (100, 2)).astype(float)]
    valid = rng.random(len(kp)) > 0.3
    for v in (None, valid):
        got = neighbour_sums(kp, 120.0, 6.0, v)
        ok = np.ones(len(kp), bool) if v is None else v
        d = kp[None, :, :] - kp[:, None, :]  # d[p, q] = q - p
        dist = np.hypot(d[..., 0], d[..., 1])
        for col, (along, band, sign) in enumerate(((0, 1, -1), (0, 1, 1), (1, 0, -1), (1, 0, 1))):
            inset = (sign * d[..., along] > 0) & (np.abs(d[..., along]) < 120.0) & (np.abs(d[..., band]) < 6.0)
            want = np.where(inset & ok[None, :], dist, 0.0).sum(1)
            np.testing.assert_allclose(got[:, col], want, rtol=1e-12, atol=1e-9)


def test_translation_inliers_equal_the_reprojection_error_test():
    calib = StereoCalib(fx=800.0, fy=800.0, cx=700.0, cy=500.0, baseline=0.12, width=1434, height=1000)
    rng = np.random.default_rng(5)
    pc = np.c_[rng.uniform(-0.4, 0.4, 400), rng.uniform(-0.3, 0.3, 400), rng.uniform(0.4, 1.2, 400)]
    t_true = np.array([0.02, -0.001, 0.003])
    pp = pc + t_true
    z = pc[:, 2]
    obs = np.c_[800 * pc[:, 0] / z + 700, 800 * pc[:, 0] / z + 700 - 800 * 0.12 / z, 800 * pc[:, 1] / z + 500]
    obs += rng.normal(0, 0.8, obs.shape)
    obs[:60] += rng.uniform(-40, 40, (60, 3))  # wrong matches
    t = pp[rng.choice(400, 50, replace=False)] - pc[rng.choice(400, 50, replace=False)]
    t[0] = [0.0, 0.0, 5.0]  # every point behind the camera
    want = stereo_reproj_error(calib, pp[None] - t[:, None, :], obs[None]) < 3.0
    assert np.array_equal(_translation_inliers(calib, pp, t, obs, 3.0), want)
    assert not want[0].any()
    est = ransac_translation(calib, pp, pc, obs, np.random.default_rng(0), 100, 3.0)
    assert np.abs(est.T_prev_cur[:3, 3] - t_true).max() < 2e-3
    assert est.inliers[60:].mean() > 0.9 and est.inliers[:60].mean() < 0.2
