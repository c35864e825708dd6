"""Ground-truth stereo renderer: Open3D ray casting (CPU), flash lighting, sensor model.

Why ray casting: one primary ray per pixel centre gives exact instance labels (which seed is seen at
pixel ``[r, c]``, i.e. at ``(u=c, v=r)``) and the same rays give the image; the wind is rigid per
panicle, so every panicle keeps one BVH built once at rest and rays are moved into its rest frame
instead of rebuilding the scene each frame. Leaves, stalks and soil are few triangles and are
rebuilt per frame.

Lighting: a single flash on the rig (a small disc, so shadows are soft), inverse-square fall-off,
an extra fade to black beyond ``imaging.light_cutoff`` (flash imaging: the far background is dark),
Lambertian + Blinn-Phong specular, baked per-seed ambient occlusion. Sensor: exposure jitter,
vignetting, optical blur, shot + read noise, sRGB gamma, optional motion blur and JPEG.
"""

from __future__ import annotations

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
MAX_CACHED_PANICLES = 24


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


def _rays_tensor(o: np.ndarray, d: np.ndarray):
    o3d = _o3d()
    r = np.empty((len(o), 6), np.float32)
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


class _FrameScene:
    """The world frozen at time ``t``: env BVH (soil, stalks, swayed leaves) + the panicles in view."""

    def __init__(self, world: World, t: float, cams: list[np.ndarray], calib: StereoCalib,
                 light: np.ndarray) -> None:
        o3d = _o3d()
        self.world = world
        self.D = world.panicle_motion(t)
        self.Dinv = invert(self.D) if len(self.D) else self.D
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

        if world.has_soil:
            x0, x1 = -world.cfg.world.gap - 4.0, world.length + world.cfg.world.gap + 4.0
            v = np.array([[x0, -6, 0], [x1, -6, 0], [x1, 6, 0], [x0, 6, 0]], float)
            add(v, np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0, 0, 1.0], (4, 1)),
                np.tile(world.soil_color, (4, 1)), np.zeros((4, 2)), CLS_SOIL)
        if len(world.stalk_vertices):
            add(world.stalk_vertices, world.stalk_triangles, vertex_normals(world.stalk_vertices,
                                                                             world.stalk_triangles),
                world.stalk_color, np.zeros((len(world.stalk_vertices), 2)), CLS_STALK)
        nL = len(world.leaf_vertices)
        self.leaf_tri0 = off
        if nL:
            M = world.leaf_motion(t)
            lv = np.einsum("lij,lvj->lvi", M[:, :3, :3], world.leaf_vertices) + M[:, None, :3, 3]
            nv = lv.shape[1]
            lf = world.leaf_triangles
            allf = (lf[None] + (np.arange(nL) * nv)[:, None, None]).reshape(-1, 3)
            allv = lv.reshape(-1, 3)
            add(allv, allf, vertex_normals(allv, allf), np.repeat(world.leaf_color, nv, axis=0),
                np.tile(world.leaf_uv, (nL, 1)), CLS_LEAF)
        if F:
            self.V = np.vstack(V).astype(np.float32)
            self.F = np.vstack(F).astype(np.int64)
            self.VN = np.vstack(VN).astype(np.float32)
            self.VC = np.vstack(VC).astype(np.float32)
            self.VUV = np.vstack(VUV).astype(np.float32)
            self.tri_cls = np.concatenate(cls)
            self.env = o3d.t.geometry.RaycastingScene()
            self.env.add_triangles(o3d.core.Tensor.from_numpy(self.V),
                                   o3d.core.Tensor.from_numpy(self.F.astype(np.uint32)))
        else:
            self.env = None
        self.leaf_tris_per = len(world.leaf_triangles)
        # panicles that can be seen from (or shadow what is seen from) any of the cameras
        self.active: list[int] = []
        self.centers = np.zeros((0, 3))
        if world.panicles:
            c_rest = np.stack([p.center for p in world.panicles])
            r = np.array([p.radius for p in world.panicles])
            c_now = np.einsum("pij,pj->pi", self.D[:, :3, :3], c_rest) + self.D[:, :3, 3]
            vis = np.zeros(len(r), bool)
            for T in cams:
                vis |= _sphere_in_frustum(c_now, r + 0.08, T, calib)
            lc = _sphere_in_frustum(c_now, r + 0.08, cams[0], calib, origin=light)
            vis |= lc
            self.active = [int(k) for k in np.nonzero(vis)[0]]
            self.centers = c_now
            self.radii = r
        self.bvh = {k: _panicle_bvh(world, k) for k in self.active}

    # ---- queries ----
    def _sphere_select(self, k: int, o: np.ndarray, d: np.ndarray, best: np.ndarray) -> np.ndarray:
        oc = (self.centers[k] - o).astype(np.float32)
        b = np.einsum("ij,ij->i", oc, d)
        c2 = np.einsum("ij,ij->i", oc, oc) - b * b
        r2 = self.radii[k] ** 2
        ok = (c2 <= r2) & (b + self.radii[k] > 0)
        enter = b - np.sqrt(np.maximum(r2 - c2, 0))
        return np.nonzero(ok & (enter < best))[0]

    def trace(self, o: np.ndarray, d: np.ndarray) -> _Hits:
        """Closest hit of rays ``o + t d`` (``d`` unit, float32 arrays (N, 3))."""
        n = len(d)
        o = np.broadcast_to(np.asarray(o, np.float32), (n, 3))
        t = np.full(n, np.inf, np.float32)
        cls = np.zeros(n, np.uint8)
        obj = np.full(n, -1, np.int32)
        prim = np.zeros(n, np.int64)
        bary = np.zeros((n, 2), np.float32)
        if self.env is not None and n:
            ans = self.env.cast_rays(_rays_tensor(o, d))
            t = ans["t_hit"].numpy().copy()
            hit = np.isfinite(t)
            prim[hit] = ans["primitive_ids"].numpy()[hit].astype(np.int64)
            bary[hit] = ans["primitive_uvs"].numpy()[hit]
            cls[hit] = self.tri_cls[prim[hit]]
        for k in self.active:
            idx = self._sphere_select(k, o, d, t)
            if len(idx) == 0:
                continue
            Di = self.Dinv[k]
            o_r = o[idx] @ Di[:3, :3].T.astype(np.float32) + Di[:3, 3].astype(np.float32)
            d_r = d[idx] @ Di[:3, :3].T.astype(np.float32)
            bvh = self.bvh[k]
            ans = bvh.scene.cast_rays(_rays_tensor(o_r, d_r))
            tk = ans["t_hit"].numpy()
            better = tk < t[idx]
            if not better.any():
                continue
            j = idx[better]
            t[j] = tk[better]
            pk = ans["primitive_ids"].numpy()[better].astype(np.int64)
            prim[j] = pk
            bary[j] = ans["primitive_uvs"].numpy()[better]
            cls[j] = np.where(pk < bvh.n_seed_tris, CLS_SEED, CLS_RACHIS)
            obj[j] = k
        seed = np.full(n, -1, np.int64)
        sm = cls == CLS_SEED
        if sm.any():
            starts = np.array([p.seed_start for p in self.world.panicles])
            seed[sm] = starts[obj[sm]] + prim[sm] // TRIS_PER_SEED
        return _Hits(t, cls, obj, prim, bary, seed)

    def occluded(self, o: np.ndarray, v: np.ndarray) -> np.ndarray:
        """True where the segment ``o -> o + v`` (not unit) hits anything."""
        n = len(o)
        occ = np.zeros(n, bool)
        if n == 0:
            return occ
        tfar = 1.0 - 1e-4
        if self.env is not None:
            occ = self.env.test_occlusions(_rays_tensor(o, v), tnear=0.0, tfar=tfar).numpy().astype(bool)
        length = np.linalg.norm(v, axis=1).astype(np.float32)
        du = v / np.maximum(length, 1e-12)[:, None]
        for k in self.active:
            rem = np.nonzero(~occ)[0]
            if len(rem) == 0:
                break
            idx = rem[self._sphere_select(k, o[rem], du[rem], length[rem])]
            if len(idx) == 0:
                continue
            Di = self.Dinv[k]
            o_r = o[idx] @ Di[:3, :3].T.astype(np.float32) + Di[:3, 3].astype(np.float32)
            v_r = v[idx] @ Di[:3, :3].T.astype(np.float32)
            occ[idx] = self.bvh[k].scene.test_occlusions(_rays_tensor(o_r, v_r), tnear=0.0,
                                                          tfar=tfar).numpy().astype(bool)
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


