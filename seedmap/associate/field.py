"""The displacement-field matcher (``refine="field"``): the paper's cost assigned inside a local field.

A coarse displacement histogram per image cell, a few refinements from unambiguous mutual-best
pairs, then the paper's cost plus a field residual term assigned with :func:`assign_capped` and an
ambiguity test. The method and its measured limits: docs/method/association.md.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.associate.assignment import assign_capped, ratio_test
from seedmap.associate.config import SemanticConfig
from seedmap.associate.cost import pair_cost
from seedmap.associate.kernels import box3_filter, box_candidates, box_residuals, knn_grid, sure_pairs, vote_histogram
from seedmap.records import Matches

#: side of the image cells of the coarse displacement histogram (full-res px)
FIELD_CELL_PX = 256.0
#: bin width of that histogram (full-res px)
FIELD_BIN_PX = 3.0
#: at most this many keypoints vote in it (a regular stride)
FIELD_COARSE_POINTS = 1500
#: search half-window of the first refinement (full-res px), shrinking to the expected spread
FIELD_COARSE_TOL_PX = 24.0
#: largest stereo disparity searched (full-res px)
FIELD_MAX_DISPARITY_PX = 1500.0
#: largest frame-to-frame shift searched without a prediction (full-res px)
FIELD_MAX_SHIFT_PX = 1500.0
#: stereo rows searched by the coarse histogram (± full-res px)
FIELD_STEREO_BAND_PX = 12.0
#: the field at a seed match is the median of its this many nearest other seed matches
FIELD_K = 25
#: refinements of the field after the coarse histogram
FIELD_ITERS = 4
#: ratio test of the "seed" matches the field is refined from
FIELD_SEED_RATIO = 0.3


def box_keys(pa: np.ndarray, pb: np.ndarray, half: np.ndarray) -> tuple | None:
    """The sorted search keys of :func:`box_pairs` (arguments of :func:`seedmap.associate.kernels.box_candidates`):
    both point sets divided by ``half``, so the box is the unit max-norm ball, and the points of B sorted by (unit
    row, u). None when either set is empty."""
    if len(pa) == 0 or len(pb) == 0:
        return None
    h = np.maximum(np.asarray(half, np.float64), 1e-9)
    sa = np.asarray(pa, np.float64) / h
    sb = np.asarray(pb, np.float64) / h
    rb = np.floor(sb[:, 1])
    ra = np.floor(sa[:, 1])
    y0 = min(rb.min(), ra.min()) - 1.0
    x0 = min(sb[:, 0].min(), sa[:, 0].min()) - 2.0
    # one key per (row, u): rows lie w apart, w wider than the u range plus the search margin, so a
    # run [u - 1 - m, u + 1 + m] of one row never reaches into the next; m covers the key's rounding
    w = max(sb[:, 0].max(), sa[:, 0].max()) - x0 + 4.0
    m = 1.0 + 1e-9 + 8.0 * np.finfo(np.float64).eps * (max(rb.max(), ra.max()) - y0 + 2.0) * w
    keyb = (rb - y0) * w + (sb[:, 0] - x0)
    order = np.argsort(keyb, kind="stable")
    qa = (ra - y0) * w + (sa[:, 0] - x0)
    return keyb[order], order, qa, w, m, sa, sb


def box_pairs(pa: np.ndarray, pb: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` with ``|pb[j] - pa[i]| <= half`` on both axes (no N x M, no KD-tree).

    ``half`` (2,) is the half-size of the search box in the same unit as the points. The pairs come
    grouped by ``i`` in increasing order (within a group by the position of ``pb[j]``).
    With both axes divided by ``half`` the box is the unit max-norm ball, so the points of B sorted by (unit row, u)
    give, for each point of A and each of the two or three unit rows its box reaches, one contiguous run of
    candidates (found walking the sorted queries); the exact test ``|pb[j] / half - pa[i] / half| <= 1`` (a
    KD-tree's test, same rounding) then runs on those candidates only, in a compiled loop
    (:func:`seedmap.associate.kernels.box_candidates`)."""
    keys = box_keys(pa, pb, half)
    if keys is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return box_candidates(*keys)


