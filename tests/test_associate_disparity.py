"""Dense-stereo prior of the stereo association (``stereo_prior="sgbm"``, seedmap.associate.disparity)."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.associate.base import GateConfig
from seedmap.associate.disparity import disparity_at, disparity_search_range, sgbm_disparity
from seedmap.associate.semantic import SemanticConfig, match_stereo_keypoints
from seedmap.slam.config import SlamConfig


def _textured_pair(d: int, h: int = 120, w: int = 320, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A random-texture plane at constant disparity ``d``: right(x) = left(x + d)."""
    rng = np.random.default_rng(seed)
    import cv2

    tex = cv2.GaussianBlur(rng.integers(0, 256, (h, w + d), dtype=np.uint8), (3, 3), 0)
    left = tex[:, :w]
    right = tex[:, d: d + w]
    return np.repeat(left[..., None], 3, 2), np.repeat(right[..., None], 3, 2)


def test_sgbm_finds_a_known_disparity_also_next_to_the_left_border():
    left, right = _textured_pair(37)
    disp = sgbm_disparity(left, right, 16, 48)
    inner = disp[10:-10, 10:-10]
    ok = np.isfinite(inner)
    assert ok.mean() > 0.9
    assert np.median(np.abs(inner[ok] - 37.0)) < 0.3
    # columns left of min_disparity + num_disparities get a disparity too (the pair is padded);
    # where x - 37 >= 0 the right view sees the point
    strip = disp[10:-10, 40:64]
    assert np.isfinite(strip).mean() > 0.8 and np.nanmedian(np.abs(strip - 37.0)) < 0.3


def test_disparity_at_takes_the_median_of_the_valid_window():
    disp = np.full((5, 5), np.nan, np.float32)
    disp[1, 1], disp[1, 2], disp[2, 2] = 10.0, 11.0, 30.0
    d = disparity_at(disp, np.array([[2.0, 2.0], [3.0, 3.0], [0.2, 0.0], [4.0, 4.0]]))
    assert d[0] == pytest.approx(11.0)  # median of 10, 11, 30
    assert d[1] == pytest.approx(30.0)  # only the (2, 2) value is in its window
    assert d[2] == pytest.approx(10.0)  # window clipped at the corner: only (1, 1) is valid
    assert np.isnan(d[3])  # no valid value in its window


def test_disparity_search_range():
    d = np.linspace(130.0, 150.0, 50)
    lo, num = disparity_search_range(d, 10.0, 17.5, 256)
    assert num % 16 == 0 and lo <= 120.2 and lo + num >= 160.0
    lo, num = disparity_search_range(d, 10.0, 125.0, 256)
    assert lo == 125  # never below the stereo gate
    lo, num = disparity_search_range(np.linspace(20.0, 600.0, 50), 10.0, 17.5, 64)
    assert num == 64 and lo <= 310 <= lo + 64  # capped, centred on the median
    assert disparity_search_range(np.arange(5.0), 10.0, 0.0, 256) is None


def _grid_scene(rng: np.random.Generator, n: int = 30, spacing: float = 3.2):
    """Keypoints ~3 px apart at disparity ~100 px; every 7th seed sits 5 px nearer (larger
    disparity) than its neighbours, as seeds in front of a loose panicle do."""
    yy, xx = np.mgrid[0:n, 0:n]
    kl = np.c_[300.0 + xx.ravel() * spacing, 200.0 + yy.ravel() * spacing] + rng.normal(0, 0.3, (n * n, 2))
    disp = 100.0 + 0.05 * (kl[:, 0] - 300.0)
    outlier = np.arange(n * n) % 7 == 3
    disp[outlier] += 5.0
    kr = kl - np.c_[disp, np.zeros(n * n)] + np.c_[rng.normal(0, 0.15, n * n), rng.normal(0, 0.1, n * n)]
    return kl, kr, disp, outlier


