"""Refining the arm's FK camera poses by ICP against the growing model (Open3D).

Modes (``RegisterConfig.mode``):

* ``fk``    -- no refinement: the nominal FK poses (the reference);
* ``full``  -- each view's full coloured cloud is registered to the union of the already placed
  clouds (point-to-plane by default);
* ``seeds`` -- only the view's 3D seed centres are registered to the seed centres already placed
  (point-to-point by default) -- the paper's "ICP on seed centres".

The first view anchors the model at its FK pose. Each later view starts from
the previous *refined* pose moved by the FK motion between the two views (the arm's relative
motion is far more accurate than its absolute pose), which keeps the nearest-neighbour
correspondences of densely packed seeds (~4 mm apart) right.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from seedmap.geometry import invert, rotation_angle_deg, transform_points
from seedmap.recon.config import RegisterConfig

#: ICP variants: full clouds point-to-plane, seed centres point-to-point
FULL_METHOD, SEEDS_METHOD = "point_to_plane", "point_to_point"
#: coarse-to-fine max correspondence distances (m) of both modes
MAX_CORR: tuple[float, ...] = (0.004, 0.002, 0.001)
#: voxel of the clouds used for full-cloud ICP (m)
FULL_VOXEL = 0.002
#: radius of the normal estimation of full clouds (m)
NORMAL_RADIUS = 0.005
#: ICP iterations per correspondence distance
MAX_ITERATIONS = 50
#: fewer seed correspondences keep the initial pose
MIN_SEED_PAIRS = 8


@dataclass
class ViewGeometry:
    """What registration needs from one view, in the LEFT camera frame (m)."""

    cloud_xyz: np.ndarray  # (N, 3) downsampled view cloud
    cloud_normals: np.ndarray  # (N, 3) normals oriented towards the camera
    seeds_xyz: np.ndarray  # (M, 3) seed centres


@dataclass
class RegistrationResult:
    poses: np.ndarray  # (V, 4, 4) refined T_world_cam
    fitness: np.ndarray  # (V,) Open3D fitness (inlier fraction), NaN when not registered
    rmse: np.ndarray  # (V,) inlier RMSE (m), NaN when not registered
    accepted: np.ndarray  # (V,) bool: the ICP correction was applied
    seconds: np.ndarray  # (V,) time spent in ICP per view (s)
    notes: list[str] = field(default_factory=list)


def _pcd(xyz: np.ndarray, normals: np.ndarray | None = None):
    import open3d as o3d

    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz, np.float64)))
    if normals is not None:
        p.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    return p


def estimate_normals(xyz: np.ndarray, radius: float) -> np.ndarray:
    """Normals (Open3D hybrid KNN/radius search) oriented towards the camera at the origin."""
    import open3d as o3d

    if len(xyz) < 3:
        return np.zeros_like(xyz)
    p = _pcd(xyz)
    p.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    p.orient_normals_towards_camera_location(np.zeros(3))
    return np.asarray(p.normals)


def voxel_down(xyz: np.ndarray, voxel: float) -> np.ndarray:
    """Open3D voxel downsampling of bare points."""
    if len(xyz) == 0:
        return xyz
    return np.asarray(_pcd(xyz).voxel_down_sample(voxel).points)


def icp(source: np.ndarray, target: np.ndarray, init: np.ndarray, max_corr: float | list[float], method: str,
        max_iter: int, source_normals: np.ndarray | None = None,
        target_normals: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """Open3D ICP, coarse to fine over the ``max_corr`` schedule (m): returns (T_target_source,
    fitness, inlier_rmse) of the last stage. Wide gates first pull a few-mm initial error in; the
    narrow last gate keeps neighbouring seeds (~4 mm apart) from becoming false correspondences."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    est = (reg.TransformationEstimationPointToPlane() if method == "point_to_plane"
           else reg.TransformationEstimationPointToPoint())
    src, tgt = _pcd(source, source_normals), _pcd(target, target_normals)
    T = np.asarray(init, float)
    fit, err = 0.0, float("nan")
    for d in np.atleast_1d(np.asarray(max_corr, float)):
        res = reg.registration_icp(
            src, tgt, float(d), T, est,
            reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iter))
        T, fit, err = np.asarray(res.transformation), float(res.fitness), float(res.inlier_rmse)
    return T, fit, err


def register_views(views: list[ViewGeometry | None], T_fk: np.ndarray, cfg: RegisterConfig,
                   progress=None) -> RegistrationResult:
    """Place every view (None = skipped view: keeps its FK pose, adds nothing to the model)."""
    V = len(views)
    poses = np.array(T_fk, float, copy=True)
    fitness = np.full(V, np.nan)
    rmse = np.full(V, np.nan)
    accepted = np.zeros(V, bool)
    secs = np.zeros(V)
    notes: list[str] = []
    model_xyz: list[np.ndarray] = []
    model_n: list[np.ndarray] = []
    prev = None  # index of the last placed view
    for k in range(V):
        if progress is not None:
            progress(k)
        g = views[k]
        if g is None:
            continue
        if prev is not None:
            init = poses[prev] @ invert(T_fk[prev]) @ T_fk[k]
        else:
            init = T_fk[k].copy()
        poses[k] = init
        if cfg.mode != "fk" and prev is not None and model_xyz:
            target = np.concatenate(model_xyz)
            t0 = time.perf_counter()
            if cfg.mode == "full":
                tn = np.concatenate(model_n)
                T, fit, err = icp(g.cloud_xyz, target, init, list(MAX_CORR), FULL_METHOD, MAX_ITERATIONS,
                                  g.cloud_normals, tn)
                ok = fit > 0.05
            else:
                if len(g.seeds_xyz) < MIN_SEED_PAIRS or len(target) < MIN_SEED_PAIRS:
                    T, fit, err, ok = init, np.nan, np.nan, False
                else:
                    T, fit, err = icp(g.seeds_xyz, target, init, list(MAX_CORR), SEEDS_METHOD, MAX_ITERATIONS)
                    ok = fit * len(g.seeds_xyz) >= MIN_SEED_PAIRS
            secs[k] = time.perf_counter() - t0
            dT = T @ invert(init)
            if ok and (np.linalg.norm(dT[:3, 3]) <= cfg.max_correction_m
                       and rotation_angle_deg(dT[:3, :3]) <= cfg.max_correction_deg):
                poses[k] = T
                accepted[k] = True
            else:
                notes.append(f"view {k}: ICP correction rejected (fitness {fit:.2f})")
            fitness[k], rmse[k] = fit, err
        R, t = poses[k][:3, :3], poses[k][:3, 3]
        if cfg.mode == "seeds":
            model_xyz.append(transform_points(poses[k], g.seeds_xyz))
        else:
            model_xyz.append(transform_points(poses[k], g.cloud_xyz))
            model_n.append(g.cloud_normals @ R.T)
        del t
        prev = k
    return RegistrationResult(poses, fitness, rmse, accepted, secs, notes)
