"""Scale-aware pixel tolerances of the multiview counter (``CountConfig.mv_scale_ref_px``): a scan
whose seeds are 1.5x larger in the image -- and whose keypoints therefore scatter 1.5x farther
(a partly hidden seed's visible centre moves by a fraction of its size between the left and the
right image and between views) -- must count as well as the reference scan."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.recon.config import CountConfig
from seedmap.recon.count import StereoKeypoints, count_multiview, scaled_tolerances, size_scale
from seedmap.recon.count.multiview import SCALED_PX_KEYS

from helpers.arm_scans import CALIB, scan


def scaled_scan(seed: int, scale: float, rel: float = 0.15, frac: float = 0.5):
    """The synthetic cylinder scan with seed image sizes multiplied by ``scale`` and, for a fraction
    ``frac`` of the keypoints (left and right independently), an offset uniform in a disc of radius
    ``rel`` x the seed size (px): the visible-centre bias of partly hidden seeds, proportional to
    their size. Returns keypoints, poses and the true count (seeds in left+right of >= 2 views)."""
    views, poses, _, countable, _ = scan(np.random.default_rng(seed), noise_px=0.2, drop=0.05)
    rng = np.random.default_rng(seed + 100)

    def offset(size: np.ndarray) -> np.ndarray:
        r = rel * size * np.sqrt(rng.random(len(size)))
        a = rng.random(len(size)) * 2 * np.pi
        return np.column_stack([r * np.cos(a), r * np.sin(a)]) * (rng.random(len(size)) < frac)[:, None]

    out = []
    for kp in views:
        size = kp.left_size * scale
        out.append(StereoKeypoints(kp.left + offset(size), kp.right + offset(np.full(len(kp.right), np.median(size))),
                                   size))
    return out, poses, len(countable)


def test_larger_seeds_count_within_tolerance_only_with_scaled_tolerances():
    small, poses, n = scaled_scan(5, 1.0)
    ref = float(np.median(np.concatenate([kp.left_size for kp in small])))  # ~8.9 px
    cfg = CountConfig(mv_scale_ref_px=ref)
    # reference scan: the scaling leaves the tolerances as configured, the count is right
    assert size_scale(small, cfg) == pytest.approx(1.0, abs=1e-9)
    assert abs(count_multiview(small, poses, CALIB, cfg).count - n) <= 0.02 * n
    large, poses, n = scaled_scan(5, 1.5)
    assert size_scale(large, cfg) == pytest.approx(1.5, rel=1e-6)
    scaled = count_multiview(large, poses, CALIB, cfg).count
    fixed = count_multiview(large, poses, CALIB, CountConfig()).count
    assert abs(scaled - n) <= 0.05 * n, (scaled, n)
    # the fixed pixel tolerances lose the seeds whose keypoints moved farther than they allow
    assert fixed < 0.94 * n, (fixed, n)
    assert scaled - fixed >= 0.03 * n


def test_scale_factor_is_clipped_and_applied_once():
    kp = [StereoKeypoints(np.zeros((3, 2)), np.zeros((3, 2)), np.array([14.0, 14.0, 14.0])), None]
    cfg = CountConfig(mv_scale_ref_px=7.0)
    assert size_scale(kp, cfg) == pytest.approx(1.6)  # 2.0 clipped to SCALE_MAX
    assert size_scale(kp, cfg.model_copy(update={"mv_scale_power": 0.5})) == pytest.approx(2.0 ** 0.5)
    small = [StereoKeypoints(np.zeros((1, 2)), np.zeros((1, 2)), np.array([3.5]))]
    assert size_scale(small, cfg) == 1.0  # never tighter than configured (SCALE_MIN)
    assert size_scale(kp, CountConfig()) == 1.0  # off by default
    s = scaled_tolerances(kp, cfg)
    assert s.mv_scale_ref_px == 0.0  # applied once
    for k in SCALED_PX_KEYS:
        assert getattr(s, k) == pytest.approx(1.6 * getattr(cfg, k))
    assert s.mv_support_sigma_px == cfg.mv_support_sigma_px  # not a scaled tolerance


def test_gt_and_fast_profiles_scale_with_the_seed_size():
    """On auto-exposed arm scans the arm network's boxes follow the seed size, so ``fast`` scales too."""
    cfg = CountConfig()
    assert cfg.for_detector("gt").mv_scale_ref_px == 7.0
    assert cfg.for_detector("fast").mv_scale_ref_px == 6.0 and cfg.for_detector("fast").mv_scale_power == 1.5
