"""Ground-truth stereo renderer: Open3D ray casting (CPU), flash lighting, sensor model.

Why ray casting: one primary ray per pixel centre gives exact instance labels (which seed is seen at
pixel ``[r, c]``, i.e. at ``(u=c, v=r)``) and the same rays give the image; the wind is rigid per
panicle, so every panicle keeps one BVH built once at rest and rays are moved into its rest frame
instead of rebuilding the scene each frame. Stalks and swayed leaves are rebuilt per frame, but only
those within reach of the cameras and their flash shadows; the soil is a plane intersected
analytically. Each camera traces a panicle / the env only at the pixels their projected proxies
cover (``_FrameScene.covers``), so the cost per frame does not grow with the range length.

Lighting: a single flash on the rig (a small disc, so shadows are soft), inverse-square fall-off,
an extra fade to black beyond ``imaging.light_cutoff`` (flash imaging: the far background is dark),
Lambertian + Blinn-Phong specular, baked per-seed ambient occlusion. Sensor: exposure jitter,
vignetting, optical blur, shot + read noise, sRGB gamma, optional motion blur and JPEG.

Cost-saving approximations (labels, depth and instance tables stay exact: they come from the
pixel-centre rays only): flash-shadow rays are traced on every ``SHADOW_STRIDE``-th pixel of every
``SHADOW_STRIDE``-th row and spread edge-aware to the pixels that see the same object (a pixel with no
such sample traces its own); an anti-aliasing sub-sample takes the shading of the neighbouring pixel
that sees the same object, deciding which object without a ray where the seeds' analytic image
outlines allow (``_antialias``; sub-samples on a seed rim are shaded analytically on the ellipsoid
with that pixel's flash visibility), and the rest are traced only against the objects the pixel and
the pixels it lies towards see. Shading is float32 struct-of-arrays with per-seed and per-triangle
tables built once per frame; a pixel's table row is gathered whole and interpolated with ``einsum``
(arithmetic on single columns of the transposed rows reads 72- or 96-byte strides, 2.5x slower).
Flash samples and sensor noise use separate random streams.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from seedmap.geometry import invert
from seedmap.io.seedmap_dataset import Instances
from seedmap.records import StereoCalib
from seedmap.sim.config import SimConfig
from seedmap.sim.meshes import ellipsoids, vertex_normals
from seedmap.sim.world import CLS_LEAF, CLS_NONE, CLS_RACHIS, CLS_SEED, CLS_SOIL, CLS_STALK, World

TRIS_PER_SEED = 80
REF_DISTANCE = 0.7  # m: a surface facing the flash at this distance is "well exposed"
MAX_CACHED_PANICLES = 16


@dataclass
class RenderedStereo:
    """One rendered stereo pair with exact ground truth (labels from pixel-centre rays, no AA)."""

    left: np.ndarray  # H x W x 3 uint8 RGB
    right: np.ndarray
    left_labels: np.ndarray  # H x W uint16, 0 = no seed, else a row of left_instances
    right_labels: np.ndarray
    left_instances: Instances
    right_instances: Instances
    left_depth: np.ndarray  # H x W float32 z-depth (m) of the left pixel-centre ray, NaN where nothing
    panicle_motion: np.ndarray  # (P, 4, 4) wind motion D of every panicle at this instant


@dataclass
class _Hits:
    t: np.ndarray  # (N,) distance along the unit ray, inf = miss
    cls: np.ndarray  # (N,) uint8 surface class
    obj: np.ndarray  # (N,) int32: panicle index (seed/rachis), -1 otherwise
    prim: np.ndarray  # (N,) int64 triangle index within its mesh
    bary: np.ndarray  # (N, 2) barycentric (u, v) of the hit
    seed: np.ndarray  # (N,) int64 global seed id or -1


def _o3d():
    import open3d as o3d

    return o3d


def _xf(a: np.ndarray, M: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """``a @ M.T + t`` for many points ``a`` (N, 3) as float32 (OpenCV's transform: numpy's matmul of
    an (N, 3) by a 3 x 3 matrix is ~50x slower)."""
    import cv2

    a = np.ascontiguousarray(a, np.float32)
    if len(a) == 0:
        return a.reshape(0, 3)
    m = np.zeros((3, 4), np.float32)
    m[:, :3] = M
    if t is not None:
        m[:, 3] = t
    return cv2.transform(a.reshape(-1, 1, 3), m).reshape(-1, 3)


_O3D_THREADS = threading.local()


def _o3d_threads() -> int:
    """Threads of one Open3D query: 1 while the two cameras render in parallel threads (the cores are
    already busy; more threads only add scheduling overhead), else 0 = automatic."""
    return getattr(_O3D_THREADS, "n", 0)


def _take(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` along the first axis for valid ``idx`` (``np.take``: 2-3x faster than fancy indexing on
    (N, k) arrays; ``mode="clip"`` skips the bounds check, up to 3x faster again on wide rows)."""
    return np.take(a, idx, axis=0, mode="clip")


def _put_rows(out: np.ndarray, idx: np.ndarray, rows: np.ndarray) -> None:
    """``out[idx] = rows`` for a C-contiguous (N, k) ``out`` and distinct ``idx``: one ``np.put`` of
    k-float records (1.6x faster than fancy row assignment, which copies element by element)."""
    rec = np.dtype((np.void, out.dtype.itemsize * out.shape[1]))
    np.put(out.view(rec).reshape(-1), idx, np.ascontiguousarray(rows, out.dtype).view(rec).reshape(-1))


def _rays_tensor(o: np.ndarray, d: np.ndarray):
    o3d = _o3d()
    r = np.empty((len(d), 6), np.float32)
    r[:, :3] = o
    r[:, 3:] = d
    return o3d.core.Tensor.from_numpy(r)


class _PanicleBVH:
    """A panicle's seeds + rachis at rest in one Open3D scene (built once, cached in the world)."""

    def __init__(self, world: World, k: int) -> None:
        o3d = _o3d()
        p = world.panicles[k]
        s = slice(p.seed_start, p.seed_stop)
        V, F = ellipsoids(world.seeds.xyz[s], world.seed_axes[s], world.seeds.radii[s])
        self.n_seed_tris = len(F)
        V = np.vstack([V, p.rachis_vertices]).astype(np.float32)
        F = np.vstack([F, p.rachis_triangles + (len(V) - len(p.rachis_vertices))]).astype(np.uint32)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor.from_numpy(V), o3d.core.Tensor.from_numpy(F))
        fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        self.face_normals = (fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-20)).astype(np.float32)
        # proxies for pixel culling (rest frame): every seed triangle lies inside the sphere of the
        # seed's largest semi-axis (icosphere vertices are on the ellipsoid); rachis triangles as-is
        self.seed_xyz = world.seeds.xyz[s].copy()
        self.seed_r = world.seeds.radii[s].max(axis=1)
        self.rachis_tri = p.rachis_vertices[p.rachis_triangles]  # (T, 3, 3)


def _panicle_bvh(world: World, k: int) -> _PanicleBVH:
    cache: OrderedDict = world.cache.setdefault("panicle_bvh", OrderedDict())
    if k in cache:
        cache.move_to_end(k)
        return cache[k]
    bvh = _PanicleBVH(world, k)
    cache[k] = bvh
    while len(cache) > MAX_CACHED_PANICLES:
        cache.popitem(last=False)
    return bvh


