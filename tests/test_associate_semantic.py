"""Semantic seed association: the paper's cost, gating and assignment on synthetic keypoints."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from seedmap.associate import (
    GATED,
    SemanticConfig,
    assign_sparse,
    available_matchers,
    make_matcher,
    match_stereo_keypoints,
    match_temporal_keypoints,
    neighbour_sums,
    pair_cost,
)
from seedmap.associate.base import GateConfig
from seedmap.errors import SeedmapError
from seedmap.slam.synthetic import default_calib, make_range, observe

W = 1434


def _cluster(rng, n=150, centre=(700.0, 500.0), spread=(120.0, 250.0)):
    return np.c_[rng.normal(centre[0], spread[0], n), rng.normal(centre[1], spread[1], n)]


def _brute_sums(kp, delta, eps):
    out = np.zeros((len(kp), 4))
    for i, p in enumerate(kp):
        for q in kp:
            d = float(np.hypot(*(q - p)))
            if 0 < p[0] - q[0] < delta and abs(q[1] - p[1]) < eps:
                out[i, 0] += d
            if 0 < q[0] - p[0] < delta and abs(q[1] - p[1]) < eps:
                out[i, 1] += d
            if 0 < p[1] - q[1] < delta and abs(q[0] - p[0]) < eps:
                out[i, 2] += d
            if 0 < q[1] - p[1] < delta and abs(q[0] - p[0]) < eps:
                out[i, 3] += d
    return out


def test_neighbour_sums_match_the_definition():
    rng = np.random.default_rng(0)
    kp = np.c_[rng.uniform(0, 300, 120), rng.uniform(0, 200, 120)]
    np.testing.assert_allclose(neighbour_sums(kp, 150.0, 12.0), _brute_sums(kp, 150.0, 12.0), atol=1e-9)


def test_self_pairing_is_minimal_under_a_pure_horizontal_shift():
    rng = np.random.default_rng(1)
    a = _cluster(rng)
    b = a + [-52.0, 0.0]
    cfg = SemanticConfig()
    sa = neighbour_sums(a, cfg.delta_px, cfg.eps_px)
    sb = neighbour_sums(b, cfg.delta_px, cfg.eps_px)
    c = pair_cost(a, b, sa, sb, cfg)
    assert np.all(np.argmin(c, axis=1) == np.arange(len(a)))
    # with identical neighbour sums each ratio is S / (S + 0.01) <= 1, so cost <= 4 r
    assert np.all(np.diag(c) <= 4 * cfg.r + 1e-9)


def test_temporal_matching_recovers_a_shifted_cluster_and_rejects_the_wrong_direction():
    rng = np.random.default_rng(2)
    a = _cluster(rng)
    b = a + [-52.0, 1.5] + rng.normal(0, 0.2, a.shape)
    m = match_temporal_keypoints(a, b, W)
    assert len(m) > 0.8 * len(a)
    assert np.mean(m.idx_a == m.idx_b) >= 0.99
    moved = a + [52.0, 0.0]  # every seed moved the wrong way: its true partner is gated out
    wrong = match_temporal_keypoints(a, moved, W)
    assert not np.any(wrong.idx_a == wrong.idx_b)
    g = GateConfig().scaled(W)
    assert np.all(g.travel_sign * (moved[wrong.idx_b, 0] - a[wrong.idx_a, 0]) >= g.temporal_min_shift_px)


def test_stereo_gates():
    rng = np.random.default_rng(3)
    left = _cluster(rng)
    right = left + [-140.0, 0.0]
    m = match_stereo_keypoints(left, right, W)
    assert len(m) > 0.8 * len(left) and np.mean(m.idx_a == m.idx_b) >= 0.99
    g = GateConfig().scaled(W)
    # negative disparity, disparity below the minimum, rows too far apart: true pairs are gated out
    for shift in ([140.0, 0.0], [-5.0, 0.0], [-140.0, 30.0]):
        r = left + shift
        bad = match_stereo_keypoints(left, r, W)
        assert not np.any(bad.idx_a == bad.idx_b)
        assert np.all(left[bad.idx_a, 0] - r[bad.idx_b, 0] >= g.stereo_min_disparity_px)
        assert np.all(np.abs(left[bad.idx_a, 1] - r[bad.idx_b, 1]) <= g.stereo_max_dy_px)
    ok = match_stereo_keypoints(left, right, W)
    kl = left[ok.idx_a]
    assert np.all((kl[:, 0] >= g.stereo_border_px) & (kl[:, 0] <= W - 1 - g.stereo_border_px))


@pytest.mark.parametrize("n_a,n_b", [(0, 0), (0, 10), (10, 0)])
def test_empty_keypoint_sets_give_no_matches(n_a, n_b):
    rng = np.random.default_rng(4)
    a = _cluster(rng, n_a) if n_a else np.zeros((0, 2))
    b = _cluster(rng, n_b) if n_b else np.zeros((0, 2))
    assert len(match_stereo_keypoints(a, b, W)) == 0
    assert len(match_temporal_keypoints(a, b, W)) == 0


def test_many_more_keypoints_in_one_image():
    rng = np.random.default_rng(5)
    a = _cluster(rng, 120)
    distract = np.c_[rng.uniform(200, 1200, 600), rng.uniform(900, 1040, 600)]  # far below the cluster
    b = np.vstack([a + [-50.0, 0.0], distract])
    perm = rng.permutation(len(b))
    m = match_temporal_keypoints(a, b[perm], W)
    assert len(m) > 0.7 * len(a)
    assert np.mean(perm[m.idx_b] == m.idx_a) >= 0.97


def test_sparse_assignment_equals_dense_gated_lsa():
    rng = np.random.default_rng(6)
    for _ in range(20):
        n, m = rng.integers(1, 25, 2)
        feas = rng.random((n, m)) < 0.2
        cost = rng.uniform(0, 300, (n, m))
        ia, ib = np.nonzero(feas)
        got = assign_sparse(n, m, ia, ib, cost[ia, ib], max_cost=200.0)
        dense = np.where(feas, cost, GATED)
        r, c = linear_sum_assignment(dense)
        keep = feas[r, c] & (dense[r, c] <= 200.0)
        # same number of feasible assignments and same total cost of the kept pairs' optimum
        n_feas = int(feas[r, c].sum())
        got_all = assign_sparse(n, m, ia, ib, cost[ia, ib], max_cost=np.inf)
        assert len(got_all) == n_feas
        assert np.isclose(got_all.cost.sum(), dense[r, c][feas[r, c]].sum())
        assert np.all(got.cost <= 200.0) and len(got) <= len(got_all)
        assert len(got) >= 0 and keep.sum() >= 0


def test_seed_matcher_on_synthetic_panicles():
    rng = np.random.default_rng(7)
    rg = make_range(rng, length=0.2, seeds_per_panicle=60)
    m = make_matcher("seeds", rg.calib)
    f0 = m.features_from_detections(observe(rg, 0, rng, noise_px=0.2, miss=0.0))
    f1 = m.features_from_detections(observe(rg, 1, rng, noise_px=0.2, miss=0.0))
    st = f1.stereo
    assert len(st) > 100
    assert np.mean(f1.seed_ids_left[st.idx_a] == f1.seed_ids_right[st.idx_b]) > 0.9
    t = m.match_temporal(f0, f1)
    assert len(t) > 100
    assert np.mean(f0.seed_ids_left[t.idx_a] == f1.seed_ids_left[t.idx_b]) > 0.9


def test_make_matcher_names():
    calib = default_calib()
    assert "seeds" in available_matchers()
    with pytest.raises(SeedmapError):
        make_matcher("nonsense", calib)
    with pytest.raises(SeedmapError):
        make_matcher("seeds", calib).features(None)  # no detector -> clear error, not a traceback


def test_every_refine_value_has_a_method_and_the_matcher_picks_it_once():
    from typing import get_args

    from seedmap.associate import METHODS, SeedMatcher
    from seedmap.errors import ConfigError

    assert set(get_args(SemanticConfig.model_fields["refine"].annotation)) == set(METHODS)
    for name, method in METHODS.items():
        assert SeedMatcher(default_calib(), cfg=SemanticConfig(refine=name))._method is method
    with pytest.raises((ConfigError, ValueError)):
        SemanticConfig(refine="consensus")
