"""refine="field" (the SLAM default): displacement-field prior, capped assignment, ratio test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from seedmap.associate import SemanticConfig, make_matcher, match_stereo_keypoints, match_temporal_keypoints
from seedmap.associate.assignment import assign_capped
from seedmap.associate.base import GateConfig
from seedmap.associate.field import box_pairs, coarse_field
from seedmap.eval.associate_metrics import score_matches, stereo_gate, temporal_gate
from seedmap.slam.config import SlamConfig
from seedmap.slam.synthetic import make_range, observe

W = 1434
FIELD = SemanticConfig(refine="field", temporal_prediction=True)


def _cloud(rng, n=400, centre=(700.0, 500.0), spread=(110.0, 220.0)):
    return np.c_[rng.normal(centre[0], spread[0], n), rng.normal(centre[1], spread[1], n)]


def test_box_pairs_equal_brute_force():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 100, (150, 2))
    b = rng.uniform(0, 100, (170, 2))
    half = np.array([6.0, 2.0])
    i, j = box_pairs(a, b, half)
    d = np.abs(b[None, :, :] - a[:, None, :])
    want = set(zip(*np.nonzero((d[..., 0] <= half[0]) & (d[..., 1] <= half[1])), strict=True))
    assert set(zip(i.tolist(), j.tolist(), strict=True)) == want


def _capped_reference(n, m, ia, ib, c, max_cost):
    """Dense LSA on the augmented (n + m) x (m + n) matrix: real pairs, one dummy per keypoint at
    max_cost / 2, dummy-dummy free. Returns the optimal objective."""
    big = 1e12
    top = np.full((n, m), big)
    top[ia, ib] = np.minimum(c, big)
    top[top >= max_cost] = big
    h = 0.5 * max_cost
    da = np.full((n, n), big)
    np.fill_diagonal(da, h)
    db = np.full((m, m), big)
    np.fill_diagonal(db, h)
    full = np.block([[top, da], [db, np.zeros((m, n))]])
    r, k = linear_sum_assignment(full)
    return full[r, k].sum()


def test_assign_capped_is_the_optimal_matching_with_an_unmatched_option():
    rng = np.random.default_rng(1)
    for _ in range(30):
        n, m = (int(x) for x in rng.integers(1, 14, 2))
        feas = rng.random((n, m)) < 0.3
        cost = rng.uniform(0, 300, (n, m))
        ia, ib = np.nonzero(feas)
        got = assign_capped(n, m, ia, ib, cost[ia, ib], 200.0)
        assert len(np.unique(got.idx_a)) == len(got) and len(np.unique(got.idx_b)) == len(got)
        assert np.all(feas[got.idx_a, got.idx_b]) and np.all(got.cost < 200.0)
        np.testing.assert_allclose(got.cost, cost[got.idx_a, got.idx_b])
        objective = got.cost.sum() + 100.0 * (n - len(got)) + 100.0 * (m - len(got))
        assert objective == pytest.approx(_capped_reference(n, m, ia, ib, cost[ia, ib], 200.0))


def test_capped_assignment_leaves_a_partnerless_keypoint_unmatched():
    # a0 -> b0 cheap; a1 has only b0 (taken) as candidate: the paper's gated Hungarian would force
    # a1 onto b0 and a0 elsewhere; the capped one keeps a0-b0 and leaves a1 unmatched
    ia, ib, c = np.array([0, 1, 0]), np.array([0, 0, 1]), np.array([10.0, 15.0, 150.0])
    got = assign_capped(2, 2, ia, ib, c, 100.0)
    assert list(zip(got.idx_a, got.idx_b, strict=True)) == [(0, 0)]


def test_coarse_field_finds_a_smooth_displacement_in_clutter():
    rng = np.random.default_rng(2)
    a = _cloud(rng, 600)
    disp = np.c_[-140.0 + 0.02 * (a[:, 1] - 500.0), np.zeros(len(a))]  # disparity varies with v
    b = np.vstack([a + disp + rng.normal(0, 0.3, a.shape), rng.uniform([0, 0], [W, 1050], (300, 2))])
    pred = coarse_field(a, b, np.array([-500.0, -4.0]), np.array([-17.0, 4.0]), 90.0, 1.0, 1500, (W, 1050.0))
    assert np.percentile(np.abs(pred[:, 0] - disp[:, 0]), 90) < 3.0


def test_field_matching_on_synthetic_panicles_is_precise():
    """Dense synthetic panicles (projected seeds, 0.3 px noise, 3 % misses per image): precision
    >= 0.98; recall counts GT pairs that pass the gates (front and back seeds of a panicle
    interleave in the image with different disparities, the ratio test drops those)."""
    rng = np.random.default_rng(3)
    rg = make_range(rng, length=0.3, seeds_per_panicle=300)
    d0, d1 = observe(rg, 2, rng), observe(rg, 3, rng)
    w, g = rg.calib.width, GateConfig()
    assert len(d1.left) > 1000
    kl, kr = d1.left.keypoints, d1.right.keypoints
    st = match_stereo_keypoints(kl, kr, w, None, FIELD)
    c = score_matches(st, d1.left.seed_ids, d1.right.seed_ids, kl, kr, stereo_gate(w, g))
    assert c.precision >= 0.98 and c.recall_gated >= 0.55
    k0 = d0.left.keypoints
    tm = match_temporal_keypoints(k0, kl, w, None, FIELD)
    c = score_matches(tm, d0.left.seed_ids, d1.left.seed_ids, k0, kl, temporal_gate(w, g))
    assert c.precision >= 0.98 and c.recall_gated >= 0.75


def test_field_matching_respects_the_gates():
    rng = np.random.default_rng(4)
    left = _cloud(rng)
    g = GateConfig().scaled(W)
    ok = match_stereo_keypoints(left, left + [-140.0, 0.0], W, None, FIELD)
    assert len(ok) > 0.7 * len(left) and np.mean(ok.idx_a == ok.idx_b) >= 0.99
    for shift in ([140.0, 0.0], [-5.0, 0.0], [-140.0, 30.0]):  # all true pairs violate a gate
        r = left + shift
        bad = match_stereo_keypoints(left, r, W, None, FIELD)
        assert not np.any(bad.idx_a == bad.idx_b)
        assert np.all(left[bad.idx_a, 0] - r[bad.idx_b, 0] >= g.stereo_min_disparity_px)
    moved = left + [52.0, 0.0]  # wrong travel direction
    wrong = match_temporal_keypoints(left, moved, W, None, FIELD)
    assert not np.any(wrong.idx_a == wrong.idx_b)
    right = match_temporal_keypoints(left, left + [-52.0, 1.0], W, None, FIELD, predicted_shift=-50.0)
    assert len(right) > 0.7 * len(left) and np.mean(right.idx_a == right.idx_b) >= 0.99


@pytest.mark.parametrize("n_a,n_b", [(0, 0), (0, 10), (10, 0)])
def test_field_empty_sets(n_a, n_b):
    rng = np.random.default_rng(5)
    a = _cloud(rng, n_a) if n_a else np.zeros((0, 2))
    b = _cloud(rng, n_b) if n_b else np.zeros((0, 2))
    assert len(match_stereo_keypoints(a, b, W, None, FIELD)) == 0
    assert len(match_temporal_keypoints(a, b, W, None, FIELD)) == 0


def test_slam_default_is_field_and_the_paper_method_stays_selectable():
    cfg = SlamConfig()
    assert cfg.association.refine == "field" and cfg.association.temporal_prediction
    paper = SlamConfig(association={"refine": "none", "temporal_prediction": False})
    rng = np.random.default_rng(6)
    rg = make_range(rng, length=0.2, seeds_per_panicle=60)
    for c in (cfg, paper):
        m = make_matcher("seeds", rg.calib, cfg=c)
        f0 = m.features_from_detections(observe(rg, 0, rng, noise_px=0.2, miss=0.0))
        f1 = m.features_from_detections(observe(rg, 1, rng, noise_px=0.2, miss=0.0))
        t = m.match_temporal(f0, f1)
        assert len(t) > 100
        assert np.mean(f0.seed_ids_left[t.idx_a] == f1.seed_ids_left[t.idx_b]) > 0.9
