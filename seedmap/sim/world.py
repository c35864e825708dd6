"""The procedural sorghum world: plants, panicles made of seeds, leaves, stalks, soil and wind.

World frame: x along the row (direction of travel), y from the robot towards the row, z up,
ground at z = 0. All lengths in metres, angles in radians inside this module.

Every seed is a low-poly ellipsoid with a global id (0..N-1, contiguous per panicle). Panicles and
leaves sway rigidly about their base (wind); ``World.panicle_motion(t)`` gives the motion ``D`` with
``p_world(t) = D @ p_rest`` for every panicle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from seedmap.io.seedmap_dataset import SeedTable
from seedmap.sim.config import (
    BACKGROUND_ROW_OFFSET,
    LEAF_LENGTH,
    LEAF_WIDTH,
    PANICLE_HEIGHT,
    PANICLE_TILT_SD_DEG,
    ROW_JITTER,
    STALK_RADIUS,
    SWAY_FREQ,
    SimConfig,
)
from seedmap.sim.meshes import cylinder, polyline_tube, ribbon_topology

# surface classes of the renderer
CLS_NONE, CLS_SOIL, CLS_STALK, CLS_LEAF, CLS_SEED, CLS_RACHIS = 0, 1, 2, 3, 4, 5

# linear-RGB albedos of grain colours (white/cream, tan, red-brown, dark brown) and glume colours
SEED_COLORS = {
    "white": np.array([0.74, 0.66, 0.50]),
    "tan": np.array([0.60, 0.42, 0.22]),
    "red": np.array([0.50, 0.20, 0.10]),
    "brown": np.array([0.28, 0.15, 0.08]),
}
GLUME_COLORS = np.array([
    [0.60, 0.50, 0.32],  # straw
    [0.42, 0.28, 0.14],  # tan-brown
    [0.30, 0.12, 0.07],  # red-brown
    [0.07, 0.055, 0.045],  # black
])
LEAF_COLORS = np.array([
    [0.10, 0.22, 0.06],  # green
    [0.16, 0.26, 0.07],  # yellow-green
    [0.30, 0.30, 0.12],  # senescing
    [0.42, 0.36, 0.22],  # dry, straw
])
N_LEAF_SEG = 16
N_SWAY = 2  # sinusoids per sway angle


@dataclass
class Panicle:
    """One panicle: its seeds are global ids ``seed_start .. seed_stop - 1``."""

    id: int
    base: np.ndarray  # (3,) rest position of the panicle base (m)
    axis: np.ndarray  # (3,) unit rachis direction at rest
    length: float
    width: float
    loose: bool
    color: str
    seed_start: int
    seed_stop: int
    center: np.ndarray  # bounding sphere at rest (m)
    radius: float
    rachis_vertices: np.ndarray  # rachis + branches mesh, rest world coordinates
    rachis_triangles: np.ndarray
    sway: np.ndarray  # (2, N_SWAY, 3) amplitude (rad), frequency (Hz), phase (rad) per tilt axis

    @property
    def n_seeds(self) -> int:
        return self.seed_stop - self.seed_start


@dataclass
class World:
    """Everything the renderer needs. Arrays are indexed by global seed id / leaf index."""

    kind: str  # "range" or "panicle"
    cfg: SimConfig
    length: float  # plants span x in [0, length] (range worlds); 0 for a panicle world
    seeds: SeedTable
    seed_axes: np.ndarray  # (N, 3, 3) columns = local axes of each seed (axis 2 = long axis, outward)
    seed_albedo: np.ndarray  # (N, 3) linear RGB
    glume_albedo: np.ndarray  # (N, 3)
    glume_extent: np.ndarray  # (N,) glume covers the seed where local z / rz < glume_extent
    seed_ao: np.ndarray  # (N,) baked ambient occlusion in [0, 1] (1 = open)
    panicles: list[Panicle]
    # leaves: same topology for all, (L, V, 3) rest vertices
    leaf_vertices: np.ndarray
    leaf_triangles: np.ndarray
    leaf_uv: np.ndarray
    leaf_attach: np.ndarray  # (L, 3) sway pivot
    leaf_color: np.ndarray  # (L, 3)
    leaf_sway: np.ndarray  # (L, 2, N_SWAY, 3)
    stalk_vertices: np.ndarray  # all stalks, static
    stalk_triangles: np.ndarray
    stalk_color: np.ndarray  # (V, 3) per-vertex albedo
    soil_texture: np.ndarray  # (S, S) float32 in ~[0.6, 1.4], tiled every ``soil_tile`` metres
    soil_tile: float = 1.5
    soil_color: np.ndarray = field(default_factory=lambda: np.array([0.26, 0.19, 0.13]))
    has_soil: bool = True
    cache: dict = field(default_factory=dict, repr=False)  # renderer's per-panicle BVHs
    # plants (for the non-rigid wind of ``seedmap.sim.wind``): top of each stalk, owner of each part
    plant_top: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (Pl, 3) stalk top (m)
    stalk_plant: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (V,) per stalk vertex
    leaf_plant: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (L,)
    panicle_plant: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (P,)
    wind_field: Any = None  # a ``seedmap.sim.wind.WindField`` when the non-rigid wind is on, else None

    # ---- wind ----
    def panicle_motion(self, t: float) -> np.ndarray:
        """``(P, 4, 4)`` motions ``D`` at time ``t`` (s): rotation about each panicle's base (rigid sway), or the
        non-rigid wind's motion (``wind_field``: the panicle rides on its bending stalk)."""
        if self.wind_field is not None:
            return self.wind_field.panicle_motion(self, t)
        P = len(self.panicles)
        D = np.tile(np.eye(4), (P, 1, 1))
        if P == 0 or not self.cfg.wind.enabled:
            return D
        sway = np.stack([p.sway for p in self.panicles])  # (P, 2, K, 3)
        base = np.stack([p.base for p in self.panicles])
        return _sway_transforms(sway, base, t)

    def leaf_motion(self, t: float) -> np.ndarray:
        """``(L, 4, 4)`` rigid sway of each leaf about its attachment at time ``t`` (s); the non-rigid part
        (``wind_field``) is added to the vertices by the renderer."""
        L = len(self.leaf_attach)
        if L == 0 or not self.cfg.wind.enabled:
            return np.tile(np.eye(4), (L, 1, 1))
        return _sway_transforms(self.leaf_sway, self.leaf_attach, t)

    def seed_centers_at(self, t: float, D: np.ndarray | None = None) -> np.ndarray:
        """``(N, 3)`` seed centres at time ``t`` (wind applied)."""
        if D is None:
            D = self.panicle_motion(t)
        out = np.empty_like(self.seeds.xyz)
        for k, p in enumerate(self.panicles):
            s = slice(p.seed_start, p.seed_stop)
            out[s] = self.seeds.xyz[s] @ D[k, :3, :3].T + D[k, :3, 3]
        return out


