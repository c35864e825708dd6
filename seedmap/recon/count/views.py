"""Multi-view geometry helpers of the multiview counter: projection, nearest keypoints, neighbouring
views, rays and their least-squares triangulation."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.geometry import transform_points
from seedmap.recon.count.records import StereoKeypoints


def project_world(calib, T_cam_world: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) m -> left pixels (N, 2) and right columns (N,) of one view."""
    return calib.project(transform_points(T_cam_world, X))


def nearest(tree: cKDTree | None, uv: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance (inf = none within ``r`` px) and index (-1) of the nearest keypoint of ``tree``."""
    d = np.full(len(uv), np.inf)
    j = np.full(len(uv), -1, np.int64)
    ok = np.all(np.isfinite(uv), axis=1)
    if tree is not None and tree.n and ok.any():
        dd, jj = tree.query(uv[ok], distance_upper_bound=r)
        hit = np.isfinite(dd)
        idx = np.flatnonzero(ok)[hit]
        d[idx], j[idx] = dd[hit], jj[hit]
    return d, j


def neighbour_views(k: int, V: int, max_off: int, circular: bool, both_sides: bool) -> list[tuple[int, int]]:
    """(lag, view) of the views up to ``max_off`` steps after (and before, ``both_sides``) view k."""
    out = []
    for off in range(1, max_off + 1):
        for m in ((k + off, k - off) if both_sides else (k + off,)):
            if circular:
                m %= V
            if 0 <= m < V and m != k and (off, m) not in out and all(m != x for _, x in out):
                out.append((off, m))
    return out


def keypoint_trees(views: list[StereoKeypoints | None]) -> list[tuple[cKDTree | None, cKDTree | None]]:
    """(left, right) keypoint KD-trees (px) of every view (None for skipped views)."""
    return [(cKDTree(v.left), cKDTree(v.right)) if v is not None else (None, None) for v in views]


def view_rays(calib, poses: np.ndarray, view: np.ndarray, u: np.ndarray, v: np.ndarray,
          right: bool) -> tuple[np.ndarray, np.ndarray]:
    """World camera centres (N, 3) and unit ray directions (N, 3) of pixels (u, v) of the left or
    right camera of each observation's view."""
    R = poses[view][:, :3, :3]
    c = poses[view][:, :3, 3] + (R[:, :, 0] * calib.baseline if right else 0.0)
    d = np.einsum("nij,nj->ni", R, np.column_stack([(u - calib.cx) / calib.fx, (v - calib.cy) / calib.fy,
                                                     np.ones(len(u))]))
    return c, d / np.linalg.norm(d, axis=1, keepdims=True)


def triangulate_rays(group: np.ndarray, n_groups: int, centres: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Linear least-squares triangulation: for each group the point (m) minimising the summed
    squared distances to its rays (camera centre ``centres``, unit direction ``dirs``), i.e. the
    solution of sum (I - d d^T)(X - c) = 0. NaN for groups whose rays are (nearly) parallel."""
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    A = np.zeros((n_groups, 3, 3))
    b = np.zeros((n_groups, 3))
    np.add.at(A, group, P)
    np.add.at(b, group, np.einsum("nij,nj->ni", P, centres))
    X = np.full((n_groups, 3), np.nan)
    ok = np.linalg.cond(A) < 1e8 if n_groups else np.zeros(0, bool)
    if ok.any():
        X[ok] = np.linalg.solve(A[ok], b[ok][:, :, None])[:, :, 0]
    return X
