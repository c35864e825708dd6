"""The paper's counter (method ``density``): de-duplication of per-view 3D seed centres by DBSCAN, Gaussian
density smoothing and local maxima (docs/method/counting.md)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.recon.config import CountConfig
from seedmap.recon.count.records import SeedCount

#: DBSCAN minimum points of a core observation
DBSCAN_MIN_POINTS = 2


def dbscan(xyz: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """Open3D DBSCAN labels (-1 = noise)."""
    import open3d as o3d

    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(xyz, np.float64)))
    return np.asarray(p.cluster_dbscan(eps=eps, min_points=min_points, print_progress=False), np.int64)


def count_density(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, cfg: CountConfig) -> SeedCount:
    """De-duplicate seed observations (world centres ``xyz`` (N, 3) m, their ``view`` ids and observed
    ``diameter`` (m)) into one entry per physical seed: DBSCAN groups (``dbscan_eps``), Gaussian density
    (``bandwidth``) inside each group, greedy non-maximum suppression within ``separation`` median
    diameters, every observation assigned to its nearest centre; centres seen from >= ``min_observations``
    views count."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    groups = dbscan(xyz, cfg.dbscan_eps, DBSCAN_MIN_POINTS)
    noise = groups < 0
    groups = groups.copy()
    groups[noise] = groups.max(initial=-1) + 1 + np.arange(noise.sum())
    sep = cfg.separation * float(np.median(diameter))
    tree = cKDTree(xyz)
    # density: Gaussian kernel over neighbours of the same group within 3 sigma
    s = cfg.bandwidth
    pairs = tree.query_pairs(3 * s, output_type="ndarray")
    dens = np.ones(n)
    if len(pairs):
        same = groups[pairs[:, 0]] == groups[pairs[:, 1]]
        pr = pairs[same]
        w = np.exp(-np.sum((xyz[pr[:, 0]] - xyz[pr[:, 1]]) ** 2, axis=1) / (2 * s * s))
        np.add.at(dens, pr[:, 0], w)
        np.add.at(dens, pr[:, 1], w)
    # greedy non-maximum suppression by decreasing density (ties broken by index: deterministic)
    order = np.lexsort((np.arange(n), -dens))
    suppressed = np.zeros(n, bool)
    centres: list[int] = []
    for i in order:
        if suppressed[i]:
            continue
        centres.append(int(i))
        nb = np.asarray(tree.query_ball_point(xyz[i], sep), np.int64)
        suppressed[nb[groups[nb] == groups[i]]] = True
    centres_a = np.asarray(centres, np.int64)
    ctree = cKDTree(xyz[centres_a])
    _, near = ctree.query(xyz)
    near = np.asarray(near, np.int64)
    # refine: mean position of each centre's members, then support by distinct views
    n_c = len(centres_a)
    pos = np.zeros((n_c, 3))
    np.add.at(pos, near, xyz)
    cnt = np.bincount(near, minlength=n_c)
    pos /= np.maximum(cnt, 1)[:, None]
    key = np.unique(near * (view.max() + 1) + view)
    nviews = np.bincount(key // (view.max() + 1), minlength=n_c)
    keep = nviews >= cfg.min_observations
    new_index = np.full(n_c, -1, np.int64)
    new_index[keep] = np.arange(keep.sum())
    assignment = new_index[near]
    diam = np.array([np.median(diameter[near == c]) for c in np.flatnonzero(keep)]) if keep.any() else np.zeros(0)
    d2 = np.sum((xyz - pos[near]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(near, weights=d2, minlength=n_c) / np.maximum(cnt, 1))
    return SeedCount(pos[keep], diam, nviews[keep], assignment, spread[keep])
