"""Compiled (numba) pixel gathers of the fast detector, each giving exactly what the numpy code it replaces gave.

* :func:`window_batch` - the network's input batch: equal windows of the padded image (a run of tiles plus the
  margin), channels first, scaled to [0, 1] (``np.stack`` + ``astype`` + ``transpose`` in one pass);
* :func:`gather_patches` - the refiner's RGB patches around peaks, written straight into its feature rows;
* :func:`peak_context` - the refiner's neighbour context of every peak (``cKDTree.query(k,
  distance_upper_bound)`` and the numpy that reads it, on a grid of radius-sized cells), with a flag where the
  tree's order could decide, for the caller to ask the tree there.

The two gathers map every uint8 value through a 256-entry table computed by the numpy expression they replace, so
the floats are the same bit for bit. Kernels compile on first use and are cached on disk
(:func:`seedmap.compiled.kernel`).
"""

from __future__ import annotations

import math

import numpy as np

from seedmap.compiled import cell_members, insert_sorted, kernel

#: ``uint8 -> float32`` of the network input (``x.astype(np.float32) * (1.0 / 255.0)``)
INPUT_LUT = np.arange(256).astype(np.uint8).astype(np.float32) * (1.0 / 255.0)
#: ``uint8 -> float32`` of the refiner's patches (``x.astype(np.float32) / 255.0``)
PATCH_LUT = np.arange(256).astype(np.uint8).astype(np.float32) / 255.0


@kernel
def window_batch(pad: np.ndarray, origins: np.ndarray, sh: int, sw: int, lut: np.ndarray) -> np.ndarray:
    """``(K, C, sh, sw)`` float32: for origin ``(y0, x0)`` of ``origins`` (K, 2) the window ``pad[y0: y0 + sh,
    x0: x0 + sw]`` of the ``(H, W, C)`` uint8 image, channels first, every value mapped by ``lut``."""
    k = len(origins)
    ch = pad.shape[2]
    out = np.empty((k, ch, sh, sw), np.float32)
    for b in range(k):
        y0 = origins[b, 0]
        x0 = origins[b, 1]
        for i in range(sh):
            for j in range(sw):
                for c in range(ch):
                    out[b, c, i, j] = lut[pad[y0 + i, x0 + j, c]]
    return out


@kernel
def gather_patches(img: np.ndarray, x: np.ndarray, y: np.ndarray, r: int, lut: np.ndarray, out: np.ndarray) -> None:
    """Write into ``out[p, :(2r+1)^2 C]`` the square of half size ``r`` around pixel ``(x[p], y[p])`` of the
    ``(H, W, C)`` uint8 ``img``, row-major with the channels of a pixel together, every value mapped by ``lut``,
    0 outside the image."""
    h, w, ch = img.shape
    flat = img.reshape(-1)
    rowlen = (2 * r + 1) * ch
    for p in range(len(x)):
        k = 0
        if r <= x[p] < w - r and r <= y[p] < h - r:  # the whole square inside: one contiguous run per row
            for yy in range(y[p] - r, y[p] + r + 1):
                s0 = (yy * w + x[p] - r) * ch
                for e in range(rowlen):
                    out[p, k + e] = lut[flat[s0 + e]]
                k += rowlen
            continue
        for dy in range(-r, r + 1):
            yy = y[p] + dy
            for dx in range(-r, r + 1):
                xx = x[p] + dx
                inside = 0 <= yy < h and 0 <= xx < w
                for c in range(ch):
                    out[p, k] = lut[img[yy, xx, c]] if inside else np.float32(0.0)
                    k += 1


#: relative band around the radius inside which a distance is left to the KD-tree (its rounding decides there)
NEAR_REL = 1e-9


