"""SLAM core on synthetic seed geometry (no renderer): tracking, lost rule, degenerate input."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.associate import make_matcher
from seedmap.associate.base import FrameFeatures
from seedmap.errors import SeedmapError
from seedmap.records import Matches, StereoCalib
from seedmap.slam.config import SlamConfig
from seedmap.slam.core import SemanticSlam
from seedmap.slam.motion import kabsch, ransac_motion
from seedmap.slam.synthetic import make_range, observe
from seedmap.eval.slam_metrics import compute_slam_metrics


def _run(rg, rng, cfg, blank=()):
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    results = []
    for i in range(len(rg.gt)):
        if i in blank:
            f = FrameFeatures(i, float(rg.gt.timestamps[i]), np.zeros((0, 2)), np.zeros((0, 2)), Matches())
        else:
            f = m.features_from_detections(observe(rg, i, rng, noise_px=0.2, miss=0.02))
        r = slam.register_frame(f)
        results.append(r)
        if not r.ok:
            break
    return slam, results


def test_kabsch_recovers_a_rigid_motion():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(30, 3))
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    t = np.array([0.3, -0.1, 0.2])
    R2, t2 = kabsch(p, p @ R.T + t)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-9)


def test_ransac_motion_rejects_outliers():
    rng = np.random.default_rng(1)
    rg = make_range(rng, length=0.1)
    calib = rg.calib
    pc = np.c_[rng.uniform(-0.3, 0.3, 80), rng.uniform(-0.2, 0.2, 80), rng.uniform(0.6, 0.8, 80)]
    T = np.eye(4)
    T[:3, 3] = [0.04, 0.002, -0.001]  # T_prev_cur
    pp = pc @ T[:3, :3].T + T[:3, 3]
    uv, ur = calib.project(pc)
    obs = np.c_[uv[:, 0], ur, uv[:, 1]]
    pp_bad = pp.copy()
    pp_bad[:15] += rng.normal(0, 0.05, (15, 3))  # 15 wrong associations
    est = ransac_motion(calib, pp_bad, pc, obs, rng, thresh_px=1.0)
    assert est is not None
    assert not est.inliers[:15].any() and est.inliers[15:].all()
    np.testing.assert_allclose(est.T_prev_cur, T, atol=1e-6)


def test_synthetic_sequence_reaches_the_end_with_small_ate():
    rng = np.random.default_rng(2)
    rg = make_range(rng, length=0.4, seeds_per_panicle=80)
    cfg = SlamConfig()
    slam, res = _run(rg, rng, cfg)
    assert all(r.ok for r in res) and len(res) == len(rg.gt)
    traj, _, name = slam.finalize()
    m = compute_slam_metrics(traj, rg.gt, len(rg.gt), slam.lost_frame, slam.lost_reason)
    assert m.lost_frame is None
    assert m.mdm_fraction == pytest.approx(1.0, abs=0.02)
    assert m.gt_mdm_fraction == pytest.approx(1.0, abs=1e-9)
    assert m.ate_rmse_m < 0.005 * 0.4  # < 0.5 % of the distance
    assert "lm" in name
    lm = slam.landmarks()
    assert len(lm) > 100
    # landmarks sit where their seeds are (ids come from the synthetic detector)
    err = np.linalg.norm(lm.xyz - rg.seeds[lm.seed_ids], axis=1)
    assert np.median(err) < 0.003


def test_blank_frames_declare_lost_at_the_right_frame():
    rng = np.random.default_rng(3)
    rg = make_range(rng, length=0.3, seeds_per_panicle=60)
    slam, res = _run(rg, rng, SlamConfig(), blank={4, 5})
    assert res[-1].index == 4 and not res[-1].ok
    assert slam.lost_frame == 4 and "too few" in slam.lost_reason
    assert len(slam.online_trajectory()) == 4
    with pytest.raises(RuntimeError):
        slam.register_frame(res[-1] and FrameFeatures(5, 1.0, np.zeros((0, 2)), np.zeros((0, 2)), Matches()))


def test_first_frame_without_keypoints_is_a_recorded_lost_state():
    rng = np.random.default_rng(4)
    rg = make_range(rng, length=0.1, seeds_per_panicle=40)
    slam, res = _run(rg, rng, SlamConfig(), blank={0})
    assert len(res) == 1 and not res[0].ok and slam.lost_frame == 0
    traj, _, _ = slam.finalize()
    m = compute_slam_metrics(traj, rg.gt, len(rg.gt), slam.lost_frame, slam.lost_reason)
    assert m.frames_tracked == 0 and m.mdm_m == 0.0 and m.gt_mdm_m == 0.0


def test_zero_baseline_calibration_is_a_clear_error():
    with pytest.raises(SeedmapError, match="baseline"):
        StereoCalib(900.0, 900.0, 700.0, 500.0, 0.0, 1434, 1050)


def test_the_streaming_api_gives_what_register_frame_gives_and_ends_at_lost():
    cfg = SlamConfig()
    rg = make_range(np.random.default_rng(3), length=0.25, seeds_per_panicle=120)
    slam_ref, ref = _run(rg, np.random.default_rng(4), cfg, blank=(5,))
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    rng = np.random.default_rng(4)
    frames = [FrameFeatures(i, float(rg.gt.timestamps[i]), np.zeros((0, 2)), np.zeros((0, 2)), Matches()) if i == 5
              else m.features_from_detections(observe(rg, i, rng, noise_px=0.2, miss=0.02))
              for i in range(len(rg.gt))]
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    got = list(slam.run(frames))
    assert [r.ok for r in got] == [r.ok for r in ref] == [True] * 5 + [False]
    for a, b in zip(got, ref):
        if a.ok:
            assert np.array_equal(a.T_world_cam, b.T_world_cam)
    assert np.array_equal(slam.landmarks().xyz, slam_ref.landmarks().xyz)
