"""The multiview counter (default): seeds counted from the 2D detections of every view and the registered
camera poses -- stereo matches verified by neighbouring views, linked across views into tracks, triangulated,
grown and de-duplicated (docs/method/counting.md)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.geometry import invert, transform_points
from seedmap.log import warn
from seedmap.recon.config import CountConfig
from seedmap.recon.count.records import CannotLinkUnionFind, MultiViewDetail, SeedCount, StereoKeypoints
from seedmap.recon.count.stereo_match import (SUPPORT_REF_DEG, stereo_matches, support_shift, view_spacing_deg,
                                              view_support)
from seedmap.recon.count.tracks import GROW_PASSES, grow_tracks, link_edges, triangulate_tracks
from seedmap.recon.count.views import keypoint_trees, triangulate_rays, view_rays

#: pixel tolerances of CountConfig that scale with the seeds' image size (mv_scale_ref_px); the support scale
#: mv_support_sigma_px is not scaled (it lets ghost matches gather support)
SCALED_PX_KEYS: tuple[str, ...] = ("mv_stereo_dv_px", "mv_link_px", "mv_max_reproj_px", "mv_grow_px")
#: clip of the size scale factor of those tolerances
SCALE_MIN, SCALE_MAX = 1.0, 1.6
#: depth range (m) of the seeds the counter looks for, unless the caller gives one (the clouds' range)
DEPTH_RANGE = (0.2, 0.42)


def size_scale(views: list[StereoKeypoints | None], cfg: CountConfig) -> float:
    """Scale factor of the pixel tolerances: (median left detection size of the scan, px /
    ``mv_scale_ref_px``) ** ``mv_scale_power``, clipped to [SCALE_MIN, SCALE_MAX]; 1 when scaling is off
    or there are no detections (a partly hidden seed's visible centre moves by a fraction of its size)."""
    sizes = [v.left_size for v in views if v is not None and len(v.left_size)]
    if cfg.mv_scale_ref_px <= 0 or not sizes:
        return 1.0
    med = float(np.median(np.concatenate(sizes)))
    return float(np.clip((med / cfg.mv_scale_ref_px) ** cfg.mv_scale_power, SCALE_MIN, SCALE_MAX))


def scaled_tolerances(views: list[StereoKeypoints | None], cfg: CountConfig) -> CountConfig:
    """``cfg`` with its SCALED_PX_KEYS pixel tolerances multiplied by :func:`size_scale` and the
    scaling switched off (applied once)."""
    f = size_scale(views, cfg)
    upd = {k: getattr(cfg, k) * f for k in SCALED_PX_KEYS}
    upd["mv_scale_ref_px"] = 0.0
    return cfg.model_copy(update=upd)


def count_multiview(views: list[StereoKeypoints | None], poses: np.ndarray, calib, cfg: CountConfig,  # noqa: ANN001
                    detail: bool = False, depth_range: tuple[float, float] = DEPTH_RANGE
                    ) -> SeedCount | tuple[SeedCount, MultiViewDetail]:
    """Count seeds from the 2D detections ``views`` (one :class:`StereoKeypoints` per view, None = skipped
    view), the registered camera poses ``poses`` (V, 4, 4) T_world_cam of the left cameras (m) and the
    rectified ``calib``; seeds are looked for in ``depth_range`` (m).

    Returns a :class:`SeedCount` whose ``assignment`` indexes the LEFT detections of all views
    concatenated in view order (-1 = not counted); ``spread`` is the RMS distance (m) of a seed's
    per-view stereo points to its triangulated position. ``detail=True`` also returns the stereo
    matches and tracks (:class:`MultiViewDetail`)."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    V = len(views)
    if len(poses) != V:
        raise ValueError(f"{len(poses)} poses for {V} views")
    sp = view_spacing_deg(poses)
    if np.isfinite(sp) and sp > 1.05 * SUPPORT_REF_DEG:
        warn(f"the views are {sp:.1f} deg apart; the multiview counter's settings are for {SUPPORT_REF_DEG:g} deg "
             "(24 views) and under-counted simulated 12-view scans by about 13 %")
    if cfg.mv_scale_ref_px > 0:
        cfg = scaled_tolerances(views, cfg)  # pixel tolerances scaled with the seeds' median image size
    Tcw = invert(poses)
    n_left = np.array([len(v.left) if v is not None else 0 for v in views], np.int64)
    offset = np.concatenate([[0], np.cumsum(n_left)])
    shift = support_shift(poses)  # (scans denser than the 24-view circle)
    st = stereo_matches(views, poses, Tcw, calib, cfg, cfg.mv_min_support + shift, depth_range)
    view = np.concatenate([np.full(len(s[0]), k, np.int64) for k, s in enumerate(st)]) if V else np.zeros(0, np.int64)
    il = np.concatenate([s[0] for s in st]) if V else np.zeros(0, np.int64)
    ir = np.concatenate([s[1] for s in st]) if V else np.zeros(0, np.int64)
    X = np.concatenate([s[2] for s in st]) if V else np.zeros((0, 3))
    support = np.concatenate([s[3] for s in st]) if V else np.zeros(0)
    n = len(view)
    if n == 0:
        empty = SeedCount(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.full(offset[-1], -1, np.int64),
                          np.zeros(0))
        det = MultiViewDetail(view, il, ir, support, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64))
        return (empty, det) if detail else empty
    uvL = np.zeros((n, 2))
    uR = np.zeros(n)
    size = np.zeros(n)
    for k in np.unique(view):
        sel = view == k
        uvL[sel] = views[k].left[il[sel]]
        uR[sel] = views[k].right[ir[sel], 0]
        size[sel] = views[k].left_size[il[sel]]
    by_view = {int(k): np.flatnonzero(view == k) for k in np.unique(view)}
    roots = _link(by_view, X, uvL, uR, support, view, poses, Tcw, calib, cfg, shift)
    alive = np.ones(n, bool)
    keep, comp, Xg = triangulate_tracks(roots, alive, view, uvL, uR, poses, Tcw, calib, by_view, cfg)
    trees_kp = keypoint_trees(views)
    for _ in range(GROW_PASSES if cfg.mv_grow_px > 0 else 0):
        # tracks claim the detections their point projects onto in the views around them
        grown = grow_tracks(views, trees_kp, comp, keep, alive, Xg, view, il, ir, Tcw, calib, cfg)
        if grown is None:
            break
        new_view, new_il, new_ir, new_group, dead = grown
        alive[dead] = False
        o = np.argsort(new_view, kind="stable")  # view order (the supports below are computed per view)
        new_view, new_il, new_ir, new_group = new_view[o], new_il[o], new_ir[o], new_group[o]
        m = len(new_view)
        Xn = np.zeros((m, 3))
        for k in np.unique(new_view):
            sel = new_view == k
            Xn[sel] = transform_points(poses[k], calib.triangulate(views[k].left[new_il[sel]],
                                                                   views[k].right[new_ir[sel], 0]))
        # a grown observation joins the track of its claiming group (root = any member of it)
        member = np.full(int(comp.max()) + 1, -1, np.int64)
        member[comp[keep & alive]] = np.flatnonzero(keep & alive)
        new_root = roots[member[new_group]]
        view = np.concatenate([view, new_view])
        il = np.concatenate([il, new_il])
        ir = np.concatenate([ir, new_ir])
        X = np.concatenate([X, Xn])
        support = np.concatenate([support] + [view_support(k, Xn[new_view == k], views, trees_kp, Tcw, calib, cfg)
                                              for k in np.unique(new_view)])
        roots = np.concatenate([roots, new_root])
        alive = np.concatenate([alive, np.ones(m, bool)])
        uvL = np.concatenate([uvL, np.array([views[k].left[i] for k, i in zip(new_view, new_il)]).reshape(-1, 2)])
        uR = np.concatenate([uR, np.array([views[k].right[j, 0] for k, j in zip(new_view, new_ir)])])
        size = np.concatenate([size, np.array([views[k].left_size[i] for k, i in zip(new_view, new_il)])])
        by_view = {int(k): np.flatnonzero(view == k) for k in np.unique(view)}
        keep, comp, Xg = triangulate_tracks(roots, alive, view, uvL, uR, poses, Tcw, calib, by_view, cfg)
    # per-observation depth -> seed diameter (m)
    z = np.einsum("nj,nj->n", Tcw[view][:, 2, :3], X) + Tcw[view][:, 2, 3]
    diam = size * z / calib.fx
    track = _dedupe(comp, alive, view, Xg, diam, cfg)
    T = int(track.max()) + 1
    cL, dL = view_rays(calib, poses, view, uvL[:, 0], uvL[:, 1], right=False)
    cR, dR = view_rays(calib, poses, view, uR, uvL[:, 1], right=True)
    Xt = triangulate_rays(np.concatenate([track, track]), T, np.concatenate([cL, cR]), np.concatenate([dL, dR]))
    key = np.unique(track[alive] * V + view[alive])
    tv = np.bincount(key // V, minlength=T)
    ok_t = (tv >= cfg.min_observations) & np.all(np.isfinite(Xt), axis=1)
    new_index = np.full(T, -1, np.int64)
    new_index[ok_t] = np.arange(ok_t.sum())
    obs_seed = new_index[track]
    assignment = np.full(offset[-1], -1, np.int64)
    assignment[offset[view[alive]] + il[alive]] = obs_seed[alive]
    cnt_obs = np.bincount(track, minlength=T)
    d2 = np.sum((X - Xt[track]) ** 2, axis=1)
    spread = np.sqrt(np.bincount(track, weights=d2, minlength=T) / np.maximum(cnt_obs, 1))
    order = np.argsort(track, kind="stable")
    bounds = np.searchsorted(track[order], np.arange(T + 1))
    dmed = np.array([np.median(diam[order[bounds[t]:bounds[t + 1]]]) for t in np.flatnonzero(ok_t)])
    res = SeedCount(Xt[ok_t], dmed.reshape(-1), tv[ok_t], assignment, spread[ok_t])
    if detail:
        return res, MultiViewDetail(view, il, ir, support, np.where(keep & alive, track, -1), Xt, tv)
    return res


def _link(by_view: dict, X: np.ndarray, uvL: np.ndarray, uR: np.ndarray, support: np.ndarray, view: np.ndarray,
          poses: np.ndarray, Tcw: np.ndarray, calib, cfg: CountConfig, shift: float) -> np.ndarray:  # noqa: ANN001
    """Cross-view links of the stereo matches (cannot-link union-find, nearest views and cheapest links
    first), then the optional second pass (``mv_relink_px``) for matches still short of ``min_observations``
    views, only between matches with support >= ``mv_relink_min_support`` (+ ``shift``). Track root of
    every match."""
    V = len(poses)
    trees = {k: cKDTree(uvL[i]) for k, i in by_view.items()}
    rays = None
    if cfg.mv_link_joint:
        rays = (*view_rays(calib, poses, view, uvL[:, 0], uvL[:, 1], right=False),
                *view_rays(calib, poses, view, uR, uvL[:, 1], right=True))
    E = link_edges(by_view, trees, X, uvL, uR, Tcw, calib, V, cfg.max_lag, cfg.mv_link_px, cfg.circular, rays)
    uf = CannotLinkUnionFind(view)
    for a, b in E[:, 2:].astype(np.int64).tolist():
        uf.union(a, b)
    if cfg.mv_relink_px > cfg.mv_link_px:
        E2 = link_edges(by_view, trees, X, uvL, uR, Tcw, calib, V, cfg.max_lag, cfg.mv_relink_px, cfg.circular)
        strong = support >= cfg.mv_relink_min_support + shift
        for a, b in E2[:, 2:].astype(np.int64).tolist():
            if not (strong[a] and strong[b]):
                continue
            ra, rb = uf.find(a), uf.find(b)
            if (bin(uf.vmask[ra]).count("1") < cfg.min_observations
                    and bin(uf.vmask[rb]).count("1") < cfg.min_observations):
                uf.union(a, b)
    return np.array([uf.find(i) for i in range(len(view))])


def _dedupe(comp: np.ndarray, alive: np.ndarray, view: np.ndarray, Xg: np.ndarray, diam: np.ndarray,
            cfg: CountConfig) -> np.ndarray:
    """Joins counted tracks closer than ``mv_dedupe`` median seed diameters that share no view (fragments of
    one seed seen from two arcs of views), then those closer than ``mv_dedupe_shared`` even when they share
    views (a detector firing twice on one seed), nearest pairs first. Final track of every observation."""
    G = int(comp.max()) + 1
    vm = [0] * G
    for k, g in zip(view[alive].tolist(), comp[alive].tolist()):
        vm[g] |= 1 << k
    nv = np.array([bin(m).count("1") for m in vm])
    counted = np.flatnonzero((nv >= cfg.min_observations) & np.all(np.isfinite(Xg), axis=1))
    uf = CannotLinkUnionFind(np.zeros(G, np.int64))
    uf.vmask = vm
    med_diam = float(np.median(diam))
    for factor, force in ((cfg.mv_dedupe, False), (cfg.mv_dedupe_shared, True)):
        radius = factor * med_diam
        if radius <= 0 or len(counted) < 2:
            continue
        pairs = cKDTree(Xg[counted]).query_pairs(radius, output_type="ndarray")
        if len(pairs):
            dd = np.linalg.norm(Xg[counted[pairs[:, 0]]] - Xg[counted[pairs[:, 1]]], axis=1)
            for p, q in counted[pairs[np.argsort(dd, kind="stable")]].tolist():
                uf.union(p, q, force=force)
    _, track = np.unique(np.array([uf.find(g) for g in range(G)])[comp], return_inverse=True)
    return track
