"""Flash shadows: pending shadow segments, sparse shadow rays and their edge-aware fill."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.sim.render.culling import _CamCovers
from seedmap.sim.render.scene import _FrameScene

SHADOW_STRIDE = 2  # flash shadow rays on every 2nd pixel of every 2nd row (plus where none is near)
SHADOW_RADIUS = 2  # px: half-width of the edge-aware window the shadow samples are averaged over


@dataclass
class _PendingShadows:
    """Shadow segments not traced yet (their ends are formed only for the few that get traced): ray
    indices, and the shading's surface points, normals, light directions and flash points ((3, m)
    float32, column ``at[k]`` for ray ``idx[k]``), pixels of the rays."""

    idx: np.ndarray  # (K,) int64 ray indices
    at: np.ndarray  # (K,) int64 columns of p / nrm / ldir / lp
    p: np.ndarray
    nrm: np.ndarray
    ldir: np.ndarray
    lp: np.ndarray
    pix: np.ndarray | None  # (N, 2) float32 pixel (u, v) of every ray (indexed by ``idx``)

    @staticmethod
    def empty() -> "_PendingShadows":
        z = np.zeros((3, 0), np.float32)
        e = np.zeros(0, np.int64)
        return _PendingShadows(e, e, z, z, z, z, None)

    def segments(self, sel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Starts, vectors (to the flash point) and pixels of pending segments ``sel``."""
        a = self.at[sel]
        start = _shadow_start(self.p[:, a], self.nrm[:, a], self.ldir[:, a])
        return start, np.ascontiguousarray(self.lp[:, a].T) - start, None if self.pix is None else self.pix[self.idx[sel]]


def _shadow_start(p: np.ndarray, nrm: np.ndarray, ldir: np.ndarray) -> np.ndarray:
    """Shadow-segment starts (K, 3): off the surface along its normal and towards the flash (no
    self-hits of the surface's own triangles)."""
    return np.ascontiguousarray((p + nrm * np.float32(2e-4) + ldir * np.float32(5e-4)).T)


def _shadow_grid(H: int, W: int) -> np.ndarray:
    """Row-major bool mask of the pixels that get their own flash shadow ray (every ``SHADOW_STRIDE``-th
    pixel in both directions)."""
    g = np.zeros((H, W), bool)
    g[::SHADOW_STRIDE, ::SHADOW_STRIDE] = True
    return g.reshape(-1)


def _edge_aware_sum(num: np.ndarray, den: np.ndarray, key: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Separable box sums of ``num`` and ``den`` (H x W float32, finite) over the ``(2 radius + 1)^2``
    window, counting only the pixels whose ``key`` equals the centre pixel's (no padding copies: each
    shift adds one shifted slice times the 0/1 key agreement; ``np.add(where=...)`` is 7x slower)."""
    for axis in (1, 0):
        n2, d2 = num.copy(), den.copy()
        L = key.shape[axis]
        for s in range(1, radius + 1):
            if s >= L:
                break
            lo = (slice(None), slice(0, L - s)) if axis == 1 else (slice(0, L - s), slice(None))
            hi = (slice(None), slice(s, L)) if axis == 1 else (slice(s, L), slice(None))
            same = (key[lo] == key[hi]).view(np.uint8)
            for src_, dst in ((num, n2), (den, d2)):
                tmp = np.multiply(src_[hi], same, dtype=np.float32)
                dst[lo] += tmp
                np.multiply(src_[lo], same, out=tmp, dtype=np.float32)
                dst[hi] += tmp
        num, den = n2, d2
    return num, den


def _filter_visibility(vis: np.ndarray, key: np.ndarray, radius: int = 2) -> np.ndarray:
    """Edge-aware box filter of the flash visibility (one random flash sample per pixel makes soft
    shadows noisy): average only over neighbours that see the same object, separably. Used with a
    shadow ray on every pixel (``SHADOW_STRIDE = 1``), the reference the sparse samples are tested against."""
    num, den = _edge_aware_sum(vis.astype(np.float32), np.ones(vis.shape, np.float32), key, radius)
    return num / den


def _shadows_from_samples(fs: _FrameScene, vis: np.ndarray, key: np.ndarray, pending: _PendingShadows,
                          scovers: _CamCovers | None) -> np.ndarray:
    """Soft-shadow visibility of every pixel from sparse samples (``vis`` NaN where no shadow ray was
    traced): the edge-aware average of the traced samples within ``SHADOW_RADIUS`` px that see the
    same object (separable, like ``_filter_visibility``). Pixels with no such sample (slivers of an
    object) trace their own pending shadow ray."""
    H, W = vis.shape
    out = np.ones((H, W), np.float32)
    # only the band of rows with a shadow sample or pending pixel (+ 2 radii: rows whose window
    # sees only fully lit rows average to 1) is filtered; above and below everything stays 1
    busy = np.nonzero((vis != 1).any(axis=1))[0]  # NaN != 1
    if len(busy) == 0:
        return out
    r = SHADOW_RADIUS
    a, b = max(int(busy[0]) - 2 * r, 0), min(int(busy[-1]) + 1 + 2 * r, H)
    vb = vis[a:b]
    w = np.isfinite(vb)
    num, den = _edge_aware_sum(np.where(w, vb, np.float32(0)), w.astype(np.float32), key[a:b], r)
    empty = den <= 0
    num /= np.maximum(den, np.float32(1e-12))
    num[empty] = 1.0
    out[a:b] = num
    if len(pending.idx):
        rr, cc = np.divmod(pending.idx, W)
        lone = np.nonzero(den[rr - a, cc] <= 0)[0]
        if len(lone):
            occ = fs.occluded(*pending.segments(lone), scovers)
            out[rr[lone], cc[lone]] = np.where(occ, 0.0, 1.0)
    return out
