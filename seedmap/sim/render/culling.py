"""Which pixels' rays can meet an object: bounding spheres, projected boxes, pixel covers, frustum tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.records import StereoCalib
from seedmap.sim.world import World

PIX_MARGIN = 1.5  # px around projected proxies: float32 rays, and sub-samples up to 0.5 px off a centre

def _tri_spheres(world: World, key: str, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding spheres (centre, radius) of static triangles ``tri`` (T, 3, 3), cached under ``key``."""
    got = world.cache.get(key)
    if got is None:
        c = tri.mean(axis=1)
        got = world.cache[key] = (c, np.linalg.norm(tri - c[:, None, :], axis=2).max(axis=1))
    return got


def _leaf_spheres(world: World) -> tuple[np.ndarray, np.ndarray]:
    """Per leaf, a sphere holding it at every instant: the rest bounding sphere grown by the largest
    sway displacement (a rotation by at most ``theta`` about the attachment moves a vertex at most
    ``theta |v - attach|``), and by the non-rigid wind's bound (``WindField.leaf_bound``)."""
    got = world.cache.get("leaf_spheres")
    if got is None:
        v = world.leaf_vertices
        c = 0.5 * (v.min(axis=1) + v.max(axis=1))
        r = np.linalg.norm(v - c[:, None, :], axis=2).max(axis=1)
        if world.cfg.wind.enabled and len(v):
            amp = np.abs(world.leaf_sway[..., 0]).sum(axis=2)  # (L, 2) bound of each tilt angle
            theta = np.linalg.norm(amp, axis=1)
            r = r + theta * np.linalg.norm(v - world.leaf_attach[:, None, :], axis=2).max(axis=1)
        if world.wind_field is not None:
            r = r + world.wind_field.leaf_bound
        got = world.cache["leaf_spheres"] = (c, r + 1e-4)
    return got


