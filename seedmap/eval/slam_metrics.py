"""SLAM metrics: maximum distance mapped (MDM), its GT-validated variant, ATE and RPE.

Definitions (all distances in metres):

* **MDM** (paper): distance travelled according to the *estimate* up to the last frame tracked
  before the system was declared lost (or the last frame when it never was).
* **GT-validated MDM**: the ground-truth distance travelled up to the last frame whose estimated
  position error stays within ``max(5 % of the distance travelled so far, 5 cm)``, after aligning
  the estimate to GT by the first pose (the SLAM prior normally makes that alignment the identity).
  It catches runs that "track" but drift away.
* **fractions**: MDM / range length (range length from ``seedmap.sim.range_length`` when known,
  else the GT path length, else ``None``).
* **ATE**: evo APE on the translation part after a rigid SE(3) Umeyama alignment (no scale) over
  the tracked frames (``ate_rmse_m``); also after first-pose alignment only
  (``ate_first_pose_rmse_m``), which is the stricter, drift-revealing number.
* **RPE**: evo RPE, translation part, between consecutive frames (delta = 1 frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seedmap.geometry import invert
from seedmap.records import Trajectory

#: GT-validated MDM: allowed position error = max(REL * distance travelled, ABS).
GT_ERR_REL = 0.05
GT_ERR_ABS_M = 0.05


@dataclass
class SlamMetrics:
    """What one SLAM run achieved; ``metrics.json`` is ``dataclasses.asdict`` of this."""

    frames: int
    frames_tracked: int
    mdm_m: float
    mdm_fraction: float | None
    gt_mdm_m: float | None
    gt_mdm_fraction: float | None
    range_length_m: float | None
    ate_rmse_m: float | None
    rpe_trans_rmse_m: float | None
    lost_frame: int | None
    lost_reason: str | None
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    matcher: str = ""
    detector: str = ""
    #: the detector read the simulator's ground truth (ORACLE), not the images
    oracle_detector: bool = False
    backend: str = ""
    ate_first_pose_rmse_m: float | None = None
    ate_online_rmse_m: float | None = None
    ate_fraction_of_distance: float | None = None
    landmarks: int = 0


def _evo_traj(t: Trajectory):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(poses_se3=[np.asarray(p) for p in t.poses], timestamps=np.asarray(t.timestamps))


def sync_by_time(est: Trajectory, gt: Trajectory, tol_s: float | None = None) -> tuple[Trajectory, Trajectory]:
    """Pair every estimated pose with the ground-truth pose nearest in time (within ``tol_s``).

    Real datasets' ground truth may start late, end early or be sampled differently (EuRoC, KITTI
    subsets), so metrics never pair poses by index. ``tol_s`` defaults to half the median frame interval of
    ``est`` (1 ms when it has fewer than two poses). Returns the two trajectories restricted to the pairs.
    """
    if len(est) == 0 or len(gt) == 0:
        return Trajectory(np.zeros(0), np.zeros((0, 4, 4))), Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    if tol_s is None:
        tol_s = 0.5 * float(np.median(np.diff(est.timestamps))) if len(est) > 1 else 1e-3
    order = np.argsort(gt.timestamps)
    tg = gt.timestamps[order]
    j = np.clip(np.searchsorted(tg, est.timestamps), 1, len(tg) - 1) if len(tg) > 1 else np.zeros(len(est), int)
    if len(tg) > 1:
        j = np.where(np.abs(tg[j - 1] - est.timestamps) <= np.abs(tg[j] - est.timestamps), j - 1, j)
    ok = np.abs(tg[j] - est.timestamps) <= tol_s
    gi = order[j[ok]]
    return (Trajectory(est.timestamps[ok], est.poses[ok]), Trajectory(gt.timestamps[gi], gt.poses[gi]))


def gt_pose_at(t: float, gt: Trajectory | None, timestamps: np.ndarray) -> np.ndarray | None:
    """The ground-truth pose at time ``t`` (the nearest within half the median interval of the frame
    ``timestamps``; 2 ms with fewer than two frames), None where the ground truth does not cover it. A run's
    first pose is anchored there, so that its trajectory compares with the ground truth."""
    if gt is None or len(gt) == 0:
        return None
    dt = float(np.median(np.diff(timestamps))) if len(timestamps) > 1 else 2e-3
    _, g = sync_by_time(Trajectory(np.array([t], float), np.eye(4)[None]), gt, 0.5 * dt)
    return g.poses[0] if len(g) else None


def ate_rmse(est: Trajectory, gt: Trajectory, align: str = "se3") -> float | None:
    """evo APE (translation, RMSE) of ``est`` vs ``gt`` (same length, frame-by-frame).

    ``align="se3"``: rigid least-squares (Umeyama, no scale) alignment of the positions;
    ``"first"``: align the first poses only.
    """
    from evo.core import metrics

    n = min(len(est), len(gt))
    if n < 3 and align == "se3" or n < 1:
        return None
    poses = est.poses[:n]
    if align == "se3":
        # Umeyama/Kabsch on the positions (no scale). evo's own align() refuses (near-)collinear
        # paths, which a straight row traversal is; the SVD solution is still the least-squares
        # optimum there (the roll about the line is irrelevant to position errors).
        from seedmap.slam.motion import kabsch

        R, t = kabsch(est.positions[:n], gt.positions[:n])
    else:
        A = gt.poses[0] @ invert(est.poses[0])
        R, t = A[:3, :3], A[:3, 3]
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = R, t
    e = _evo_traj(Trajectory(est.timestamps[:n], A[None] @ poses))
    r = _evo_traj(Trajectory(gt.timestamps[:n], gt.poses[:n]))
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((r, e))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def rpe_trans_rmse(est: Trajectory, gt: Trajectory) -> float | None:
    from evo.core import metrics

    n = min(len(est), len(gt))
    if n < 2:
        return None
    e = _evo_traj(Trajectory(est.timestamps[:n], est.poses[:n]))
    r = _evo_traj(Trajectory(gt.timestamps[:n], gt.poses[:n]))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames)
    rpe.process_data((r, e))
    return float(rpe.get_statistic(metrics.StatisticsType.rmse))


def gt_validated_mdm(est: Trajectory, gt: Trajectory) -> tuple[float, int]:
    """``(distance, frames_valid)``: GT distance up to the last frame within the error bound."""
    n = min(len(est), len(gt))
    if n == 0:
        return 0.0, 0
    A = gt.poses[0] @ invert(est.poses[0])
    p_est = est.positions[:n] @ A[:3, :3].T + A[:3, 3]
    err = np.linalg.norm(p_est - gt.positions[:n], axis=1)
    dist = Trajectory(gt.timestamps[:n], gt.poses[:n]).path_length()
    bad = np.flatnonzero(err > np.maximum(GT_ERR_REL * dist, GT_ERR_ABS_M))
    last = n - 1 if len(bad) == 0 else int(bad[0]) - 1
    if last < 0:
        return 0.0, 0
    return float(dist[last]), last + 1


def compute_slam_metrics(
    est: Trajectory,
    gt: Trajectory | None,
    frames: int,
    lost_frame: int | None,
    lost_reason: str | None,
    range_length: float | None = None,
    ms_per_frame: dict[str, float] | None = None,
    online: Trajectory | None = None,
    **extra,
) -> SlamMetrics:
    """Metrics of an estimated trajectory (frames ``0..len(est)-1`` of the dataset)."""
    mdm = float(est.path_length()[-1]) if len(est) else 0.0
    if range_length is None and gt is not None and len(gt):
        range_length = float(gt.path_length()[-1])
    frac = (mdm / range_length) if range_length else None
    gt_mdm = gt_frac = ate = ate_first = rpe = ate_on = ate_frac = None
    gt_full = gt
    if gt is not None and len(gt):
        if online is not None and len(online):
            online, gt_online = sync_by_time(online, gt_full)
        est, gt = sync_by_time(est, gt_full)
    if gt_full is not None and len(gt_full):
        gt_mdm, _ = gt_validated_mdm(est, gt)
        gt_frac = (gt_mdm / range_length) if range_length else None
    if gt is not None and len(gt) and len(est):
        ate = ate_rmse(est, gt, "se3")
        ate_first = ate_rmse(est, gt, "first")
        rpe = rpe_trans_rmse(est, gt)
        if online is not None and len(online):
            ate_on = ate_rmse(online, gt_online, "se3")
        dist = float(Trajectory(gt.timestamps[: len(est)], gt.poses[: len(est)]).path_length()[-1])
        if ate is not None and dist > 0:
            ate_frac = ate / dist
    return SlamMetrics(
        frames=int(frames),
        frames_tracked=int(len(est)),
        mdm_m=mdm,
        mdm_fraction=frac,
        gt_mdm_m=gt_mdm,
        gt_mdm_fraction=gt_frac,
        range_length_m=range_length,
        ate_rmse_m=ate,
        rpe_trans_rmse_m=rpe,
        lost_frame=lost_frame,
        lost_reason=lost_reason,
        ms_per_frame=dict(ms_per_frame or {}),
        ate_first_pose_rmse_m=ate_first,
        ate_online_rmse_m=ate_on,
        ate_fraction_of_distance=ate_frac,
        **extra,
    )
