"""The world frozen at one instant for ray casting: cached per-panicle BVHs and the per-frame env scene."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from seedmap.geometry import invert
from seedmap.records import StereoCalib
from seedmap.sim.config import FLASH_RADIUS
from seedmap.sim.meshes import ellipsoids, vertex_normals
from seedmap.sim.render.culling import (
    _CamCovers,
    _cover_from_boxes,
    _grow_shadow,
    _leaf_spheres,
    _nearest_rc,
    _sphere_boxes,
    _sphere_in_frustum,
    _tri_spheres,
    _triangle_boxes,
)
from seedmap.sim.render.rays import ENV_CODE, _dot, _Hits, _o3d, _o3d_threads, _put_rows, _rays_tensor, _take, _xf
from seedmap.sim.world import CLS_LEAF, CLS_RACHIS, CLS_SEED, CLS_SOIL, CLS_STALK, World

TRIS_PER_SEED = 80

MAX_CACHED_PANICLES = 16

SOIL_HALF_WIDTH = 6.0  # m: the soil rectangle spans y in [-6, 6] and x 4 m beyond the range's gaps



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


class _FrameScene:
    """The world frozen at time ``t``: env (analytic soil plane + a BVH of the stalks and swayed leaves
    that can be seen, or cast a shadow that can be seen, from these cameras) + the panicles in view.
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
        margin = max(float(np.linalg.norm(light - T[:3, 3])) for T in cams) + FLASH_RADIUS + 0.01

        def in_view(c: np.ndarray, r: np.ndarray) -> np.ndarray:
            keep = np.zeros(len(c), bool)
            for T in cams:
                keep |= _sphere_in_frustum(c, r + margin, T, calib)
            return keep

        wf = world.wind_field
        if len(world.stalk_vertices):
            sc, sr = _tri_spheres(world, "stalk_spheres", world.stalk_vertices[world.stalk_triangles])
            keep = in_view(sc, sr if wf is None else sr + wf.stalk_bound)
            if keep.any():
                if wf is None:
                    sv = world.stalk_vertices
                    vn = world.cache.get("stalk_normals")
                    if vn is None:
                        vn = world.cache["stalk_normals"] = vertex_normals(sv, world.stalk_triangles)
                else:  # bent by the wind
                    sv = wf.stalk_vertices(world, t)
                    vn = vertex_normals(sv, world.stalk_triangles)
                add(sv, world.stalk_triangles[keep], vn, world.stalk_color, np.zeros((len(sv), 2)), CLS_STALK)
        if len(world.leaf_vertices):
            lc, lr = _leaf_spheres(world)
            sel = np.nonzero(in_view(lc, lr))[0]
            nL = len(sel)
            if nL:
                M = world.leaf_motion(t)[sel]
                lv = np.einsum("lij,lvj->lvi", M[:, :3, :3], world.leaf_vertices[sel]) + M[:, None, :3, 3]
                if wf is not None:
                    lv += wf.leaf_offsets(world, sel, t)
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
    def covers(self, T_wc: np.ndarray, calib: StereoCalib, light: np.ndarray) -> tuple[_CamCovers, _CamCovers]:
        """For camera ``T_wc``: the pixels whose rays may hit the env BVH / each active panicle, and
        the pixels whose surface point may be shadowed by them (supersets of the truth): projected boxes
        of the env triangles and the panicles' proxies, grown against the flash direction for shadows
        (docs/method/simulator.md)."""
        H, W = calib.height, calib.width
        R, o = T_wc[:3, :3], T_wc[:3, 3]
        L = R.T @ (light - o)
        rho = FLASH_RADIUS
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
