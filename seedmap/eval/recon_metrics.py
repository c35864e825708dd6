"""Ground-truth metrics of a panicle reconstruction (simulated arm scans).

Poses and clouds live in the frame of the first view's FK pose; they are compared with the truth
after one rigid alignment (Umeyama on the camera centres, via evo, no scale) that is then applied
to the cloud too. The truth is the camera pose in the panicle's REST frame (the sway D of each
view removed: ``D^-1 T_world_cam``), the frame in which a rigid panicle model can exist.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from seedmap.geometry import invert, rotation_angle_deg, transform_points


def umeyama_se3(est_xyz: np.ndarray, ref_xyz: np.ndarray) -> np.ndarray:
    """4x4 rigid transform mapping estimated positions onto reference ones (evo's Umeyama)."""
    from evo.core.geometry import umeyama_alignment

    R, t, _ = umeyama_alignment(np.asarray(est_xyz, float).T, np.asarray(ref_xyz, float).T, False)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


@dataclass
class PoseErrors:
    trans_mm: np.ndarray  # (V,)
    rot_deg: np.ndarray  # (V,)
    T_align: np.ndarray

    def summary(self) -> dict:
        return {"pose_trans_mm_mean": float(np.mean(self.trans_mm)),
                "pose_trans_mm_rmse": float(np.sqrt(np.mean(self.trans_mm ** 2))),
                "pose_rot_deg_mean": float(np.mean(self.rot_deg))}


def pose_errors(est: np.ndarray, ref: np.ndarray, align: bool = True) -> PoseErrors:
    """Per-view translation (mm) and rotation (deg) error of ``est`` vs ``ref`` (V, 4, 4)."""
    est = np.asarray(est, float)
    ref = np.asarray(ref, float)
    T = umeyama_se3(est[:, :3, 3], ref[:, :3, 3]) if align and len(est) >= 3 else np.eye(4)
    E = invert(ref) @ (T @ est)
    return PoseErrors(np.linalg.norm(E[:, :3, 3], axis=1) * 1000.0, rotation_angle_deg(E[:, :3, :3]), T)


def sample_ellipsoids(centres: np.ndarray, radii: np.ndarray, per_seed: int, rng: np.random.Generator,
                      rotations: np.ndarray | None = None) -> np.ndarray:
    """Points on axis-aligned (or ``rotations`` (N,3,3)-oriented) ellipsoids: a GT surface proxy."""
    n = len(centres)
    v = rng.normal(size=(n, per_seed, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    p = v * radii[:, None, :]
    if rotations is not None:
        p = np.einsum("nij,nkj->nki", rotations, p)
    return (p + centres[:, None, :]).reshape(-1, 3)


def cloud_accuracy(points: np.ndarray, surface: np.ndarray) -> dict:
    """Distance (mm) from every reconstructed point to the nearest GT surface sample."""
    if len(points) == 0:
        return {"cloud_dist_mm_median": float("nan"), "cloud_dist_mm_p90": float("nan")}
    d, _ = cKDTree(surface).query(points, workers=1)
    d = d * 1000.0
    return {"cloud_dist_mm_median": float(np.median(d)), "cloud_dist_mm_p90": float(np.percentile(d, 90)),
            "cloud_within_1mm": float(np.mean(d <= 1.0))}


def count_error(count: int, gt: int) -> dict:
    return {"count": int(count), "count_gt": int(gt),
            "count_ape_pct": float(abs(count - gt) / max(gt, 1) * 100.0)}


def evaluate_reconstruction(poses: np.ndarray, cloud_xyz: np.ndarray, count: int, gt_rest_poses: np.ndarray,
                            surface: np.ndarray, gt_visible: int, fk_poses: np.ndarray | None = None) -> dict:
    """All GT metrics in one flat dict (mm, degrees, percent)."""
    pe = pose_errors(poses, gt_rest_poses)
    out = pe.summary()
    out.update(cloud_accuracy(transform_points(pe.T_align, cloud_xyz), surface))
    out.update(count_error(count, gt_visible))
    if fk_poses is not None:
        out.update({f"fk_{k}": v for k, v in pose_errors(fk_poses, gt_rest_poses).summary().items()})
    return out


def summarize_scan_rows(rows: list[dict], modes: list[str], tune_panicles: tuple[int, ...] = ()) -> dict:
    """Aggregate per-panicle evaluation rows (as written by the recon evaluation) into per-mode
    means/stds on the held-out panicles, plus the Spearman correlation of the GT-free scores with
    the GT errors over all (panicle, mode) pairs."""
    from scipy.stats import spearmanr

    held = [r for r in rows if r["panicle"] not in tune_panicles]
    out: dict = {"panicles": [r["panicle"] for r in held], "modes": {}}
    keys = ["pose_trans_mm_mean", "pose_rot_deg_mean", "cloud_dist_mm_median", "cloud_dist_mm_p90",
            "icp_s_per_view", "count_ape_pct"]
    for m in modes:
        vals = {k: np.array([r["modes"][m][k] for r in held if m in r["modes"]], float) for k in keys}
        out["modes"][m] = {k: {"mean": float(np.mean(v)), "std": float(np.std(v))} for k, v in vals.items() if len(v)}
    pairs = [(r["modes"][m]["quality"]["seed_spread_mm"], r["modes"][m]["quality"]["surface_thickness_mm"],
              r["modes"][m]["pose_trans_mm_mean"], r["modes"][m]["cloud_dist_mm_median"],
              r["modes"][m]["quality"].get("cross_view_seed_mm", np.nan))
             for r in held for m in modes if m in r["modes"]]
    a = np.array(pairs, float)
    if len(a) >= 4:
        out["quality_correlation"] = {
            "seed_spread_vs_pose_error": float(spearmanr(a[:, 0], a[:, 2]).statistic),
            "seed_spread_vs_cloud_error": float(spearmanr(a[:, 0], a[:, 3]).statistic),
            "surface_thickness_vs_pose_error": float(spearmanr(a[:, 1], a[:, 2]).statistic),
            "surface_thickness_vs_cloud_error": float(spearmanr(a[:, 1], a[:, 3]).statistic),
            "cross_view_seed_vs_pose_error": float(spearmanr(a[:, 4], a[:, 2]).statistic),
            "cross_view_seed_vs_cloud_error": float(spearmanr(a[:, 4], a[:, 3]).statistic),
            "n_pairs": int(len(a)),
        }
    return out