def _soil_albedo(world: World, p: np.ndarray) -> np.ndarray:
    tex = world.soil_texture
    S = tex.shape[0]
    u = (p[:, 0] / world.soil_tile) * S
    v = (p[:, 1] / world.soil_tile) * S
    i0 = np.floor(u).astype(np.int64)
    j0 = np.floor(v).astype(np.int64)
    fu = (u - i0)[:, None]
    fv = (v - j0)[:, None]
    i0 %= S
    j0 %= S
    i1, j1 = (i0 + 1) % S, (j0 + 1) % S
    val = ((tex[j0, i0][:, None] * (1 - fu) + tex[j0, i1][:, None] * fu) * (1 - fv)
           + (tex[j1, i0][:, None] * (1 - fu) + tex[j1, i1][:, None] * fu) * fv)
    return world.soil_color[None, :] * val


def _shade(fs: _FrameScene, o: np.ndarray, d: np.ndarray, h: _Hits, light: np.ndarray, light_axes: np.ndarray,
           cfg: SimConfig, rng: np.random.Generator) -> np.ndarray:
    """Linear RGB radiance (relative to a white surface facing the flash at REF_DISTANCE) per ray."""
    ic = cfg.imaging
    world = fs.world
    n = len(d)
    out = np.zeros((n, 3), np.float32)
    far = REF_DISTANCE * 0 + ic.light_cutoff * 1.3
    live = np.nonzero(np.isfinite(h.t) & (h.t < far + 0.6))[0]
    if len(live) == 0:
        return out
    o = np.broadcast_to(o, (n, 3))[live]
    dl = d[live]
    t = h.t[live]
    cls = h.cls[live]
    p = o + t[:, None] * dl
    m = len(live)
    albedo = np.zeros((m, 3), np.float32)
    nrm = np.zeros((m, 3), np.float32)
    ks = np.zeros(m, np.float32)
    shin = np.full(m, 20.0, np.float32)
    ao = np.ones(m, np.float32)
    prim = h.prim[live]
    bary = h.bary[live]
    # env surfaces: interpolate vertex attributes
    em = np.nonzero((cls == CLS_SOIL) | (cls == CLS_STALK) | (cls == CLS_LEAF))[0]
    if len(em):
        F = fs.F[prim[em]]
        b1, b2 = bary[em, 0:1], bary[em, 1:2]
        b0 = 1 - b1 - b2
        nrm[em] = fs.VN[F[:, 0]] * b0 + fs.VN[F[:, 1]] * b1 + fs.VN[F[:, 2]] * b2
        albedo[em] = fs.VC[F[:, 0]] * b0 + fs.VC[F[:, 1]] * b1 + fs.VC[F[:, 2]] * b2
        uvw = fs.VUV[F[:, 0]] * b0 + fs.VUV[F[:, 1]] * b1 + fs.VUV[F[:, 2]] * b2
        c = cls[em]
        soil = c == CLS_SOIL
        if soil.any():
            albedo[em[soil]] = _soil_albedo(world, p[em[soil]])
            ks[em[soil]] = 0.01
        leaf = c == CLS_LEAF
        if leaf.any():
            s, w = uvw[leaf, 0], uvw[leaf, 1]
            midrib = 1.0 + 0.35 * np.exp(-((w - 0.5) / 0.05) ** 2)
            veins = 1.0 + 0.05 * np.sin(2 * np.pi * w * 11.0)
            tipdry = 1.0 + 0.25 * np.clip((s - 0.75) / 0.25, 0, 1)
            albedo[em[leaf]] *= (midrib * veins * tipdry)[:, None]
            ks[em[leaf]] = 0.10
            shin[em[leaf]] = 25.0
        stalk = c == CLS_STALK
        ks[em[stalk]] = 0.06
    # rachis: flat normals from the panicle mesh, rotated by the wind
    rm = np.nonzero(cls == CLS_RACHIS)[0]
    if len(rm):
        objs = h.obj[live][rm]
        for k in np.unique(objs):
            sel = rm[objs == k]
            nrm[sel] = fs.bvh[k].face_normals[prim[sel]] @ fs.D[k, :3, :3].T.astype(np.float32)
        albedo[rm] = np.array([0.30, 0.26, 0.13], np.float32)
        ks[rm] = 0.04
    # seeds: analytic ellipsoid normal (smooth shading on a low-poly mesh), glume at the base
    sm = np.nonzero(cls == CLS_SEED)[0]
    if len(sm):
        sid = h.seed[live][sm]
        objs = h.obj[live][sm]
        p_rest = np.empty((len(sm), 3), np.float32)
        for k in np.unique(objs):
            sel = objs == k
            Di = fs.Dinv[k]
            p_rest[sel] = p[sm[sel]] @ Di[:3, :3].T + Di[:3, 3]
        A = world.seed_axes[sid]
        r = world.seeds.radii[sid]
        q = np.einsum("nji,nj->ni", A, p_rest - world.seeds.xyz[sid])  # local coordinates
        n_loc = q / (r * r)
        n_rest = np.einsum("nij,nj->ni", A, n_loc)
        n_w = np.empty_like(n_rest)
        for k in np.unique(objs):
            sel = objs == k
            n_w[sel] = n_rest[sel] @ fs.D[k, :3, :3].T
        nrm[sm] = n_w
        zrel = q[:, 2] / r[:, 2]
        g = np.clip((world.glume_extent[sid] + 0.15 - zrel) / 0.3, 0, 1)
        g = g * g * (3 - 2 * g)
        albedo[sm] = world.seed_albedo[sid] * (1 - g[:, None]) + world.glume_albedo[sid] * g[:, None]
        ks[sm] = 0.12 * (1 - g) + 0.03 * g
        shin[sm] = 45.0
        ao[sm] = world.seed_ao[sid]
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    flip = np.einsum("ij,ij->i", nrm, dl) > 0
    nrm[flip] *= -1
    # flash: a random point on a small disc per sample (soft shadows)
    rr = ic.flash_radius * np.sqrt(rng.uniform(0, 1, m))
    th = rng.uniform(0, 2 * np.pi, m)
    lp = light[None, :] + (rr * np.cos(th))[:, None] * light_axes[0] + (rr * np.sin(th))[:, None] * light_axes[1]
    lv = (lp - p).astype(np.float32)
    dist = np.linalg.norm(lv, axis=1)
    ldir = lv / dist[:, None]
    ndl = np.maximum(np.einsum("ij,ij->i", nrm, ldir), 0)
    fade = np.clip((ic.light_cutoff + 0.25 - dist) / 0.5, 0, 1)
    fade = fade * fade * (3 - 2 * fade)
    irr = (REF_DISTANCE / dist) ** 2 * fade
    vis = np.ones(m, np.float32)
    if ic.shadows:
        lit = np.nonzero((ndl > 0) & (irr > 1e-4))[0]
        start = p[lit] + nrm[lit] * 2e-4
        occ = fs.occluded(start.astype(np.float32), (lp[lit] - start).astype(np.float32))
        vis[lit[occ]] = 0.0
    hv = ldir - dl
    hv /= np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-12)
    spec = ks * np.maximum(np.einsum("ij,ij->i", nrm, hv), 0) ** shin * (ndl > 0)
    rad = albedo * (ndl * vis)[:, None] + spec[:, None] * vis[:, None] + albedo * (ic.ambient * ao)[:, None]
    out[live] = rad * irr[:, None]
    return out


