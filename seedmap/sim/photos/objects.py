"""Things on a grain photo: seeds of several varieties and the look-alikes around them (glumes, stones, straw, chaff).

An object is an ellipse-footprint solid (:class:`Thing`) drawn into the lit image with per-pixel normals, so it
takes the light of its photo (:class:`Light`: direction, ambient, specular) and leaves a footprint in the instance
map. Seed varieties are registered in :data:`VARIETIES` with their split, like the backgrounds: ``validation`` and
``heldout`` varieties are never trained on. Method and the reasoning behind the parameters: docs/method/photos.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seedmap.sim.photos.textures import noise

Rng = np.random.Generator

#: variety -> (split, base albedo RGB, pattern): pattern in plain | germ | blotch | mould | speckle
VARIETIES: dict[str, tuple[str, tuple[float, float, float], str]] = {
    "white": ("train", (0.88, 0.85, 0.76), "germ"),
    "cream": ("train", (0.86, 0.76, 0.56), "germ"),
    "yellow": ("train", (0.86, 0.7, 0.36), "germ"),
    "tan": ("train", (0.72, 0.55, 0.36), "plain"),
    "red": ("train", (0.66, 0.3, 0.17), "plain"),
    "brown": ("train", (0.45, 0.28, 0.16), "plain"),
    "dark": ("train", (0.16, 0.11, 0.09), "plain"),
    "discoloured": ("train", (0.74, 0.6, 0.42), "blotch"),
    "mouldy": ("train", (0.8, 0.72, 0.55), "mould"),
    "green": ("validation", (0.55, 0.62, 0.33), "plain"),
    "grey": ("validation", (0.62, 0.6, 0.56), "blotch"),
    "purple": ("heldout", (0.45, 0.2, 0.3), "plain"),
    "orange": ("heldout", (0.92, 0.52, 0.2), "germ"),
    "speckled": ("heldout", (0.84, 0.74, 0.55), "speckle"),
}


def varieties(split: str) -> list[str]:
    """Variety names of ``split``, sorted."""
    return sorted(k for k, v in VARIETIES.items() if v[0] == split)


@dataclass
class Light:
    """How a photo is lit: unit vector towards the light (x right, y down, z towards the camera), ambient and
    diffuse weights, specular weight and exponent, and the cast shadows' offset per unit height and blur."""

    direction: np.ndarray
    ambient: float
    diffuse: float
    specular: float
    shininess: float
    shadow: float  # darkening under a full shadow (0-1)
    shadow_blur: float  # in seed diameters


@dataclass
class Thing:
    """One object: footprint ellipse (centre px, semi-axes a >= b px, angle rad), height (px), albedo, gloss and
    shape (``ellipsoid`` seed or stone, ``lens`` glume, ``rod`` straw, ``flake`` chaff); ``seed`` marks GT."""

    cx: float
    cy: float
    a: float
    b: float
    angle: float
    height: float
    albedo: np.ndarray
    gloss: float = 0.3
    shape: str = "ellipsoid"
    seed: bool = False
    pattern: str = "plain"
    alpha: float = 1.0
    rough: float = 0.0
    tex_seed: int = 0
    extra: dict = field(default_factory=dict)


def make_seed(rng: Rng, cx: float, cy: float, d: float, variety: str) -> Thing:
    """A seed of diameter ~``d`` px (geometric mean of its axes), aspect 1.0-1.35, of ``variety``."""
    _, base, pat = VARIETIES[variety]
    asp = rng.uniform(1.0, 1.35)
    d = d * rng.normal(1.0, 0.08)
    a, b = d / 2 * np.sqrt(asp), d / 2 / np.sqrt(asp)
    alb = np.clip(np.asarray(base) * rng.normal(1.0, 0.06, 3) * rng.uniform(0.85, 1.1), 0, 1)
    gloss = 0.5 if variety in ("dark", "red", "brown", "purple") else 0.3
    return Thing(cx, cy, a, b, rng.uniform(0, np.pi), d * rng.uniform(0.5, 0.7), alb, gloss, "ellipsoid", True, pat,
                 tex_seed=int(rng.integers(2**31)))


