"""The paper's pair cost: neighbour-distance sums per direction and their symmetric ratios.

Keypoints enter in full-resolution-equivalent pixels (:func:`full_res_scale`), so the paper's
pixel parameters keep their meaning at any image width (docs/method/association.md).
"""

from __future__ import annotations

import numpy as np

from seedmap.associate.base import FULL_RES_WIDTH
from seedmap.associate.config import SemanticConfig
from seedmap.associate.kernels import band_sums

#: regulariser of the ratio's denominator (full-res px), paper 0.01
RATIO_EPS = 0.01
#: cost of a direction whose neighbour set is empty in one image only (above any kept pair's cost)
IMPOSSIBLE_COST = 1.0e4


def full_res_scale(width: int) -> float:
    """Factor that maps pixels of an image ``width`` px wide to full-resolution pixels."""
    return FULL_RES_WIDTH / float(width)


def neighbour_sums(
    kp: np.ndarray, delta: float, eps: float, valid: np.ndarray | None = None
) -> np.ndarray:
    """``(N, 4)`` sums of distances to the left/right/top/bottom neighbour sets (pixels).

    ``kp`` (N, 2) in any pixel unit consistent with ``delta`` and ``eps``. ``valid`` (N,) bool marks
    which points may serve as neighbours (default: all). Candidate pairs come from sorting along
    the band axis (only points within ``eps`` are ever paired) and every unordered pair is
    visited once (``q`` left of ``p`` <=> ``p`` right of ``q``, same distance) in a compiled loop
    (:func:`seedmap.associate.kernels.band_sums`), so the work is ~N x band density / 2, not N x N.
    """
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    n = len(kp)
    out = np.zeros((n, 4))
    if n == 0:
        return out
    use_ok = valid is not None
    ok = np.asarray(valid, bool).reshape(-1) if use_ok else np.ones(1, bool)
    # axis 0: horizontal band (|dy| < eps) -> left / right sets; axis 1: vertical -> top / bottom
    for along, band, col in ((0, 1, 0), (1, 0, 2)):
        # points in band order (each point's band partners follow it contiguously); sums scattered back
        order = np.argsort(kp[:, band], kind="stable")
        before, after = band_sums(np.ascontiguousarray(kp[order, band]), np.ascontiguousarray(kp[order, along]),
                                  float(eps), float(delta), ok[order] if use_ok else ok, use_ok)
        out[order, col] = before
        out[order, col + 1] = after
    return out


def structure_cost(
    sa: np.ndarray, sb: np.ndarray, r: float, ratio_eps: float = RATIO_EPS, impossible: float = IMPOSSIBLE_COST
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
        return dy + structure_cost(sa[:, None, :], sb[None, :, :], cfg.r)
    dy = np.abs(kp_a[ia, 1] - kp_b[ib, 1])
    return dy + structure_cost(sa[ia], sb[ib], cfg.r)


def full_res_sums(ka: np.ndarray, kb: np.ndarray, s: float, cfg: SemanticConfig,
                  sums: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``sums`` when given (a cache), else the :func:`neighbour_sums` of ``ka`` and ``kb`` (image px)
    in full-resolution units (``s`` = :func:`full_res_scale`), with every keypoint a neighbour."""
    if sums is not None:
        return sums
    return neighbour_sums(ka * s, cfg.delta_px, cfg.eps_px), neighbour_sums(kb * s, cfg.delta_px, cfg.eps_px)


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
