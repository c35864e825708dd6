"""Session 9: stereo cues from the previous frame (``stereo_history=True``): the history prior
(seedmap.associate.semantic.history_prior), the candidates and cues (history_cue_candidates), the
stereo_history ScoreModel kind, the shipped weights and the matcher path (the temporal matches are
computed before the stereo matching and reused by match_temporal)."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.associate.base import GateConfig
from seedmap.associate.semantic import (
    CUE_NAMES,
    HISTORY_CUE_NAMES,
    ScoreModel,
    SeedMatcher,
    StereoCues,
    StereoHistory,
    history_cue_candidates,
    history_prior,
    history_prior_assign,
    image_cues,
    score_model,
    stereo_cue_candidates,
)
from seedmap.errors import ConfigError, SeedmapError
from seedmap.records import Matches, StereoCalib
from seedmap.slam.config import SlamConfig

W, H = 1434, 240
D0 = 60.0


def _cfg(**kw):
    return SlamConfig().association.model_copy(update={"stereo_prior": "sgbm", "prior_score": "mlp",
                                                       "temporal_score": "mlp", "stereo_history": True, **kw})


def _plane(seed: int):
    """A textured RGB plane at disparity D0, keypoints ~8 px apart (jittered); right = left - D0."""
    import cv2

    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.integers(0, 256, (H, W + int(D0)), dtype=np.uint8), (3, 3), 0)
    tex = np.stack([g, (0.8 * g).astype(np.uint8), (0.5 * g).astype(np.uint8)], 2)
    left, right = np.ascontiguousarray(tex[:, :W]), np.ascontiguousarray(tex[:, int(D0): int(D0) + W])
    uu, vv = np.meshgrid(np.arange(120, W - 120, 8.0), np.arange(20, H - 20, 8.0))
    kl = np.c_[uu.ravel(), vv.ravel()] + rng.uniform(-2, 2, (uu.size, 2))
    return left, right, kl, kl - [D0, 0.0]


def _scene(seed: int):
    left, right, kl, kr = _plane(seed)
    ell = np.c_[kl, np.full(len(kl), 5.0), np.full(len(kl), 4.0), np.zeros(len(kl))]
    cues = StereoCues(image_cues(left, kl, ell, W, 31.4), image_cues(right, kr, ell, W, 31.4),
                      np.full((H, W), D0, np.float32))
    n = len(kl)
    ident = Matches(np.arange(n), np.arange(n), np.zeros(n))
    # frame t-1 = the same view (a static camera): stereo and temporal matches are the identity
    hist = StereoHistory(kl, kr, ident, ident, cues.right)
    return kl, kr, cues, hist


def test_history_prior_follows_the_track_and_the_local_disparity_change():
    kl, kr, cues, hist = _scene(1)
    n = len(kl)
    disp = np.full(n, D0 + 1.5)  # the whole frame's dense disparity moved by 1.5 px since t-1
    disp[::5] = D0 + 20.0  # ... and is wrong on every fifth keypoint
    prev_right, d_hist, v_hist, dev = history_prior(kl, hist, disp, W, 25)
    assert np.array_equal(prev_right, np.arange(n))
    assert np.allclose(d_hist, D0 + 1.5) and np.allclose(v_hist, 0.0)
    assert np.allclose(dev[::5], 18.5) and np.allclose(np.delete(dev, np.s_[::5]), 0.0)
    # an untracked keypoint (no temporal match) has no history
    h2 = StereoHistory(kl, kr, hist.stereo, Matches(np.arange(1, n), np.arange(1, n), np.zeros(n - 1)), hist.right)
    pr2, d2, _, _ = history_prior(kl, h2, disp, W, 25)
    assert pr2[0] == -1 and np.isnan(d2[0]) and (pr2[1:] >= 0).all()


def test_history_window_and_cues_recover_a_seed_whose_dense_disparity_is_wrong():
    kl, kr, cues, hist = _scene(2)
    n = len(kl)
    cfg = _cfg()
    disp = np.full(n, D0)
    bad = np.arange(3, n, 7)
    disp[bad] = D0 + 14.0  # the occluder's disparity: the true partner is 7 sigma off the dense prior
    ia, ib, x = history_cue_candidates(kl, kr, W, GateConfig(), cfg, disp, cues, hist)
    assert x.shape == (len(ia), len(CUE_NAMES) + len(HISTORY_CUE_NAMES))
    col = {k: x[:, j] for j, k in enumerate(CUE_NAMES + HISTORY_CUE_NAMES)}
    true = ia == ib
    inside = bad[(kr[bad, 0] >= 75) & (kl[bad, 0] <= W - 75)]  # the stereo border gates (70 px at 1434 px)
    assert len(inside) > 50 and set(ia[true]) >= set(inside)  # the true partners are candidates (history window)
    assert (col["has_history"] == 1).all()
    for c in ("hist_u_res", "hist_v_res", "hist_ncc_right", "hist_ncc_right_large"):
        assert np.abs(col[c][true]).max() < 1e-3, c
    # without a history the candidates are those of the dense prior and the history cues sit at their caps
    ja, jb, x0 = history_cue_candidates(kl, kr, W, GateConfig(), cfg, disp, cues, None)
    assert (x0[:, len(CUE_NAMES)] == 0).all() and not set(ja[ja == jb]) & set(inside)


def test_without_a_history_the_candidates_and_cues_are_those_of_the_mlp_stereo_score():
    """The two learned stereo scores share one setup (dense-prior candidates, 17 cues): without a
    history the stereo_history candidates are the session-7 ones bit for bit, the history cues at
    their caps."""
    kl, kr, cues, _ = _scene(4)
    disp = np.full(len(kl), D0)
    disp[::6] = np.nan  # unknown disparities take their neighbours' (wider spread)
    disp[1::9] = D0 + 9.0
    cfg = _cfg()
    ia, ib, x = stereo_cue_candidates(kl, kr, W, GateConfig(), cfg, disp, cues)
    ja, jb, y = history_cue_candidates(kl, kr, W, GateConfig(), cfg, disp, cues, None)
    assert len(ia) > len(kl) and np.array_equal(ia, ja) and np.array_equal(ib, jb)
    nc = len(CUE_NAMES)
    assert np.array_equal(x, y[:, :nc])
    assert np.array_equal(y[:, nc:], np.tile([0.0, 4.0, 4.0, 1.0, 1.0, 4.0], (len(ja), 1)))
    none = np.full(len(kl), np.nan)  # too few known disparities: neither scores anything
    assert stereo_cue_candidates(kl, kr, W, GateConfig(), cfg, none, cues)[2].shape == (0, nc)
    assert history_cue_candidates(kl, kr, W, GateConfig(), cfg, none, cues, None)[2].shape == (
        0, nc + len(HISTORY_CUE_NAMES))


def test_shipped_history_model_ranks_the_true_partner_first_where_the_dense_prior_is_wrong():
    kl, kr, cues, hist = _scene(3)
    n = len(kl)
    cfg = _cfg()
    disp = np.full(n, D0)
    bad = np.arange(3, n, 7)
    disp[bad] = D0 + 8.0  # points at a neighbour's partner (keypoints ~8 px apart)
    ia, ib, x = history_cue_candidates(kl, kr, W, GateConfig(), cfg, disp, cues, hist)
    t = score_model(cfg.history_score_model, "stereo_history").logits(x)
    order = np.lexsort((-t, ia))
    first = np.r_[True, ia[order][1:] != ia[order][:-1]]
    best = np.full(n, -1)
    best[ia[order][first]] = ib[order][first]
    bad = bad[(kr[bad, 0] >= 75) & (kl[bad, 0] <= W - 75)]  # inside the stereo border gates
    assert (best[bad] == bad).mean() >= 0.95
    m = history_prior_assign(kl, kr, W, GateConfig(), cfg, disp, cues, hist)
    assert len(m) >= 0.85 * n and np.array_equal(m.idx_a, m.idx_b)
    assert np.isin(bad, m.idx_a).mean() >= 0.9


def test_history_model_kind_round_trips_and_is_checked(tmp_path):
    rng = np.random.default_rng(0)
    feats = ("u_res2", "ncc", "has_history", "hist_u_res")
    mdl = ScoreModel(feats, np.zeros(4), np.ones(4), [(rng.normal(size=(3, 4)), rng.normal(size=3)),
                                                      (rng.normal(size=(1, 3)), rng.normal(size=1))], {},
                     "stereo_history")
    p = tmp_path / "h.json"
    mdl.save(p)
    back = ScoreModel.load(str(p))
    x = rng.normal(size=(6, len(CUE_NAMES) + len(HISTORY_CUE_NAMES)))
    assert back.kind == "stereo_history" and np.allclose(back.logits(x), mdl.logits(x))
    with pytest.raises(SeedmapError, match="stereo_history association score model, but a stereo"):
        score_model(str(p), "stereo")
    # the session-7 stereo weights still load and read the first 17 columns only
    s7 = score_model("stereo_score_s7.json")
    assert s7.kind == "stereo" and np.allclose(s7.logits(x[:, :len(CUE_NAMES)]), s7.logits(x))


def test_shipped_history_model_is_finite_and_never_saw_the_evaluation_ranges():
    mdl = score_model(_cfg().history_score_model, "stereo_history")
    assert set(HISTORY_CUE_NAMES) <= set(mdl.features) and len(mdl.layers) >= 2
    assert all(np.isfinite(w).all() and np.isfinite(b).all() for w, b in mdl.layers)
    for s in (13, 14, 15, 25, 26, 27, 28):
        assert f"assoc_s{s}" not in str(mdl.info)


def test_defaults_unchanged_and_incompatible_settings_refused():
    cfg = SlamConfig().association
    assert cfg.stereo_history is False and cfg.score_model == "stereo_score_s7.json"
    calib = StereoCalib(width=W, height=600, fx=900.0, fy=900.0, cx=W / 2, cy=300.0, baseline=0.11)
    SeedMatcher(calib, cfg=_cfg())
    for bad in ({"temporal_score": "field"}, {"prior_score": "learned"}, {"stereo_prior": "none"}):
        with pytest.raises(ConfigError, match="stereo_history needs"):
            SeedMatcher(calib, cfg=_cfg(**bad))


@pytest.mark.slow
def test_stereo_history_on_the_rendered_range(tiny_range):
    """gt detector on the rendered tiny range (819 px, a width the networks were not fitted at): with
    the option on, match_temporal returns the temporal matches computed before the stereo matching,
    which are what the temporal network gives those frames afterwards, and the stereo matches are
    about as precise and at least as many as the session-7 network's."""
    from seedmap.eval.associate_metrics import evaluate_association
    from seedmap.io import open_dataset
    from seedmap.slam.pipeline import _detector_for

    base = {"stereo_prior": "sgbm", "prior_score": "mlp", "temporal_score": "mlp"}
    cfg = SlamConfig(association={**base, "stereo_history": True})
    ds = open_dataset(tiny_range)
    sm = SeedMatcher(ds.calib, detector=_detector_for("gt", tiny_range, cfg.detect), cfg=cfg.association,
                     gates=cfg.gates)
    prev = None
    for i in range(4):
        f = sm.features(ds[i])
        if prev is not None:
            early = sm._early_temporal
            assert early is not None and early[0] is prev and early[1] == f.index
            ia, ib, x = sm.temporal_candidates(prev, f)
            again = sm._temporal_assign(ia, ib, x, len(prev.kp_left), len(f.kp_left))
            m = sm.match_temporal(prev, f)
            assert m is early[2] and len(m) > 50
            assert np.array_equal(m.idx_a, again.idx_a) and np.array_equal(m.idx_b, again.idx_b)
        prev = f
    old = evaluate_association(tiny_range, detector="gt", progress=False, config=SlamConfig(association=base))
    new = evaluate_association(tiny_range, detector="gt", progress=False, config=cfg)
    print("tiny range stereo P/R: mlp", old.stereo["precision"], old.stereo["recall"], "history",
          new.stereo["precision"], new.stereo["recall"])
    assert new.stereo["precision"] >= old.stereo["precision"] - 0.005
    assert new.stereo["correct"] >= old.stereo["correct"]
    assert new.temporal["correct"] >= 0.99 * old.temporal["correct"]
