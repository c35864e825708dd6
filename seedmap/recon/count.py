"""Counting seeds by de-duplicating per-view detections in 3D.

Every view contributes one 3D centre per detected seed (in the registered world frame), so a seed
seen from ``n`` views appears as a tight cloud of ``n`` observations.

Method ``rays`` (default): a per-view seed centre is precise ACROSS its viewing ray (keypoint,
~0.2 mm at 0.3 m) but not ALONG it (stereo depth of a 3 mm seed: ~1 mm core, a long tail), so two
observations are compared by the Mahalanobis distance under covariances elongated along their rays
(``sigma_lateral`` across, ``sigma_depth`` along, needs each observation's camera centre). Pairs
of views up to ``max_lag`` steps apart within ``gate_chi2`` are merged (union-find) nearest views
first -- their rays are nearly parallel, so depth errors hardly matter -- and by increasing distance
within a lag, under the cannot-link rule below. A group seen from ``min_observations`` distinct
views is one seed; its position is the information-weighted mean (rays from different directions
fix the depth). A seed hidden for more than ``max_lag`` views in between (seen from two separate
arcs) gives two groups: ``merge_passes`` passes join counted groups that share no view and whose
information-weighted positions agree within ``merge_chi2`` (group covariances).

Method ``tracks``: observations of views up to ``max_lag`` steps apart around the circle
are linked when they are mutual nearest neighbours within ``link_radius``; links are merged
shortest first (union-find) under a cannot-link rule -- one view sees a seed at most once, so two
groups that share a view are never merged (this is what keeps touching seeds ~4 mm apart
separate even where a few bad centres scatter by several mm). A group supported by at least
``min_observations`` distinct views is one seed.

Method ``density`` (default; DBSCAN, density smoothing, local maxima):

1. **DBSCAN** (Open3D ``cluster_dbscan``, ``eps`` ~ one seed diameter) splits the observations into
   spatially separate groups and marks isolated observations as noise (kept as singleton groups;
   step 4 decides whether they count).
2. **Density smoothing**: inside a group every observation gets a Gaussian kernel density
   (sigma = ``bandwidth``, ~ the registration + stereo scatter) summed over its neighbours.
3. **Local maxima**: observations are visited by decreasing density; one becomes a seed centre
   when no stronger centre lies within ``separation`` x the median seed diameter (non-maximum
   suppression -- touching seeds are one diameter apart, duplicates of one seed far closer).
   Every observation is then assigned to its nearest centre.
4. A centre counts as a seed when its observations come from at least ``min_observations``
   distinct views. Position = mean of its observations, size = median observed diameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from seedmap.recon.config import CountConfig


@dataclass
class SeedCount:
    """Counted seeds: positions (m, world), diameters (m), supporting views, and per-observation
    assignment (index into the counted seeds, -1 = not counted)."""

    xyz: np.ndarray  # (S, 3)
    diameter: np.ndarray  # (S,)
    n_views: np.ndarray  # (S,)
    assignment: np.ndarray  # (N_obs,)
    spread: np.ndarray  # (S,) RMS distance of the observations to the centre (m)

    @property
    def count(self) -> int:
        return len(self.xyz)


def dbscan(xyz: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """Open3D DBSCAN labels (-1 = noise)."""
    import open3d as o3d

    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(xyz, np.float64)))
    return np.asarray(p.cluster_dbscan(eps=eps, min_points=min_points, print_progress=False), np.int64)


def count_seeds(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, cfg: CountConfig,
                origin: np.ndarray | None = None) -> SeedCount:
    """De-duplicate seed observations (world centres ``xyz`` (N, 3) m, their ``view`` ids and
    observed ``diameter`` (m)) into one entry per physical seed (methods in the module docstring).
    ``origin`` (N, 3) m: the camera centre each observation was seen from (method ``rays`` needs it:
    the depth along that ray is far less certain than the position across it)."""
    if cfg.method == "rays":
        if origin is None:
            raise ValueError("count method 'rays' needs the camera centre of every observation (origin)")
        return count_rays(xyz, view, diameter, origin, cfg)
    if cfg.method == "tracks":
        return count_tracks(xyz, view, diameter, cfg)
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    groups = dbscan(xyz, cfg.dbscan_eps, cfg.dbscan_min_points)
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


def count_tracks(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, cfg: CountConfig) -> SeedCount:
    """The ``tracks`` method (module docstring): constrained linking of cross-view mutual neighbours."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    views = np.unique(view)
    V = int(views.max()) + 1
    by_view = {int(v): np.flatnonzero(view == v) for v in views}
    trees = {v: cKDTree(xyz[i]) for v, i in by_view.items()}
    edges = []
    for a in by_view:
        for lag in range(1, cfg.max_lag + 1):
            b = (a + lag) % V
            if b == a or b not in by_view:
                continue
            ia, ib = by_view[a], by_view[b]
            dab, jab = trees[b].query(xyz[ia], distance_upper_bound=cfg.link_radius)
            dba, jba = trees[a].query(xyz[ib], distance_upper_bound=cfg.link_radius)
            ok = np.isfinite(dab)
            ka = np.flatnonzero(ok)
            kb = jab[ok]
            mutual = jba[kb] == ka
            for x, y, d in zip(ia[ka[mutual]], ib[kb[mutual]], dab[ok][mutual], strict=True):
                edges.append((float(d), int(x), int(y)))
    edges.sort()
    parent = np.arange(n)
    vmask = [1 << int(v) for v in view]  # views present in each group (python ints: any number of views)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for _, x, y in edges:
        rx, ry = find(x), find(y)
        if rx == ry or (vmask[rx] & vmask[ry]):
            continue
        parent[ry] = rx
        vmask[rx] |= vmask[ry]
    roots = np.array([find(i) for i in range(n)])
    uniq, comp = np.unique(roots, return_inverse=True)
    nviews = np.array([bin(vmask[r]).count("1") for r in uniq])
    keep = nviews >= cfg.min_observations
    new_index = np.full(len(uniq), -1, np.int64)
    new_index[keep] = np.arange(keep.sum())
    cnt = np.bincount(comp, minlength=len(uniq))
    pos = np.zeros((len(uniq), 3))
    np.add.at(pos, comp, xyz)
    pos /= cnt[:, None]
    d2 = np.sum((xyz - pos[comp]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(comp, weights=d2, minlength=len(uniq)) / cnt)
    diam = np.array([np.median(diameter[comp == c]) for c in np.flatnonzero(keep)]) if keep.any() else np.zeros(0)
    return SeedCount(pos[keep], diam, nviews[keep], new_index[comp], spread[keep])


def _ray_covariances(xyz: np.ndarray, origin: np.ndarray, sigma_lat: float, sigma_depth: float) -> np.ndarray:
    """(N, 3, 3) covariance of each observation: ``sigma_lat`` across its viewing ray, ``sigma_depth`` along it."""
    r = xyz - origin
    r /= np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-12)
    return sigma_lat ** 2 * np.eye(3)[None] + (sigma_depth ** 2 - sigma_lat ** 2) * r[:, :, None] * r[:, None, :]


