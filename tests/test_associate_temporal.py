"""Session 8: the learned temporal candidate score (``temporal_score="mlp"``): its cues
(seedmap.associate.semantic.temporal_cue_candidates), the temporal ScoreModel kind, the shipped
weights and the matcher path (SeedMatcher.match_temporal)."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.associate.base import GateConfig
from seedmap.associate.semantic import (
    CUE_NAMES,
    TEMPORAL_CUE_NAMES,
    ScoreModel,
    TemporalInputs,
    image_cues,
    mlp_temporal_assign,
    score_model,
    temporal_cue_candidates,
)
from seedmap.errors import SeedmapError
from seedmap.slam.config import SlamConfig

W, H = 1434, 240
SHIFT = -40.0  # u_cur - u_prev of a static seed at disparity D0 (travel_sign -1: points slide left)
D0 = 60.0


def _cfg(**kw):
    return SlamConfig().association.model_copy(update={"temporal_score": "mlp", **kw})


def _texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    import cv2

    g = cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (3, 3), 0)
    return np.stack([g, (0.8 * g).astype(np.uint8), (0.5 * g).astype(np.uint8)], 2)


def _shifted_frames(seed: int, depth_step: float = 0.0):
    """Two consecutive left views of a textured plane moving by SHIFT px, keypoints ~8 px apart
    (jittered); every fourth keypoint column may lie nearer (disparity D0 + depth_step), so it
    shifts by SHIFT * (D0 + depth_step) / D0 (a static point's shift is proportional to its
    disparity under a translation along the rows). Returns images, keypoints, disparities."""
    rng = np.random.default_rng(seed)
    tex = _texture(rng, H, W + 80)
    prev = np.ascontiguousarray(tex[:, :W])
    cur = np.ascontiguousarray(tex[:, -int(SHIFT): W - int(SHIFT)])  # cur(x) = prev(x - SHIFT)
    uu, vv = np.meshgrid(np.arange(140, W - 140, 8.0), np.arange(20, H - 20, 8.0))
    ka = np.c_[uu.ravel(), vv.ravel()] + rng.uniform(-2, 2, (uu.size, 2))
    da = np.full(len(ka), D0)
    near = (np.round((uu.ravel() - 140) / 8).astype(int) % 4) == 1
    da[near] += depth_step
    kb = ka + np.c_[SHIFT * da / D0, np.zeros(len(ka))]
    return prev, cur, ka, kb, da


def _inputs(img, kp, d):
    ell = np.c_[kp, np.full(len(kp), 5.0), np.full(len(kp), 4.0), np.zeros(len(kp))]
    return TemporalInputs(image_cues(img, kp, ell, W, 31.4), np.asarray(d, np.float64))


def test_temporal_cues_of_true_pairs_on_a_shifted_plane():
    prev, cur, ka, kb, da = _shifted_frames(1)
    ia, ib, x = temporal_cue_candidates(ka, kb, W, GateConfig(), _cfg(), _inputs(prev, ka, da), _inputs(cur, kb, da))
    assert x.shape == (len(ia), len(TEMPORAL_CUE_NAMES)) and np.isfinite(x).all()
    true = ia == ib
    assert true.sum() >= 0.95 * len(ka)  # the window around the field holds the true partners
    col = {n: x[:, k] for k, n in enumerate(TEMPORAL_CUE_NAMES)}
    for n in ("u_res", "v_res", "parallax_res", "ncc", "ncc_small", "ncc_colour", "chroma", "brightness", "area_ratio",
              "disp_change", "disp_dev"):
        assert np.abs(col[n][true]).max() < 0.05, n
    # a wrong candidate is a neighbour ~8 px away: far in residual, unlike in appearance
    assert (col["u_res"][~true] > 2.0).mean() > 0.9 or (col["v_res"][~true] > 2.0).mean() > 0.9


def test_parallax_cue_explains_a_nearer_seeds_extra_shift():
    """Every fourth column lies nearer (disparity 64 vs 60): it shifts 2.7 px more than its
    neighbours, ~4 field sigmas off the smooth field (the neighbours' median), but its parallax
    residual is ~0."""
    prev, cur, ka, kb, da = _shifted_frames(2, depth_step=4.0)
    ia, ib, x = temporal_cue_candidates(ka, kb, W, GateConfig(), _cfg(), _inputs(prev, ka, da), _inputs(cur, kb, da))
    col = {n: x[:, k] for k, n in enumerate(TEMPORAL_CUE_NAMES)}
    true = ia == ib
    near_true = true & (da[ia] > D0)
    assert near_true.sum() > 100
    assert np.median(col["u_res"][near_true]) > 3.0  # off the smooth field
    assert np.median(col["parallax_res"][near_true]) < 0.3 * np.median(col["u_res"][near_true])
    assert np.median(col["disp_dev"][near_true]) > 0.5  # 4 image px = 11.4 full-res px -> 1.1 (capped 6)


def test_shipped_temporal_model_ranks_the_true_partner_first_and_assigns_it():
    prev, cur, ka, kb, da = _shifted_frames(3)
    cfg = _cfg()
    pa, pb = _inputs(prev, ka, da), _inputs(cur, kb, da)
    ia, ib, x = temporal_cue_candidates(ka, kb, W, GateConfig(), cfg, pa, pb)
    t = score_model(cfg.temporal_score_model, "temporal").logits(x)
    best = np.full(len(ka), -1)
    order = np.lexsort((-t, ia))
    first = np.r_[True, ia[order][1:] != ia[order][:-1]]
    best[ia[order][first]] = ib[order][first]
    has = best >= 0
    assert (best[has] == np.flatnonzero(has)).mean() >= 0.98
    m = mlp_temporal_assign(ka, kb, W, GateConfig(), cfg, pa, pb)
    assert len(m) >= 0.9 * len(ka) and np.array_equal(m.idx_a, m.idx_b)


def test_temporal_score_model_kind_round_trips_and_is_checked(tmp_path):
    rng = np.random.default_rng(0)
    feats = ("u_res", "ncc", "disp_change")
    mdl = ScoreModel(feats, np.zeros(3), np.ones(3), [(rng.normal(size=(4, 3)), rng.normal(size=4)),
                                                      (rng.normal(size=(1, 4)), rng.normal(size=1))], {"t": 1},
                     "temporal")
    x = rng.normal(size=(10, len(TEMPORAL_CUE_NAMES)))
    p = tmp_path / "t.json"
    mdl.save(p)
    back = ScoreModel.load(str(p))
    assert back.kind == "temporal" and back.cue_names == TEMPORAL_CUE_NAMES
    assert np.allclose(back.logits(x), mdl.logits(x))
    with pytest.raises(SeedmapError, match="temporal association score model, but a stereo"):
        score_model(str(p), "stereo")
    with pytest.raises(SeedmapError, match="stereo association score model, but a temporal"):
        score_model(SlamConfig().association.score_model, "temporal")
    assert ScoreModel.load(SlamConfig().association.score_model).cue_names == CUE_NAMES  # old files: stereo


def test_shipped_temporal_model_is_finite_and_never_saw_the_evaluation_ranges():
    mdl = score_model(SlamConfig().association.temporal_score_model, "temporal")
    assert set(mdl.features) <= set(TEMPORAL_CUE_NAMES) and len(mdl.layers) >= 2
    assert all(np.isfinite(w).all() and np.isfinite(b).all() for w, b in mdl.layers)
    for s in (13, 14, 15, 25, 26):
        assert f"assoc_s{s}" not in str(mdl.info)


def test_defaults_unchanged():
    cfg = SlamConfig().association
    assert cfg.temporal_score == "field" and cfg.temporal_score_model == "temporal_score_s8.json"


@pytest.mark.slow
def test_temporal_mlp_on_the_rendered_range(tiny_range, tmp_path):
    """gt detector on the rendered tiny range (819 px, a width the network was not fitted at): the
    network's temporal matches are at least as precise as the field path with the NCC check, about
    as many, and the configured weights are what scores them (a missing file is an error)."""
    from seedmap.eval.associate_metrics import evaluate_association

    base = {"stereo_prior": "sgbm", "prior_score": "mlp"}
    old = evaluate_association(tiny_range, detector="gt", progress=False,
                               config=SlamConfig(association={**base, "temporal_min_ncc": 0.3}))
    new = evaluate_association(tiny_range, detector="gt", progress=False,
                               config=SlamConfig(association={**base, "temporal_score": "mlp"}))
    print("tiny range temporal P/R: field+ncc", old.temporal["precision"], old.temporal["recall"], "mlp",
          new.temporal["precision"], new.temporal["recall"])
    assert new.temporal["precision"] >= old.temporal["precision"] - 0.005
    assert new.temporal["correct"] >= 0.97 * old.temporal["correct"]
    with pytest.raises(SeedmapError, match="not found"):
        evaluate_association(tiny_range, detector="gt", progress=False, max_frames=2, config=SlamConfig(
            association={**base, "temporal_score": "mlp", "temporal_score_model": str(tmp_path / "none.json")}))