@kernel
def _cells(xy: np.ndarray, cell: float):
    """Square cells of side >= ``cell`` over the points ``xy`` (N >= 1, 2): the grid's width and height, each
    point's cell and the points of each cell (``members[counts[c]:counts[c + 1]]``)."""
    n = len(xy)
    x0, y0, x1, y1 = xy[0, 0], xy[0, 1], xy[0, 0], xy[0, 1]
    for p in range(n):
        x0 = min(x0, xy[p, 0])
        x1 = max(x1, xy[p, 0])
        y0 = min(y0, xy[p, 1])
        y1 = max(y1, xy[p, 1])
    gx = int((x1 - x0) / cell) + 1
    gy = int((y1 - y0) / cell) + 1
    while gx * gy > 4 * n + 16:  # bounded memory for points spread far apart
        cell *= 2.0
        gx = int((x1 - x0) / cell) + 1
        gy = int((y1 - y0) / cell) + 1
    cid = np.empty(n, np.int64)
    for p in range(n):
        cid[p] = min(int((xy[p, 1] - y0) / cell), gy - 1) * gx + min(int((xy[p, 0] - x0) / cell), gx - 1)
    counts, members = cell_members(cid, gx * gy)
    return gx, gy, cid, counts, members


@kernel
def peak_context(xy: np.ndarray, rw: np.ndarray, k: int, radius: float, near: float,
                 scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The refiner's neighbour context ``(N, 8)`` float32 of the peaks ``xy`` (N, 2) with raw rows ``rw`` (N, 7
    float32; logit first, box edges already / ``scale``), among each peak's ``k`` nearest points (itself
    included) closer than ``radius``: flag of a higher-logit neighbour, offset to the strongest one (/ ``scale``),
    its logit difference, its box width and height, the other peaks within ``near`` and within ``radius``; as
    seedmap.detect.cnn_refine computes it from ``cKDTree(xy).query(xy, k, distance_upper_bound=radius)``. Also a
    flag per peak where the tree's order could decide (more than ``k`` points in the disc, another point at
    distance 0, a distance within ``NEAR_REL`` of the radius that is not a whole-pixel offset, two strongest
    higher neighbours of equal logit): the caller computes those rows with the tree."""
    n = len(xy)
    nb = np.zeros((n, 8), np.float32)
    amb = np.zeros(n, np.bool_)
    if n == 0:
        return nb, amb
    gx, gy, cid, counts, members = _cells(xy, max(radius, 1e-9))
    r2 = radius * radius
    lo_band = r2 * (1.0 - NEAR_REL)
    hi_band = r2 * (1.0 + NEAR_REL)
    cap = 64
    bd = np.empty(cap)
    bi = np.empty(cap, np.int64)
    for p in range(n):
        px = xy[p, 0]
        py = xy[p, 1]
        cx = cid[p] % gx
        cy = cid[p] // gx
        cnt = 0
        zeros = 0
        for yy in range(max(cy - 1, 0), min(cy + 2, gy)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gx)):
                c = yy * gx + xx
                for s in range(counts[c], counts[c + 1]):
                    q = members[s]
                    dx = xy[q, 0] - px
                    dy = xy[q, 1] - py
                    d2 = dx * dx + dy * dy
                    if d2 >= lo_band and d2 <= hi_band and not (dx == math.floor(dx) and dy == math.floor(dy)):
                        amb[p] = True  # rounding could decide (whole-pixel offsets give exact squares)
                    if d2 >= r2:
                        continue
                    if d2 == 0.0:
                        zeros += 1
                    if cnt == cap:
                        amb[p] = True
                        continue
                    cnt = insert_sorted(bd, bi, cnt, cap, d2, q)
        if cnt > k or zeros > 1:
            amb[p] = True
            continue
        own = rw[p, 0]
        b = -1
        ties = 0
        n_all = 0
        n_near = 0
        for t in range(cnt):
            q = bi[t]
            if q == p:
                continue
            n_all += 1
            if math.sqrt(bd[t]) <= near:
                n_near += 1
            lq = rw[q, 0]
            if lq > own:
                if b < 0 or lq > rw[b, 0]:
                    b = q
                    ties = 0
                elif lq == rw[b, 0]:
                    ties += 1
        if ties:
            amb[p] = True
            continue
        if b >= 0:
            nb[p, 0] = 1.0
            nb[p, 1] = (xy[b, 0] - px) / scale
            nb[p, 2] = (xy[b, 1] - py) / scale
            nb[p, 3] = rw[b, 0] - own
            nb[p, 4] = rw[b, 1] + rw[b, 3]
            nb[p, 5] = rw[b, 2] + rw[b, 4]
        nb[p, 6] = n_near
        nb[p, 7] = n_all
    return nb, amb