def make_glume(rng: Rng, cx: float, cy: float, d: float, angle: float | None = None) -> Thing:
    """A glume (the husk around a seed): pointed, 1.1-1.6 seed diameters long, black, dark red or straw, glossy."""
    L = d * rng.uniform(1.1, 1.6)
    W = L / rng.uniform(1.8, 2.6)
    c = [np.array([0.07, 0.05, 0.04]), np.array([0.35, 0.12, 0.08]), np.array([0.75, 0.62, 0.38])][int(rng.integers(3))]
    return Thing(cx, cy, L / 2, W / 2, rng.uniform(0, np.pi) if angle is None else angle, d * 0.3,
                 np.clip(c * rng.uniform(0.8, 1.2), 0, 1), 0.6, "lens")


def make_stone(rng: Rng, cx: float, cy: float, d: float) -> Thing:
    """A small stone: grey or beige, rough, 0.6-2.5 seed diameters."""
    s = d * rng.uniform(0.6, 2.5)
    asp = rng.uniform(1.0, 1.6)
    g = rng.uniform(0.3, 0.8)
    alb = np.clip(np.array([g, g * rng.uniform(0.92, 1.0), g * rng.uniform(0.8, 1.0)]), 0, 1)
    return Thing(cx, cy, s / 2 * np.sqrt(asp), s / 2 / np.sqrt(asp), rng.uniform(0, np.pi), s * 0.5, alb, 0.1,
                 "ellipsoid", rough=0.35, tex_seed=int(rng.integers(2**31)))


def make_straw(rng: Rng, cx: float, cy: float, d: float) -> Thing:
    """A piece of straw or stalk: a rod 2-10 seed diameters long, 0.15-0.4 wide, pale yellow to brown."""
    L = d * rng.uniform(2, 10)
    W = d * rng.uniform(0.15, 0.4)
    alb = np.clip(np.array([0.8, 0.68, 0.42]) * rng.uniform(0.5, 1.15), 0, 1)
    return Thing(cx, cy, L / 2, W / 2, rng.uniform(0, np.pi), W, alb, 0.2, "rod")


def make_chaff(rng: Rng, cx: float, cy: float, d: float) -> Thing:
    """A chaff flake: thin, pale, translucent, irregular, 0.6-2 seed diameters long."""
    s = d * rng.uniform(0.6, 2.0)
    alb = np.clip(np.array([0.85, 0.78, 0.6]) * rng.uniform(0.7, 1.1), 0, 1)
    return Thing(cx, cy, s / 2, s / 2 * rng.uniform(0.3, 0.7), rng.uniform(0, np.pi), d * 0.05, alb, 0.05, "flake",
                 alpha=rng.uniform(0.4, 0.75), tex_seed=int(rng.integers(2**31)))


def _frame(t: Thing, h: int, w: int) -> tuple | None:
    """The object's pixel window and its local coordinates there: ``(y0, y1, x0, x1, u, v)`` (u, v in semi-axes)."""
    r = int(np.ceil(t.a)) + 2
    x0, x1 = max(0, int(t.cx) - r), min(w, int(t.cx) + r + 2)
    y0, y1 = max(0, int(t.cy) - r), min(h, int(t.cy) + r + 2)
    if x1 <= x0 or y1 <= y0:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    dx, dy = xx - t.cx, yy - t.cy
    c, s = np.cos(t.angle), np.sin(t.angle)
    return y0, y1, x0, x1, (dx * c + dy * s) / t.a, (-dx * s + dy * c) / t.b