def count_rays(xyz: np.ndarray, view: np.ndarray, diameter: np.ndarray, origin: np.ndarray,
               cfg: CountConfig) -> SeedCount:
    """The ``rays`` method (module docstring): cannot-link agglomeration of observations under a
    ray-aligned (anisotropic) Mahalanobis distance."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    view = np.asarray(view, np.int64).reshape(-1)
    diameter = np.asarray(diameter, float).reshape(-1)
    origin = np.asarray(origin, float).reshape(-1, 3)
    n = len(xyz)
    if n == 0:
        return SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(origin) != n:
        raise ValueError(f"origin has {len(origin)} rows for {n} observations")
    cov = _ray_covariances(xyz, origin, cfg.sigma_lateral, cfg.sigma_depth)
    # candidate pairs: Euclidean pre-filter wide enough for the depth uncertainty of both ends
    radius = min(np.sqrt(cfg.gate_chi2 * 2.0) * cfg.sigma_depth, cfg.max_pair_distance)
    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    pairs = pairs[view[pairs[:, 0]] != view[pairs[:, 1]]] if len(pairs) else np.zeros((0, 2), np.int64)
    if len(pairs):
        d = xyz[pairs[:, 0]] - xyz[pairs[:, 1]]
        S = cov[pairs[:, 0]] + cov[pairs[:, 1]]
        m2 = np.einsum("pi,pi->p", d, np.linalg.solve(S, d[:, :, None])[:, :, 0])
        V = int(view.max()) + 1
        lag = np.abs(view[pairs[:, 0]] - view[pairs[:, 1]])
        lag = np.minimum(lag, V - lag) if cfg.circular else lag
        ok = (m2 <= cfg.gate_chi2) & (lag <= cfg.max_lag)
        pairs, m2, lag = pairs[ok], m2[ok], lag[ok]
        # neighbouring views first (their rays are nearly parallel, so depth errors barely matter),
        # each lag by increasing distance
        order = np.lexsort((m2, lag))
        pairs = pairs[order]
    uf = _CannotLinkUnionFind(view)
    for x, y in pairs.tolist():
        uf.union(x, y)
    # information matrices: across-ray directions are known precisely, the depth loosely
    W = np.linalg.inv(cov)
    Wx = np.einsum("nij,nj->ni", W, xyz)
    for _ in range(cfg.merge_passes):
        if not _merge_groups(uf, xyz, W, Wx, cfg):
            break
    roots = np.array([uf.find(i) for i in range(n)])
    uniq, comp = np.unique(roots, return_inverse=True)
    nviews = np.array([bin(uf.vmask[r]).count("1") for r in uniq])
    keep = nviews >= cfg.min_observations
    new_index = np.full(len(uniq), -1, np.int64)
    new_index[keep] = np.arange(keep.sum())
    pos, _ = _group_estimates(comp, len(uniq), W, Wx)
    cnt = np.bincount(comp, minlength=len(uniq))
    d2 = np.sum((xyz - pos[comp]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(comp, weights=d2, minlength=len(uniq)) / cnt)
    diam = np.array([np.median(diameter[comp == c]) for c in np.flatnonzero(keep)]) if keep.any() else np.zeros(0)
    return SeedCount(pos[keep], diam, nviews[keep], new_index[comp], spread[keep])


class _CannotLinkUnionFind:
    """Union-find over observations that refuses to join two groups seen by a common view."""

    def __init__(self, view: np.ndarray) -> None:
        self.parent = np.arange(len(view))
        self.vmask = [1 << int(v) for v in view]  # views of each group (python ints: any number of views)

    def find(self, i: int) -> int:
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union(self, x: int, y: int) -> bool:
        rx, ry = self.find(x), self.find(y)
        if rx == ry or (self.vmask[rx] & self.vmask[ry]):
            return False  # cannot-link: one view sees a seed at most once
        self.parent[ry] = rx
        self.vmask[rx] |= self.vmask[ry]
        return True


def _group_estimates(comp: np.ndarray, n_groups: int, W: np.ndarray, Wx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Information-weighted position (G, 3) and its covariance (G, 3, 3) of each group."""
    Wsum = np.zeros((n_groups, 3, 3))
    np.add.at(Wsum, comp, W)
    b = np.zeros((n_groups, 3))
    np.add.at(b, comp, Wx)
    C = np.linalg.inv(Wsum)
    return np.einsum("gij,gj->gi", C, b), C