@dataclass
class _Cover:
    """Pixels whose rays may meet one object: a boolean mask over the rectangle ``[r0, r0 + h) x
    [c0, c0 + w)`` of an ``H x W`` image (``mask=None``: the whole image). Pixel ``[r, c]`` has its
    centre at ``(u=c, v=r)``."""

    H: int
    W: int
    r0: int
    c0: int
    mask: np.ndarray | None

    def flat(self) -> np.ndarray:
        """Row-major indices of the covered pixels."""
        if self.mask is None:
            return np.arange(self.H * self.W)
        rr, cc = np.nonzero(self.mask)
        return (rr + self.r0) * self.W + (cc + self.c0)

    def lookup(self, rc: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Indices of the points whose nearest pixel centre ``rc = (rows, cols)`` (see ``_nearest_rc``)
        is covered."""
        r, c = rc
        if self.mask is None:
            return np.arange(len(r))
        h, w = self.mask.shape
        idx = np.nonzero((c >= self.c0) & (c < self.c0 + w) & (r >= self.r0) & (r < self.r0 + h))[0]
        return idx[self.mask[r[idx] - self.r0, c[idx] - self.c0]]


def _nearest_rc(pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column (int32) of the pixel centre nearest to each (u, v) of ``pix`` (N, 2)."""
    return np.floor(pix[:, 1] + 0.5).astype(np.int32), np.floor(pix[:, 0] + 0.5).astype(np.int32)


@dataclass
class _CamCovers:
    """One camera's pixel covers: of the env BVH (None: test every ray) and of each active panicle."""

    env: _Cover | None
    pan: list[_Cover]


def _grow_shadow(boxes: np.ndarray, z_near: np.ndarray, L: np.ndarray, rho: float, calib: StereoCalib) -> np.ndarray:
    """Boxes of occluders (nearest depth ``z_near`` each) grown to the pixels they may shadow, for a
    flash disc of radius ``rho`` at ``L`` (camera frame); see ``_FrameScene.covers``."""
    g = np.array(boxes, float, copy=True)
    full = (z_near <= 0.05) | (abs(L[2]) > 0.5 * z_near)
    zz = np.where(full, 1.0, z_near - abs(L[2]))
    sx, sy = calib.fx / zz, calib.fy / zz
    g[:, 0] -= sx * (max(L[0], 0) + rho) + 1
    g[:, 2] += sx * (max(-L[0], 0) + rho) + 1
    g[:, 1] -= sy * (max(L[1], 0) + rho) + 1
    g[:, 3] += sy * (max(-L[1], 0) + rho) + 1
    g[full] = (-1e9, -1e9, 1e9, 1e9)
    return g


def _sphere_boxes(pc: np.ndarray, r: np.ndarray, calib: StereoCalib, margin: float = PIX_MARGIN) -> np.ndarray:
    """Conservative pixel boxes ``(u0, v0, u1, v1)`` of spheres (camera frame centres ``pc`` (N, 3),
    radii ``r`` (N,), metres): the projection of each sphere's bounding cube; a sphere reaching
    behind the camera gets the whole plane."""
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    behind = z - r <= 0.01
    zn = np.where(behind, 1.0, z - r)
    zf = z + r
    out = np.empty((len(pc), 4))
    out[:, 0] = calib.cx + calib.fx * np.minimum((x - r) / zn, (x - r) / zf) - margin
    out[:, 2] = calib.cx + calib.fx * np.maximum((x + r) / zn, (x + r) / zf) + margin
    out[:, 1] = calib.cy + calib.fy * np.minimum((y - r) / zn, (y - r) / zf) - margin
    out[:, 3] = calib.cy + calib.fy * np.maximum((y + r) / zn, (y + r) / zf) + margin
    out[behind] = (-1e9, -1e9, 1e9, 1e9)
    return out


def _triangle_boxes(tri: np.ndarray, calib: StereoCalib, margin: float = PIX_MARGIN) -> np.ndarray:
    """Pixel boxes of triangles ``tri`` (T, 3, 3) in the camera frame (whole plane if one reaches
    behind the camera)."""
    z = tri[:, :, 2]
    behind = z.min(axis=1) <= 0.01
    zs = np.where(behind[:, None], 1.0, z)
    u = calib.cx + calib.fx * tri[:, :, 0] / zs
    v = calib.cy + calib.fy * tri[:, :, 1] / zs
    out = np.column_stack([u.min(1) - margin, v.min(1) - margin, u.max(1) + margin, v.max(1) + margin])
    out[behind] = (-1e9, -1e9, 1e9, 1e9)
    return out


def _cover_from_boxes(boxes: np.ndarray, H: int, W: int) -> _Cover:
    """The pixel centres inside any of ``boxes`` (n, 4) of ``(u0, v0, u1, v1)``: a 2-D difference
    array over the boxes' bounding rectangle (cost O(n + area), whatever the box sizes)."""
    c0 = np.maximum(np.ceil(boxes[:, 0]), 0)
    c1 = np.minimum(np.floor(boxes[:, 2]), W - 1)
    r0 = np.maximum(np.ceil(boxes[:, 1]), 0)
    r1 = np.minimum(np.floor(boxes[:, 3]), H - 1)
    ok = (c1 >= c0) & (r1 >= r0)
    if not ok.any():
        return _Cover(H, W, 0, 0, np.zeros((0, 0), bool))
    c0, c1, r0, r1 = (a[ok].astype(np.int64) for a in (c0, c1, r0, r1))
    R0, C0 = int(r0.min()), int(c0.min())
    h, w = int(r1.max()) - R0 + 1, int(c1.max()) - C0 + 1
    r0, r1, c0, c1 = r0 - R0, r1 - R0 + 1, c0 - C0, c1 - C0 + 1
    n = (h + 1) * (w + 1)
    # int32 counts (exact; float64 weights made the two prefix sums 2.5x slower)
    acc = np.bincount(np.concatenate([r0 * (w + 1) + c0, r1 * (w + 1) + c1]), minlength=n)
    acc -= np.bincount(np.concatenate([r0 * (w + 1) + c1, r1 * (w + 1) + c0]), minlength=n)
    acc = acc.astype(np.int32).reshape(h + 1, w + 1)
    np.cumsum(acc, axis=0, dtype=np.int32, out=acc)
    np.cumsum(acc, axis=1, dtype=np.int32, out=acc)
    mask = acc[:h, :w] > 0
    return _Cover(H, W, R0, C0, mask)


def _sphere_in_frustum(c: np.ndarray, r: np.ndarray, T_world_cam: np.ndarray, calib: StereoCalib,
                       origin: np.ndarray | None = None) -> np.ndarray:
    """Conservative test: which spheres (world) touch the view frustum of the camera (optionally moved
    to ``origin``, same orientation)."""
    R = T_world_cam[:3, :3]
    o = T_world_cam[:3, 3] if origin is None else origin
    p = (c - o) @ R  # camera coordinates
    tx = max(calib.cx + 0.5, calib.width - 0.5 - calib.cx) / calib.fx
    ty = max(calib.cy + 0.5, calib.height - 0.5 - calib.cy) / calib.fy
    z = p[:, 2]
    okx = np.abs(p[:, 0]) - r * np.sqrt(1 + tx * tx) <= z * tx
    oky = np.abs(p[:, 1]) - r * np.sqrt(1 + ty * ty) <= z * ty
    return (z + r > 0.01) & okx & oky
