"""Compiled (numba) inner loops of the association, each giving exactly what the numpy code it replaces gave.

* :func:`box_candidates` - the candidate runs of :func:`seedmap.associate.field.box_pairs` and their exact box test,
  pair by pair in the numpy version's order (no repeat/offset arrays of every candidate); :func:`box_residuals`
  the same with the field's residual gate of :func:`seedmap.associate.field.field_candidates`;
* :func:`band_sums` - the left/right (or top/bottom) neighbour sums of :func:`seedmap.associate.cost.neighbour_sums`,
  every pair's distance added in the order ``np.bincount`` adds it (same sums bit for bit);
* :func:`sure_pairs` - the mutual-best, ratio-tested pairs the field is refined from (``mutual_best`` +
  ``ratio_test`` of seedmap.associate.assignment without their sorts and ``np.minimum.at``);
* :func:`vote_histogram` - the coarse field's displacement histogram (``np.bincount`` of the votes' bins);
* :func:`box3_filter` - ``scipy.ndimage.uniform_filter(x, 3, mode="constant")`` of a 4-D float32 array, line by
  line as scipy does (the lines of one axis advanced together);
* :func:`knn_grid` - the ``k`` nearest points of every query point on a uniform grid, with a flag where the
  ``k``-th and ``(k+1)``-th distances tie or the query is far from every point (the caller asks a KD-tree there,
  so ties resolve as before).

Kernels compile on first use and are cached on disk (:func:`seedmap.compiled.kernel`). The method: docs/method/association.md.
"""

from __future__ import annotations

import math

import numpy as np

from seedmap.compiled import cell_members, insert_sorted, kernel

#: relative gap below which the k-th and (k+1)-th squared distances count as a tie (left to the KD-tree)
TIE_REL = 1e-9
#: rings of grid cells searched around a k-NN query before it is left to the KD-tree (a query far from all points)
MAX_RING = 16
#: points per occupied grid cell of the k-NN search (fastest on the field's seed matches: 4 for k = 26, ...
KNN_CELL_POINTS = 4.0
#: ... 12 for the nearest seed match of every keypoint, whose queries lie farther from the points)
KNN_CELL_POINTS_1 = 12.0


@kernel
def _runs(ks: np.ndarray, qa: np.ndarray, w: float, m: float) -> tuple[np.ndarray, np.ndarray]:
    """For each query ``i`` and row offset -1, 0, 1 the run ``[lo, hi)`` of sorted keys ``ks`` within
    ``qa[i] + dr * w -+ m`` (``searchsorted`` left / right): the queries taken in sorted order, so both run ends
    only move forward along ``ks``."""
    n = len(qa)
    nk = len(ks)
    lo = np.empty(3 * n, np.int64)
    hi = np.empty(3 * n, np.int64)
    oq = np.argsort(qa)
    for c in range(3):
        pl = 0
        ph = 0
        for t in range(n):
            i = oq[t]
            base = qa[i] + (c - 1.0) * w
            vl = base - m
            vh = base + m
            while pl < nk and ks[pl] < vl:
                pl += 1
            while ph < nk and ks[ph] <= vh:
                ph += 1
            lo[3 * i + c] = pl
            hi[3 * i + c] = max(ph, pl)
    return lo, hi


@kernel
def box_candidates(ks: np.ndarray, order: np.ndarray, qa: np.ndarray, w: float, m: float, sa: np.ndarray,
                   sb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i, j)`` with ``|sb[j] - sa[i]| <= 1`` on both axes: for each query ``i`` (in order) and row offset
    -1, 0, 1 the run of sorted keys ``ks`` (``order``: their points) within ``qa[i] + dr * w -+ m``, tested exactly."""
    lo, hi = _runs(ks, qa, w, m)
    total = int((hi - lo).sum())
    oi = np.empty(total, np.int64)
    oj = np.empty(total, np.int64)
    k = 0
    for i in range(len(qa)):
        ax, ay = sa[i, 0], sa[i, 1]
        for c in range(3):
            for p in range(lo[3 * i + c], hi[3 * i + c]):
                j = order[p]
                if abs(sb[j, 0] - ax) <= 1.0 and abs(sb[j, 1] - ay) <= 1.0:
                    oi[k] = i
                    oj[k] = j
                    k += 1
    return oi[:k], oj[:k]


@kernel
def box_residuals(ks: np.ndarray, order: np.ndarray, qa: np.ndarray, w: float, m: float, sa: np.ndarray,
                  sb: np.ndarray, ka: np.ndarray, kb: np.ndarray, pred: np.ndarray, sig: np.ndarray,
                  gate_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs of :func:`box_candidates` whose normalised residual ``hypot((kb[j] - ka[i] - pred[i]) / sig)``
    (the numpy expression, evaluated the same way) is at most ``gate_sigma``, with that residual."""
    lo, hi = _runs(ks, qa, w, m)
    total = int((hi - lo).sum())
    oi = np.empty(total, np.int64)
    oj = np.empty(total, np.int64)
    orr = np.empty(total)
    k = 0
    for i in range(len(qa)):
        ax, ay = sa[i, 0], sa[i, 1]
        for c in range(3):
            for p in range(lo[3 * i + c], hi[3 * i + c]):
                j = order[p]
                if abs(sb[j, 0] - ax) <= 1.0 and abs(sb[j, 1] - ay) <= 1.0:
                    r = math.hypot(((kb[j, 0] - ka[i, 0]) - pred[i, 0]) / sig[0],
                                   ((kb[j, 1] - ka[i, 1]) - pred[i, 1]) / sig[1])
                    if r <= gate_sigma:
                        oi[k] = i
                        oj[k] = j
                        orr[k] = r
                        k += 1
    return oi[:k], oj[:k], orr[:k]