def _pixel_dirs(calib: StereoCalib, R: np.ndarray, du: float = 0.0, dv: float = 0.0,
                idx: np.ndarray | None = None) -> np.ndarray:
    """Unit world directions of rays through pixel centres (+ sub-pixel offsets ``du, dv``)."""
    H, W = calib.height, calib.width
    if idx is None:
        vv, uu = np.mgrid[0:H, 0:W]
        uu, vv = uu.reshape(-1), vv.reshape(-1)
    else:
        vv, uu = np.divmod(idx, W)
    x = ((uu + du - calib.cx) / calib.fx).astype(np.float32)
    y = ((vv + dv - calib.cy) / calib.fy).astype(np.float32)
    dc = np.stack([x, y, np.ones_like(x)], 1)
    dc /= np.linalg.norm(dc, axis=1, keepdims=True)
    return (dc @ R.T.astype(np.float32)).astype(np.float32)


def _render_camera(fs: _FrameScene, T_wc: np.ndarray, calib: StereoCalib, cfg: SimConfig,
                   rng: np.random.Generator, light: np.ndarray, light_axes: np.ndarray):
    H, W = calib.height, calib.width
    R = T_wc[:3, :3]
    o = T_wc[:3, 3].astype(np.float32)[None, :]
    d = _pixel_dirs(calib, R)
    h = fs.trace(o, d)
    rgb = _shade(fs, o, d, h, light, light_axes, cfg, rng)
    seed_img = h.seed.reshape(H, W)
    zdir = (d @ R[:, 2].astype(np.float32))
    depth = np.where(np.isfinite(h.t), h.t * zdir, np.nan).reshape(H, W).astype(np.float32)
    # adaptive anti-aliasing: supersample pixels whose neighbours see another object or depth
    n_ss = cfg.imaging.supersample
    if n_ss > 1:
        key = np.where(h.seed >= 0, h.seed, -(h.cls.astype(np.int64) * 1_000_000 + h.obj + 2)).reshape(H, W)
        tt = np.where(np.isfinite(h.t), h.t, 1e3).reshape(H, W)
        edge = np.zeros((H, W), bool)
        dk = key[:, 1:] != key[:, :-1]
        dz = np.abs(tt[:, 1:] - tt[:, :-1]) > 0.02 * np.minimum(tt[:, 1:], tt[:, :-1])
        e = dk | dz
        edge[:, 1:] |= e
        edge[:, :-1] |= e
        dk = key[1:, :] != key[:-1, :]
        dz = np.abs(tt[1:, :] - tt[:-1, :]) > 0.02 * np.minimum(tt[1:, :], tt[:-1, :])
        e = dk | dz
        edge[1:, :] |= e
        edge[:-1, :] |= e
        # nothing to anti-alias between two far, unlit surfaces
        edge &= (tt < cfg.imaging.light_cutoff * 1.3 + 0.6) | np.roll(tt < 3, 1, axis=1)
        idx = np.nonzero(edge.reshape(-1))[0]
        if len(idx):
            acc = np.zeros((len(idx), 3), np.float32)
            offs = (np.arange(n_ss) + 0.5) / n_ss - 0.5
            for dv in offs:
                for du in offs:
                    ds = _pixel_dirs(calib, R, du, dv, idx)
                    hs = fs.trace(o, ds)
                    acc += _shade(fs, o, ds, hs, light, light_axes, cfg, rng)
            rgb[idx] = acc / (n_ss * n_ss)
    return rgb.reshape(H, W, 3), seed_img, depth, h