def test_the_dense_prior_matches_seeds_that_the_smooth_field_cannot():
    rng = np.random.default_rng(3)
    kl, kr, disp, outlier = _grid_scene(rng)
    width = 1434
    cfg = SlamConfig().association
    measured = disp + rng.normal(0, 0.3, len(disp))  # SGBM-like error of the per-keypoint disparity
    m = match_stereo_keypoints(kl, kr, width, GateConfig(), cfg, disparity=measured)
    ok = m.idx_a == m.idx_b
    assert ok.mean() >= 0.99 and len(m) >= 0.9 * len(kl)
    assert np.isin(np.flatnonzero(outlier), m.idx_a[ok]).mean() >= 0.75
    # the keypoint field alone (the session-2 default) takes a seed's disparity from its neighbours
    f = match_stereo_keypoints(kl, kr, width, GateConfig(), cfg.model_copy(update={"stereo_prior": "none"}))
    f_ok = f.idx_a == f.idx_b
    assert np.isin(np.flatnonzero(outlier), f.idx_a[f_ok]).mean() < 0.5
    # unknown disparities (NaN) fall back to the neighbours' median
    holes = measured.copy()
    holes[::5] = np.nan
    h = match_stereo_keypoints(kl, kr, width, GateConfig(), cfg, disparity=holes)
    assert np.mean(h.idx_a == h.idx_b) >= 0.97 and len(h) >= 0.8 * len(kl)


def test_left_right_check_drops_pairs_whose_right_disparity_disagrees():
    rng = np.random.default_rng(4)
    kl, kr, disp, _ = _grid_scene(rng)
    cfg = SlamConfig().association.model_copy(update={"sgbm_lr_tol_px": 3.0})
    d_right = disp.copy()
    d_right[:50] += 4.0  # the right map says these right keypoints belong elsewhere
    m = match_stereo_keypoints(kl, kr, 1434, GateConfig(), cfg, disparity=disp, disparity_right=d_right)
    assert not np.isin(np.arange(50), m.idx_b).any()
    assert len(m) >= 0.9 * (len(kl) - 50)
    off = match_stereo_keypoints(kl, kr, 1434, GateConfig(), cfg.model_copy(update={"sgbm_lr_tol_px": 0.0}),
                                 disparity=disp, disparity_right=d_right)
    assert np.isin(np.arange(50), off.idx_b).sum() >= 40


def test_defaults_and_the_paper_method():
    assert SlamConfig().association.stereo_prior == "none"  # opt-in: SLAM drifts more with it (see SlamConfig)
    paper = SemanticConfig()
    assert paper.stereo_prior == "none" and paper.refine == "none" and not paper.temporal_prediction


@pytest.mark.slow
def test_dense_prior_on_the_rendered_range(tiny_range):
    """gt detector on the rendered tiny range (819 px wide): stereo precision >= 0.98 with the dense
    prior and its left-right check; without the check more correct pairs than the keypoint field of
    session 2 at no lower precision."""
    from seedmap.eval.associate_metrics import evaluate_association

    new = evaluate_association(tiny_range, detector="gt", config=SlamConfig(association={"stereo_prior": "sgbm"}),
                               progress=False)
    lr = evaluate_association(tiny_range, detector="gt",
                              config=SlamConfig(association={"stereo_prior": "sgbm", "sgbm_lr_tol_px": 3.0}),
                              progress=False)
    print("tiny range stereo P/R: sgbm", new.stereo["precision"], new.stereo["recall"], "lr", lr.stereo["precision"],
          lr.stereo["recall"])
    old = evaluate_association(tiny_range, detector="gt",
                               config=SlamConfig(association={"stereo_prior": "none"}), progress=False)
    assert lr.stereo["precision"] >= 0.98
    assert new.stereo["correct"] > old.stereo["correct"]
    assert lr.stereo["precision"] > new.stereo["precision"]
    assert new.stereo["precision"] >= old.stereo["precision"] - 0.005
    assert new.temporal["precision"] >= 0.99


def test_debias_recentres_a_biased_dense_prior():
    rng = np.random.default_rng(5)
    kl, kr, disp, _ = _grid_scene(rng)
    cfg = SlamConfig().association
    biased = disp + 0.9 + rng.normal(0, 0.2, len(disp))  # SGBM-like constant offset from the keypoint centres
    plain = match_stereo_keypoints(kl, kr, 1434, GateConfig(), cfg, disparity=biased)
    fixed = match_stereo_keypoints(kl, kr, 1434, GateConfig(), cfg.model_copy(update={"prior_debias": True}),
                                   disparity=biased)
    good = lambda m: int(np.sum(m.idx_a == m.idx_b))  # noqa: E731
    assert good(fixed) > good(plain)
    assert np.mean(fixed.idx_a == fixed.idx_b) >= 0.99