@kernel
def band_sums(sb: np.ndarray, sa: np.ndarray, eps: float, delta: float, ok: np.ndarray,
              use_ok: bool) -> tuple[np.ndarray, np.ndarray]:
    """Sums of distances to the points before / after each point along ``sa`` within the band ``|Δsb| < eps``
    and ``0 < |Δsa| < delta`` (``sb`` sorted ascending; ``ok`` marks the points that count as neighbours when
    ``use_ok``). Pairs are visited ``i`` ascending, then ``j`` ascending, as the numpy version lists them."""
    n = len(sb)
    before = np.zeros(n)
    after = np.zeros(n)
    for i in range(n):
        lim = sb[i] + eps
        j = i + 1
        while j < n and sb[j] < lim:
            d = sa[j] - sa[i]
            if d != 0 and abs(d) < delta:
                dist = math.hypot(d, sb[j] - sb[i])
                if d > 0:
                    first, second = i, j
                else:
                    first, second = j, i
                if not use_ok or ok[first]:
                    before[second] += dist
                if not use_ok or ok[second]:
                    after[first] += dist
            j += 1
    return before, after


@kernel
def sure_pairs(ia: np.ndarray, ib: np.ndarray, c: np.ndarray, n: int, m: int,
               ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`seedmap.associate.assignment.mutual_best` followed by its ``ratio_test`` on the same ``c``, in one pass
    each: the candidates ``(ia, ib)`` that are the lowest-``c`` candidate of both their keypoints (the first such
    candidate on ties), kept when ``c < ratio * c`` of every other candidate sharing one of their keypoints
    (``ratio >= 1``: no test); ordered by ``ia``."""
    best_a = np.full(n, -1, np.int64)
    best_b = np.full(m, -1, np.int64)
    for k in range(len(ia)):
        a, b = ia[k], ib[k]
        if best_a[a] < 0 or c[k] < c[best_a[a]]:
            best_a[a] = k
        if best_b[b] < 0 or c[k] < c[best_b[b]]:
            best_b[b] = k
    # mutual: a's best candidate is also its B keypoint's best (same a)
    kept = np.full(n, -1, np.int64)
    cnt = 0
    for a in range(n):
        k = best_a[a]
        if k >= 0 and ia[best_b[ib[k]]] == a:
            kept[a] = k
            cnt += 1
    if ratio < 1.0:
        kept_b = np.full(m, -1, np.int64)
        for a in range(n):
            if kept[a] >= 0:
                kept_b[ib[kept[a]]] = kept[a]
        alt_a = np.full(n, np.inf)
        alt_b = np.full(m, np.inf)
        for k in range(len(ia)):
            a, b = ia[k], ib[k]
            if kept[a] >= 0 and ib[kept[a]] != b:
                alt_a[a] = min(alt_a[a], c[k])
            if kept_b[b] >= 0 and ia[kept_b[b]] != a:
                alt_b[b] = min(alt_b[b], c[k])
        cnt = 0
        for a in range(n):
            k = kept[a]
            if k >= 0:
                if c[k] < ratio * min(alt_a[a], alt_b[ib[k]]):
                    cnt += 1
                else:
                    kept[a] = -1
    oa = np.empty(cnt, np.int64)
    ob = np.empty(cnt, np.int64)
    t = 0
    for a in range(n):
        if kept[a] >= 0:
            oa[t] = a
            ob[t] = ib[kept[a]]
            t += 1
    return oa, ob


@kernel
def vote_histogram(i: np.ndarray, j: np.ndarray, ka: np.ndarray, kb: np.ndarray, cell_of: np.ndarray,
                   lo: np.ndarray, binw: np.ndarray, nb: np.ndarray, ncell: int) -> np.ndarray:
    """float32 ``(ncell * nb[0] * nb[1])`` vote counts: pair ``(i, j)`` votes in cell ``cell_of[i]`` at the bin of
    its displacement ``kb[j] - ka[i]`` (``int((d - lo) / binw)`` clipped to the bins, as the numpy version)."""
    n0, n1 = nb[0], nb[1]
    hist = np.zeros(ncell * n0 * n1, np.float32)
    for p in range(len(i)):
        a, b = i[p], j[p]
        u = int(((kb[b, 0] - ka[a, 0]) - lo[0]) / binw[0])
        v = int(((kb[b, 1] - ka[a, 1]) - lo[1]) / binw[1])
        u = min(max(u, 0), n0 - 1)
        v = min(max(v, 0), n1 - 1)
        hist[(cell_of[a] * n0 + u) * n1 + v] += 1.0
    return hist


@kernel
def _box3_pass(flat: np.ndarray, base: int, length: int, post: int, tmp: np.ndarray, m2: np.ndarray,
               m1: np.ndarray) -> None:
    """One pass of :func:`box3_filter` along the first axis of the ``length`` x ``post`` block at ``base`` of
    ``flat``, its ``post`` lines advanced together (contiguous reads); ``tmp``, ``m2``, ``m1``: scratch."""
    for q in range(post):
        x0 = np.float64(flat[base + q])
        x1 = np.float64(flat[base + post + q]) if length > 1 else 0.0
        tmp[q] = (0.0 + x0) + x1
        m2[q] = 0.0  # input at t - 2
        m1[q] = x0  # input at t - 1
        flat[base + q] = np.float32(tmp[q] / 3.0) if tmp[q] != 0.0 else np.float32(0.0)
    for t in range(1, length):
        bt = base + t * post
        last = t + 1 >= length
        for q in range(post):
            xn = 0.0 if last else np.float64(flat[bt + post + q])
            tmp[q] += xn - m2[q]
            m2[q] = m1[q]
            m1[q] = flat[bt + q]
            # most windows of the sparse histogram are empty: 0 / 3 needs no division
            flat[bt + q] = np.float32(tmp[q] / 3.0) if tmp[q] != 0.0 else np.float32(0.0)


@kernel
def _box3_line(flat: np.ndarray, b: int, length: int) -> None:
    """One pass of :func:`box3_filter` along one contiguous line of ``flat`` starting at ``b``."""
    x0 = np.float64(flat[b])
    x1 = np.float64(flat[b + 1]) if length > 1 else 0.0
    tmp = (0.0 + x0) + x1
    p2 = 0.0
    p1 = x0
    flat[b] = np.float32(tmp / 3.0) if tmp != 0.0 else np.float32(0.0)
    for t in range(1, length):
        xn = np.float64(flat[b + t + 1]) if t + 1 < length else 0.0
        cur = np.float64(flat[b + t])
        tmp += xn - p2
        p2 = p1
        p1 = cur
        flat[b + t] = np.float32(tmp / 3.0) if tmp != 0.0 else np.float32(0.0)


@kernel
def box3_filter(x: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.uniform_filter(x, size=3, mode="constant")`` of a C-contiguous 4-D float32 array, bit for
    bit: per axis, per line, the window's sum in double (a running sum: exact for these float32 values) divided by
    3 and stored as float32 before the next axis. Axes 2 and 3 are filtered block by block of the first two
    axes' indices (each block stays in cache between its two passes)."""
    out = x.copy()
    n0, n1, n2, n3 = out.shape
    flat = out.reshape(-1)
    if flat.size == 0:
        return out
    big = max(n1 * n2 * n3, 1)
    tmp = np.empty(big)
    m2 = np.empty(big)
    m1 = np.empty(big)
    _box3_pass(flat, 0, n0, n1 * n2 * n3, tmp, m2, m1)
    for a in range(n0):
        _box3_pass(flat, a * n1 * n2 * n3, n1, n2 * n3, tmp, m2, m1)
    blk = n2 * n3
    for c in range(n0 * n1):
        _box3_pass(flat, c * blk, n2, n3, tmp, m2, m1)
        for r in range(n2):
            _box3_line(flat, c * blk + r * n3, n3)
    return out


@kernel
def _grid(pts: np.ndarray, x0: float, y0: float, x1: float, y1: float, cell: float):
    """Square cells of side ~``cell`` over the box ``[x0, x1] x [y0, y1]``: the cell side used, the grid size
    and the points of each cell (``members[counts[c]:counts[c + 1]]``)."""
    n = len(pts)
    gx = max(1, min(int((x1 - x0) / cell) + 1, 4096))
    gy = max(1, min(int((y1 - y0) / cell) + 1, 4096))
    while gx * gy > 16 * n + 16:  # bounded memory for tiny cells
        gx = max(1, gx // 2)
        gy = max(1, gy // 2)
    cell = max((x1 - x0) / gx, (y1 - y0) / gy, 1e-9) * (1.0 + 1e-12)
    cid = np.empty(n, np.int64)
    for p in range(n):
        cx = min(int((pts[p, 0] - x0) / cell), gx - 1)
        cy = min(int((pts[p, 1] - y0) / cell), gy - 1)
        cid[p] = cy * gx + cx
    counts, members = cell_members(cid, gx * gy)
    return cell, gx, gy, counts, members


@kernel
def knn_grid(pts: np.ndarray, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(Q, k)`` of the ``k`` nearest ``pts`` (N, 2; Euclidean, ``k <= N``) of every query ``q`` (Q, 2),
    nearest first, and a flag per query: True where the set is not well defined (the ``k``-th and ``(k+1)``-th
    squared distances within ``TIE_REL``) or the query lies more than ``MAX_RING`` rings of cells from its
    neighbours, for the caller to decide there. Points sit in square grid cells holding ~``KNN_CELL_POINTS`` each
    where they are (sized on their occupied cells: seeds cluster in panicles); rings of cells are searched outward
    until no point outside the searched block can beat the (k+1)-th best."""
    n = len(pts)
    nq = len(q)
    nn = np.empty((nq, k), np.int64)
    far = np.zeros(nq, np.bool_)
    nn[:] = -1
    x0, y0 = pts[0, 0], pts[0, 1]
    x1, y1 = x0, y0
    for p in range(n):
        x0 = min(x0, pts[p, 0])
        x1 = max(x1, pts[p, 0])
        y0 = min(y0, pts[p, 1])
        y1 = max(y1, pts[p, 1])
    target = KNN_CELL_POINTS_1 if k == 1 else KNN_CELL_POINTS
    cell = max(math.sqrt(max((x1 - x0) * (y1 - y0), 1e-12) * target / n), 1e-9)
    cell, gx, gy, counts, members = _grid(pts, x0, y0, x1, y1, cell)
    used = 0
    for c in range(gx * gy):
        used += counts[c + 1] > counts[c]
    mean = n / max(used, 1)
    if mean > 1.5 * target:  # clustered points: smaller cells where they are
        cell, gx, gy, counts, members = _grid(pts, x0, y0, x1, y1, cell * math.sqrt(target / mean))
    cap = min(k + 1, n)
    bd = np.empty(cap)
    bi = np.empty(cap, np.int64)
    # coordinates in cell order: each cell's points are contiguous
    sx = np.empty(n)
    sy = np.empty(n)
    for s in range(n):
        sx[s] = pts[members[s], 0]
        sy[s] = pts[members[s], 1]
    for t in range(nq):
        qx, qy = q[t, 0], q[t, 1]
        cx = min(max(int(math.floor((qx - x0) / cell)), -1), gx)
        cy = min(max(int(math.floor((qy - y0) / cell)), -1), gy)
        cnt = 0
        r = 0
        while True:
            for yy in range(cy - r, cy + r + 1):
                if yy < 0 or yy >= gy:
                    continue
                step = 1 if (yy == cy - r or yy == cy + r) else 2 * r
                xx = cx - r
                while xx <= cx + r:
                    if 0 <= xx < gx:
                        c = yy * gx + xx
                        for s in range(counts[c], counts[c + 1]):
                            dx = sx[s] - qx
                            dy = sy[s] - qy
                            d = dx * dx + dy * dy
                            if cnt == cap and d >= bd[cap - 1]:
                                continue
                            cnt = insert_sorted(bd, bi, cnt, cap, d, members[s])
                    xx += step
            if cx - r <= 0 and cy - r <= 0 and cx + r >= gx - 1 and cy + r >= gy - 1:
                break  # the whole grid searched
            if r >= MAX_RING:  # a query far from every point: left to the caller (flagged)
                far[t] = True
                break
            if cnt == cap:
                # distance from the query to the nearest point outside the searched block of cells
                gap = min(qx - (x0 + (cx - r) * cell), x0 + (cx + r + 1) * cell - qx,
                          qy - (y0 + (cy - r) * cell), y0 + (cy + r + 1) * cell - qy)
                if gap > 0 and bd[cap - 1] < gap * gap * (1.0 - 1e-9):  # margin for the rounding
                    break
            r += 1
        if far[t]:
            continue
        for s in range(k):
            nn[t, s] = bi[s]
        if cap > k and bd[k] - bd[k - 1] <= TIE_REL * bd[k]:
            far[t] = True
    return nn, far
