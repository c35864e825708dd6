"""Descriptor baselines on synthetic textured images that we shift ourselves (exact ground truth)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from seedmap.associate.base import GateConfig
from seedmap.associate.features import KINDS, FeatureMatcher, FeatureMatcherConfig, available_kinds
from seedmap.errors import SeedmapError
from seedmap.records import StereoCalib, StereoFrame

W, H = 480, 360
AVAILABLE = [k for k, why in available_kinds().items() if why is None]


def _texture(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Random blobs + noise: plenty of corners and blobs for every descriptor."""
    img = np.zeros((h, w, 3), np.uint8)
    for _ in range(900):
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        r = int(rng.integers(2, 9))
        col = tuple(int(x) for x in rng.integers(30, 256, 3))
        cv2.circle(img, c, r, col, -1, lineType=cv2.LINE_AA)
    noise = rng.normal(0, 4, img.shape)
    return np.clip(cv2.GaussianBlur(img, (3, 3), 0) + noise, 0, 255).astype(np.uint8)


def _calib() -> StereoCalib:
    return StereoCalib(fx=300.0, fy=300.0, cx=W / 2, cy=H / 2, baseline=0.11, width=W, height=H)


def _shifted(big: np.ndarray, x0: int, y0: int = 20) -> np.ndarray:
    """Crop so that a scene point at big-column c appears at u = c - x0."""
    return np.ascontiguousarray(big[y0:y0 + H, x0:x0 + W])


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    return _texture(rng, W + 200, H + 40)


@pytest.mark.parametrize("kind", AVAILABLE)
def test_stereo_matches_pass_gates_and_are_correct(kind, scene):
    disp = 40  # > stereo_min_disparity (50 px at 4096 -> ~5.9 px at 480)
    left = _shifted(scene, 100)  # left[u] = scene[u + 100]
    right = _shifted(scene, 100 + disp)  # right[u] = scene[u + 100 + disp] -> u_l - u_r = disp
    frame = StereoFrame(0, 0.0, left, right)
    m = FeatureMatcher(kind, _calib())
    f = m.features(frame)
    assert len(f.stereo) >= 20, f"{kind}: only {len(f.stereo)} stereo matches"
    a, b = f.kp_left[f.stereo.idx_a], f.kp_right[f.stereo.idx_b]
    g = GateConfig().scaled(W)
    assert np.all(np.abs(a[:, 1] - b[:, 1]) <= g.stereo_max_dy_px)
    assert np.all(a[:, 0] - b[:, 0] >= g.stereo_min_disparity_px)
    for u in (a[:, 0], b[:, 0]):
        assert np.all((u >= g.stereo_border_px) & (u <= W - 1 - g.stereo_border_px))
    # one-to-one
    assert len(np.unique(f.stereo.idx_a)) == len(f.stereo) == len(np.unique(f.stereo.idx_b))
    # mostly the true disparity
    correct = np.abs((a[:, 0] - b[:, 0]) - disp) < 2.0
    assert correct.mean() > 0.9, f"{kind}: {correct.mean():.2f} correct"


@pytest.mark.parametrize("kind", AVAILABLE)
@pytest.mark.parametrize("gate_first", [False, True])
def test_temporal_matches_follow_travel_direction(kind, gate_first, scene):
    shift = 30  # points slide towards -u by 30 px (travel_sign = -1)
    prev = StereoFrame(0, 0.0, _shifted(scene, 50), _shifted(scene, 50))
    cur = StereoFrame(1, 0.2, _shifted(scene, 50 + shift), _shifted(scene, 50 + shift))
    m = FeatureMatcher(kind, _calib(), FeatureMatcherConfig(gate_first=gate_first))
    fp, fc = m.features(prev), m.features(cur)
    t = m.match_temporal(fp, fc)
    assert len(t) >= 20
    a, b = fp.kp_left[t.idx_a], fc.kp_left[t.idx_b]
    g = GateConfig().scaled(W)
    assert np.all(-(b[:, 0] - a[:, 0]) >= g.temporal_min_shift_px)
    assert np.all(np.abs(a[:, 1] - b[:, 1]) <= g.temporal_post_max_dy_px)
    for u in (a[:, 0], b[:, 0]):
        assert np.all((u >= g.temporal_border_px) & (u <= W - 1 - g.temporal_border_px))
    assert len(np.unique(t.idx_b)) == len(t)
    assert (np.abs((a[:, 0] - b[:, 0]) - shift) < 2.0).mean() > 0.9
    assert "temporal_match" in fc.timings_ms


@pytest.mark.parametrize("kind", AVAILABLE)
def test_wrong_direction_is_gated_out(kind, scene):
    """Travel reversed (points slide to +u): the gates must reject every true correspondence."""
    prev = StereoFrame(0, 0.0, _shifted(scene, 80), _shifted(scene, 80))
    cur = StereoFrame(1, 0.2, _shifted(scene, 50), _shifted(scene, 50))
    m = FeatureMatcher(kind, _calib())
    t = m.match_temporal(m.features(prev), m.features(cur))
    a_u = m.features(prev).kp_left[t.idx_a, 0]
    b_u = m.features(cur).kp_left[t.idx_b, 0]
    assert np.all(a_u - b_u >= GateConfig().scaled(W).temporal_min_shift_px)
    # true correspondences move by +30 px, so none of them can be among the survivors
    assert not np.any(np.abs((b_u - a_u) - 30) < 2.0)


def test_blank_images_give_no_matches():
    blank = np.zeros((H, W, 3), np.uint8)
    m = FeatureMatcher("sift", _calib())
    f = m.features(StereoFrame(0, 0.0, blank, blank))
    assert len(f.kp_left) == 0 and len(f.stereo) == 0
    assert len(m.match_temporal(f, f)) == 0


def test_unavailable_kinds_raise_one_line_na():
    for kind, why in available_kinds().items():
        if why is None:
            continue
        with pytest.raises(SeedmapError, match="^n/a"):
            FeatureMatcher(kind, _calib())
    with pytest.raises(SeedmapError):
        FeatureMatcher("brief", _calib())
    assert set(available_kinds()) == set(KINDS)
    assert "sift" in AVAILABLE and "orb" in AVAILABLE
