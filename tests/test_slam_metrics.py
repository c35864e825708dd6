"""SLAM metrics on constructed trajectories: MDM, GT-validated MDM, ATE (evo), RPE."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.eval.slam_metrics import compute_slam_metrics, gt_validated_mdm
from seedmap.records import Trajectory
from seedmap.slam.synthetic import R_WORLD_CAM


def _line(n=30, step=0.04, drift_from=None, drift_rate=0.0):
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, :3, :3] = R_WORLD_CAM
    P[:, 0, 3] = np.arange(n) * step
    if drift_from is not None:
        k = np.arange(n) - drift_from
        P[:, 1, 3] += np.where(k > 0, k * drift_rate, 0.0)
    return Trajectory(np.arange(n) * 0.2, P)


def test_perfect_estimate():
    gt = _line()
    m = compute_slam_metrics(gt, gt, frames=30, lost_frame=None, lost_reason=None, range_length=1.16)
    assert m.mdm_m == pytest.approx(1.16)
    assert m.mdm_fraction == pytest.approx(1.0)
    assert m.gt_mdm_m == pytest.approx(1.16)
    assert m.ate_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert m.rpe_trans_rmse_m == pytest.approx(0.0, abs=1e-9)


def test_gt_validated_mdm_stops_where_the_error_exceeds_the_bound():
    gt = _line()
    est = _line(drift_from=10, drift_rate=0.02)  # lateral drift of 2 cm per frame after frame 10
    # error at frame 10 + j is 0.02 j; the bound is max(0.05 * 0.04 (10 + j), 0.05) = 0.05 until
    # 0.05*0.04*(10+j) > 0.05 -> never within 30 frames; so the first violation is j = 3 (0.06 m):
    # frames 0..12 are valid
    d, nvalid = gt_validated_mdm(est, gt)
    assert nvalid == 13 and d == pytest.approx(12 * 0.04)
    m = compute_slam_metrics(est, gt, frames=30, lost_frame=None, lost_reason=None, range_length=1.16)
    assert m.gt_mdm_fraction == pytest.approx(12 * 0.04 / 1.16)
    assert m.mdm_m > m.gt_mdm_m


def test_lost_run_and_unknown_range_length():
    gt = _line()
    est = Trajectory(gt.timestamps[:10], gt.poses[:10])
    m = compute_slam_metrics(est, gt, frames=30, lost_frame=10, lost_reason="too few", range_length=None)
    # the range length falls back to the GT path length
    assert m.range_length_m == pytest.approx(29 * 0.04)
    assert m.mdm_m == pytest.approx(9 * 0.04)
    assert m.frames_tracked == 10 and m.lost_frame == 10
    m2 = compute_slam_metrics(est, None, frames=30, lost_frame=10, lost_reason="x", range_length=None)
    assert m2.mdm_fraction is None and m2.ate_rmse_m is None and m2.gt_mdm_m is None


def test_se3_alignment_removes_a_constant_offset_but_first_pose_alignment_does_not_hide_drift():
    gt = _line()
    est = _line()
    est.poses[:, :3, 3] += [0.0, 0.01, 0.0]  # constant offset: aligned away by both
    m = compute_slam_metrics(est, gt, frames=30, lost_frame=None, lost_reason=None)
    assert m.ate_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert m.ate_first_pose_rmse_m == pytest.approx(0.0, abs=1e-9)
    drift = _line(drift_from=0, drift_rate=0.001)
    m = compute_slam_metrics(drift, gt, frames=30, lost_frame=None, lost_reason=None)
    assert m.ate_first_pose_rmse_m > m.ate_rmse_m > 0


def test_metrics_pair_poses_by_time_when_gt_starts_late():
    """A GT file that starts 3 frames late must not shift every pair by 3 frames."""
    from seedmap.eval.slam_metrics import compute_slam_metrics
    from seedmap.records import Trajectory

    n = 20
    t = np.arange(n) * 0.2
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = 0.04 * np.arange(n)
    est = Trajectory(t, T)
    gt_full = Trajectory(t, T.copy())
    gt_late = Trajectory(t[3:], T[3:].copy())
    m_full = compute_slam_metrics(est, gt_full, frames=n, lost_frame=None, lost_reason=None)
    m_late = compute_slam_metrics(est, gt_late, frames=n, lost_frame=None, lost_reason=None)
    assert m_full.ate_rmse_m < 1e-9
    assert m_late.ate_rmse_m < 1e-9  # index pairing would give a 0.12 m error here
    assert m_late.rpe_trans_rmse_m < 1e-9


def test_topview_without_ground_truth_plots_the_ground_plane(tmp_path):
    """Without GT the world is the first camera's optical frame: a camera moving 1 m forward (z) must draw a long
    red track, not a dot (the plot used to show x against y = height)."""
    import cv2

    from seedmap.records import Trajectory
    from seedmap.slam.outputs import plot_topview

    n = 20
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, 2, 3] = np.linspace(0.0, 1.0, n)
    plot_topview(tmp_path / "t.png", Trajectory(np.arange(n, dtype=float), poses), None, np.zeros((0, 3)), "t")
    img = cv2.imread(str(tmp_path / "t.png"))
    red = (img[:, :, 2] > 200) & (img[:, :, 1] < 80) & (img[:, :, 0] < 80)
    rows = np.nonzero(red.any(axis=1))[0]
    assert rows.max() - rows.min() > 0.4 * img.shape[0]
