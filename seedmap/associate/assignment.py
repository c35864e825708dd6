"""One-to-one assignment of scored candidate pairs.

:func:`assign_sparse` is the paper's gated Hungarian (maximum number of pairs, then minimum cost);
:func:`assign_capped` lets a keypoint stay unmatched (the field matcher's assignment);
:func:`mutual_best` and :func:`ratio_test` pick unambiguous pairs by a residual.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, min_weight_full_bipartite_matching

from seedmap.records import Matches

#: Cost given to gated-out pairs (removed after the assignment).
GATED = 1e9


def assign_sparse(n: int, m: int, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray, max_cost: float) -> Matches:
    """Gated linear sum assignment on the K feasible pairs ``(ia, ib)`` with costs ``cost``.

    Equivalent to ``linear_sum_assignment`` on the dense ``n x m`` matrix with ``GATED`` at every
    infeasible entry followed by removal of gated and above-``max_cost`` pairs: the problem splits
    into connected components of the feasible bipartite graph (an optimum of the whole is an optimum
    of each component), and each component is solved densely with scipy. Keypoints without any
    feasible partner never enter the solver.
    """
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


def best_per_row(ia: np.ndarray, ib: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def assign_capped(n: int, m: int, ia: np.ndarray, ib: np.ndarray, cost: np.ndarray, max_cost: float) -> Matches:
    """Minimum-cost matching on the sparse candidates where leaving a keypoint unmatched is allowed.

    Why: :func:`assign_sparse` (the paper's gated Hungarian) first maximises the *number* of
    assignments, so a keypoint whose true partner is missing (occlusion, detector miss, outside
    the other view) is forced onto a neighbour's partner and pushes that neighbour onto a wrong
    one. Here each keypoint may instead stay unmatched at a price of ``max_cost / 2`` per side,
    so a pair is only taken when it beats leaving both ends unmatched (``cost < max_cost``) and
    the sum over the matching is minimal. Solved exactly with
    ``scipy.sparse.csgraph.min_weight_full_bipartite_matching`` on the candidates plus one dummy
    partner per keypoint (a perfect matching then always exists).
    """
    keep = np.asarray(cost) < max_cost
    ia, ib, cost = np.asarray(ia)[keep], np.asarray(ib)[keep], np.asarray(cost, np.float64)[keep]
    if n == 0 or m == 0 or len(ia) == 0:
        return Matches()
    half = 0.5 * max_cost
    rows = np.r_[ia, np.arange(n), n + np.arange(m), n + ib]
    cols = np.r_[ib, m + np.arange(n), np.arange(m), m + ia]
    # +1 on every edge: a perfect matching has exactly n + m edges, so the optimum is unchanged,
    # and no edge weight is an (implicit-looking) zero
    w = np.r_[cost, np.full(n, half), np.full(m, half), np.zeros(len(ia))] + 1.0
    g = csr_matrix((w, (rows, cols)), shape=(n + m, m + n))
    _, col = min_weight_full_bipartite_matching(g)
    a = np.flatnonzero(col[:n] < m)
    b = col[a]
    # cost of each kept pair (look-up in the candidate list)
    c = cost[candidate_positions(ia, ib, m, a, b)]
    return Matches(a.astype(np.int64), b.astype(np.int64), c)


def candidate_positions(ia: np.ndarray, ib: np.ndarray, m: int, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Positions in the candidate list ``(ia, ib)`` of the pairs ``(qa, qb)``, every one of which is
    a candidate (e.g. the pairs an assignment kept); ``m`` = number of keypoints of B. One sort of
    the pair keys ``ia * m + ib`` and a binary search, no dict of pairs."""
    key = ia * m + ib
    order = np.argsort(key)
    return order[np.searchsorted(key[order], qa * m + qb)]


def second_best(ia: np.ndarray, ib: np.ndarray, c: np.ndarray, m: Matches, n: int, mm: int) -> np.ndarray:
    """For each pair of ``m``: the lowest ``c`` among the *other* candidates that share its A or
    its B keypoint (``inf`` when there is none) - the competitor the ratio test compares with."""
    alt = np.full(len(m), np.inf)
    if len(m) == 0:
        return alt
    pos_a = np.full(n, -1)
    pos_a[m.idx_a] = np.arange(len(m))
    pos_b = np.full(mm, -1)
    pos_b[m.idx_b] = np.arange(len(m))
    ka, kb = pos_a[ia], pos_b[ib]
    sel = (ka >= 0) & (m.idx_b[np.maximum(ka, 0)] != ib)
    np.minimum.at(alt, ka[sel], c[sel])
    sel = (kb >= 0) & (m.idx_a[np.maximum(kb, 0)] != ia)
    np.minimum.at(alt, kb[sel], c[sel])
    return alt


def mutual_best(ia: np.ndarray, ib: np.ndarray, c: np.ndarray, n: int, m: int) -> Matches:
    """Pairs that are each other's lowest-``c`` candidate."""
    if len(ia) == 0:
        return Matches()
    a1, b1 = best_per_row(ia, ib, c)
    b2, a2 = best_per_row(ib, ia, c)
    best_a = np.full(m, -1)
    best_a[b2] = a2
    mutual = best_a[b1] == a1
    return Matches(a1[mutual], b1[mutual], np.zeros(int(mutual.sum())))


def ratio_test(out: Matches, ia: np.ndarray, ib: np.ndarray, resid: np.ndarray, n: int, m: int,
                ratio: float) -> Matches:
    """Ambiguity test on the geometric residual: a kept pair must be clearly closer to the local
    field (``resid`` of every candidate ``(ia, ib)``) than any competitor sharing one of its
    keypoints (``resid_pair < ratio * resid_competitor``)."""
    if len(out) == 0 or ratio >= 1.0:
        return out
    pos = candidate_positions(ia, ib, m, out.idx_a, out.idx_b)
    alt = second_best(ia, ib, resid, out, n, m)
    keep = resid[pos] < ratio * alt
    return Matches(out.idx_a[keep], out.idx_b[keep], out.cost[keep])
