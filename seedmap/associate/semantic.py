"""Semantic seed association: the paper's neighbour-structure cost + gated linear assignment.

Why: seeds carry no distinctive appearance, but panicles are rigid, so the *geometry* of a seed's
neighbourhood (distances to its left / right / top / bottom neighbours) is nearly the same in the
two images of a stereo pair and in two consecutive frames. The paper turns this into a cost and
solves a linear sum assignment (Hungarian) problem.

Cost (paper + facts.md, full-resolution pixels). For keypoint ``p`` in its own image the neighbour
sets are ``L = {q : 0 < x_p - x_q < Δ, |y_q - y_p| < ε}`` and likewise ``R, T, B`` (``T``/``B`` swap
the roles of x and y). ``S_d(p)`` is the sum of Euclidean distances from ``p`` to the set ``d``.
The cost of pairing ``a`` (image A) with ``b`` (image B) is::

    C(a, b) = |y_a - y_b| + r * sum_d ratio_d,
    ratio_d = max(S_d(a), S_d(b)) / (min(S_d(a), S_d(b)) + 0.01)   if both sets are non-empty
            = impossible_cost                                      if exactly one is empty
            = 0                                                    if both are empty

(the symmetric ratio of the original code; the paper's plain ratio is minimised by a large
denominator, see facts.md). ``Δ = 1000``, ``ε = 15``, ``r = 10``, keep a pair when ``C ≤ 200``.

Resolution: every parameter of the paper is in pixels of a 4096 px wide image. Rather than
scaling each parameter separately we express keypoints in *full-resolution-equivalent pixels*
(multiply by ``4096 / width``) before computing the cost, so Δ, ε, the 0.01 regulariser, the
|Δy| term and therefore the acceptance threshold 200 all keep the paper's meaning at any
resolution (the ratio terms are scale-free anyway; only |Δy| and the 0.01 are not). The gates use
:class:`~seedmap.associate.base.GateConfig` scaled to the image width, exactly as the descriptor
baselines do, so every matcher sees the same geometric constraints.

Cases the paper leaves open (our choices):

* Zero keypoints in either image -> no matches (empty :class:`Matches`), never an error.
* Rectangular problems (N != M) -> ``scipy.optimize.linear_sum_assignment`` handles them: every
  keypoint of the smaller side is assigned, pairs through a gated entry are removed afterwards.
* Many more keypoints in one image than the other -> only keypoints with at least one feasible
  (gated-in) partner enter the assignment, which keeps the problem small and avoids forcing
  assignments through infeasible entries.
* A direction where only one side has neighbours -> ``impossible_cost`` (a large finite cost,
  above the acceptance threshold, so such a pair is never kept but the solver stays finite).
* Gated-out pairs -> ``GATED`` (1e9) in the cost matrix, removed after the assignment.
* Neighbour sets are built from *all* keypoints of the image (also those the gates or border
  margins exclude from matching), because they describe the visible structure.

Acceptance threshold: the ratio terms are scale-free, and with keypoints in full-resolution
units the |Δy| term is too, so the paper's 200 is kept unchanged at every resolution (at equality
of all four neighbour sums a pair costs ~4 r = 40 plus its |Δy|).

Known weakness and our options. The ratio of *raw sums* changes when a neighbour is visible in
only one image (image border, occlusion, detector miss), and in dense panicles (2,000-5,000
keypoints per image, ~3 px apart on the simulated ranges) many neighbouring seeds have nearly
the same sums, so one assignment on this cost alone is ambiguous (measured: stereo precision
~0.3, temporal ~0.5 with the ``gt`` oracle, see the report). Options (the paper's method stays the
default of :class:`SemanticConfig`):

* ``refine="consensus"`` (:func:`consensus_assign`): panicles are rigid and smooth, so a seed's
  disparity / frame-to-frame shift is close to its neighbours'. The paper's cost gives mutual
  best pairs, their local median displacement predicts every keypoint's partner, and a second
  gated assignment on ``paper cost + w * residual`` keeps candidates near the prediction.
* ``temporal_prediction=True`` gates temporal pairs around a constant-velocity prediction of the
  image shift (the median shift of the previous frame pair).
* ``neighbours="overlap"`` counts, for temporal matching, only neighbours inside the field of view
  common to both frames given the predicted shift.

The SLAM pipeline (``seedmap.slam.config.SlamAssociationConfig``) enables the first two by default.
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
from scipy.optimize import linear_sum_assignment

from seedmap.associate.base import FULL_RES_WIDTH, FrameFeatures, GateConfig
from seedmap.config import ConfigModel
from seedmap.errors import SeedmapError
from seedmap.records import Matches, StereoCalib, StereoDetections, StereoFrame

#: Cost given to gated-out pairs (removed after the assignment).
GATED = 1e9

_DIRS = ("left", "right", "top", "bottom")


class SemanticConfig(ConfigModel):
    """Parameters of the semantic cost (full-resolution pixels, i.e. a 4096 px wide image)."""

    delta_px: float = 1000.0
    eps_px: float = 15.0
    r: float = 10.0
    ratio_eps: float = 0.01
    impossible_cost: float = 1.0e4
    max_cost: float = 200.0
    neighbours: Literal["all", "overlap"] = "all"
    temporal_prediction: bool = False
    prediction_tol_px: float = 150.0
    #: "none" = the paper (one gated assignment on its cost); "consensus" = our option, see module doc
    refine: Literal["none", "consensus"] = "none"
    consensus_k: int = 15
    consensus_tol_px: float = 4.3
    consensus_weight: float = 10.0
    consensus_iters: int = 2
    chunk: int = 512


def full_res_scale(width: int) -> float:
    """Factor that maps pixels of an image ``width`` px wide to full-resolution pixels."""
    return FULL_RES_WIDTH / float(width)


# ----------------------------------------------------------------------------------------------
# neighbour structure and cost
# ----------------------------------------------------------------------------------------------


def _band_pairs(a: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs (i, j), i != j, with ``|a_j - a_i| < eps`` (sort + searchsorted, no N x N)."""
    order = np.argsort(a, kind="stable")
    sa = a[order]
    lo = np.searchsorted(sa, sa - eps, side="right")
    hi = np.searchsorted(sa, sa + eps, side="left")
    cnt = hi - lo
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ii = np.repeat(np.arange(len(sa)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    jj = lo[ii] + offs
    keep = ii != jj
    return order[ii[keep]], order[jj[keep]]


def neighbour_sums(
    kp: np.ndarray, delta: float, eps: float, valid: np.ndarray | None = None, chunk: int = 512
) -> np.ndarray:
    """``(N, 4)`` sums of distances to the left/right/top/bottom neighbour sets (pixels).

    ``kp`` (N, 2) in any pixel unit consistent with ``delta`` and ``eps``. ``valid`` (N,) bool marks
    which points may serve as neighbours (default: all). Candidate pairs come from sorting along
    the band axis (only points within ``eps`` are ever paired), so the work is ~N x band density,
    not N x N. ``chunk`` is kept for API stability (unused).
    """
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    n = len(kp)
    out = np.zeros((n, 4))
    if n == 0:
        return out
    ok = np.ones(n, bool) if valid is None else np.asarray(valid, bool).reshape(-1)
    # horizontal band (|dy| < eps): left / right sets
    i, j = _band_pairs(kp[:, 1], eps)
    keep = ok[j]
    i, j = i[keep], j[keep]
    dx = kp[j, 0] - kp[i, 0]
    dist = np.hypot(dx, kp[j, 1] - kp[i, 1])
    m = (dx < 0) & (-dx < delta)
    out[:, 0] = np.bincount(i[m], dist[m], minlength=n)
    m = (dx > 0) & (dx < delta)
    out[:, 1] = np.bincount(i[m], dist[m], minlength=n)
    # vertical band (|dx| < eps): top / bottom sets
    i, j = _band_pairs(kp[:, 0], eps)
    keep = ok[j]
    i, j = i[keep], j[keep]
    dy = kp[j, 1] - kp[i, 1]
    dist = np.hypot(kp[j, 0] - kp[i, 0], dy)
    m = (dy < 0) & (-dy < delta)
    out[:, 2] = np.bincount(i[m], dist[m], minlength=n)
    m = (dy > 0) & (dy < delta)
    out[:, 3] = np.bincount(i[m], dist[m], minlength=n)
    return out


def structure_cost(
    sa: np.ndarray, sb: np.ndarray, r: float, ratio_eps: float = 0.01, impossible: float = 1.0e4
) -> np.ndarray:
    """Sum over directions of ``r * ratio_d`` between neighbour sums ``sa`` and ``sb``.

    ``sa`` and ``sb`` are ``(..., 4)`` arrays that broadcast against each other: ``(N, 1, 4)`` with
    ``(1, M, 4)`` gives the dense ``(N, M)`` matrix, ``(K, 4)`` with ``(K, 4)`` the costs of K pairs.
    """
    a = np.asarray(sa, np.float64)
    b = np.asarray(sb, np.float64)
    hi = np.maximum(a, b)
    lo = np.minimum(a, b)
    both = lo > 0
    one = (hi > 0) & ~both
    terms = np.where(one, impossible, np.where(both, r * hi / (lo + ratio_eps), 0.0))
    return terms.sum(-1)


def pair_cost(kp_a: np.ndarray, kp_b: np.ndarray, sa: np.ndarray, sb: np.ndarray, cfg: SemanticConfig,
              ia: np.ndarray | None = None, ib: np.ndarray | None = None) -> np.ndarray:
    """The paper's cost ``|y_a - y_b| + r * Σ_d ratio_d`` (full-resolution units).

    Dense ``(N, M)`` when ``ia``/``ib`` are None, else the costs of the K pairs ``(ia[k], ib[k])``.
    """
    if ia is None or ib is None:
        dy = np.abs(kp_a[:, 1][:, None] - kp_b[:, 1][None, :])
        return dy + structure_cost(sa[:, None, :], sb[None, :, :], cfg.r, cfg.ratio_eps, cfg.impossible_cost)
    dy = np.abs(kp_a[ia, 1] - kp_b[ib, 1])
    return dy + structure_cost(sa[ia], sb[ib], cfg.r, cfg.ratio_eps, cfg.impossible_cost)


def assign_sparse(n: int, m: int, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray, max_cost: float) -> Matches:
    """Gated linear sum assignment on the K feasible pairs ``(ia, ib)`` with costs ``cost``.

    Equivalent to ``linear_sum_assignment`` on the dense ``n x m`` matrix with ``GATED`` at every
    infeasible entry followed by removal of gated and above-``max_cost`` pairs: the problem splits
    into connected components of the feasible bipartite graph (an optimum of the whole is an optimum
    of each component), and each component is solved densely with scipy. Keypoints without any
    feasible partner never enter the solver.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if n == 0 or m == 0 or len(ia) == 0:
        return Matches()
    g = coo_matrix((np.ones(len(ia)), (ia, n + ib)), shape=(n + m, n + m))
    _, lab = connected_components(g, directed=False)
    comp = lab[ia]
    order = np.argsort(comp, kind="stable")
    ia, ib, cost, comp = ia[order], ib[order], cost[order], comp[order]
    bounds = np.flatnonzero(np.diff(comp)) + 1
    out_a, out_b, out_c = [], [], []
    for s, e in zip(np.r_[0, bounds], np.r_[bounds, len(comp)], strict=True):
        a, b, c = ia[s:e], ib[s:e], cost[s:e]
        ua, ra = np.unique(a, return_inverse=True)
        ub, rb = np.unique(b, return_inverse=True)
        if len(c) == 1:
            ri, ci, cc = np.zeros(1, int), np.zeros(1, int), c
        else:
            sub = np.full((len(ua), len(ub)), GATED)
            sub[ra, rb] = c
            ri, ci = linear_sum_assignment(sub)
            cc = sub[ri, ci]
        keep = (cc < GATED) & (cc <= max_cost)
        out_a.append(ua[ri[keep]])
        out_b.append(ub[ci[keep]])
        out_c.append(cc[keep])
    return Matches(np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_c))


def assign(cost: np.ndarray, feasible: np.ndarray, max_cost: float) -> Matches:
    """Dense front-end of :func:`assign_sparse`: ``cost`` (N, M) and ``feasible`` (N, M) bool."""
    ia, ib = np.nonzero(feasible)
    return assign_sparse(cost.shape[0], cost.shape[1], ia, ib, cost[ia, ib], max_cost)


def candidate_pairs(ka: np.ndarray, kb: np.ndarray, max_dy: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` with ``|kb[j, 1] - ka[i, 1]| <= max_dy`` without an N x M matrix."""
    order = np.argsort(kb[:, 1], kind="stable")
    vb = kb[order, 1]
    lo = np.searchsorted(vb, ka[:, 1] - max_dy, side="left")
    hi = np.searchsorted(vb, ka[:, 1] + max_dy, side="right")
    cnt = hi - lo
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ia = np.repeat(np.arange(len(ka)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    return ia, order[lo[ia] + offs]


def _best_per_row(ia: np.ndarray, ib: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every distinct ``ia`` the pair with the lowest cost (O(K) after one stable sort)."""
    if len(ia) == 0:
        return ia, ib
    o = np.argsort(ia, kind="stable")
    ia, ib, c = ia[o], ib[o], c[o]
    starts = np.r_[0, np.flatnonzero(np.diff(ia)) + 1]
    counts = np.diff(np.r_[starts, len(ia)])
    mins = np.minimum.reduceat(c, starts)
    pos = np.flatnonzero(c == np.repeat(mins, counts))
    grp = np.repeat(np.arange(len(starts)), counts)[pos]
    first = pos[np.r_[True, np.diff(grp) != 0]]
    return ia[first], ib[first]


def consensus_assign(ka: np.ndarray, kb: np.ndarray, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray,
                     cfg: SemanticConfig, scale: float) -> Matches:
    """Our option on top of the paper's cost: local displacement consensus.

    Panicles are rigid and smooth, so the image displacement (disparity, or the frame-to-frame
    shift) of a seed is close to that of its neighbours. Stage 1 keeps the *mutual* lowest-cost
    pairs of the paper's cost; the displacement predicted for every keypoint of A is the median
    displacement of its ``consensus_k`` nearest stage-1 matches (robust to the many stage-1
    errors); stage 2 keeps only candidates within ``consensus_tol_px`` (full-res px) of that
    prediction, adds ``consensus_weight`` x the residual (full-res px) to the paper's cost and solves
    the gated assignment; the prediction is re-estimated from the result ``consensus_iters`` times.
    """
    from scipy.spatial import cKDTree

    n, m = len(ka), len(kb)
    if len(ia) == 0:
        return Matches()
    a1, b1 = _best_per_row(ia, ib, cost)
    b2, a2 = _best_per_row(ib, ia, cost)
    best_a = np.full(m, -1)
    best_a[b2] = a2
    mutual = best_a[b1] == a1
    ma, mb = a1[mutual], b1[mutual]
    tol = cfg.consensus_tol_px / scale
    out = Matches()
    for _ in range(max(1, cfg.consensus_iters)):
        if len(ma) == 0:
            return Matches()
        disp = kb[mb] - ka[ma]
        k = min(cfg.consensus_k, len(ma))
        _, nn = cKDTree(ka[ma]).query(ka, k)
        pred = np.median(disp[np.asarray(nn).reshape(n, k)], axis=1)
        res = np.hypot(*(kb[ib] - ka[ia] - pred[ia]).T)
        keep = res <= tol
        c2 = cost[keep] + cfg.consensus_weight * res[keep] * scale
        out = assign_sparse(n, m, ia[keep], ib[keep], c2, cfg.max_cost + cfg.consensus_weight * cfg.consensus_tol_px)
        ma, mb = out.idx_a, out.idx_b
    return out


def _inside(u: np.ndarray, width: int, border: float) -> np.ndarray:
    return (u >= border) & (u <= width - 1 - border)


# ----------------------------------------------------------------------------------------------
# stereo and temporal matching on keypoint sets
# ----------------------------------------------------------------------------------------------


def match_stereo_keypoints(
    kp_left: np.ndarray, kp_right: np.ndarray, width: int, gates: GateConfig | None = None,
    cfg: SemanticConfig | None = None,
) -> Matches:
    """Left<->right association of one rectified stereo pair (pixels of an image ``width`` wide)."""
    cfg = cfg or SemanticConfig()
    g = (gates or GateConfig()).scaled(width)
    kl = np.asarray(kp_left, np.float64).reshape(-1, 2)
    kr = np.asarray(kp_right, np.float64).reshape(-1, 2)
    if len(kl) == 0 or len(kr) == 0:
        return Matches()
    s = full_res_scale(width)
    fl, fr = kl * s, kr * s
    sa = neighbour_sums(fl, cfg.delta_px, cfg.eps_px, chunk=cfg.chunk)
    sb = neighbour_sums(fr, cfg.delta_px, cfg.eps_px, chunk=cfg.chunk)
    ia, ib = candidate_pairs(kl, kr, g.stereo_max_dy_px)
    ok = (kl[ia, 0] - kr[ib, 0]) >= g.stereo_min_disparity_px
    ok &= _inside(kl[ia, 0], width, g.stereo_border_px) & _inside(kr[ib, 0], width, g.stereo_border_px)
    ia, ib = ia[ok], ib[ok]
    cost = pair_cost(fl, fr, sa, sb, cfg, ia, ib)
    if cfg.refine == "consensus":
        return consensus_assign(kl, kr, ia, ib, cost, cfg, s)
    return assign_sparse(len(kl), len(kr), ia, ib, cost, cfg.max_cost)


def match_temporal_keypoints(
    kp_prev: np.ndarray, kp_cur: np.ndarray, width: int, gates: GateConfig | None = None,
    cfg: SemanticConfig | None = None, predicted_shift: float | None = None,
) -> Matches:
    """Previous-left <-> current-left association under the horizontal-travel gates.

    ``predicted_shift`` (pixels of this image, u_cur - u_prev) enables the constant-velocity gate
    and the ``overlap`` neighbour option when ``cfg`` asks for them; ``None`` = no prediction.
    """
    cfg = cfg or SemanticConfig()
    g = (gates or GateConfig()).scaled(width)
    ka = np.asarray(kp_prev, np.float64).reshape(-1, 2)
    kb = np.asarray(kp_cur, np.float64).reshape(-1, 2)
    if len(ka) == 0 or len(kb) == 0:
        return Matches()
    s = full_res_scale(width)
    fa, fb = ka * s, kb * s
    va = vb = None
    if cfg.neighbours == "overlap" and predicted_shift is not None:
        # count only neighbours that are inside the view common to both frames
        va = _inside(ka[:, 0] + predicted_shift, width, 0.0)
        vb = _inside(kb[:, 0] - predicted_shift, width, 0.0)
    sa = neighbour_sums(fa, cfg.delta_px, cfg.eps_px, va, chunk=cfg.chunk)
    sb = neighbour_sums(fb, cfg.delta_px, cfg.eps_px, vb, chunk=cfg.chunk)
    ia, ib = candidate_pairs(ka, kb, g.temporal_max_dy_px)
    du = kb[ib, 0] - ka[ia, 0]
    ok = g.travel_sign * du >= g.temporal_min_shift_px
    if cfg.temporal_prediction and predicted_shift is not None:
        ok &= np.abs(du - predicted_shift) <= cfg.prediction_tol_px / s
    ok &= _inside(ka[ia, 0], width, g.temporal_border_px) & _inside(kb[ib, 0], width, g.temporal_border_px)
    ia, ib = ia[ok], ib[ok]
    cost = pair_cost(fa, fb, sa, sb, cfg, ia, ib)
    if cfg.refine == "consensus":
        m = consensus_assign(ka, kb, ia, ib, cost, cfg, s)
    else:
        m = assign_sparse(len(ka), len(kb), ia, ib, cost, cfg.max_cost)
    # post-filter on the vertical offset (facts.md: 60 px at full resolution)
    keep = np.abs(kb[m.idx_b, 1] - ka[m.idx_a, 1]) <= g.temporal_post_max_dy_px
    return Matches(m.idx_a[keep], m.idx_b[keep], m.cost[keep])


# ----------------------------------------------------------------------------------------------
# the Matcher
# ----------------------------------------------------------------------------------------------


class SeedMatcher:
    """Seeds as semantic features: a detector gives keypoints, the semantic cost associates them.

    ``detector`` needs ``detect_stereo(frame: StereoFrame) -> StereoDetections`` (every seedmap
    detector has it); :meth:`features_from_detections` works without a detector.
    ``match_temporal`` remembers the median image shift of the last accepted temporal matches
    (used only by the optional constant-velocity prediction / overlap options).
    """

    name = "seeds"

    def __init__(self, calib: StereoCalib, detector=None, cfg: SemanticConfig | None = None,
                 gates: GateConfig | None = None) -> None:
        self.calib = calib
        self.detector = detector
        self.cfg = cfg or SemanticConfig()
        self.gates = gates or GateConfig()
        self._last_shift: float | None = None

    def features_from_detections(self, det: StereoDetections) -> FrameFeatures:
        t0 = time.perf_counter()
        kl, kr = det.left.keypoints, det.right.keypoints
        m = match_stereo_keypoints(kl, kr, self.calib.width, self.gates, self.cfg)
        ms = (time.perf_counter() - t0) * 1e3
        return FrameFeatures(
            index=det.index, timestamp=det.timestamp, kp_left=kl, kp_right=kr, stereo=m,
            seed_ids_left=det.left.seed_ids, seed_ids_right=det.right.seed_ids,
            timings_ms={"stereo_match": ms},
        )

    def features(self, frame: StereoFrame) -> FrameFeatures:
        if self.detector is None:
            raise SeedmapError("the seeds matcher needs a detector to turn images into keypoints")
        t0 = time.perf_counter()
        det = self.detector.detect_stereo(frame)
        t_det = (time.perf_counter() - t0) * 1e3
        f = self.features_from_detections(det)
        f.timings_ms["detect"] = t_det
        return f

    def match_temporal(self, prev: FrameFeatures, cur: FrameFeatures) -> Matches:
        pred = self._last_shift if (self.cfg.temporal_prediction or self.cfg.neighbours == "overlap") else None
        m = match_temporal_keypoints(prev.kp_left, cur.kp_left, self.calib.width, self.gates, self.cfg, pred)
        if len(m) >= 5:
            self._last_shift = float(np.median(cur.kp_left[m.idx_b, 0] - prev.kp_left[m.idx_a, 0]))
        return m

    def reset(self) -> None:
        self._last_shift = None