def _sway_transforms(sway: np.ndarray, pivots: np.ndarray, t: float) -> np.ndarray:
    """Rotations about world x and y (tilts) through ``pivots`` from summed sinusoids."""
    amp, freq, phase = sway[..., 0], sway[..., 1], sway[..., 2]
    ang = np.sum(amp * np.sin(2 * np.pi * freq * t + phase), axis=-1)  # (n, 2)
    rv = np.column_stack([ang[:, 0], ang[:, 1], np.zeros(len(ang))])
    R = Rotation.from_rotvec(rv).as_matrix()
    D = np.tile(np.eye(4), (len(ang), 1, 1))
    D[:, :3, :3] = R
    D[:, :3, 3] = pivots - np.einsum("nij,nj->ni", R, pivots)
    return D


def _sway_params(rng: np.random.Generator, n: int, amp_deg: float) -> np.ndarray:
    out = np.zeros((n, 2, N_SWAY, 3))
    a = np.radians(amp_deg)
    # split the amplitude over the sinusoids so the peak stays near amp_deg
    out[..., 0] = a * rng.uniform(0.4, 0.8, (n, 2, N_SWAY)) / np.sqrt(N_SWAY)
    out[..., 1] = rng.uniform(SWAY_FREQ[0], SWAY_FREQ[1], (n, 2, N_SWAY))
    out[..., 2] = rng.uniform(0, 2 * np.pi, (n, 2, N_SWAY))
    return out