def coarse_field(ka: np.ndarray, kb: np.ndarray, lo: np.ndarray, hi: np.ndarray, cell: float, bin_px: float,
                 max_points: int, image_shape: tuple[float, float]) -> np.ndarray:
    """Per-keypoint displacement prior ``(N, 2)`` (u, v image px) by voting in image cells.

    Every candidate pair ``(a, b)`` whose displacement ``kb[b] - ka[a]`` lies in the box
    ``[lo, hi]`` votes in a histogram of displacements of ``a``'s image cell (``cell`` px, bins of
    ``bin_px``). True pairs of a cell share nearly one displacement (rigid, smooth panicles), wrong
    pairs spread over the box, so the peak of the histogram smoothed over 3 x 3 cells and
    neighbouring bins is the cell's displacement. At most ``max_points`` keypoints of A vote (a
    regular stride, deterministic). Cells without votes take the global peak.
    """
    n = len(ka)
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    nb = np.maximum(1, np.ceil((hi - lo) / bin_px).astype(int))
    binw = (hi - lo) / nb
    stride = max(1, int(np.ceil(n / max(1, max_points))))
    sub = np.arange(0, n, stride)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    i, j = box_pairs(ka[sub] + centre, kb, half)
    glob = centre.copy()
    ncx = int(np.ceil(image_shape[0] / cell)) + 1
    ncy = int(np.ceil(image_shape[1] / cell)) + 1
    if len(i) == 0:
        return np.tile(glob, (n, 1))
    i = sub[i]
    pcx = np.clip((ka[:, 0] // cell).astype(int), 0, ncx - 1)
    pcy = np.clip((ka[:, 1] // cell).astype(int), 0, ncy - 1)
    # votes per (cell, u bin, v bin)
    hist = vote_histogram(i, j, ka, kb, (pcx * ncy + pcy).astype(np.int64), lo, binw, nb.astype(np.int64), ncx * ncy)
    hist = hist.reshape(ncx, ncy, nb[0], nb[1])
    g = hist.sum((0, 1))
    gi = np.unravel_index(int(np.argmax(g)), g.shape)
    glob = lo + (np.asarray(gi) + 0.5) * binw
    sm = box3_filter(hist)  # scipy.ndimage.uniform_filter(hist, 3, mode="constant"), bit for bit
    flat_sm = sm.reshape(ncx, ncy, -1)
    best = flat_sm.argmax(-1)
    has = flat_sm.max(-1) > 0
    peak = lo + (np.stack(np.unravel_index(best, (nb[0], nb[1])), -1) + 0.5) * binw
    peak[~has] = glob
    return peak[pcx, pcy]


def local_field(ka: np.ndarray, m: Matches, kb: np.ndarray, k: int, fallback: np.ndarray) -> np.ndarray:
    """Displacement predicted for every keypoint of A from the matches ``m`` (the "seed" matches).

    At each seed match the field is the median displacement of its ``k`` nearest *other* seed
    matches (its own displacement excluded, so a match never predicts itself); every keypoint of
    A takes the field of its nearest seed match (the field is smooth at that scale, and this
    needs one k-NN query over the seeds instead of over all keypoints). ``fallback`` (N, 2)
    where fewer than 3 matches exist."""
    if len(m) < 3:
        return fallback
    pa = ka[m.idx_a]
    at_seed = loo_local_median(pa, kb[m.idx_b] - pa, k)
    # a seed match's own keypoint is its nearest seed (distance 0) unless two seed matches share
    # a position (then the KD-tree decides, as before); only the other keypoints are queried
    near = np.full(len(ka), -1, np.int64)
    near[m.idx_a] = np.arange(len(m))
    if len(np.unique(pa.view(np.complex128))) < len(pa):
        near[:] = -1
    rest = np.flatnonzero(near < 0)
    if len(rest):
        near[rest] = nearest_points(pa, ka[rest], 1)[:, 0]
    return at_seed[near]


def _median_rows(v: np.ndarray) -> np.ndarray:
    """``np.median(v, axis=-1)`` of a ``(..., k)`` array, bit for bit, for finite values: one
    ``np.partition`` at the middle (two middles for even ``k``, averaged as ``np.median`` does)
    without its axis moves and NaN bookkeeping (the median of the field's neighbours is the
    field association's most frequent operation)."""
    k = v.shape[-1]
    if np.isnan(v).any():
        return np.median(v, axis=-1)
    h = k // 2
    if k % 2:
        return np.partition(v, h, axis=-1)[..., h]
    p = np.partition(v, (h - 1, h), axis=-1)
    return (p[..., h - 1] + p[..., h]) / 2.0


def nearest_points(pts: np.ndarray, q: np.ndarray, k: int) -> np.ndarray:
    """Indices ``(Q, k)`` of the ``k`` nearest ``pts`` of every query ``q``, the sets ``cKDTree(pts).query(q, k)``
    gives: a compiled grid search (:func:`seedmap.associate.kernels.knn_grid`), and the KD-tree itself for the
    queries whose ``k``-th and ``(k+1)``-th nearest lie at the same distance (the tree's order decides there) or
    far from every point."""
    pts = np.ascontiguousarray(pts, np.float64)
    q = np.ascontiguousarray(q, np.float64)
    nn, left = knn_grid(pts, q, k)
    if left.any():
        nn[left] = np.asarray(cKDTree(pts).query(q[left], k)[1]).reshape(-1, k)
    return nn


def loo_local_median(pos: np.ndarray, val: np.ndarray, k: int) -> np.ndarray:
    """Median of ``val`` over the ``k`` nearest *other* points of every point ``pos`` (N, 2).

    ``val`` (N, D). Leave-one-out, so an outlier never hides itself in its own median; with fewer
    than 2 points the values themselves are returned (no neighbours to compare with)."""
    n = len(pos)
    val = np.asarray(val, np.float64)
    if n < 2:
        return val.copy()
    kk = min(k + 1, n)
    nn = nearest_points(pos, pos, kk)
    is_self = nn == np.arange(n)[:, None]
    if is_self[:, 0].all():  # the usual case: every point is its own nearest neighbour
        others = nn[:, 1:]
    else:
        # drop the own point (first column unless positions repeat), else the farthest neighbour
        drop = np.where(is_self.any(1), is_self.argmax(1), kk - 1)
        keep = np.ones_like(nn, bool)
        keep[np.arange(n), drop] = False
        others = nn[keep].reshape(n, kk - 1)
    # (D, N, k): the median runs over the contiguous last axis
    return _median_rows(val.reshape(n, -1).T[:, others]).T.reshape(val.shape)


def field_candidates(ka: np.ndarray, kb: np.ndarray, pred: np.ndarray, sig: np.ndarray, gate,
                      gate_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gated candidate pairs within ``gate_sigma`` normalised residual of the predicted field and
    their residuals ``|(kb - ka - pred) / sig|``."""
    keys = box_keys(ka + pred, kb, gate_sigma * sig)
    if keys is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    # the box and the residual gate in one compiled pass, then the travel gates on what is left
    ia, ib, res = box_residuals(*keys, ka, kb, pred, np.asarray(sig, np.float64), float(gate_sigma))
    ok = gate(ia, ib)
    return ia[ok], ib[ok], res[ok]


def field_assign(ka: np.ndarray, kb: np.ndarray, fa: np.ndarray, fb: np.ndarray, sa: np.ndarray,
                 sb: np.ndarray, gate, lo: np.ndarray, hi: np.ndarray, sigma: np.ndarray, cfg: SemanticConfig,
                 scale: float, image_shape: tuple[float, float], fixed_v: float | None = None) -> Matches:
    """The ``refine="field"`` association of keypoints ``ka`` (image A) with ``kb`` (image B).

    ``ka``/``kb`` image pixels, ``fa``/``fb`` the same in full-resolution units, ``sa``/``sb`` their
    neighbour sums, ``gate(ia, ib) -> bool`` the horizontal-travel gates, ``[lo, hi]`` (2,) the
    displacement box searched (image px), ``sigma`` (2,) the expected spread (u, v, image px) of a
    true displacement around the local field. ``fixed_v``: the v displacement is known (rectified
    stereo: 0, epipolar lines are image rows) and only the u field is estimated.
    """
    n, m = len(ka), len(kb)
    if n == 0 or m == 0:
        return Matches()
    pred = field_estimate(ka, kb, gate, lo, hi, sigma, cfg, scale, image_shape, fixed_v)
    ia, ib, res = field_candidates(ka, kb, pred, np.asarray(sigma, np.float64), gate, cfg.field_gate_sigma)
    return assign_in_field(fa, fb, sa, sb, ia, ib, res, n, m, cfg)


def field_estimate(ka: np.ndarray, kb: np.ndarray, gate, lo: np.ndarray, hi: np.ndarray, sigma: np.ndarray,
                   cfg: SemanticConfig, scale: float, image_shape: tuple[float, float],
                   fixed_v: float | None = None) -> np.ndarray:
    """Steps 1-2 of :func:`field_assign` (same arguments): the local displacement field (N, 2; image
    px) at every keypoint of ``ka``, from the coarse histogram refined by the mutual best,
    ratio-tested candidate pairs."""
    n, m = len(ka), len(kb)
    s_inv = 1.0 / scale
    pred = coarse_field(ka, kb, lo, hi, FIELD_CELL_PX * s_inv, FIELD_BIN_PX * s_inv, FIELD_COARSE_POINTS, image_shape)
    if fixed_v is not None:
        pred[:, 1] = fixed_v
    coarse_sig = np.full(2, FIELD_COARSE_TOL_PX * s_inv / cfg.field_gate_sigma)
    iters = FIELD_ITERS
    for it in range(iters):
        # shrink the search window geometrically from the coarse tolerance to ``sigma``
        t = (it + 1) / (iters + 1)
        sig = coarse_sig ** (1 - t) * np.asarray(sigma) ** t if it else coarse_sig
        ia, ib, res = field_candidates(ka, kb, pred, sig, gate, cfg.field_gate_sigma)
        # the next field comes from unambiguous mutual-best pairs only (cheap, no assignment)
        a_sure, b_sure = sure_pairs(ia, ib, res, n, m, FIELD_SEED_RATIO)  # mutual_best + ratio_test
        sure = Matches(a_sure, b_sure, np.zeros(len(a_sure)))
        pred = local_field(ka, sure, kb, FIELD_K, pred)
        if fixed_v is not None:
            pred[:, 1] = fixed_v
    return pred


def assign_in_field(fa: np.ndarray, fb: np.ndarray, sa: np.ndarray, sb: np.ndarray, ia: np.ndarray,
                    ib: np.ndarray, res: np.ndarray, n: int, m: int, cfg: SemanticConfig) -> Matches:
    """Final step: the paper's cost plus ``field_weight * res^2`` (``res`` the candidates'
    normalised residuals from the field) assigned with :func:`assign_capped`, then the ambiguity
    test on the residual (``field_ratio``)."""
    w = cfg.field_weight
    cost = pair_cost(fa, fb, sa, sb, cfg, ia, ib) + w * res * res
    out = assign_capped(n, m, ia, ib, cost, cfg.max_cost + w * cfg.field_gate_sigma ** 2)
    return ratio_test(out, ia, ib, res, n, m, cfg.field_ratio)
