"""Stereo-temporal loop (``stereo_carry``, an option of the SLAM association): stereo carried
through the left and right temporal matches, parallax test, loop check of the temporal matches."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.associate.semantic import (
    SeedMatcher,
    SemanticConfig,
    field_at,
    loo_local_median,
    loop_associate,
)
from seedmap.records import Matches
from seedmap.slam.config import SlamConfig
from seedmap.slam.synthetic import make_range, observe

LOOP = SlamConfig(association={"stereo_carry": True}).association  # field + constant velocity + loop


def _precision(m: Matches, ids_a: np.ndarray, ids_b: np.ndarray) -> float:
    return float(np.mean(ids_a[m.idx_a] == ids_b[m.idx_b]))


def _correct(m: Matches, ids_a: np.ndarray, ids_b: np.ndarray) -> int:
    return int(np.sum(ids_a[m.idx_a] == ids_b[m.idx_b]))


@pytest.fixture(scope="module")
def seq():
    rng = np.random.default_rng(11)
    rg = make_range(rng, length=0.24, seeds_per_panicle=300)
    return rg, [observe(rg, i, rng, noise_px=0.3, miss=0.05) for i in range(len(rg.gt))]


def test_loo_local_median_does_not_let_an_outlier_hide_in_its_own_median():
    pos = np.c_[np.arange(10.0), np.zeros(10)]
    val = np.zeros((10, 1))
    val[4] = 5.0
    med = loo_local_median(pos, val, 3)
    assert med[4, 0] == 0.0  # its neighbours say 0
    assert np.all(med[[0, 1, 2, 6, 7, 8, 9], 0] == 0.0)
    f = field_at(pos, np.c_[pos[:, 0] * 2.0, np.ones(10)], np.array([[2.2, 0.0]]), 3)
    assert np.allclose(f, [[4.0, 1.0]])


def test_the_loop_is_an_option_and_the_defaults_stay():
    assert LOOP.refine == "field" and LOOP.stereo_carry and LOOP.temporal_prediction
    assert not SemanticConfig().stereo_carry  # the paper's method does not carry
    s2 = SlamConfig().association  # the SLAM default stays the field association without the loop
    assert s2.refine == "field" and not s2.stereo_carry


def test_carried_stereo_is_used_and_checked_on_a_synthetic_sequence(seq):
    rg, dets = seq
    loop = SeedMatcher(rg.calib, cfg=LOOP)
    per_frame = SeedMatcher(rg.calib, cfg=LOOP.model_copy(update={"stereo_carry": False}))
    n_carried, corr_loop, corr_pf, wrong_loop = 0, 0, 0, 0
    for i, d in enumerate(dets):
        f = loop.features_from_detections(d)
        g = per_frame.features_from_detections(d)
        if i == 0:  # no history: the loop's first frame is the per-frame stereo
            assert np.array_equal(f.stereo.idx_a, g.stereo.idx_a) and np.array_equal(f.stereo.idx_b, g.stereo.idx_b)
            continue
        step = loop._loop[2]
        n_carried += len(step.carried)
        assert len(step.carried) > 0.3 * len(f.stereo)
        corr_loop += _correct(f.stereo, f.seed_ids_left, f.seed_ids_right)
        wrong_loop += len(f.stereo) - _correct(f.stereo, f.seed_ids_left, f.seed_ids_right)
        corr_pf += _correct(g.stereo, g.seed_ids_left, g.seed_ids_right)
    assert n_carried > 0
    assert corr_loop / (corr_loop + wrong_loop) >= 0.98
    assert corr_loop > 0.9 * corr_pf  # carrying keeps (nearly) every correct pair of the per-frame stereo


def test_match_temporal_returns_the_loop_checked_matches_and_falls_back_for_other_pairs(seq):
    rg, dets = seq
    m = SeedMatcher(rg.calib, cfg=LOOP)
    f0 = m.features_from_detections(dets[0])
    f1 = m.features_from_detections(dets[1])
    t = m.match_temporal(f0, f1)
    assert t is m._loop[2].temporal and len(t) > 100
    assert _precision(t, f0.seed_ids_left, f1.seed_ids_left) > 0.97
    f2 = m.features_from_detections(dets[2])
    t02 = m.match_temporal(f0, f2)  # not the loop's pair: matched directly
    assert t02 is not m._loop[2].temporal
    # a frame index that does not follow the last one starts a new sequence (per-frame stereo)
    again = m.features_from_detections(dets[0])
    fresh = SeedMatcher(rg.calib, cfg=LOOP).features_from_detections(dets[0])
    assert np.array_equal(again.stereo.idx_a, fresh.stereo.idx_a)
    assert np.array_equal(again.stereo.idx_b, fresh.stereo.idx_b)


def test_a_wrong_carried_partner_is_caught_by_the_parallax_test(seq):
    """Swap the right partners of neighbouring stereo pairs at t-1 (a consistent wrong disparity of a
    few px that the per-frame field cannot see); after a few frames of tracking the parallax test
    must have removed most of them."""
    rg, dets = seq
    calib = rg.calib
    k = [np.asarray(d.left.keypoints) for d in dets[:5]], [np.asarray(d.right.keypoints) for d in dets[:5]]
    ids_l, ids_r = dets[0].left.seed_ids, dets[0].right.seed_ids
    # perfect stereo at frame 0 from GT ids, then corrupt 10 % of the pairs by swapping right partners
    common, a, b = np.intersect1d(ids_l, ids_r, return_indices=True)
    rng = np.random.default_rng(0)
    bad = rng.choice(len(a), size=len(a) // 10, replace=False)
    b_bad = b.copy()
    from scipy.spatial import cKDTree

    _, nn = cKDTree(k[1][0][b]).query(k[1][0][b[bad]], 2)
    b_bad[bad] = b[nn[:, 1]]  # the nearest other right keypoint of a stereo pair
    _, uniq = np.unique(b_bad, return_index=True)
    cand = Matches(a[uniq], b_bad[uniq], np.zeros(len(uniq)))
    wrong0 = int(np.sum(ids_l[cand.idx_a] != ids_r[cand.idx_b]))
    assert wrong0 > 20
    track = None
    flow = None
    for t in range(1, 5):
        step = loop_associate(k[0][t - 1], k[1][t - 1], cand, k[0][t], k[1][t], calib.width, None, LOOP,
                              prev_track=track, prev_flow=flow)
        track, cand = step.track, step.candidates
        tm = step.temporal
        flow = (k[0][t][tm.idx_b], k[0][t][tm.idx_b] - k[0][t - 1][tm.idx_a])
    il, ir = dets[4].left.seed_ids, dets[4].right.seed_ids
    carried_wrong = int(np.sum(il[step.carried.idx_a] != ir[step.carried.idx_b]))
    assert carried_wrong < 0.2 * wrong0
    assert _precision(step.carried, il, ir) >= 0.98


def test_rendered_range_loop_is_more_precise_than_per_frame_field_stereo(tiny_range):
    """gt detector on the rendered tiny range: stereo precision of the loop >= 0.98 once tracks
    exist and above the per-frame field stereo over the sequence. (Since the gt oracle emits no
    keypoints for slivers, session 4, the loop's recall is no longer above the field's: 0.761 vs
    0.772 on this range; the loop's output waits for the parallax test.)"""
    from seedmap.eval.associate_metrics import evaluate_association

    loop = evaluate_association(tiny_range, detector="gt",
                                config=SlamConfig(association={"stereo_carry": True, "stereo_prior": "none"}),
                                progress=False)
    field = evaluate_association(tiny_range, detector="gt", config=SlamConfig(association={"stereo_prior": "none"}),
                                 progress=False)
    later = [r["stereo"] for r in loop.per_frame if r["frame"] >= 2]
    p_later = sum(s["correct"] for s in later) / sum(s["known"] for s in later)
    assert p_later >= 0.98
    assert loop.stereo["precision"] > field.stereo["precision"] + 0.01
    assert loop.stereo["recall"] > 0.8 * field.stereo["recall"]
    assert loop.temporal["precision"] >= field.temporal["precision"]
    assert loop.cpu_ms_per_frame["temporal_right"] > 0  # the right images were matched in time


def test_frame_output_keeps_the_per_frame_stereo_and_the_loop_checked_temporal(seq):
    rg, dets = seq
    cfg = LOOP.model_copy(update={"stereo_output": "frame"})
    m = SeedMatcher(rg.calib, cfg=cfg)
    ref = SeedMatcher(rg.calib, cfg=LOOP.model_copy(update={"stereo_carry": False}))
    prev = None
    for d in dets[:4]:
        f = m.features_from_detections(d)
        g = ref.features_from_detections(d)
        assert np.array_equal(f.stereo.idx_a, g.stereo.idx_a) and np.array_equal(f.stereo.idx_b, g.stereo.idx_b)
        if prev is not None:
            t = m.match_temporal(prev, f)
            assert t is m._loop[2].temporal
            assert len(m._loop[2].candidates) > 0.3 * len(f.stereo)  # the loop still runs internally
            assert _precision(t, prev.seed_ids_left, f.seed_ids_left) > 0.97
        prev = f