# ------------------------------------------------------------------------------------------------
# panicles
# ------------------------------------------------------------------------------------------------


def _frames_from_axes(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``(N, 3, 3)`` random rotations whose third columns are the unit vectors ``a`` (N, 3)."""
    a = np.asarray(a, float).reshape(-1, 3)
    tmp = np.where((np.abs(a[:, 0]) < 0.9)[:, None], np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    u = np.cross(a, tmp)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(a, u)
    th = rng.uniform(0, 2 * np.pi, len(a))[:, None]
    u2 = np.cos(th) * u + np.sin(th) * w
    w2 = np.cross(a, u2)
    return np.stack([u2, w2, a], axis=2)


def _frame_from_axis(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random rotation whose third column is ``a`` (unit)."""
    return _frames_from_axes(a[None, :], rng)[0]


def _envelope(s: np.ndarray, R: float) -> np.ndarray:
    """Spindle radius at relative height ``s`` in [0, 1] (widest at ~40 % of the length)."""
    s = np.clip(s, 0, 1)
    return R * np.sin(np.pi * s ** 0.756) ** 0.7


def _thin(points: np.ndarray, order: np.ndarray, dmin: float, n_max: int) -> np.ndarray:
    """Greedy dart throwing in ``order``: keep a point unless an earlier kept point lies within
    ``dmin``; return the first ``n_max`` kept points (in order).

    Computed as the lexicographically-first maximal independent set of the ``dmin`` neighbour graph
    in rounds (a point whose undecided neighbours all come later is kept, its neighbours dropped),
    which equals the sequential greedy result without a Python loop over points.
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(points).query_pairs(dmin, output_type="ndarray")
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(len(order))
    a, b = pairs[:, 0], pairs[:, 1]
    lo = np.where(rank[a] < rank[b], a, b)
    hi = np.where(rank[a] < rank[b], b, a)
    state = np.zeros(n, np.int8)  # 0 undecided, 1 kept, 2 dropped
    while True:
        und = state == 0
        if not und.any():
            break
        live = und[lo] & und[hi]
        blocked = np.zeros(n, bool)
        blocked[hi[live]] = True
        new = und & ~blocked
        state[new] = 1
        state[hi[new[lo] & (state[hi] == 0)]] = 2
        state[lo[new[hi] & (state[lo] == 0)]] = 2
    kept = np.nonzero(state == 1)[0]
    kept = kept[np.argsort(rank[kept])]
    return kept[:n_max]


@dataclass
class _PanicleSeeds:
    local_xyz: np.ndarray
    local_axes: np.ndarray
    radii: np.ndarray
    ao: np.ndarray
    rachis_v: np.ndarray
    rachis_f: np.ndarray


def _grow_panicle(rng: np.random.Generator, cfg: SimConfig, n_target: int, L: float, W: float,
                  loose: bool) -> _PanicleSeeds:
    """Seeds of one panicle in its local frame (rachis along +z from the origin).

    Primary branches leave the rachis in a golden-angle spiral and end on a spindle-shaped envelope.
    Candidate seed positions fill the envelope (compact panicles) or tubes around the outer part
    of the branches (loose panicles); dart throwing keeps them about one seed diameter apart,
    outermost first, so the visible surface is densely packed and inner layers fill only for large
    counts. Where the envelope cannot hold ``n_target`` seeds it is enlarged a little.
    """
    pc = cfg.panicle
    d_mean = rng.uniform(pc.seed_diameter_min, pc.seed_diameter_max)
    step = rng.uniform(0.004, 0.006) if not loose else rng.uniform(0.008, 0.012)
    rise_lo, rise_hi = (25, 45) if not loose else (35, 60)
    grow = 1.0
    for _attempt in range(7):
        R = W / 2 * grow
        Lg = L * grow ** 0.5
        n_br = max(6, int(Lg * 0.92 / step))
        h0 = np.sort(rng.uniform(0.04 * Lg, 0.95 * Lg, n_br))
        phi = np.arange(n_br) * 2.39996 + rng.normal(0, 0.3, n_br)
        rise_ang = np.radians(rng.uniform(rise_lo, rise_hi, n_br))
        r_here = np.maximum(_envelope(h0 / Lg, R), 0.006)
        h1 = np.minimum(h0 + r_here / np.tan(rise_ang), Lg)
        r_end = np.maximum(_envelope(h1 / Lg, R), 0.5 * d_mean) * rng.uniform(0.85, 1.0, n_br)
        radial = np.stack([np.cos(phi), np.sin(phi), np.zeros(n_br)], 1)
        p_start = np.stack([np.zeros(n_br), np.zeros(n_br), h0], 1)
        p_end = radial * r_end[:, None] + np.stack([np.zeros(n_br), np.zeros(n_br), h1], 1)
        m = int(np.ceil(5.0 * n_target / n_br))
        # candidates around the outer 65 % of each branch: tubes (loose) or wide fans (compact)
        t = 1.0 - rng.uniform(0, 1, (n_br, m)) ** 1.5 * 0.65
        cand = p_start[:, None, :] + t[..., None] * (p_end - p_start)[:, None, :]
        spread = (0.9 * r_end if not loose else 0.35 * r_end)[:, None, None]
        cand = (cand + rng.normal(0, 1, cand.shape) * spread * 0.5).reshape(-1, 3)
        h = cand[:, 2]
        ok = (h > 0.02 * Lg) & (h < 0.995 * Lg)
        cand = cand[ok]
        h = cand[:, 2]
        rr = np.linalg.norm(cand[:, :2], axis=1)
        env = np.maximum(_envelope(h / Lg, R), 0.6 * d_mean)
        outside = rr > env - 0.5 * d_mean
        target_r = env - 0.5 * d_mean * rng.uniform(0.6, 1.3, len(rr))
        scale = np.where(outside, target_r / np.maximum(rr, 1e-9), 1.0)
        cand[:, :2] *= np.clip(scale, 0, None)[:, None]
        rr = np.linalg.norm(cand[:, :2], axis=1)
        inner = rr > 0.9 * d_mean
        cand, rr, env = cand[inner], rr[inner], env[inner]
        key = (env - rr) / d_mean + rng.uniform(0, 0.5, len(rr))
        keep = _thin(cand, np.argsort(key), 0.97 * d_mean, n_target)
        if len(keep) >= max(0.97 * n_target, min(n_target, pc.seeds_min)):
            break
        grow *= 1.15
    xyz = cand[keep]
    n = len(xyz)
    # mean diameter (2 x mean semi-axis) per seed within [seed_diameter_min, seed_diameter_max];
    # grains are slightly flattened spheroids, the long axis pointing out of the panicle
    d = np.clip(d_mean * rng.normal(1.0, 0.07, n), pc.seed_diameter_min, pc.seed_diameter_max)
    shape = np.array([1.0, 0.86, 1.1]) * rng.normal(1.0, 0.04, (n, 3))
    radii = (d / 2)[:, None] * shape / shape.mean(axis=1, keepdims=True)
    out = np.column_stack([xyz[:, :2], np.zeros(n)])
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9)
    long_ax = out + np.array([0, 0, 0.6]) + rng.normal(0, 0.25, (n, 3))
    long_ax /= np.linalg.norm(long_ax, axis=1, keepdims=True)
    axes = _frames_from_axes(long_ax, rng)
    depth = (env[keep] - rr[keep]) / d_mean  # in seed diameters below the envelope
    ao = np.clip(1.0 - 0.25 * depth, 0.25, 1.0) * rng.uniform(0.9, 1.0, n)
    rv, rf = [], []
    off = 0
    v, f = cylinder(np.zeros(3), np.array([0, 0, 0.97 * Lg]), 0.0022, 0.0012, sides=6)
    rv.append(v)
    rf.append(f)
    off += len(v)
    for k in range(n_br):
        v, f = cylinder(p_start[k], p_end[k] * 0.92 + p_start[k] * 0.08, 0.0008, 0.0005, sides=4)
        rv.append(v)
        rf.append(f + off)
        off += len(v)
    return _PanicleSeeds(xyz, axes, radii, ao, np.vstack(rv), np.vstack(rf))


def _seed_colors(rng: np.random.Generator, n: int, color: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    base = SEED_COLORS[color] * rng.uniform(0.85, 1.12) * (1 + rng.normal(0, 0.04, 3))
    shade = np.exp(rng.normal(0, 0.10, (n, 1)))  # per-seed brightness
    tint = 1 + rng.normal(0, 0.035, (n, 3))  # per-seed hue
    albedo = np.clip(base[None, :] * shade * tint, 0.01, 0.95)
    g = {"white": [0, 1], "tan": [0, 1, 3], "red": [1, 2, 3], "brown": [2, 3]}[color]
    gl = GLUME_COLORS[rng.choice(g)] * (1 + rng.normal(0, 0.05, 3))
    glume = np.clip(gl[None, :] * np.exp(rng.normal(0, 0.12, (n, 1))), 0.01, 0.9)
    extent = np.clip(rng.uniform(-0.55, 0.05) + rng.normal(0, 0.12, n), -0.95, 0.4)
    return albedo, glume, extent


# ------------------------------------------------------------------------------------------------
# plants
# ------------------------------------------------------------------------------------------------


@dataclass
class _Parts:
    seeds_xyz: list = field(default_factory=list)
    seeds_axes: list = field(default_factory=list)
    seeds_radii: list = field(default_factory=list)
    seeds_pid: list = field(default_factory=list)
    seeds_albedo: list = field(default_factory=list)
    seeds_glume: list = field(default_factory=list)
    seeds_extent: list = field(default_factory=list)
    seeds_ao: list = field(default_factory=list)
    panicles: list = field(default_factory=list)
    leaves: list = field(default_factory=list)  # (V, 3) arrays
    leaf_attach: list = field(default_factory=list)
    leaf_color: list = field(default_factory=list)
    stalk_v: list = field(default_factory=list)
    stalk_f: list = field(default_factory=list)
    stalk_c: list = field(default_factory=list)
    plant_top: list = field(default_factory=list)
    stalk_plant: list = field(default_factory=list)
    leaf_plant: list = field(default_factory=list)
    panicle_plant: list = field(default_factory=list)
    n_seeds: int = 0
    n_stalk_v: int = 0


def _add_panicle(parts: _Parts, rng: np.random.Generator, cfg: SimConfig, base: np.ndarray,
                 axis: np.ndarray) -> None:
    pc = cfg.panicle
    n_target = int(rng.integers(pc.seeds_min, pc.seeds_max + 1))
    q = (n_target - pc.seeds_min) / max(pc.seeds_max - pc.seeds_min, 1)
    q2 = np.clip(q + rng.normal(0, 0.15), 0, 1)
    L = pc.length_min + (pc.length_max - pc.length_min) * q2
    W = pc.width_min + (pc.width_max - pc.width_min) * np.clip(q + rng.normal(0, 0.2), 0, 1)
    loose = bool(rng.uniform() < pc.loose_fraction)
    color = str(rng.choice(pc.seed_colors))
    g = _grow_panicle(rng, cfg, n_target, L, W, loose)
    Rm = _frame_from_axis(axis, rng)  # local z -> axis, random spin about it
    xyz = g.local_xyz @ Rm.T + base
    axes = np.einsum("ij,njk->nik", Rm, g.local_axes)
    n = len(xyz)
    pid = len(parts.panicles)
    albedo, glume, extent = _seed_colors(rng, n, color)
    rv = g.rachis_v @ Rm.T + base
    allp = np.vstack([xyz, rv])
    lo, hi = allp.min(0) - 0.006, allp.max(0) + 0.006
    center = (lo + hi) / 2
    radius = float(np.linalg.norm(allp - center, axis=1).max() + 0.006)
    parts.panicles.append(Panicle(
        id=pid, base=np.asarray(base, float), axis=np.asarray(axis, float), length=float(L), width=float(W),
        loose=loose, color=color, seed_start=parts.n_seeds, seed_stop=parts.n_seeds + n, center=center,
        radius=radius, rachis_vertices=rv, rachis_triangles=g.rachis_f,
        sway=_sway_params(rng, 1, cfg.wind.panicle_amplitude_deg)[0]))
    parts.seeds_xyz.append(xyz)
    parts.seeds_axes.append(axes)
    parts.seeds_radii.append(g.radii)
    parts.seeds_pid.append(np.full(n, pid))
    parts.seeds_albedo.append(albedo)
    parts.seeds_glume.append(glume)
    parts.seeds_extent.append(extent)
    parts.seeds_ao.append(g.ao)
    parts.n_seeds += n


def _leaf_vertices(rng: np.random.Generator, attach: np.ndarray, azimuth: float, length: float,
                   width: float) -> np.ndarray:
    """A long arching ribbon leaf (3 vertices across, folded along the midrib)."""
    s = np.linspace(0, 1, N_LEAF_SEG + 1)
    elev0 = np.radians(rng.uniform(40, 75))
    elev1 = np.radians(rng.uniform(-70, -10))
    curve = rng.uniform(1.2, 2.2)
    elev = elev0 + (elev1 - elev0) * s ** curve
    az = azimuth + rng.normal(0, 0.15) * s
    ds = length / N_LEAF_SEG
    dirs = np.stack([np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev)], 1)
    centre = attach + np.vstack([np.zeros(3), np.cumsum(dirs[:-1] * ds, axis=0)])
    # across direction: horizontal, perpendicular to the leaf's heading, with a slow twist
    side = np.stack([-np.sin(az), np.cos(az), np.zeros_like(az)], 1)
    twist = rng.normal(0, 0.5) * s
    up = np.cross(dirs, side)
    side = np.cos(twist)[:, None] * side + np.sin(twist)[:, None] * up
    up = np.cross(dirs, side)
    w = width * (0.35 + 0.65 * np.sin(np.pi * np.clip(s, 0, 1) ** 0.55)) * (1 - s ** 5)
    fold = np.radians(rng.uniform(8, 25))
    half = w[:, None] / 2
    lift = (half * np.sin(fold)) * up
    v0 = centre - half * np.cos(fold) * side + lift
    v2 = centre + half * np.cos(fold) * side + lift
    return np.stack([v0, centre, v2], 1).reshape(-1, 3)


def _add_plant(parts: _Parts, rng: np.random.Generator, cfg: SimConfig, x: float, y: float,
               with_panicle: bool) -> None:
    pc, wc = cfg.panicle, cfg.world
    tilt = np.radians(abs(rng.normal(0, PANICLE_TILT_SD_DEG)))
    tdir = rng.uniform(0, 2 * np.pi)
    axis = np.array([np.sin(tilt) * np.cos(tdir), np.sin(tilt) * np.sin(tdir), np.cos(tilt)])
    c_h = max(0.3, rng.normal(PANICLE_HEIGHT[0], PANICLE_HEIGHT[1]))
    L_guess = 0.5 * (pc.length_min + pc.length_max)
    top = np.array([x, y, c_h - 0.5 * L_guess * axis[2]]) - 0.5 * L_guess * np.array([axis[0], axis[1], 0])
    ground = np.array([x + rng.normal(0, 0.02), y + rng.normal(0, 0.02), 0.0])
    # stalk (a gently bent tube) up to the panicle base
    n_pts = 7
    s = np.linspace(0, 1, n_pts)
    bend = rng.normal(0, 0.015, 3) * np.array([1, 1, 0])
    pts = ground + s[:, None] * (top - ground) + np.sin(np.pi * s)[:, None] * bend
    r0 = STALK_RADIUS * rng.uniform(0.85, 1.15)
    radii = r0 * (1 - 0.55 * s)
    v, f = polyline_tube(pts, radii, sides=10)
    parts.stalk_f.append(f + parts.n_stalk_v)
    parts.stalk_v.append(v)
    sc = np.array([0.30, 0.32, 0.14]) * rng.uniform(0.8, 1.2) * (1 + rng.normal(0, 0.05, 3))
    parts.stalk_c.append(np.tile(sc, (len(v), 1)))
    parts.n_stalk_v += len(v)
    plant = len(parts.plant_top)
    parts.plant_top.append(pts[-1])
    parts.stalk_plant.append(np.full(len(v), plant))
    if with_panicle:
        parts.panicle_plant.append(plant)
        _add_panicle(parts, rng, cfg, top, axis)
    # leaves, alternating on two sides of the stalk, attached below the panicle
    n_leaves = int(rng.integers(wc.leaves_min, wc.leaves_max + 1))
    phi0 = rng.uniform(0, 2 * np.pi)
    h_top = top[2] - rng.uniform(0.03, 0.10)
    for k in range(n_leaves):
        frac = (k + 0.5) / max(n_leaves, 1)
        h = 0.25 + (h_top - 0.25) * frac ** 0.8
        attach = ground + (h / max(top[2], 1e-6)) * (top - ground)
        az = phi0 + np.pi * k + rng.normal(0, 0.5)
        length = rng.uniform(LEAF_LENGTH[0], LEAF_LENGTH[1]) * (0.75 if k == n_leaves - 1 else 1.0)
        width = rng.uniform(LEAF_WIDTH[0], LEAF_WIDTH[1])
        v = _leaf_vertices(rng, attach, az, length, width)
        # the robot drives 'standoff' from the row: leaves reaching into its path would be pushed
        # aside, so squash any leaf that comes closer than 0.3 m to the lens plane
        y_min = -cfg.camera.standoff + 0.3
        if v[:, 1].min() < y_min and attach[1] > y_min:
            v[:, 1] = attach[1] + (v[:, 1] - attach[1]) * (y_min - attach[1]) / (v[:, 1].min() - attach[1])
        parts.leaves.append(v)
        parts.leaf_attach.append(attach)
        parts.leaf_plant.append(plant)
        lc = LEAF_COLORS[min(3, int(rng.integers(0, 3)) + (1 if frac < 0.35 and rng.uniform() < 0.5 else 0))]
        parts.leaf_color.append(lc * rng.uniform(0.8, 1.2) * (1 + rng.normal(0, 0.06, 3)))


def _soil_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Multi-scale value noise (tileable), mean ~1: multiplies the soil albedo."""
    import cv2

    tex = np.zeros((size, size), np.float32)
    for cells, amp in ((8, 0.35), (32, 0.25), (128, 0.18), (256, 0.12)):
        g = rng.normal(0, 1, (cells, cells)).astype(np.float32)
        g = np.tile(g, (3, 3))
        up = cv2.resize(g, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)[size:2 * size, size:2 * size]
        tex += amp * up
    return np.clip(1.0 + tex, 0.4, 1.8).astype(np.float32)


def _assemble(kind: str, cfg: SimConfig, parts: _Parts, rng: np.random.Generator, length: float,
              has_soil: bool) -> World:
    if parts.n_seeds:
        xyz = np.vstack(parts.seeds_xyz)
        seeds = SeedTable(np.arange(parts.n_seeds, dtype=np.int64), np.concatenate(parts.seeds_pid).astype(np.int64),
                          xyz, np.vstack(parts.seeds_radii))
        axes = np.concatenate(parts.seeds_axes)
        albedo, glume = np.vstack(parts.seeds_albedo), np.vstack(parts.seeds_glume)
        extent, ao = np.concatenate(parts.seeds_extent), np.concatenate(parts.seeds_ao)
    else:
        z = np.zeros((0, 3))
        seeds = SeedTable(np.zeros(0, np.int64), np.zeros(0, np.int64), z, z)
        axes, albedo, glume, extent, ao = np.zeros((0, 3, 3)), z, z, np.zeros(0), np.zeros(0)
    lf, luv = ribbon_topology(N_LEAF_SEG)
    n_leaf_v = 3 * (N_LEAF_SEG + 1)
    leaves = np.stack(parts.leaves) if parts.leaves else np.zeros((0, n_leaf_v, 3))
    attach = np.stack(parts.leaf_attach) if parts.leaf_attach else np.zeros((0, 3))
    lcol = np.stack(parts.leaf_color) if parts.leaf_color else np.zeros((0, 3))
    sv = np.vstack(parts.stalk_v) if parts.stalk_v else np.zeros((0, 3))
    sf = np.vstack(parts.stalk_f) if parts.stalk_f else np.zeros((0, 3), np.int64)
    scol = np.vstack(parts.stalk_c) if parts.stalk_c else np.zeros((0, 3))
    return World(
        kind=kind, cfg=cfg, length=length, seeds=seeds, seed_axes=axes, seed_albedo=albedo, glume_albedo=glume,
        glume_extent=extent, seed_ao=ao, panicles=parts.panicles, leaf_vertices=leaves, leaf_triangles=lf,
        leaf_uv=luv, leaf_attach=attach, leaf_color=np.clip(lcol, 0.01, 0.9),
        leaf_sway=_sway_params(rng, len(attach), cfg.wind.leaf_amplitude_deg), stalk_vertices=sv,
        stalk_triangles=sf, stalk_color=scol, soil_texture=_soil_texture(rng), has_soil=has_soil,
        plant_top=np.array(parts.plant_top, float).reshape(-1, 3),
        stalk_plant=np.concatenate(parts.stalk_plant) if parts.stalk_plant else np.zeros(0, np.int64),
        leaf_plant=np.array(parts.leaf_plant, np.int64), panicle_plant=np.array(parts.panicle_plant, np.int64))


def build_range_world(cfg: SimConfig, rng: np.random.Generator) -> World:
    """A sorghum range: plants along the row line (y = 0) over x in [0, length], soil everywhere,
    empty gaps beyond both ends, optionally a dim neighbouring row behind (y = +offset)."""
    wc = cfg.world
    parts = _Parts()
    x = rng.uniform(0, wc.spacing_min)  # first plant near the start of the range
    xs = []
    while x <= wc.length:
        xs.append(x)
        x += rng.uniform(wc.spacing_min, wc.spacing_max)
    for x in xs:
        _add_plant(parts, rng, cfg, float(x), float(rng.normal(0, ROW_JITTER)), with_panicle=True)
    if wc.background_row:
        x = rng.uniform(-0.5, 0.0)
        while x <= wc.length + 0.5:
            _add_plant(parts, rng, cfg, float(x), BACKGROUND_ROW_OFFSET + float(rng.normal(0, ROW_JITTER)),
                       with_panicle=False)
            x += rng.uniform(wc.spacing_min, wc.spacing_max)
    return _assemble("range", cfg, parts, rng, float(wc.length), has_soil=True)


def build_panicle_world(cfg: SimConfig, rng: np.random.Generator) -> World:
    """A single panicle: rachis along world +z, base at the origin, nothing else (no soil, no leaves)."""
    parts = _Parts()
    _add_panicle(parts, rng, cfg, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    return _assemble("panicle", cfg, parts, rng, 0.0, has_soil=False)