SOIL_HALF_WIDTH = 6.0  # m: the soil rectangle spans y in [-6, 6] and x 4 m beyond the range's gaps


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
    ``theta |v - attach|``)."""
    got = world.cache.get("leaf_spheres")
    if got is None:
        v = world.leaf_vertices
        c = 0.5 * (v.min(axis=1) + v.max(axis=1))
        r = np.linalg.norm(v - c[:, None, :], axis=2).max(axis=1)
        if world.cfg.wind.enabled and len(v):
            amp = np.abs(world.leaf_sway[..., 0]).sum(axis=2)  # (L, 2) bound of each tilt angle
            theta = np.linalg.norm(amp, axis=1)
            r = r + theta * np.linalg.norm(v - world.leaf_attach[:, None, :], axis=2).max(axis=1)
        got = world.cache["leaf_spheres"] = (c, r + 1e-4)
    return got


PIX_MARGIN = 1.5  # px around projected proxies: float32 rays, and sub-samples up to 0.5 px off a centre


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


class _FrameScene:
    """The world frozen at time ``t``: env (analytic soil plane + a BVH of the stalks and swayed leaves
    that can matter for these cameras) + the panicles in view.

    Env culling: a surface seen by a camera lies in its view frustum, and a point on a shadow segment
    from such a surface to a flash point ``L`` lies within ``|L - camera|`` of that frustum (the
    frustum is a cone with its apex at the camera). So only triangles whose bounding spheres come
    within that distance (plus the flash radius) of a camera's frustum can change the pixels.
    Triangle ids keep the soil's two triangles first (``n_soil``) so shading reads them like any
    other env triangle."""

    def __init__(self, world: World, t: float, cams: list[np.ndarray], calib: StereoCalib,
                 light: np.ndarray) -> None:
        o3d = _o3d()
        self.world = world
        self.D = world.panicle_motion(t)
        self.Dinv = invert(self.D) if len(self.D) else self.D
        self.D32 = self.D.astype(np.float32)
        self.Dinv32 = self.Dinv.astype(np.float32)
        V, F, VN, VC, VUV, cls = [], [], [], [], [], []
        off = 0

        def add(v, f, vn, vc, vuv, c):
            nonlocal off
            V.append(v)
            F.append(f + off)
            VN.append(vn)
            VC.append(vc)
            VUV.append(vuv)
            cls.append(np.full(len(f), c, np.uint8))
            off += len(v)

        self.soil_x: tuple[float, float] | None = None
        if world.has_soil:
            x0, x1 = -world.cfg.world.gap - 4.0, world.length + world.cfg.world.gap + 4.0
            self.soil_x = (x0, x1)
            v = np.array([[x0, -SOIL_HALF_WIDTH, 0], [x1, -SOIL_HALF_WIDTH, 0], [x1, SOIL_HALF_WIDTH, 0],
                          [x0, SOIL_HALF_WIDTH, 0]], float)
            add(v, np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0, 0, 1.0], (4, 1)),
                np.tile(world.soil_color, (4, 1)), np.zeros((4, 2)), CLS_SOIL)
        self.n_soil = len(F[0]) if world.has_soil else 0  # the soil's triangles come first
        margin = max(float(np.linalg.norm(light - T[:3, 3])) for T in cams) + world.cfg.imaging.flash_radius + 0.01

        def in_view(c: np.ndarray, r: np.ndarray) -> np.ndarray:
            keep = np.zeros(len(c), bool)
            for T in cams:
                keep |= _sphere_in_frustum(c, r + margin, T, calib)
            return keep

        if len(world.stalk_vertices):
            vn = world.cache.get("stalk_normals")
            if vn is None:
                vn = world.cache["stalk_normals"] = vertex_normals(world.stalk_vertices, world.stalk_triangles)
            sc, sr = _tri_spheres(world, "stalk_spheres", world.stalk_vertices[world.stalk_triangles])
            keep = in_view(sc, sr)
            if keep.any():
                add(world.stalk_vertices, world.stalk_triangles[keep], vn, world.stalk_color,
                    np.zeros((len(world.stalk_vertices), 2)), CLS_STALK)
        if len(world.leaf_vertices):
            lc, lr = _leaf_spheres(world)
            sel = np.nonzero(in_view(lc, lr))[0]
            nL = len(sel)
            if nL:
                M = world.leaf_motion(t)[sel]
                lv = np.einsum("lij,lvj->lvi", M[:, :3, :3], world.leaf_vertices[sel]) + M[:, None, :3, 3]
                nv = lv.shape[1]
                lf = world.leaf_triangles
                allf = (lf[None] + (np.arange(nL) * nv)[:, None, None]).reshape(-1, 3)
                allv = lv.reshape(-1, 3)
                add(allv, allf, vertex_normals(allv, allf), np.repeat(world.leaf_color[sel], nv, axis=0),
                    np.tile(world.leaf_uv, (nL, 1)), CLS_LEAF)
        self.env = None
        self.tri_table = np.zeros((0, 18), np.float32)
        if F:
            self.V = np.vstack(V).astype(np.float32)
            self.F = np.vstack(F).astype(np.int64)
            self.VN = np.vstack(VN).astype(np.float32)
            self.VC = np.vstack(VC).astype(np.float32)
            self.VUV = np.vstack(VUV).astype(np.float32)
            self.tri_cls = np.concatenate(cls)
            self.tri_albedo = self.VC[self.F[:, 0]]  # albedo is constant per leaf / stalk
            # per-triangle shading table (T, 18): vertex normals (3 x 3), uv (3 x 2), albedo (3); one
            # row per triangle so a pixel's gather reads one or two cache lines
            self.tri_table = np.ascontiguousarray(np.concatenate(
                [self.VN[self.F].reshape(-1, 9), self.VUV[self.F].reshape(-1, 6), self.tri_albedo], axis=1))
            if len(self.F) > self.n_soil:  # the soil is a plane, intersected analytically
                self.env = o3d.t.geometry.RaycastingScene()
                self.env.add_triangles(o3d.core.Tensor.from_numpy(self.V),
                                       o3d.core.Tensor.from_numpy(self.F[self.n_soil:].astype(np.uint32)))
        # panicles that can be seen from (or shadow what is seen from) any of the cameras
        self.active = np.zeros(0, np.int64)
        self.centers = np.zeros((0, 3), np.float32)
        self.radii = np.zeros(0, np.float32)
        if world.panicles:
            c_rest = np.stack([p.center for p in world.panicles])
            r = np.array([p.radius for p in world.panicles])
            c_now = np.einsum("pij,pj->pi", self.D[:, :3, :3], c_rest) + self.D[:, :3, 3]
            vis = np.zeros(len(r), bool)
            for T in cams:
                vis |= _sphere_in_frustum(c_now, r + 0.08, T, calib)
            vis |= _sphere_in_frustum(c_now, r + 0.08, cams[0], calib, origin=light)
            self.active = np.nonzero(vis)[0]
            self.centers = c_now[self.active].astype(np.float32)
            self.radii = r[self.active].astype(np.float32)
        self.bvh = {int(k): _panicle_bvh(world, int(k)) for k in self.active}
        self.seed_start = np.array([p.seed_start for p in world.panicles], np.int64)
        # per-seed shading table (N, 24) over global seed ids, filled for the active panicles' seeds
        # only: axes at this instant (9, row-major A[i, j] = axis j's component i), centre now (3) and
        # the constants of _seed_static (12); one row per seed so a pixel's gather reads one row
        N = len(world.seeds)
        self.seed_tab = np.empty((N, 24), np.float32)
        ids = [np.arange(world.panicles[k].seed_start, world.panicles[k].seed_stop) for k in self.active]
        self.active_seed_ids = np.concatenate(ids) if ids else np.zeros(0, np.int64)
        stat = _seed_static(world)
        for k, s in zip(self.active, ids, strict=True):
            Rk = self.D[k, :3, :3]
            self.seed_tab[s, :9] = np.einsum("ik,nkj->nij", Rk, world.seed_axes[s]).reshape(-1, 9)
            self.seed_tab[s, 9:12] = world.seeds.xyz[s] @ Rk.T + self.D[k, :3, 3]
            self.seed_tab[s, 12:] = stat[s]

    def _soil_hits(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the rays ``o + t d`` meeting the soil rectangle (z = 0) at ``0 < t < tmax``, and
        their ``t``."""
        oz = o[:, 2] if len(o) > 1 else np.full(len(d), o[0, 2], np.float32)
        dz = d[:, 2]
        cand = np.nonzero(oz * dz < 0)[0]  # moving towards the plane
        ts = -oz[cand] / dz[cand]
        keep = ts < tmax[cand]
        cand, ts = cand[keep], ts[keep]
        oc = o[cand] if len(o) > 1 else o
        x = oc[:, 0] + ts * d[cand, 0]
        y = oc[:, 1] + ts * d[cand, 1]
        x0, x1 = self.soil_x
        inside = (x >= x0) & (x <= x1) & (np.abs(y) <= SOIL_HALF_WIDTH)
        return cand[inside], ts[inside]

    # ---- ray selection ----
    def covers(self, T_wc: np.ndarray, calib: StereoCalib, light: np.ndarray,
               cfg: SimConfig) -> tuple[_CamCovers, _CamCovers]:
        """For camera ``T_wc``: the pixels whose rays may hit the env BVH / each active panicle, and
        the pixels whose surface point may be shadowed by them (conservative: supersets of the truth).

        Primary: the projected boxes of the env triangles and of the panicles' proxies (one sphere
        per seed, the rachis triangles) at this instant. Shadows: the segment from a surface point
        to a flash point ``L`` (camera frame, ``L_z ~ 0``) projects to the half-line from the pixel in
        direction ``(fx L_x, fy L_y)``; where it can meet an occluder at depth >= z_near it has moved
        at most ``f |L| / z_near`` pixels, so each box is grown by that much against the flash
        direction (plus the flash radius)."""
        H, W = calib.height, calib.width
        R, o = T_wc[:3, :3], T_wc[:3, 3]
        L = R.T @ (light - o)
        rho = cfg.imaging.flash_radius
        env = env_s = None
        if self.env is not None:
            tri = _xf(self.V, R.T, -R.T @ o)[self.F[self.n_soil:]]  # (T, 3, 3) camera frame
            boxes = _triangle_boxes(tri, calib)
            env = _cover_from_boxes(boxes, H, W)
            env_s = _cover_from_boxes(_grow_shadow(boxes, tri[:, :, 2].min(axis=1), L, rho, calib), H, W)
        pc = (self.centers - o) @ R
        prim, shad = [], []
        for j, k in enumerate(self.active):
            b = self.bvh[int(k)]
            M = R.T @ self.D[k, :3, :3]
            tr = R.T @ (self.D[k, :3, 3] - o)
            boxes = np.vstack([_sphere_boxes(b.seed_xyz @ M.T + tr, b.seed_r, calib),
                               _triangle_boxes((b.rachis_tri.reshape(-1, 3) @ M.T + tr).reshape(-1, 3, 3), calib)])
            prim.append(_cover_from_boxes(boxes, H, W))
            z_near = np.full(len(boxes), pc[j, 2] - self.radii[j])
            shad.append(_cover_from_boxes(_grow_shadow(boxes, z_near, L, rho, calib), H, W))
        return _CamCovers(env, prim), _CamCovers(env_s, shad)

    def _select(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, rc: tuple | None,
                covers: _CamCovers | None, grid: bool = False) -> list[np.ndarray]:
        """Per active panicle, the rays that may hit it (pixel cover, else a bounding-sphere test)."""
        P = len(self.active)
        if P == 0 or len(d) == 0:
            return [np.zeros(0, np.int64)] * P
        if grid and covers is not None:  # rays of all pixels, row-major
            return [c.flat() for c in covers.pan]
        if rc is not None and covers is not None:
            return [c.lookup(rc) for c in covers.pan]
        C = self.centers
        r2 = self.radii ** 2
        if o.shape[0] == 1:
            oc = C - o[0]  # (P, 3)
            b = d @ oc.T  # (N, P)
            c2 = (oc * oc).sum(1)[None, :] - b * b
        else:
            b = d @ C.T - (d * o).sum(1)[:, None]
            c2 = (C * C).sum(1)[None, :] - 2 * (o @ C.T) + (o * o).sum(1)[:, None] - b * b
        ok = (c2 <= r2[None, :]) & (b + self.radii[None, :] > 0)
        ok &= (b - np.sqrt(np.maximum(r2[None, :] - c2, 0))) < tmax[:, None]
        return [np.nonzero(ok[:, j])[0] for j in range(P)]

    # ---- queries ----
    def trace(self, o: np.ndarray, d: np.ndarray, pix: np.ndarray | None = None,
              covers: _CamCovers | None = None, grid: bool = False, only: np.ndarray | None = None) -> _Hits:
        """Closest hit of rays ``o + t d`` (``d`` unit float32 (N, 3); ``o`` (1, 3) or (N, 3)).

        ``pix``/``covers``: pixel coordinates of camera rays and the panicles' pixel covers (see
        ``covers``; cheaper than the sphere test); ``grid=True`` when the rays are all pixels, row-major.
        ``only`` (N, K) int: per ray, the objects it is traced against (``ENV_CODE`` = stalks and
        leaves, k >= 0 = panicle k; the soil plane always): anti-aliasing rays only look for what the
        pixels around them see. ``prim``/``bary`` are only meaningful where ``t`` is finite."""
        n = len(d)
        o = np.asarray(o, np.float32)
        cls = np.zeros(n, np.uint8)
        obj = np.full(n, -1, np.int32)
        rc = None if pix is None or grid or covers is None else _nearest_rc(pix)
        env_sel = None
        if covers is not None and covers.env is not None:
            env_sel = covers.env.flat() if grid else covers.env.lookup(rc) if rc is not None else None
            if only is not None and env_sel is not None:
                env_sel = env_sel[(only[env_sel] == ENV_CODE).any(axis=1)]
        if self.env is not None and n and env_sel is None:
            ans = self.env.cast_rays(_rays_tensor(o, d), nthreads=_o3d_threads())
            t = ans["t_hit"].numpy()
            prim = ans["primitive_ids"].numpy()
            bary = ans["primitive_uvs"].numpy()
        else:
            t = np.full(n, np.inf, np.float32)
            prim = np.zeros(n, np.uint32)
            bary = np.zeros((n, 2), np.float32)
            if self.env is not None and env_sel is not None and len(env_sel):
                ans = self.env.cast_rays(_rays_tensor(o if len(o) == 1 else _take(o, env_sel), _take(d, env_sel)),
                                          nthreads=_o3d_threads())
                t[env_sel] = ans["t_hit"].numpy()
                prim[env_sel] = ans["primitive_ids"].numpy()
                _put_rows(bary, env_sel, ans["primitive_uvs"].numpy())
        if self.env is not None:
            hit = np.nonzero(t < np.inf)[0]
            prim[hit] += self.n_soil
            cls[hit] = self.tri_cls[prim[hit]]
        if self.soil_x is not None and n:
            sh, ts = self._soil_hits(o, d, t)
            t[sh] = ts
            cls[sh] = CLS_SOIL
            prim[sh] = 0
            bary[sh] = 0.0
        for j, idx in enumerate(self._select(o, d, t, rc, covers, grid)):
            k = int(self.active[j])
            if only is not None and len(idx):
                idx = idx[(only[idx] == k).any(axis=1)]
            if len(idx) == 0:
                continue
            Di = self.Dinv32[k]
            oo = o if len(o) == 1 else _take(o, idx)
            o_r = _xf(oo, Di[:3, :3], Di[:3, 3])
            d_r = _xf(_take(d, idx), Di[:3, :3])
            bvh = self.bvh[k]
            ans = bvh.scene.cast_rays(_rays_tensor(o_r, d_r), nthreads=_o3d_threads())
            tk = ans["t_hit"].numpy()
            better = tk < t[idx]
            if not better.any():
                continue
            jj = idx[better]
            t[jj] = tk[better]
            pk = ans["primitive_ids"].numpy()[better]
            prim[jj] = pk
            _put_rows(bary, jj, ans["primitive_uvs"].numpy()[better])
            cls[jj] = np.where(pk < bvh.n_seed_tris, CLS_SEED, CLS_RACHIS)
            obj[jj] = k
        seed = np.full(n, -1, np.int64)
        sm = cls == CLS_SEED
        if sm.any():
            seed[sm] = self.seed_start[obj[sm]] + (prim[sm] // TRIS_PER_SEED).astype(np.int64)
        return _Hits(t, cls, obj, prim, bary, seed)

    def occluded(self, o: np.ndarray, v: np.ndarray, pix: np.ndarray | None = None,
                 covers: _CamCovers | None = None) -> np.ndarray:
        """True where the segment ``o -> o + v`` (float32 (N, 3), not unit) hits anything.

        ``pix``/``covers``: for shadow rays of camera pixels, the pixels and per-panicle shadow covers
        outside which a panicle cannot shadow the pixel (see ``covers``)."""
        n = len(o)
        occ = np.zeros(n, bool)
        if n == 0:
            return occ
        tfar = 1.0 - 1e-4
        rc = None if pix is None or covers is None else _nearest_rc(pix)
        if self.env is not None:
            if rc is not None and covers.env is not None:
                sel = covers.env.lookup(rc)
                if len(sel):
                    occ[sel] = self.env.test_occlusions(_rays_tensor(_take(o, sel), _take(v, sel)), tnear=0.0, tfar=tfar,
                                                        nthreads=_o3d_threads()).numpy().astype(bool)
            else:
                occ = self.env.test_occlusions(_rays_tensor(o, v), tnear=0.0, tfar=tfar,
                                              nthreads=_o3d_threads()).numpy().astype(bool)
        if self.soil_x is not None:
            occ[self._soil_hits(o, v, np.full(n, tfar, np.float32))[0]] = True
        rem = np.nonzero(~occ)[0]
        if len(rem) == 0 or len(self.active) == 0:
            return occ
        if rc is not None:
            rc = (rc[0][rem], rc[1][rem])
            sels = []
            for j, cov in enumerate(covers.pan):
                cand = cov.lookup(rc)
                if len(cand):
                    # exact sphere test on the candidates only
                    ii = rem[cand]
                    vv = v[ii]
                    length = np.sqrt(_dot(vv, vv))
                    oc = self.centers[j] - o[ii]
                    bb = _dot(oc, vv) / np.maximum(length, 1e-12)
                    c2 = _dot(oc, oc) - bb * bb
                    r = self.radii[j]
                    ok = (c2 <= r * r) & (bb + r > 0) & (bb - np.sqrt(np.maximum(r * r - c2, 0)) < length)
                    cand = cand[ok]
                sels.append(cand)
        else:
            length = np.sqrt(_dot(v[rem], v[rem]))
            du = v[rem] / np.maximum(length, 1e-12)[:, None]
            sels = self._select(o[rem], du, length, None, None)
        for j, sel in enumerate(sels):
            idx = rem[sel]
            idx = idx[~occ[idx]]
            if len(idx) == 0:
                continue
            k = int(self.active[j])
            Di = self.Dinv32[k]
            o_r = _xf(_take(o, idx), Di[:3, :3], Di[:3, 3])
            v_r = _xf(_take(v, idx), Di[:3, :3])
            occ[idx] = self.bvh[k].scene.test_occlusions(_rays_tensor(o_r, v_r), tnear=0.0, tfar=tfar,
                                                          nthreads=_o3d_threads()).numpy().astype(bool)
        return occ


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


# ------------------------------------------------------------------------------------------------
# shading
# ------------------------------------------------------------------------------------------------


def _soil_albedo(world: World, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Soil albedo (3, n) float32 at ground points ``(x, y)`` (m): the tiled texture, bilinear."""
    tex = _soil_tex_f32(world)
    S = tex.shape[0]
    u = x * np.float32(S / world.soil_tile)
    v = y * np.float32(S / world.soil_tile)
    fu = np.floor(u)
    fv = np.floor(v)
    i0 = fu.astype(np.int64)
    j0 = fv.astype(np.int64)
    fu = u - fu
    fv = v - fv
    i0 %= S
    j0 %= S
    i1 = i0 + 1
    j1 = j0 + 1  # the texture is padded by one row and column (wrap)
    a = tex[j0, i0]
    a += (tex[j0, i1] - a) * fu
    b = tex[j1, i0]
    b += (tex[j1, i1] - b) * fu
    a += (b - a) * fv
    return world.soil_color.astype(np.float32)[:, None] * a[None, :]


def _soil_tex_f32(world: World) -> np.ndarray:
    """The soil texture as float32, padded by one wrapped row and column (cached on the world)."""
    t = world.cache.get("soil_tex_f32")
    if t is None:
        tex = world.soil_texture
        t = world.cache["soil_tex_f32"] = np.pad(tex, ((0, 1), (0, 1)), mode="wrap").astype(np.float32)
    return t


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of two (3, n) struct-of-arrays vectors."""
    out = a[0] * b[0]
    out += a[1] * b[1]
    out += a[2] * b[2]
    return out


def _normalize3(a: np.ndarray) -> np.ndarray:
    """Normalise (3, n) vectors in place (and return them)."""
    a *= 1.0 / np.maximum(np.sqrt(_dot3(a, a)), np.float32(1e-12))
    return a


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


def _shade(fs: _FrameScene, o: np.ndarray, d: np.ndarray, h: _Hits, light: np.ndarray, light_axes: np.ndarray,
           cfg: SimConfig, rng: np.random.Generator, pix: np.ndarray | None = None,
           scovers: _CamCovers | None = None) -> np.ndarray:
    """Linear RGB radiance (1 = white surface facing the flash at REF_DISTANCE) per ray (float32 (N, 3))."""
    return _shade_parts(fs, o, d, h, light, light_axes, cfg, rng, pix, scovers).radiance(len(d))


# per-class specular strength and exponent (Blinn-Phong); seeds: 0.12 on the grain, 0.03 on the glume
KS_SOIL, KS_STALK, KS_LEAF, KS_RACHIS = 0.01, 0.06, 0.10, 0.04
SHIN_DEFAULT, SHIN_LEAF, SHIN_SEED = 20.0, 25.0, 45.0
RACHIS_ALBEDO = (0.30, 0.26, 0.13)
_LEAF_LUT_N = 8192  # samples of the leaf's across-pattern (midrib x veins) over w in [0, 1]


def _leaf_pattern_lut() -> np.ndarray:
    """Midrib and vein brightening of a leaf as a function of the across-leaf coordinate ``w`` in
    [0, 1] (a table: exp and sin per pixel were a tenth of the shading time)."""
    w = np.linspace(0, 1, _LEAF_LUT_N)
    return ((1.0 + 0.35 * np.exp(-((w - 0.5) / 0.05) ** 2)) * (1.0 + 0.05 * np.sin(w * 2 * np.pi * 11.0))).astype(
        np.float32)


_LEAF_LUT = _leaf_pattern_lut()


def _seed_static(world: World) -> np.ndarray:
    """Per-seed shading constants (N, 12) float32 (cached on the world): columns ``1/r^2`` (3),
    ``1/r_z``, grain albedo (3), glume albedo (3), glume edge (``extent + 0.15``), AO."""
    t = world.cache.get("seed_static")
    if t is None:
        r = world.seeds.radii
        t = np.column_stack([1.0 / (r * r), 1.0 / r[:, 2], world.seed_albedo, world.glume_albedo,
                             world.glume_extent + 0.15, world.seed_ao]).astype(np.float32)
        world.cache["seed_static"] = t = np.ascontiguousarray(t)
    return t


def _rows(table: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``table[idx]`` as a (K, n) struct-of-arrays view (one contiguous row of ``table`` per item)."""
    return np.take(table, idx, axis=0, mode="clip").T


@dataclass
class _Shading:
    """Shading of the rays ``live`` (the others are black): radiance = ``direct * vis + amb``."""

    live: np.ndarray  # (m,) int64 ray indices
    direct: np.ndarray  # (3, m) float32
    vis: np.ndarray  # (m,) flash visibility (NaN: shadow ray pending)
    amb: np.ndarray  # (3, m)
    pending: _PendingShadows

    def radiance(self, n: int, vis: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) float32 linear RGB of all n rays; ``vis`` (n,): visibility to use instead of ours."""
        v = self.vis if vis is None else _take(vis, self.live)
        out = np.zeros((n, 3), np.float32)
        rad = self.direct * v
        rad += self.amb
        _put_rows(out, self.live, rad.T)
        return out


def _shade_parts(fs: _FrameScene, o: np.ndarray, d: np.ndarray, h: _Hits, light: np.ndarray,
                 light_axes: np.ndarray, cfg: SimConfig, rng: np.random.Generator, pix: np.ndarray | None = None,
                 scovers: _CamCovers | None = None, shadow_rays: np.ndarray | None = None,
                 vis_given: np.ndarray | None = None) -> _Shading:
    """Direct light, flash visibility and ambient light of the rays that reach a lit surface.

    ``vis_given`` (N,): the flash visibility to use instead of tracing shadow rays.
    ``shadow_rays`` (bool (N,), None = all): which lit rays get a shadow ray now; the others get
    ``vis = NaN`` and their shadow segments are returned in ``pending`` (``_PendingShadows``) so the
    caller can trace the ones it cannot interpolate.

    Struct-of-arrays float32 throughout ((3, m) vectors, per-surface constants gathered once from
    per-seed / per-triangle tables): the shading of a million pixels is memory-bound, so fewer and
    smaller temporaries are what makes it fast."""
    ic = cfg.imaging
    world = fs.world
    far = ic.light_cutoff + 0.3
    live = np.nonzero(h.t < far)[0]
    pending = _PendingShadows.empty()
    m = len(live)
    if m == 0:
        z = np.zeros((3, 0), np.float32)
        return _Shading(live, z, np.zeros(0, np.float32), z, pending)
    # the rays grouped by surface class (a stable counting sort): each class is a slice, so the
    # per-class work reads and writes contiguous runs instead of scattering through index arrays
    cls = np.take(h.cls, live)
    order = np.argsort(cls, kind="stable")
    live = np.take(live, order)
    cls = np.take(cls, order)
    start = np.searchsorted(cls, np.arange(CLS_RACHIS + 2))

    def span(c0: int, c1: int) -> slice:
        return slice(int(start[c0]), int(start[c1 + 1]))

    t = np.take(h.t, live)
    dl = np.ascontiguousarray(_take(d, live).T)  # (3, m)
    p = dl * t
    p += o[0][:, None] if len(o) == 1 else _take(o, live).T
    albedo = np.empty((3, m), np.float32)
    nrm = np.empty((3, m), np.float32)
    ks = np.empty(m, np.float32)
    shin = np.full(m, SHIN_DEFAULT, np.float32)
    ao = np.ones(m, np.float32)
    # soil: flat, textured
    soil = span(CLS_SOIL, CLS_SOIL)
    if soil.stop > soil.start:
        nrm[:, soil] = np.array([[0.0], [0.0], [1.0]], np.float32)
        albedo[:, soil] = _soil_albedo(world, p[0, soil], p[1, soil])
        ks[soil] = KS_SOIL
    # stalks and leaves: interpolated vertex normals, per-triangle albedo, leaf pattern
    em = span(CLS_STALK, CLS_LEAF)
    if em.stop > em.start:
        le = live[em]
        # (e, 18) rows: vertex normals (9), uv (6), albedo (3); interpolated with einsum over the rows
        # as they come (per-column arithmetic on the transposed rows reads 72-byte strides: 2.5x slower)
        tab = np.take(fs.tri_table, np.take(h.prim, le), axis=0, mode="clip")
        bw = np.empty((len(le), 3), np.float32)  # barycentric weights of the three vertices
        bw[:, 1:] = _take(h.bary, le)
        bw[:, 0] = 1 - bw[:, 1] - bw[:, 2]
        nrm[:, em] = np.einsum("ek,ekc->ce", bw, tab[:, :9].reshape(-1, 3, 3))
        albedo[:, em] = tab[:, 15:18].T
        st_ = span(CLS_STALK, CLS_STALK)
        ks[st_] = KS_STALK
        lf = span(CLS_LEAF, CLS_LEAF)
        if lf.stop > lf.start:
            ks[lf] = KS_LEAF
            shin[lf] = SHIN_LEAF
            li = slice(lf.start - em.start, lf.stop - em.start)  # the leaves within the env slice
            s, w = np.einsum("ek,ekc->ce", bw[li], tab[li, 9:15].reshape(-1, 3, 2))
            wi = np.clip(w * np.float32(_LEAF_LUT_N - 1) + np.float32(0.5), 0, _LEAF_LUT_N - 1).astype(np.int32)
            tipdry = np.clip((s - np.float32(0.75)) * np.float32(4.0), 0, 1)
            tipdry *= np.float32(0.25)
            tipdry += np.float32(1.0)
            albedo[:, lf] *= np.take(_LEAF_LUT, wi) * tipdry
    # rachis: flat normals from the panicle mesh, rotated by the wind
    rm = span(CLS_RACHIS, CLS_RACHIS)
    if rm.stop > rm.start:
        lr = live[rm]
        objs = np.take(h.obj, lr)
        prim = np.take(h.prim, lr)
        nr = nrm[:, rm]
        for k in np.unique(objs):
            sel = objs == k
            nr[:, sel] = _xf(fs.bvh[int(k)].face_normals[prim[sel]], fs.D32[k, :3, :3]).T
        nrm[:, rm] = nr
        albedo[:, rm] = np.array(RACHIS_ALBEDO, np.float32)[:, None]
        ks[rm] = KS_RACHIS
    # seeds: analytic ellipsoid normal (smooth shading on a low-poly mesh), glume at the base
    sm = span(CLS_SEED, CLS_SEED)
    if sm.stop > sm.start:
        sid = np.take(h.seed, live[sm])
        rows = np.take(fs.seed_tab, sid, axis=0, mode="clip")  # (s, 24), see _FrameScene
        A = rows[:, :9].reshape(-1, 3, 3)  # axes now, A[s, i, j] = axis j's component i
        st = rows[:, 12:].T  # _seed_static's columns
        dp = p[:, sm] - rows[:, 9:12].T  # from the centre now
        # local coordinates q_j = sum_i A[i, j] dp_i; normal n_i = sum_j A[i, j] q_j / r_j^2 (einsum
        # over the rows as gathered: arithmetic on the transposed rows reads 96-byte strides)
        q = np.einsum("sij,is->js", A, dp)
        wq = q * st[:3]
        nrm[:, sm] = np.einsum("sij,js->is", A, wq)
        g = np.clip((st[10] - q[2] * st[3]) * np.float32(1 / 0.3), 0, 1)
        g = g * g * (3 - 2 * g)
        albedo[:, sm] = st[4:7] + (st[7:10] - st[4:7]) * g
        ks[sm] = np.float32(0.12) - np.float32(0.09) * g
        shin[sm] = SHIN_SEED
        ao[sm] = st[11]
    _normalize3(nrm)
    nrm *= np.where(_dot3(nrm, dl) > 0, np.float32(-1), np.float32(1))
    # flash: a random point on a small disc per sample (soft shadows)
    # (drawn in pixel order and carried along with the class sort: the samples do not depend on it)
    rr = np.sqrt(np.take(rng.random(m, np.float32), order)) * np.float32(ic.flash_radius)
    th = np.take(rng.random(m, np.float32), order) * np.float32(2 * np.pi)
    ca, sa = np.cos(th) * rr, np.sin(th) * rr
    lp = np.empty((3, m), np.float32)
    for c in range(3):
        lp[c] = ca * light_axes[0, c] + sa * light_axes[1, c] + np.float32(light[c])
    lv = lp - p
    dist2 = _dot3(lv, lv)
    dist = np.sqrt(dist2)
    ldir = lv * (1 / dist)
    ndl = np.maximum(_dot3(nrm, ldir), 0)
    fade = np.clip((np.float32(ic.light_cutoff + 0.25) - dist) * 2, 0, 1)
    fade = fade * fade * (3 - 2 * fade)
    irr = fade * np.float32(REF_DISTANCE * REF_DISTANCE) / dist2
    vis = np.ones(m, np.float32)
    if vis_given is not None:
        vis = vis_given[live].astype(np.float32)
    elif ic.shadows:
        lit = np.nonzero((ndl > 0) & (irr > 1e-4))[0]
        if shadow_rays is not None:
            later = ~shadow_rays[live[lit]]
            if later.any():
                lt = lit[later]
                pending = _PendingShadows(live[lt], lt, p, nrm, ldir, lp, pix)
                vis[lt] = np.nan
                lit = lit[~later]
        start = _shadow_start(p[:, lit], nrm[:, lit], ldir[:, lit])
        occ = fs.occluded(np.ascontiguousarray(start), np.ascontiguousarray(lp[:, lit].T - start),
                          None if pix is None else pix[live[lit]], scovers)
        vis[lit[occ]] = 0.0
    hv = ldir - dl
    _normalize3(hv)
    nh = np.maximum(_dot3(nrm, hv), np.float32(1e-30))
    spec = np.exp(np.log(nh) * shin)
    spec *= ks
    spec *= irr
    spec *= ndl > 0
    ndl *= irr
    direct = albedo * ndl
    direct += spec
    irr *= np.float32(ic.ambient)
    irr *= ao
    return _Shading(live, direct, vis, albedo * irr, pending)


SHADOW_STRIDE = 2  # flash shadow rays on every 2nd pixel of every 2nd row (plus where none is near)
SHADOW_RADIUS = 2  # px: half-width of the edge-aware window the shadow samples are averaged over


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
    shadows noisy): average only over neighbours that see the same object, separably."""
    num, den = _edge_aware_sum(vis.astype(np.float32), np.ones(vis.shape, np.float32), key, radius)
    return num / den


def _shadows_from_samples(fs: _FrameScene, vis: np.ndarray, key: np.ndarray, pending: _PendingShadows,
                          scovers: _CamCovers | None) -> np.ndarray:
    """Soft-shadow visibility of every pixel from sparse samples (``vis`` NaN where no shadow ray was
    traced): the edge-aware average of the traced samples within ``SHADOW_RADIUS`` px that see the
    same object (separable, like ``_filter_visibility``). Pixels with no such sample (slivers of an
    object) trace their own pending shadow ray. Why: one shadow ray per pixel was a third of the
    render's ray casts; the penumbra of the small flash disc is smooth at this sampling."""
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


ENV_CODE = -2  # ``_FrameScene.trace(only=...)`` code of the env BVH (stalks and leaves)
SEED_AA_SCALE = 0.97  # the seed mesh's outline is about its ellipsoid's scaled by this (80-face icosphere)


def _seed_conics(fs: _FrameScene, T_wc: np.ndarray, calib: StereoCalib, scale: float = SEED_AA_SCALE,
                 ids: np.ndarray | None = None) -> np.ndarray:
    """Image outlines of the seeds of the active panicles as seen by camera ``T_wc`` at this instant:
    (N, 8) float32 over global seed ids (NaN for seeds of other panicles / behind the camera).

    A pixel point ``(u, v)`` lies inside seed ``s``'s outline (its ray meets the seed's ellipsoid,
    semi-axes scaled by ``scale``) iff ``1 + a_u du + a_v dv + c_uu du^2 + c_uv du dv + c_vv dv^2 >= 0``
    with ``du = u - u_c``, ``dv = v - v_c``; columns are ``u_c, v_c, a_u, a_v, c_uu, c_uv, c_vv`` (and
    one of padding: a row is 32 bytes).
    Derivation: with ``G = A diag(1/r^2) A^T`` and the centre ``c`` in the camera frame, the ray ``t x``
    (``x = K^-1 (u, v, 1)``) meets the ellipsoid iff ``x^T E x >= 0``, ``E = g g^T - (c.g - 1) G``,
    ``g = G c``; expanded about the projected centre ``x_c = c / c_z`` (where ``E x_c = g / c_z``) and
    divided by ``x_c^T E x_c = c.g / c_z^2 > 0`` it is the polynomial above, evaluated near the centre
    in float32 without cancellation (the per-seed terms are formed in float64)."""
    N = len(fs.world.seeds)
    out = np.full((N, 8), np.nan, np.float32)
    ids = fs.active_seed_ids if ids is None else ids  # (seeds of the active panicles only)
    if len(ids) == 0:
        return out
    R, o = T_wc[:3, :3], T_wc[:3, 3]
    dyn = fs.seed_tab[ids, :12].T.astype(np.float64)
    A = dyn[:9].T.reshape(-1, 3, 3)
    cc = (dyn[9:12].T - o) @ R  # centres, camera frame
    Ac = np.matmul(R.T, A)  # axes (columns), camera frame
    inv_r2 = 1.0 / (scale * fs.world.seeds.radii[ids]) ** 2
    G = (Ac * inv_r2[:, None, :]) @ Ac.transpose(0, 2, 1)
    g = np.einsum("nij,nj->ni", G, cc)
    cg = np.einsum("ni,ni->n", cc, g)
    z = cc[:, 2]
    ok = (z > 1e-3) & (cg > 1.0)  # in front, camera outside the ellipsoid
    z = np.where(ok, z, 1.0)
    cg = np.where(ok, cg, 1.0)
    E2 = g[:, :2, None] * g[:, None, :2] - (cg - 1)[:, None, None] * G[:, :2, :2]
    fx, fy = calib.fx, calib.fy
    s2 = z * z / cg
    rows = np.stack([fx * cc[:, 0] / z + calib.cx, fy * cc[:, 1] / z + calib.cy,
                     2 * z * g[:, 0] / (cg * fx), 2 * z * g[:, 1] / (cg * fy),
                     s2 * E2[:, 0, 0] / (fx * fx), 2 * s2 * E2[:, 0, 1] / (fx * fy), s2 * E2[:, 1, 1] / (fy * fy)])
    rows[:, ~ok] = np.nan
    out[ids, :7] = rows.T
    return out


def _inside_outline(conics: np.ndarray, sid: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """True where pixel point ``(u, v)`` lies inside seed ``sid``'s outline (see ``_seed_conics``)."""
    c = _rows(conics, sid)
    du = u - c[0]
    dv = v - c[1]
    f = c[4] * du
    f += c[2]
    f += c[5] * dv
    f *= du
    f += (c[6] * dv + c[3]) * dv
    return f >= -1.0


def _seed_entry(fs: _FrameScene, o: np.ndarray, d: np.ndarray, sid: np.ndarray) -> np.ndarray:
    """Distance (m, float32) at which rays ``o + t d`` (``o`` (3,), ``d`` unit (n, 3)) enter seed ``sid``'s
    ellipsoid at this instant (the tangent point where they just miss it). Started at the ray's closest
    approach to the seed centre (millimetres, not the camera's metres: well conditioned in float32)."""
    rows = np.take(fs.seed_tab, sid, axis=0, mode="clip")  # (n, 24), see _FrameScene
    A = rows[:, :9].reshape(-1, 3, 3)  # A[s, i, j] = axis j's component i
    inv_r = np.sqrt(rows[:, 12:15].T)
    dT = np.ascontiguousarray(d.T)
    dp = o.astype(np.float32)[:, None] - rows[:, 9:12].T
    tc = -_dot3(dp, dT)
    dp += dT * tc
    q0 = np.einsum("sij,is->js", A, dp) * inv_r
    qd = np.einsum("sij,is->js", A, dT) * inv_r
    a = qd[0] * qd[0] + qd[1] * qd[1] + qd[2] * qd[2]
    b = q0[0] * qd[0] + q0[1] * qd[1] + q0[2] * qd[2]
    c = q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] - 1
    return (tc - (b + np.sqrt(np.maximum(b * b - a * c, 0))) / a).astype(np.float32)


def _antialias(fs: _FrameScene, o: np.ndarray, R: np.ndarray, calib: StereoCalib, cfg: SimConfig, h: _Hits,
               key: np.ndarray, rgb: np.ndarray, covers: _CamCovers, scovers: _CamCovers, light: np.ndarray,
               light_axes: np.ndarray, rng: np.random.Generator, T_wc: np.ndarray, vis: np.ndarray) -> None:
    """Adaptive anti-aliasing of ``rgb`` ((H W, 3), in place): ``n x n`` sub-samples on the pixels whose
    neighbours see another object or depth.

    A sub-sample sees one of the objects seen by its pixel and the pixels it lies towards (its
    quadrant neighbours), and takes the shading of a pixel that sees that object (no new shading or
    shadow rays). Which one is decided without rays where geometry allows: seeds by their exact
    image outline (``_seed_conics``; the nearest covering seed wins unless a non-seed neighbour is
    nearer), and if no seed covers it and all non-seed neighbours agree, that surface. Only the
    rest (leaf and stalk silhouettes, a leaf edge in front of a seed, gaps between seeds) is traced,
    against the objects those pixels see; a traced sub-sample that meets an object none of them
    sees is shaded on its own."""
    H, W = calib.height, calib.width
    n_ss = cfg.imaging.supersample
    tt = np.minimum(h.t, np.float32(1e3))
    key2, tt2 = key.reshape(H, W), tt.reshape(H, W)
    lit2 = tt2 < cfg.imaging.light_cutoff + 0.3
    edge = np.zeros((H, W), bool)
    for ea, eb in (((slice(None), slice(1, None)), (slice(None), slice(0, -1))),
                   ((slice(1, None), slice(None)), (slice(0, -1), slice(None)))):
        ta, tb = tt2[ea], tt2[eb]
        e = (key2[ea] != key2[eb]) | (np.abs(ta - tb) > 0.05 * np.minimum(ta, tb))
        e &= lit2[ea] | lit2[eb]
        edge[ea] |= e
        edge[eb] |= e
    idx = np.nonzero(edge.reshape(-1))[0]
    if len(idx) == 0:
        return
    offs = (np.arange(n_ss) + 0.5) / n_ss - 0.5
    grid_off = [(float(du), float(dv)) for dv in offs for du in offs]
    S = len(grid_off)
    idx = idx.astype(np.int32)  # int32 pixel indices: the (4, M) candidate tables are the AA's peak memory
    er, ec = np.divmod(idx, np.int32(W))
    k0 = np.take(key, idx)
    nbf: dict[tuple[int, int], np.ndarray] = {(0, 0): idx}
    same: dict[tuple[int, int], np.ndarray] = {}

    def quadrant(du: float, dv: float) -> list[tuple[int, int]]:
        sx, sy = int(np.sign(du)), int(np.sign(dv))
        return [(0, sx), (sy, 0), (sy, sx)]

    for du, dv in grid_off:
        for nb in quadrant(du, dv):
            if nb not in nbf:
                f = np.clip(er + np.int32(nb[0]), 0, H - 1) * np.int32(W) + np.clip(ec + np.int32(nb[1]), 0, W - 1)
                nbf[nb] = f
                same[nb] = np.take(key, f) == k0
    same[(0, 0)] = np.ones(len(idx), bool)
    # the sub-samples whose quadrant neighbours do not all see the pixel's object: candidates (4, M)
    # (where they all do, even at another depth (a fold, a grazing surface), the sub-sample sees
    # that object and keeps the pixel's shading, as a traced sub-sample of the same object would)
    # (row 0 the pixel itself), one contiguous row per candidate so the per-row logic stays cheap
    ej, cf, pu, pv = [], [], [], []
    for du, dv in grid_off:
        q = quadrant(du, dv)
        e = np.nonzero(~(same[q[0]] & same[q[1]] & same[q[2]]))[0]
        ej.append(e)
        cf.append(np.stack([idx[e]] + [nbf[nb][e] for nb in q]))
        pu.append((ec[e] + du).astype(np.float32))
        pv.append((er[e] + dv).astype(np.float32))
    counts = [len(e) for e in ej]
    ej_a, cf_a = np.concatenate(ej), np.concatenate(cf, axis=1)
    pu_a, pv_a = np.concatenate(pu), np.concatenate(pv)
    M = len(ej_a)
    if M == 0:
        return
    ar = np.arange(M)
    ck, ct, cs = np.take(key, cf_a), np.take(tt, cf_a), np.take(h.seed.astype(np.int32), cf_a)
    seedc = cs >= 0
    # each distinct seed among a sub-sample's candidates is tested once (neighbours often see the
    # pixel's own seed): a candidate repeating an earlier one copies its answer
    first = seedc.copy()
    dup_of = np.full((4, M), -1, np.int8)
    for r in range(1, 4):
        for q in range(r):
            d_ = first[r] & (cs[r] == cs[q])
            dup_of[r][d_] = q
            first[r] &= ~d_
    si = np.nonzero(first.reshape(-1))[0]
    cov = np.zeros(4 * M, bool)
    if len(si):
        sid = np.take(cs.reshape(-1), si)
        needed = np.zeros(len(fs.world.seeds), bool)
        needed[sid] = True
        conics = _seed_conics(fs, T_wc, calib, ids=np.nonzero(needed)[0])
        m_ = si % M
        cov[si] = _inside_outline(conics, sid, np.take(pu_a, m_), np.take(pv_a, m_))
    cov = cov.reshape(4, M)
    for r in range(1, 4):
        for q in range(r):
            d_ = dup_of[r] == q
            cov[r][d_] = cov[q][d_]
    inf = np.float32(np.inf)
    # nearest covering seed candidate (best, tbest); nearest non-seed candidate; first non-seed one
    tbest = np.where(cov[0], ct[0], inf)
    best = np.zeros(M, np.intp)
    t_nons = np.where(seedc[0], inf, ct[0])
    fi = np.full(M, -1, np.intp)
    for r in range(1, 4):
        tr = np.where(cov[r], ct[r], inf)
        better = tr < tbest
        tbest = np.where(better, tr, tbest)
        best[better] = r
        np.minimum(t_nons, np.where(seedc[r], inf, ct[r]), out=t_nons)
    for r in range(3, -1, -1):
        fi[~seedc[r]] = r
    any_nons = fi >= 0
    fi[~any_nons] = 0
    seen_seed = np.isfinite(tbest) & (t_nons > tbest)
    def pick(a: np.ndarray, row: np.ndarray) -> np.ndarray:  # a[row[m], m] (a flat take: fast)
        return np.take(a.reshape(-1), row * M + ar)

    kf, tf = pick(ck, fi), pick(ct, fi)
    behind = ~np.isfinite(tbest) & any_nons
    for r in range(4):
        behind &= seedc[r] | ((ck[r] == kf) & (np.abs(ct[r] - tf) <= 0.05 * np.minimum(ct[r], tf)))
    col = np.where(seen_seed, best, fi)
    col[pick(ck, col) == ck[0]] = 0  # the pixel's own object: its own shading
    src = pick(cf_a, col)
    traced = np.nonzero(~(seen_seed | behind))[0]
    fresh = np.zeros(0, np.int64)
    if len(traced):
        ps = np.stack([pu_a[traced], pv_a[traced]], 1)
        ds = _xf(_unit_dirs(calib, ps), R)
        cft = np.ascontiguousarray(np.take(cf_a, traced, axis=1).T)  # (n, 4)
        ccls = np.take(h.cls, cft)
        only = np.where((ccls == CLS_STALK) | (ccls == CLS_LEAF), ENV_CODE, np.take(h.obj, cft)).astype(np.int32)
        hs = fs.trace(o, ds, ps, covers, only=only)
        match = np.take(ck, traced, axis=1) == _object_key(hs)  # (4, n)
        first = np.full(len(traced), -1, np.intp)
        for r in range(3, -1, -1):
            first[match[r]] = r
        has = first >= 0
        src[traced[has]] = np.take(cft.reshape(-1), np.nonzero(has)[0] * 4 + first[has])
        fresh = traced[~has]
        if len(fresh):
            nf = ~has
            sub = _Hits(hs.t[nf], hs.cls[nf], hs.obj[nf], hs.prim[nf], hs.bary[nf], hs.seed[nf])
            fresh_rgb = _shade(fs, o, ds[nf], sub, light, light_axes, cfg, rng, ps[nf], scovers)
    sub_rgb = _take(rgb, src)
    if len(fresh):
        _put_rows(sub_rgb, fresh, fresh_rgb)
    # a sub-sample on another seed than its pixel's is shaded where its ray meets that seed (seed
    # rims are darker than the neighbouring pixel centre: the surface turns away from the flash),
    # with the flash visibility of the pixel that sees the seed
    on_seed = (np.take(h.seed, src) >= 0) & (np.take(key, src) != ck[0])
    on_seed[fresh] = False
    ns = np.nonzero(on_seed)[0]
    if len(ns):
        s_src = src[ns]
        sid = h.seed[s_src]
        ps = np.stack([pu_a[ns], pv_a[ns]], 1)
        ds = _xf(_unit_dirs(calib, ps), R)
        t_hit = _seed_entry(fs, o[0], ds, sid)
        zero = np.zeros(len(ns), np.int64)
        sub = _Hits(t_hit, np.full(len(ns), CLS_SEED, np.uint8), h.obj[s_src], zero, np.zeros((len(ns), 2), np.float32),
                    sid)
        sh = _shade_parts(fs, o, ds, sub, light, light_axes, cfg, rng, vis_given=vis[s_src])
        _put_rows(sub_rgb, ns, sh.radiance(len(ns)))
    acc = _take(rgb, idx)
    base = acc.copy()
    acc *= S
    start = 0
    for c in counts:
        e = ej_a[start:start + c]
        acc[e] += sub_rgb[start:start + c] - base[e]
        start += c
    acc *= np.float32(1.0 / S)
    _put_rows(rgb, idx, acc)


def _camera_dirs(world: World, calib: StereoCalib) -> tuple[np.ndarray, np.ndarray]:
    """Unit ray directions through all pixel centres in the camera frame (cached) and pixel (u, v)."""
    key = ("dirs", calib)
    got = world.cache.get(key)
    if got is None:
        H, W = calib.height, calib.width
        vv, uu = np.mgrid[0:H, 0:W]
        pix = np.stack([uu.reshape(-1), vv.reshape(-1)], 1).astype(np.float32)
        got = (_unit_dirs(calib, pix), pix)
        world.cache[key] = got
    return got


def _unit_dirs(calib: StereoCalib, pix: np.ndarray) -> np.ndarray:
    x = (pix[:, 0] - np.float32(calib.cx)) / np.float32(calib.fx)
    y = (pix[:, 1] - np.float32(calib.cy)) / np.float32(calib.fy)
    inv = 1.0 / np.sqrt(x * x + y * y + 1.0)
    return np.stack([x * inv, y * inv, inv], 1).astype(np.float32)


def _object_key(h: _Hits) -> np.ndarray:
    """One int32 per ray naming what it sees: the seed id, or a negative code of (class, object)."""
    return np.where(h.seed >= 0, h.seed.astype(np.int32), -(h.cls.astype(np.int32) * 1_000_000 + h.obj + 2))


def _render_camera(fs: _FrameScene, T_wc: np.ndarray, calib: StereoCalib, cfg: SimConfig,
                   rng: np.random.Generator, light: np.ndarray, light_axes: np.ndarray):
    H, W = calib.height, calib.width
    R = T_wc[:3, :3].astype(np.float32)
    o = T_wc[:3, 3].astype(np.float32)[None, :]
    dc, pix = _camera_dirs(fs.world, calib)
    d = _xf(dc, R)
    covers, scovers = fs.covers(T_wc, calib, light, cfg)
    h = fs.trace(o, d, pix, covers, grid=True)
    key = _object_key(h)
    soft = cfg.imaging.shadows and cfg.imaging.flash_radius > 0
    sparse = soft and SHADOW_STRIDE > 1
    sh = _shade_parts(fs, o, d, h, light, light_axes, cfg, rng, pix, scovers,
                      _shadow_grid(H, W) if sparse else None)
    vis = np.ones(H * W, np.float32)
    vis[sh.live] = sh.vis
    if sparse:
        vis = _shadows_from_samples(fs, vis.reshape(H, W), key.reshape(H, W), sh.pending, scovers).reshape(-1)
    elif soft:
        vis = _filter_visibility(vis.reshape(H, W), key.reshape(H, W)).reshape(-1)
    rgb = sh.radiance(H * W, vis)
    seed_img = h.seed.reshape(H, W)
    depth = np.where(np.isfinite(h.t), h.t * dc[:, 2], np.nan).reshape(H, W).astype(np.float32)
    if cfg.imaging.supersample > 1:
        _antialias(fs, o, R, calib, cfg, h, key, rgb, covers, scovers, light, light_axes, rng, T_wc, vis)
    return rgb.reshape(H, W, 3), seed_img, depth, h


_GAMMA_LUT = np.round(255.0 * np.linspace(0, 1, 4096) ** (1 / 2.2)).astype(np.uint8)


def _develop(lin: np.ndarray, calib: StereoCalib, cfg: SimConfig, rng: np.random.Generator, gain: float,
             depth: np.ndarray | None, cache: dict) -> np.ndarray:
    """Sensor + ISP model: gain, vignetting, blur, noise, gamma, 8-bit (and optional JPEG). ``lin`` (H, W, 3)
    float32 is overwritten."""
    import cv2

    ic = cfg.imaging
    H, W = lin.shape[:2]
    key = ("vignette", calib, ic.vignetting)
    vig = cache.get(key)
    if vig is None:
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        rn2 = ((xx - calib.cx) ** 2 + (yy - calib.cy) ** 2) / (0.25 * (W * W + H * H))
        vig = cache[key] = (1 - ic.vignetting * rn2).astype(np.float32)[..., None]
    img = lin  # (the caller's buffer, scaled in place)
    img *= vig * np.float32(gain * ic.full_well)  # electrons
    if ic.motion_blur:
        z = np.nanmedian(depth) if depth is not None and np.isfinite(depth).any() else REF_DISTANCE
        blur_px = calib.fx * cfg.motion.speed * ic.exposure_time / max(float(z), 0.05)
        k = int(round(blur_px))
        if k >= 2:
            img = cv2.blur(img, (k, 1))
    if ic.psf_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), ic.psf_sigma_px)
    np.maximum(img, 0, out=img)
    # shot + read noise as one Gaussian of the combined variance
    noise = rng.standard_normal(img.shape, np.float32)
    sd = img + np.float32(ic.read_noise ** 2)
    np.sqrt(sd, out=sd)
    noise *= sd
    img += noise
    img *= np.float32(4095.0 / ic.full_well)
    np.clip(img, 0, 4095, out=img)
    # uint16 codes (the same truncation as an integer cast; a quarter of the memory traffic of intp)
    out = np.take(_GAMMA_LUT, img.astype(np.uint16), mode="clip")
    if ic.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(ic.jpeg_quality)])
        if ok:
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return out


