"""Adaptive anti-aliasing of edge pixels: seed image outlines (conics), analytic seed entry, sub-samples."""

from __future__ import annotations

import numpy as np

from seedmap.records import StereoCalib
from seedmap.sim.config import LIGHT_CUTOFF, SimConfig
from seedmap.sim.render.culling import _CamCovers
from seedmap.sim.render.rays import ENV_CODE, _dot3, _Hits, _object_key, _put_rows, _rows, _take, _unit_dirs, _xf
from seedmap.sim.render.scene import _FrameScene
from seedmap.sim.render.shading import _shade, _shade_parts
from seedmap.sim.world import CLS_LEAF, CLS_SEED, CLS_STALK

SEED_AA_SCALE = 0.97  # the seed mesh's outline is about its ellipsoid's scaled by this (80-face icosphere)


def _seed_conics(fs: _FrameScene, T_wc: np.ndarray, calib: StereoCalib, scale: float = SEED_AA_SCALE,
                 ids: np.ndarray | None = None) -> np.ndarray:
    """Image outlines of the seeds of the active panicles as seen by camera ``T_wc`` at this instant:
    (N, 8) float32 over global seed ids (NaN for seeds of other panicles / behind the camera).

    A pixel point ``(u, v)`` lies inside seed ``s``'s outline (its ray meets the seed's ellipsoid,
    semi-axes scaled by ``scale``) iff ``1 + a_u du + a_v dv + c_uu du^2 + c_uv du dv + c_vv dv^2 >= 0``
    with ``du = u - u_c``, ``dv = v - v_c``; columns are ``u_c, v_c, a_u, a_v, c_uu, c_uv, c_vv`` and one
    of padding (a row is 32 bytes). Derivation: docs/method/simulator.md."""
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
    neighbours see another object or depth, each taking the shading of a neighbouring pixel that sees
    the same object; decided by seed outlines where possible, else traced against the objects the
    neighbours see (docs/method/simulator.md)."""
    H, W = calib.height, calib.width
    n_ss = cfg.imaging.supersample
    tt = np.minimum(h.t, np.float32(1e3))
    key2, tt2 = key.reshape(H, W), tt.reshape(H, W)
    lit2 = tt2 < LIGHT_CUTOFF + 0.3
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
