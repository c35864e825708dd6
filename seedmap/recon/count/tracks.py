"""Steps 2-3b of the multiview counter: cross-view links, track triangulation with the reprojection check,
and growing tracks into the views they lack (docs/method/counting.md)."""

from __future__ import annotations

import numpy as np

from seedmap.geometry import transform_points
from seedmap.recon.config import CountConfig
from seedmap.recon.count.records import StereoKeypoints
from seedmap.recon.count.views import nearest, neighbour_views, project_world, triangulate_rays, view_rays

#: re-triangulation rounds of the reprojection check (each drops the worst observation of every track)
REPROJ_ROUNDS = 12
#: joint links: partner search radius, in link tolerances
LINK_SEARCH = 2.0
#: growing: a track claims a left keypoint only when no other lies within this distance of its projection (px)
GROW_UNIQUE_PX = 4.0
#: growing: views beyond a track's own on each side it may grow into (only between views it has)
GROW_VIEWS = 3
#: growing passes (each followed by re-triangulation)
GROW_PASSES = 2


def link_edges(by_view: dict, trees: dict, X: np.ndarray, uvL: np.ndarray, uR: np.ndarray, Tcw: np.ndarray,
               calib, V: int, max_lag: int, link_px: float, circular: bool,  # noqa: ANN001
               rays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Symmetric reprojection links between the stereo matches of views up to ``max_lag`` apart, tolerance
    ``link_px`` px; each match of the later view keeps its cheapest partner. Rows (lag, cost px, a, b),
    nearest views first, cheapest first.

    With ``rays`` (left centres, left directions, right centres, right directions of every match)
    the test is joint instead: the nearest match b within LINK_SEARCH x the tolerance of a's
    projection is linked when the point triangulated from the four rays of a and b reprojects within
    the tolerance into all four images -- the depth error of one biased stereo match (a partly
    hidden seed's visible centre differs between left and right) is then shared by both views."""
    edges = []
    for k, A in by_view.items():
        for lag, m in neighbour_views(k, V, max_lag, circular, both_sides=False):
            if m not in by_view:
                continue
            lnk = link_px
            pl, pr = project_world(calib, Tcw[m], X[A])
            dl, j = nearest(trees[m], pl, lnk if rays is None else LINK_SEARCH * lnk)
            hit = np.flatnonzero(j >= 0)
            a, b = A[hit], by_view[m][j[hit]]
            if rays is None:
                e_r = np.abs(pr[hit] - uR[b])
                ql, qr = project_world(calib, Tcw[k], X[b])
                e_bl = np.linalg.norm(ql - uvL[a], axis=1)
                e_br = np.abs(qr - uR[a])
                ok = (e_r <= lnk) & (e_bl <= lnk) & (e_br <= lnk)
                cost = (dl[hit][ok] + e_r[ok] + e_bl[ok] + e_br[ok]) / 4.0
            else:
                cl, dl_, cr, dr_ = rays
                P = len(a)
                grp = np.tile(np.arange(P), 4)
                Xj = triangulate_rays(grp, P, np.concatenate([cl[a], cr[a], cl[b], cr[b]]),
                                      np.concatenate([dl_[a], dr_[a], dl_[b], dr_[b]]))
                e = np.zeros((P, 4))
                for col, (idx, kk) in enumerate(((a, k), (b, m))):
                    ql, qr = project_world(calib, Tcw[kk], Xj)
                    e[:, 2 * col] = np.linalg.norm(ql - uvL[idx], axis=1)
                    e[:, 2 * col + 1] = np.abs(qr - uR[idx])
                e[~np.isfinite(e)] = np.inf
                ok = np.all(e <= lnk, axis=1)
                cost = e[ok].mean(axis=1)
            a, b = a[ok], b[ok]
            o = np.lexsort((cost, b))  # each b keeps its cheapest a
            first = np.ones(len(o), bool)
            first[1:] = b[o][1:] != b[o][:-1]
            o = o[first]
            edges.append(np.column_stack([np.full(len(o), lag), cost[o], a[o], b[o]]))
    E = np.concatenate(edges) if edges else np.zeros((0, 4))
    return E[np.lexsort((E[:, 1], E[:, 0]))]


def triangulate_tracks(roots: np.ndarray, alive: np.ndarray, view: np.ndarray, uvL: np.ndarray, uR: np.ndarray,
                       poses: np.ndarray, Tcw: np.ndarray, calib, by_view: dict,  # noqa: ANN001
                       cfg: CountConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulates every track (observations sharing a ``root``) from the rays of all its left and right
    keypoints and drops observations reprojecting farther than ``mv_max_reproj_px`` -- only the worst one of
    each track per round (one wrong observation pulls the point and makes the good ones look bad too), up to
    REPROJ_ROUNDS rounds. Dropped and dead (``~alive``) observations become singleton groups. Returns (kept mask,
    group per observation, world point (m) per group)."""
    n = len(view)
    cL, dL = view_rays(calib, poses, view, uvL[:, 0], uvL[:, 1], right=False)
    cR, dR = view_rays(calib, poses, view, uR, uvL[:, 1], right=True)
    C2, D2 = np.concatenate([cL, cR]), np.concatenate([dL, dR])
    keep = alive.copy()
    for _ in range(REPROJ_ROUNDS):
        _, comp = np.unique(np.where(keep, roots, -1 - np.arange(n)), return_inverse=True)
        G = int(comp.max()) + 1
        Xg = triangulate_rays(np.concatenate([comp, comp]), G, C2, D2)
        err = np.full(n, np.inf)
        for k, idx in by_view.items():
            pl, pr = project_world(calib, Tcw[k], Xg[comp[idx]])
            err[idx] = np.maximum(np.linalg.norm(pl - uvL[idx], axis=1), np.abs(pr - uR[idx]))
        bad = keep & ~(err <= cfg.mv_max_reproj_px)
        if not bad.any():
            break
        # drop only the worst of each track per round, then re-triangulate
        worst = np.full(G, -np.inf)
        np.maximum.at(worst, comp[keep], np.where(np.isfinite(err[keep]), err[keep], 1e9))
        bad &= np.where(np.isfinite(err), err, 1e9) >= worst[comp]
        keep &= ~bad
    _, comp = np.unique(np.where(keep, roots, -1 - np.arange(n)), return_inverse=True)
    Xg = triangulate_rays(np.concatenate([comp, comp]), int(comp.max()) + 1, C2, D2)
    return keep, comp, Xg


def grow_tracks(views: list[StereoKeypoints | None], trees: list, comp: np.ndarray, keep: np.ndarray,
                alive: np.ndarray, Xg: np.ndarray, view: np.ndarray, il: np.ndarray, ir: np.ndarray,
                Tcw: np.ndarray, calib, cfg: CountConfig) -> tuple | None:  # noqa: ANN001
    """Growing: every track seen from >= ``min_observations`` views projects its point into the views it
    lacks that have views of the track on both sides within GROW_VIEWS (beyond the end of its arc a seed
    turns away); where an unambiguous left keypoint (no other within GROW_UNIQUE_PX) AND a right keypoint
    (same row) lie within ``mv_grow_px`` of the projection it claims that pair --
    taking it from its current stereo match only when that match belongs to a track with fewer views
    (a ghost match built from this seed's keypoint, or a fragment of it). Tracks with more views
    choose first, nearest first. Returns None when nothing was claimed, else the new observations
    (view, left idx, right idx, claiming group) and the indices of the observations they replace."""
    V = len(views)
    live = keep & alive
    G = int(comp.max()) + 1
    vm = np.zeros((G, V), bool)
    vm[comp[live], view[live]] = True
    nv = vm.sum(axis=1)
    grower = (nv >= cfg.min_observations) & np.all(np.isfinite(Xg), axis=1)
    if not grower.any():
        return None
    lown = [np.full(len(v.left), -1, np.int64) if v is not None else None for v in views]
    rown = [np.full(len(v.right), -1, np.int64) if v is not None else None for v in views]
    for o in np.flatnonzero(alive).tolist():
        lown[view[o]][il[o]] = o
        rown[view[o]][ir[o]] = o
    onv = np.where(live, nv[comp], 0)  # views of the track each observation is in (0 = dropped)
    w = GROW_VIEWS
    cand = []
    for m in range(V):
        if views[m] is None:
            continue
        before = np.zeros(G, bool)
        after = np.zeros(G, bool)
        for off in range(1, w + 1):
            for k, side in ((m - off, before), (m + off, after)):
                if cfg.circular:
                    k %= V
                if 0 <= k < V:
                    side |= vm[:, k]
        # gap filling only (seen on both sides of view m): beyond the end of its arc a seed turns away
        # and its foreshortened neighbour lands where it would project
        near = before & after
        g = np.flatnonzero(grower & near & ~vm[:, m])
        if len(g) == 0:
            continue
        pc = transform_points(Tcw[m], Xg[g])
        front = pc[:, 2] > 0
        g, pc = g[front], pc[front]
        pl, pr = calib.project(pc)
        dl, i = nearest(trees[m][0], pl, cfg.mv_grow_px)
        dr, j = nearest(trees[m][1], np.column_stack([pr, pl[:, 1]]), cfg.mv_grow_px)
        hit = (i >= 0) & (j >= 0)
        if hit.any():
            # unambiguous only: near the silhouette (grazing view) neighbouring seeds crowd together
            # in the image and a hidden seed's projection lands on a neighbour
            d2, _ = trees[m][0].query(pl[hit], k=2)
            hit[np.flatnonzero(hit)[d2[:, 1] < GROW_UNIQUE_PX]] = False
        cand.append(np.column_stack([-nv[g[hit]], dl[hit] + dr[hit], g[hit], np.full(hit.sum(), m), i[hit], j[hit]]))
    if not cand:
        return None
    C = np.concatenate(cand)
    C = C[np.lexsort((C[:, 1], C[:, 0]))]
    taken_l: set = set()
    taken_r: set = set()
    out, dead = [], []
    for _, _, g, m, i, j in C.tolist():
        g, m, i, j = int(g), int(m), int(i), int(j)
        if (m, i) in taken_l or (m, j) in taken_r:
            continue
        oi, oj = int(lown[m][i]), int(rown[m][j])
        if (oi >= 0 and onv[oi] >= nv[g]) or (oj >= 0 and onv[oj] >= nv[g]):
            continue
        taken_l.add((m, i))
        taken_r.add((m, j))
        dead += [o for o in (oi, oj) if o >= 0]
        out.append((m, i, j, g))
    if not out:
        return None
    o = np.array(out, np.int64)
    return o[:, 0], o[:, 1], o[:, 2], o[:, 3], np.unique(np.array(dead, np.int64))