def _instances(fs: _FrameScene, seed_img: np.ndarray, centers_now: np.ndarray, T_wc: np.ndarray,
               calib: StereoCalib) -> tuple[np.ndarray, Instances]:
    world = fs.world
    H, W = seed_img.shape
    flat = seed_img.reshape(-1)
    has = flat >= 0
    labels = np.zeros(H * W, np.uint16)
    if not has.any():
        return labels.reshape(H, W), Instances.empty()
    pix = np.nonzero(has)[0]
    ids, inv, area = np.unique(flat[pix], return_inverse=True, return_counts=True)
    if len(ids) > 65535:
        raise RuntimeError("more than 65535 visible seeds in one image")
    K = len(ids)
    labels[pix] = (inv + 1).astype(np.uint16)
    rows, cols = np.divmod(pix, W)
    x0 = np.full(K, W, np.int64)
    y0 = np.full(K, H, np.int64)
    x1 = np.zeros(K, np.int64)
    y1 = np.zeros(K, np.int64)
    np.minimum.at(x0, inv, cols)
    np.minimum.at(y0, inv, rows)
    np.maximum.at(x1, inv, cols + 1)
    np.maximum.at(y1, inv, rows + 1)
    c_world = centers_now[ids]
    Tcw = invert(T_wc)
    pc = c_world @ Tcw[:3, :3].T + Tcw[:3, 3]
    # rounded to the 1/1000 px the dataset stores, so the pixel test below agrees with what is read back
    u = np.round(calib.fx * pc[:, 0] / pc[:, 2] + calib.cx, 3)
    v = np.round(calib.fy * pc[:, 1] / pc[:, 2] + calib.cy, 3)
    # center_visible: the ray from the optical centre towards the 3D centre meets this seed first
    o = T_wc[:3, 3]
    dv = (c_world - o).astype(np.float32)
    dist = np.linalg.norm(dv, axis=1)
    hc = fs.trace(o.astype(np.float32)[None, :], (dv / dist[:, None]).astype(np.float32))
    ray_ok = (hc.seed == ids) & (hc.t <= dist + 1e-5)
    # ... and the pixel that contains the projected centre shows this seed (a seed can be hit by the
    # exact centre ray while the pixel-centre ray, up to half a pixel away, meets a neighbour)
    cu = np.floor(u + 0.5).astype(np.int64)
    cr = np.floor(v + 0.5).astype(np.int64)
    inside = (cu >= 0) & (cu < W) & (cr >= 0) & (cr < H)
    pix_ok = np.zeros(K, bool)
    pix_ok[inside] = seed_img[cr[inside], cu[inside]] == ids[inside]
    visible = ray_ok & pix_ok
    inst = Instances(
        label=np.arange(1, K + 1, dtype=np.uint16), seed_id=world.seeds.seed_id[ids].astype(np.int64),
        panicle_id=world.seeds.panicle_id[ids].astype(np.int64), boxes=np.column_stack([x0, y0, x1, y1]),
        center_uv=np.column_stack([u, v]), area=area.astype(np.int64), center_visible=visible)
    return labels.reshape(H, W), inst