def _develop(lin: np.ndarray, calib: StereoCalib, cfg: SimConfig, rng: np.random.Generator, gain: float,
             depth: np.ndarray | None) -> np.ndarray:
    """Sensor + ISP model: gain, vignetting, blur, noise, gamma, 8-bit (and optional JPEG)."""
    import cv2

    ic = cfg.imaging
    H, W = lin.shape[:2]
    img = lin * gain
    if ic.vignetting > 0:
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        rn2 = ((xx - calib.cx) ** 2 + (yy - calib.cy) ** 2) / (0.25 * (W * W + H * H))
        img *= (1 - ic.vignetting * rn2)[..., None]
    if ic.motion_blur:
        z = np.nanmedian(depth) if depth is not None and np.isfinite(depth).any() else REF_DISTANCE
        blur_px = calib.fx * cfg.motion.speed * ic.exposure_time / max(float(z), 0.05)
        k = int(round(blur_px))
        if k >= 2:
            img = cv2.blur(img, (k, 1))
    if ic.psf_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), ic.psf_sigma_px)
    e = np.clip(img, 0, None) * ic.full_well
    e = e + np.sqrt(e) * rng.standard_normal(e.shape, np.float32) + ic.read_noise * rng.standard_normal(e.shape,
                                                                                                           np.float32)
    v = np.clip(e / ic.full_well, 0, 1)
    out = np.round(255.0 * v ** (1 / 2.2)).astype(np.uint8)
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
    u = calib.fx * pc[:, 0] / pc[:, 2] + calib.cx
    v = calib.fy * pc[:, 1] / pc[:, 2] + calib.cy
    # center_visible: the ray from the optical centre towards the 3D centre meets this seed first
    o = T_wc[:3, 3]
    dv = (c_world - o).astype(np.float32)
    dist = np.linalg.norm(dv, axis=1)
    hc = fs.trace(o.astype(np.float32)[None, :], (dv / dist[:, None]).astype(np.float32))
    visible = (hc.seed == ids) & (hc.t <= dist + 1e-5)
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
    out = {}
    for name, T in (("left", T_l), ("right", T_r)):
        lin, seed_img, depth, _ = _render_camera(fs, T, calib, cfg, rng, light, light_axes)
        img = _develop(lin, calib, cfg, rng, gain, depth)
        labels, inst = _instances(fs, seed_img, centers, T, calib)
        out[name] = (img, labels, inst, depth)
    return RenderedStereo(
        left=out["left"][0], right=out["right"][0], left_labels=out["left"][1], right_labels=out["right"][1],
        left_instances=out["left"][2], right_instances=out["right"][2], left_depth=out["left"][3],
        panicle_motion=fs.D)