def _profile(t: Thing, u: np.ndarray, v: np.ndarray, wobble: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(rr, edge_px)``: normalised radius (< 1 inside) and the distance to the outline in px (antialiasing);
    ``wobble``: a chaff flake gets its irregular outline (shadow footprints keep the plain ellipse)."""
    if t.shape == "lens":
        half = np.clip(1 - u * u, 1e-3, None)
        rr = np.where(np.abs(u) < 1, (v / half) ** 2, 2.0)
        return rr, (1 - np.sqrt(np.clip(rr, 0, 4))) * t.b * half
    if t.shape == "rod":
        rr = np.maximum(u ** 8, v * v)
        return rr, np.minimum((1 - np.abs(u)) * t.a, (1 - np.abs(v)) * t.b)
    rr = u * u + v * v
    if t.shape == "flake" and wobble:
        wob = noise(np.random.default_rng(t.tex_seed), *u.shape, max(2.0, t.b * 0.6))
        rr = rr * (0.75 + 0.5 * wob)
    return rr, (1 - np.sqrt(np.clip(rr, 0, 4))) * t.b


def _albedo(t: Thing, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The object's albedo over its window (seed patterns, stone roughness)."""
    hh, ww = u.shape
    alb = np.broadcast_to(t.albedo, (hh, ww, 3)).astype(np.float32).copy()
    if t.pattern == "plain" and not t.rough:
        return alb
    r = np.random.default_rng(t.tex_seed)
    if t.rough:
        alb *= (1 - t.rough / 2 + t.rough * noise(r, hh, ww, max(1.5, t.b * 0.3)))[..., None]
    if t.pattern == "germ" and r.random() < 0.6:
        g = ((u - 0.45) / 0.35) ** 2 + (v / 0.45) ** 2 < 1
        alb[g] = alb[g] * np.array([1.0, 1.02, 0.85]) * 1.08
    elif t.pattern == "blotch":
        m = noise(r, hh, ww, max(1.5, t.b * 0.5)) > r.uniform(0.5, 0.75)
        alb[m] = alb[m] * np.array([0.45, 0.38, 0.32])
    elif t.pattern == "mould":
        m = noise(r, hh, ww, max(1.2, t.b * 0.3)) > r.uniform(0.6, 0.8)
        c = [np.array([0.45, 0.5, 0.42]), np.array([0.85, 0.6, 0.65]), np.array([0.15, 0.16, 0.14])][int(r.integers(3))]
        alb[m] = 0.3 * alb[m] + 0.7 * c
    elif t.pattern == "speckle":
        m = noise(r, hh, ww, 1.0) > 0.78
        alb[m] *= 0.35
    return np.clip(alb, 0, 1)


def draw(t: Thing, img: np.ndarray, ids: np.ndarray, ident: int, light: Light, falloff: np.ndarray) -> None:
    """Draw ``t`` lit by ``light`` into ``img`` (h, w, 3 linear float) and write ``ident`` into the instance map
    ``ids`` where it covers more than half of a pixel (0 for non-seeds: they hide what lies beneath)."""
    h, w = ids.shape
    fr = _frame(t, h, w)
    if fr is None:
        return
    y0, y1, x0, x1, u, v = fr
    rr, edge = _profile(t, u, v, True)
    cov = np.clip(edge + 0.5, 0, 1) * t.alpha
    if not (cov > 0).any():
        return
    z = np.sqrt(np.clip(1 - rr, 0, 1))
    c, s = np.cos(t.angle), np.sin(t.angle)
    # ellipsoid normal in the local frame, rotated back to the image; flatter objects have flatter normals
    k = max(t.height / max(t.b, 1e-3), 0.2)
    nu, nv, nz = u / t.a * t.b, v, z * k
    n = np.stack([nu * c - nv * s, nu * s + nv * c, nz], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-6
    L = light.direction
    ndl = np.clip(n @ L, 0, 1)
    hv = L + np.array([0.0, 0.0, 1.0])
    hv = hv / np.linalg.norm(hv)
    spec = light.specular * t.gloss * np.clip(n @ hv, 0, 1) ** light.shininess
    alb = _albedo(t, u, v)
    f = falloff[y0:y1, x0:x1, None]
    col = (alb * (light.ambient + light.diffuse * ndl)[..., None] + spec[..., None]) * f
    m = cov[..., None]
    img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - m) + m * col
    win = ids[y0:y1, x0:x1]
    win[cov >= 0.5] = ident if t.seed else 0


def footprint(t: Thing, shadow: np.ndarray, offset: np.ndarray) -> None:
    """Add the object's footprint, moved by ``offset`` px per unit of its height, to the shadow map."""
    moved = Thing(t.cx + offset[0] * t.height, t.cy + offset[1] * t.height, t.a, t.b, t.angle, t.height,
                  t.albedo, shape=t.shape)
    fr = _frame(moved, *shadow.shape)
    if fr is None:
        return
    y0, y1, x0, x1, u, v = fr
    rr, edge = _profile(moved, u, v, False)
    np.maximum(shadow[y0:y1, x0:x1], np.clip(edge + 0.5, 0, 1) * t.alpha, out=shadow[y0:y1, x0:x1])