def _merge_groups(uf: _CannotLinkUnionFind, xyz: np.ndarray, W: np.ndarray, Wx: np.ndarray,
                  cfg: CountConfig) -> bool:
    """One pass of group-level merging: fragments of one seed seen from views more than ``max_lag``
    apart (a seed hidden for a few views in between) are joined when their information-weighted
    positions agree (``merge_chi2``) and they share no view. Returns whether anything merged."""
    roots = np.array([uf.find(i) for i in range(len(xyz))])
    uniq, comp = np.unique(roots, return_inverse=True)
    pos, C = _group_estimates(comp, len(uniq), W, Wx)
    # only groups that count already: a seed seen from two separate arcs of views
    nviews = np.array([bin(uf.vmask[r]).count("1") for r in uniq])
    counted = np.flatnonzero(nviews >= max(cfg.min_observations, 2))
    pairs = cKDTree(pos[counted]).query_pairs(cfg.merge_radius, output_type="ndarray")
    if len(pairs) == 0:
        return False
    pairs = counted[pairs]
    d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
    m2 = np.einsum("pi,pi->p", d, np.linalg.solve(C[pairs[:, 0]] + C[pairs[:, 1]], d[:, :, None])[:, :, 0])
    ok = m2 <= cfg.merge_chi2
    merged = False
    for k in np.flatnonzero(ok)[np.argsort(m2[ok], kind="stable")]:
        merged |= uf.union(int(uniq[pairs[k, 0]]), int(uniq[pairs[k, 1]]))
    return merged


def naive_2d_count(per_view_counts: np.ndarray, expected_views_per_seed: float) -> float:
    """The 2D baseline: total detections over all views divided by how many views see a seed."""
    return float(np.sum(per_view_counts) / max(expected_views_per_seed, 1e-9))