def right_pose(T_world_left: np.ndarray, baseline: float) -> np.ndarray:
    """Pose of the right camera: ``+baseline`` along the left camera's x axis."""
    T = np.asarray(T_world_left, float).copy()
    T[:3, 3] = T[:3, 3] + T[:3, 0] * baseline
    return T


def render_stereo(world: World, T_world_cam: np.ndarray, calib: StereoCalib, cfg: SimConfig,
                  rng: np.random.Generator, t: float) -> RenderedStereo:
    """Render the rectified pair whose LEFT camera is at ``T_world_cam`` with the world at time ``t`` (s).

    Works for any pose (range robot, arm around a single panicle). Random effects of this frame
    (exposure jitter, flash sampling, sensor noise) are drawn from ``rng``.
    """
    T_l = np.asarray(T_world_cam, float)
    T_r = right_pose(T_l, calib.baseline)
    light = T_l[:3, :3] @ np.asarray(cfg.imaging.flash_offset, float) + T_l[:3, 3]
    light_axes = np.stack([T_l[:3, 0], T_l[:3, 1]]).astype(np.float32)
    fs = _FrameScene(world, t, [T_l, T_r], calib, light)
    gain = cfg.imaging.exposure * 1.1 * float(np.exp(rng.normal(0, cfg.imaging.exposure_jitter)))
    centers = world.seed_centers_at(t, fs.D)
    # one generator per camera, so the result does not depend on whether they run in parallel
    cam_rngs = rng.spawn(2)
    jobs = (("left", T_l, cam_rngs[0]), ("right", T_r, cam_rngs[1]))

    def one(job):
        name, T, crng = job
        _O3D_THREADS.n = 1 if cfg.imaging.threads > 1 else 0
        # flash sampling and sensor noise from separate streams: the noise image does not depend on
        # how many flash samples the shading drew
        shade_rng, noise_rng = crng.spawn(2)
        lin, seed_img, depth, _ = _render_camera(fs, T, calib, cfg, shade_rng, light, light_axes)
        img = _develop(lin, calib, cfg, noise_rng, gain, depth, world.cache)
        labels, inst = _instances(fs, seed_img, centers, T, calib)
        return name, (img, labels, inst, depth)

    if cfg.imaging.threads > 1:
        from concurrent.futures import ThreadPoolExecutor

        _camera_dirs(world, calib)  # fill the shared caches before the threads start
        with ThreadPoolExecutor(max_workers=2) as ex:
            out = dict(ex.map(one, jobs))
    else:
        out = dict(one(j) for j in jobs)
    return RenderedStereo(
        left=out["left"][0], right=out["right"][0], left_labels=out["left"][1], right_labels=out["right"][1],
        left_instances=out["left"][2], right_instances=out["right"][2], left_depth=out["left"][3],
        panicle_motion=fs.D)
