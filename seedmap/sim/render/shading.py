"""Flash shading: surface normals and albedo per class, soft flash visibility, Blinn-Phong, ambient."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.sim.conditions import WET_COVER, WET_DROP, WET_KS, WET_SHININESS
from seedmap.sim.config import AMBIENT, FLASH_RADIUS, LIGHT_CUTOFF, SimConfig
from seedmap.sim.render.culling import _CamCovers
from seedmap.sim.render.rays import _dot3, _Hits, _normalize3, _put_rows, _take, _xf
from seedmap.sim.render.scene import _FrameScene
from seedmap.sim.render.shadows import _PendingShadows, _shadow_start
from seedmap.sim.world import CLS_LEAF, CLS_RACHIS, CLS_SEED, CLS_SOIL, CLS_STALK, World

REF_DISTANCE = 0.7  # m: a surface facing the flash at this distance is "well exposed"

# per-class specular strength and exponent (Blinn-Phong); seeds: 0.12 on the grain, 0.03 on the glume
KS_SOIL, KS_STALK, KS_LEAF, KS_RACHIS = 0.01, 0.06, 0.10, 0.04
SHIN_DEFAULT, SHIN_LEAF, SHIN_SEED = 20.0, 25.0, 45.0
RACHIS_ALBEDO = (0.30, 0.26, 0.13)
_LEAF_LUT_N = 8192  # samples of the leaf's across-pattern (midrib x veins) over w in [0, 1]
DROP_DENSITY, DROP_RADIUS = 0.4, 0.18  # share of leaf cells holding a droplet; glint radius (cell widths)


def _leaf_pattern_lut() -> np.ndarray:
    """Midrib and vein brightening of a leaf as a function of the across-leaf coordinate ``w`` in
    [0, 1] (a table: exp and sin per pixel were a tenth of the shading time)."""
    w = np.linspace(0, 1, _LEAF_LUT_N)
    return ((1.0 + 0.35 * np.exp(-((w - 0.5) / 0.05) ** 2)) * (1.0 + 0.05 * np.sin(w * 2 * np.pi * 11.0))).astype(
        np.float32)


_LEAF_LUT = _leaf_pattern_lut()


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


def _wet_patches(s: np.ndarray, w: np.ndarray, prim: np.ndarray) -> np.ndarray:
    """Water film cover in [0, 1] of leaf points at along/across coordinates ``s``, ``w`` on triangle ``prim``:
    smooth patches (two waves along and across the blade, a phase per leaf) over about ``WET_COVER`` of it."""
    leaf = (prim // 64).astype(np.float32)  # 64 triangles per leaf
    p = np.sin(np.float32(2 * np.pi) * (np.float32(7.0) * s + np.float32(0.37) * leaf))
    p += np.sin(np.float32(2 * np.pi) * (np.float32(2.0) * w + np.float32(3.0) * s + np.float32(0.61) * leaf))
    # p in [-2, 2]; wet where it is above the quantile that leaves WET_COVER, with soft edges
    return np.clip((p - np.float32(2.0 - 4.0 * WET_COVER)) * np.float32(2.0), 0, 1)


def _hash01(a: np.ndarray) -> np.ndarray:
    """A cheap deterministic pseudo-random number in [0, 1) per element of ``a`` (float32)."""
    x = np.sin(a) * np.float32(43758.5453)
    return x - np.floor(x)


def _droplets(s: np.ndarray, w: np.ndarray, prim: np.ndarray) -> np.ndarray:
    """Droplet glints in [0, 1] at leaf coordinates ``s``, ``w`` on triangle ``prim``: the blade is divided into
    cells of about 7 x 5 mm; a cell holds a droplet with probability ``DROP_DENSITY``, at a random place in it, a
    glint about 1 mm across."""
    leaf = (prim // 64).astype(np.float32)  # 64 triangles per leaf
    cs = s * np.float32(97.0)
    cw = w * np.float32(13.0)
    i = np.floor(cs)
    j = np.floor(cw)
    key = i * np.float32(12.9898) + j * np.float32(78.233) + leaf * np.float32(37.719)
    du = cs - i - (np.float32(0.25) + np.float32(0.5) * _hash01(key + np.float32(1.7)))
    dv = cw - j - (np.float32(0.25) + np.float32(0.5) * _hash01(key + np.float32(4.1)))
    g = np.clip(np.float32(1.0) - (du * du + dv * dv) * np.float32(1 / DROP_RADIUS ** 2), 0, 1)
    return g * (_hash01(key) < np.float32(DROP_DENSITY))


def _soil_tex_f32(world: World) -> np.ndarray:
    """The soil texture as float32, padded by one wrapped row and column (cached on the world)."""
    t = world.cache.get("soil_tex_f32")
    if t is None:
        tex = world.soil_texture
        t = world.cache["soil_tex_f32"] = np.pad(tex, ((0, 1), (0, 1)), mode="wrap").astype(np.float32)
    return t


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


def _shade(fs: _FrameScene, o: np.ndarray, d: np.ndarray, h: _Hits, light: np.ndarray, light_axes: np.ndarray,
           cfg: SimConfig, rng: np.random.Generator, pix: np.ndarray | None = None,
           scovers: _CamCovers | None = None) -> np.ndarray:
    """Linear RGB radiance (1 = white surface facing the flash at REF_DISTANCE) per ray (float32 (N, 3))."""
    return _shade_parts(fs, o, d, h, light, light_axes, cfg, rng, pix, scovers).radiance(len(d))


def _shade_parts(fs: _FrameScene, o: np.ndarray, d: np.ndarray, h: _Hits, light: np.ndarray,
                 light_axes: np.ndarray, cfg: SimConfig, rng: np.random.Generator, pix: np.ndarray | None = None,
                 scovers: _CamCovers | None = None, shadow_rays: np.ndarray | None = None,
                 vis_given: np.ndarray | None = None) -> _Shading:
    """Direct light, flash visibility and ambient light of the rays that reach a lit surface.

    ``vis_given`` (N,): the flash visibility to use instead of tracing shadow rays.
    ``shadow_rays`` (bool (N,), None = all): which lit rays get a shadow ray now; the others get
    ``vis = NaN`` and their shadow segments are returned in ``pending`` (``_PendingShadows``) so the
    caller can trace the ones it cannot interpolate.
    Float32 struct-of-arrays throughout ((3, m) vectors; per-surface constants gathered from the
    per-seed / per-triangle tables): the shading is memory-bound."""
    ic = cfg.imaging
    world = fs.world
    far = LIGHT_CUTOFF + 0.3
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
    wet = np.zeros(m, np.float32) if cfg.conditions.wet > 0 else None  # water film cover of leaves and stalks
    drops = None  # droplet glints on the wet leaves
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
            if wet is not None:
                wet[lf] = _wet_patches(s, w, np.take(h.prim, le[li]))
                drops = np.zeros(m, np.float32)
                drops[lf] = _droplets(s, w, np.take(h.prim, le[li])) * wet[lf]
        if wet is not None:
            wet[st_] = WET_COVER
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
    rr = np.sqrt(np.take(rng.random(m, np.float32), order)) * np.float32(FLASH_RADIUS)
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
    fade = np.clip((np.float32(LIGHT_CUTOFF + 0.25) - dist) * 2, 0, 1)
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
    if wet is not None:  # the water film: a sharp highlight on top of the surface's own
        spec += np.exp(np.log(nh) * np.float32(WET_SHININESS)) * (np.float32(WET_KS * cfg.conditions.wet) * wet) \
            * irr * (ndl > 0)
        if drops is not None:  # a droplet (a small sphere) always holds a point that mirrors the flash
            spec += drops * np.float32(WET_DROP * cfg.conditions.wet) * irr
    ndl *= irr
    direct = albedo * ndl
    direct += spec
    irr *= np.float32(AMBIENT)
    irr *= ao
    return _Shading(live, direct, vis, albedo * irr, pending)
