"""Descriptor baselines on a rendered stereo pair and a rendered frame pair (exact GT depth and poses)."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.associate.base import GateConfig
from seedmap.associate.features import FeatureMatcher, available_kinds
from seedmap.config import load_config
from seedmap.geometry import invert, transform_points
from seedmap.records import StereoFrame

AVAILABLE = [k for k, why in available_kinds().items() if why is None]


@pytest.fixture(scope="module")
def rendered():
    from seedmap.sim import SimConfig, build_range_world, preset_dict, range_trajectory, render_stereo

    cfg = load_config(SimConfig, base=preset_dict("paper1"),
                      overrides=["world.length=0.4", "world.gap=0.2", "camera.scale=0.2", "panicle.seeds_min=400",
                                 "panicle.seeds_max=800", "imaging.supersample=1", "seed=5"])
    rng = np.random.default_rng(cfg.seed)
    world = build_range_world(cfg, rng)
    traj = range_trajectory(cfg, np.random.default_rng(1))
    calib = cfg.camera.calib()
    k = len(traj) // 2
    frames = [render_stereo(world, traj.poses[i], calib, cfg, np.random.default_rng(i), float(traj.timestamps[i]))
              for i in (k, k + 1)]
    return calib, traj.poses[k:k + 2], frames


def _depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    c = np.clip(np.round(uv).astype(int), 0, [depth.shape[1] - 1, depth.shape[0] - 1])
    return depth[c[:, 1], c[:, 0]]


@pytest.mark.parametrize("kind", AVAILABLE)
def test_rendered_stereo_matches_pass_gates_and_fit_gt_depth(kind, rendered):
    calib, _, (r0, _) = rendered
    m = FeatureMatcher(kind, calib)
    f = m.features(StereoFrame(0, 0.0, r0.left, r0.right))
    assert len(f.stereo) >= 10, f"{kind}: {len(f.stereo)} stereo matches on a rendered pair"
    a, b = f.kp_left[f.stereo.idx_a], f.kp_right[f.stereo.idx_b]
    g = GateConfig().scaled(calib.width)
    assert np.all(np.abs(a[:, 1] - b[:, 1]) <= g.stereo_max_dy_px)
    assert np.all(a[:, 0] - b[:, 0] >= g.stereo_min_disparity_px)
    for u in (a[:, 0], b[:, 0]):
        assert np.all((u >= g.stereo_border_px) & (u <= calib.width - 1 - g.stereo_border_px))
    assert len(np.unique(f.stereo.idx_b)) == len(f.stereo)
    # disparity predicted by the GT depth under the left keypoint. Keypoints on an occluding edge may
    # see the background and repeated seed texture gives some wrong matches (measured: 10-20 % of
    # matches off by > 10 px), so compare the median and require most matches within 3 px.
    z = _depth_at(r0.left_depth, a)
    ok = np.isfinite(z)
    err = np.abs((a[ok, 0] - b[ok, 0]) - calib.disparity_of_depth(z[ok]))
    assert np.median(err) < 2.5, f"{kind}: median disparity error {np.median(err):.2f} px"
    assert np.mean(err < 3.0) > 0.5, f"{kind}: {np.mean(err < 3.0):.2f} of matches within 3 px"


@pytest.mark.parametrize("kind", AVAILABLE)
def test_rendered_temporal_matches_follow_the_gt_motion(kind, rendered):
    calib, poses, (r0, r1) = rendered
    m = FeatureMatcher(kind, calib)
    f0 = m.features(StereoFrame(0, 0.0, r0.left, r0.right))
    f1 = m.features(StereoFrame(1, 0.2, r1.left, r1.right))
    t = m.match_temporal(f0, f1)
    assert len(t) >= 10
    a, b = f0.kp_left[t.idx_a], f1.kp_left[t.idx_b]
    g = GateConfig().scaled(calib.width)
    assert np.all(g.travel_sign * (b[:, 0] - a[:, 0]) >= g.temporal_min_shift_px)
    assert np.all(np.abs(a[:, 1] - b[:, 1]) <= g.temporal_post_max_dy_px)
    # predict where each previous keypoint goes with the GT depth and GT relative pose
    z = _depth_at(r0.left_depth, a)
    ok = np.isfinite(z)
    p0 = np.column_stack([(a[ok, 0] - calib.cx) * z[ok] / calib.fx, (a[ok, 1] - calib.cy) * z[ok] / calib.fy, z[ok]])
    T_1_0 = invert(poses[1]) @ poses[0]
    uv1, _ = calib.project(transform_points(T_1_0, p0))
    err = np.linalg.norm(uv1 - b[ok], axis=1)
    # Repeated seed texture makes many temporal descriptor matches wrong (measured 25-45 % off by
    # > 10 px: the weakness the paper reports); a pair drawn at random under the gates would almost
    # never land within 3 px, so a third within 3 px shows the matcher finds real correspondences.
    assert np.mean(err < 3.0) > 0.3, f"{kind}: only {np.mean(err < 3.0):.2f} of temporal matches within 3 px"
