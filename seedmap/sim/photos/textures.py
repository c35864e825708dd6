"""Procedural backgrounds of grain photos: surfaces loose grain lies on and the scenes panicles stand in.

Every generator returns an albedo image ``(h, w, 3)`` float32 in [0, 1] at the photo's resolution, scaled to the
image's seed size ``seed_px`` where the texture has a physical scale (a weave's threads, pebbles, leaves).
Generators are registered in :data:`BACKGROUNDS` with the split they belong to: ``train`` backgrounds are what the
shipped networks see; ``validation`` and ``heldout`` ones are never trained on: the first choose between networks
and settings, the second measure how detection copes with a surface it has not seen. The reasoning behind each and
its parameters: docs/method/photos.md.
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

Rng = np.random.Generator
#: name -> (split, generator(rng, h, w, seed_px) -> albedo)
BACKGROUNDS: dict[str, tuple[str, Callable[[Rng, int, int, float], np.ndarray]]] = {}


def background(name: str, split: str):  # noqa: ANN201 - decorator
    """Register a background generator under ``name`` in ``split`` (train, validation or heldout)."""

    def deco(fn: Callable) -> Callable:
        BACKGROUNDS[name] = (split, fn)
        return fn

    return deco


def backgrounds(split: str) -> list[str]:
    """The registered background names of ``split``, sorted (a stable order for seeded draws)."""
    return sorted(k for k, (s, _) in BACKGROUNDS.items() if s == split)


def noise(rng: Rng, h: int, w: int, cell: float) -> np.ndarray:
    """Smooth value noise in [0, 1] with features ~``cell`` px: uniform noise on a coarse grid, cubic-upsampled."""
    gh, gw = max(2, int(np.ceil(h / max(cell, 1.0))) + 2), max(2, int(np.ceil(w / max(cell, 1.0))) + 2)
    g = rng.random((gh, gw)).astype(np.float32)
    up = cv2.resize(g, (int(round(gw * cell)), int(round(gh * cell))), interpolation=cv2.INTER_CUBIC)
    return np.clip(up[:h, :w] if up.shape[0] >= h and up.shape[1] >= w else cv2.resize(g, (w, h)), 0, 1)


def fbm(rng: Rng, h: int, w: int, cell: float, octaves: int = 4) -> np.ndarray:
    """Fractal noise: octaves of :func:`noise`, each half the size and half the weight, in [0, 1]."""
    acc = np.zeros((h, w), np.float32)
    tot = 0.0
    for k in range(octaves):
        a = 0.5 ** k
        acc += a * noise(rng, h, w, max(cell / 2 ** k, 1.5))
        tot += a
    return acc / tot


def tint(gray: np.ndarray, colour) -> np.ndarray:  # noqa: ANN001
    """A grey pattern ``(h, w)`` times an RGB colour -> ``(h, w, 3)`` float32."""
    return (gray[..., None] * np.asarray(colour, np.float32)[None, None]).astype(np.float32)


def random_colour(rng: Rng, sat: tuple[float, float] = (0.1, 0.7), val: tuple[float, float] = (0.25, 0.9)) -> np.ndarray:
    """A random RGB colour from hue, saturation and value ranges."""
    hsv = np.array([[[rng.uniform(0, 180), rng.uniform(*sat) * 255, rng.uniform(*val) * 255]]], np.float32)
    return cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32) / 255.0


def _folds(rng: Rng, h: int, w: int, amount: float) -> np.ndarray:
    """Low-frequency shading of a draped or crumpled surface: 1 +- ``amount``."""
    return (1.0 + amount * (2 * fbm(rng, h, w, max(h, w) / 3, 3) - 1)).astype(np.float32)


def _weave(rng: Rng, h: int, w: int, period: float, gap: float, twill: bool) -> np.ndarray:
    """Over/under threads of period ``period`` px; ``gap`` = dark space between threads; ``twill`` = diagonal."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    x = xx + (fbm(rng, h, w, period * 6, 2) - 0.5) * period * 0.6
    y = yy + (fbm(rng, h, w, period * 6, 2) - 0.5) * period * 0.6
    cx, cy = np.floor(x / period), np.floor(y / period)
    fx, fy = x / period - cx, y / period - cy
    over = ((cx + cy) % 2 == 0) if not twill else (((cx - cy) % 3) == 0)
    tx = np.sin(np.pi * fy) ** 0.6  # a warp thread's round profile across it
    ty = np.sin(np.pi * fx) ** 0.6
    v = np.where(over, tx, ty)
    v = v * (1 - gap) + gap * np.minimum(np.sin(np.pi * fx), np.sin(np.pi * fy)) ** 2 * 0.3
    fibre = 0.85 + 0.15 * noise(rng, h, w, 1.5)
    return (v * fibre).astype(np.float32)


@background("cloth", "train")
def cloth(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Woven cloth of any colour, folds: a fine tight weave (threads 0.15-0.6 seed diameters wide) or, one cloth in
    three, a coarse open one (sacking, scrim: threads 0.5-1.3 seeds wide with dark gaps)."""
    if rng.random() < 1 / 3:
        p = max(2.5, seed_px * rng.uniform(0.5, 1.3))
        pat = 0.25 + 0.75 * _weave(rng, h, w, p, rng.uniform(0.3, 0.75), bool(rng.random() < 0.3))
    else:
        p = max(2.0, seed_px * rng.uniform(0.15, 0.6))
        pat = 0.55 + 0.45 * _weave(rng, h, w, p, rng.uniform(0.0, 0.3), bool(rng.random() < 0.3))
    return tint(pat * _folds(rng, h, w, 0.25), random_colour(rng))


@background("paper", "train")
def paper(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """White, grey or kraft paper: fine fibres, faint blotches."""
    c = [np.array([0.92, 0.91, 0.88]), np.array([0.7, 0.7, 0.7]), np.array([0.62, 0.48, 0.32])][int(rng.integers(3))]
    g = 0.93 + 0.07 * fbm(rng, h, w, max(2.0, seed_px * 0.2), 3)
    return tint(g * _folds(rng, h, w, 0.08), c * rng.uniform(0.85, 1.05))


def _rotated(h: int, w: int, period: float, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates in units of ``period`` along the direction ``angle`` (rad) and across it: ``(u, v)``."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return (xx * np.cos(angle) + yy * np.sin(angle)) / period, (-xx * np.sin(angle) + yy * np.cos(angle)) / period


@background("wood", "train")
def wood(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A wooden table or board: growth rings warped by noise, along a random direction."""
    u, v = _rotated(h, w, 1.0, rng.uniform(0, np.pi))
    period = seed_px * rng.uniform(0.6, 3.0)
    warp = (fbm(rng, h, w, seed_px * 8, 3) - 0.5) * period * 4
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (v + warp + 0.02 * u) / period)
    g = 0.7 + 0.3 * rings ** 2 * (0.8 + 0.2 * noise(rng, h, w, 2))
    c = np.array([0.55, 0.36, 0.2]) * rng.uniform(0.6, 1.4)
    return np.clip(tint(g, c), 0, 1)


def _blobs(rng: Rng, img: np.ndarray, n: int, size: tuple[float, float], colour_fn: Callable[[], np.ndarray],
           shade: bool = True) -> None:
    """Draw ``n`` rough rounded blobs (pebbles, clods, aggregate) of diameter in ``size`` px into ``img``."""
    h, w = img.shape[:2]
    for _ in range(n):
        d = rng.uniform(*size)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        ax, ay = d / 2 * rng.uniform(0.7, 1.0), d / 2 * rng.uniform(0.5, 1.0)
        r = int(np.ceil(max(ax, ay))) + 1
        x0, x1, y0, y1 = max(0, int(cx) - r), min(w, int(cx) + r + 1), max(0, int(cy) - r), min(h, int(cy) + r + 1)
        if x1 <= x0 or y1 <= y0:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        t = rng.uniform(0, np.pi)
        u = ((xx - cx) * np.cos(t) + (yy - cy) * np.sin(t)) / ax
        v = (-(xx - cx) * np.sin(t) + (yy - cy) * np.cos(t)) / ay
        rr = u * u + v * v
        m = np.clip((1 - rr) * max(ax, ay), 0, 1)[..., None]
        c = colour_fn()
        if shade:
            c = c[None, None] * (0.75 + 0.35 * np.sqrt(np.clip(1 - rr, 0, 1))[..., None] - 0.15 * v[..., None])
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - m) + m * c


@background("soil", "train")
def soil(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Bare soil: brown fractal noise, clods and a few light pebbles of seed size and larger (hard negatives)."""
    c = np.array([0.42, 0.3, 0.2]) * rng.uniform(0.5, 1.3)
    img = tint(0.6 + 0.4 * fbm(rng, h, w, seed_px * 2, 5), c)
    n = int(h * w / (seed_px * seed_px) * rng.uniform(0.002, 0.02))
    _blobs(rng, img, n, (seed_px * 0.8, seed_px * 3), lambda: c * rng.uniform(0.5, 1.6))
    _blobs(rng, img, n // 4, (seed_px * 0.7, seed_px * 2), lambda: np.full(3, rng.uniform(0.4, 0.75)))
    return np.clip(img, 0, 1)


def _leaves(rng: Rng, img: np.ndarray, seed_px: float, n: int, lit: float) -> None:
    """Overlapping leaf blades (long lanceolate strips with a pale midrib) drawn into ``img``."""
    h, w = img.shape[:2]
    for _ in range(n):
        L = seed_px * rng.uniform(15, 60)
        W = seed_px * rng.uniform(1.5, 5)
        cx, cy, a = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(0, np.pi)
        r = int(L / 2) + 2
        x0, x1, y0, y1 = max(0, int(cx) - r), min(w, int(cx) + r), max(0, int(cy) - r), min(h, int(cy) + r)
        if x1 <= x0 or y1 <= y0:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        u = (xx - cx) * np.cos(a) + (yy - cy) * np.sin(a)
        v = -(xx - cx) * np.sin(a) + (yy - cy) * np.cos(a)
        half = W / 2 * np.sqrt(np.clip(1 - (2 * u / L) ** 2, 0, 1))
        m = np.clip(half - np.abs(v), 0, 1)[..., None]
        g = np.array([0.18, 0.42, 0.1]) * rng.uniform(0.5, 1.3) * lit
        shade = 0.8 + 0.2 * (v / np.maximum(half, 1e-3))[..., None]
        vein = np.exp(-(v / max(W * 0.05, 0.6)) ** 2)[..., None] * 0.25
        col = g[None, None] * shade + vein
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - m) + m * col


@background("canopy", "train")
def canopy(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Daylight canopy: leaves over darker leaves and shadowed gaps."""
    img = tint(0.3 + 0.4 * fbm(rng, h, w, seed_px * 6, 3), np.array([0.08, 0.16, 0.05]))
    _leaves(rng, img, seed_px, int(np.clip(h * w / (seed_px * seed_px * 40), 5, 400)), 1.0)
    return np.clip(img, 0, 1)


@background("night", "train")
def night(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A field at night under flash: black with a few dim leaves near the camera."""
    img = np.full((h, w, 3), 0.01, np.float32)
    _leaves(rng, img, seed_px, int(np.clip(h * w / (seed_px * seed_px * 300), 2, 60)), rng.uniform(0.2, 0.6))
    return img


@background("sky", "train")
def sky(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Sky behind a panicle: a blue-to-pale gradient with clouds."""
    yy = np.linspace(0, 1, h, dtype=np.float32)[:, None]
    base = np.array([0.35, 0.55, 0.85]) * (1 - 0.4 * yy[..., None]) + 0.4 * yy[..., None]
    cl = np.clip((fbm(rng, h, w, max(h, w) / 4, 5) - rng.uniform(0.4, 0.6)) * 3, 0, 1)[..., None]
    return np.clip(base * (1 - cl) + cl * 0.92, 0, 1).astype(np.float32)


@background("flatbed", "train")
def flatbed(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A flatbed scanner's lid: near-black or near-white, uniform."""
    v = rng.uniform(0.0, 0.06) if rng.random() < 0.7 else rng.uniform(0.85, 0.97)
    return np.full((h, w, 3), v, np.float32) + 0.01 * noise(rng, h, w, 4)[..., None]


@background("tray", "train")
def tray(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A plastic tray or Petri dish: one colour, a gentle gradient."""
    g = 0.85 + 0.15 * np.linspace(0, 1, w, dtype=np.float32)[None, :] * np.ones((h, 1), np.float32)
    return tint(g, random_colour(rng, (0.0, 0.6), (0.3, 0.95)))


@background("pebbles", "train")
def pebbles(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Grit or pebbles of any stone colour on earth or cement: fine grit 0.15-0.6 seed diameters across (half of the
    photos) or pebbles 1.3-3 seeds across, densely packed."""
    base = random_colour(rng, (0.0, 0.35), (0.3, 0.8))
    img = tint(0.5 + 0.35 * fbm(rng, h, w, seed_px * rng.uniform(1, 4), 4), base)
    fine = rng.random() < 0.5
    size = (seed_px * 0.15, seed_px * 0.6) if fine else (seed_px * 1.3, seed_px * 3.0)
    n = int(h * w / (np.mean(size) ** 2) * rng.uniform(0.2, 0.7))
    stone = random_colour(rng, (0.0, 0.3), (0.35, 0.85))
    _blobs(rng, img, n, size, lambda: stone * rng.uniform(0.5, 1.4) * rng.uniform(0.9, 1.1, 3), shade=not fine)
    return np.clip(img, 0, 1)


@background("mottled", "train")
def mottled(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A mottled print or stained surface (camouflage, marbled laminate, a patterned bag): two to four colours in
    patches 0.5-4 seed diameters across."""
    k = int(rng.integers(2, 5))
    cols = [random_colour(rng, (0.05, 0.8), (0.2, 0.95)) for _ in range(k)]
    img = tint(np.ones((h, w), np.float32), cols[0])
    for c in cols[1:]:
        m = fbm(rng, h, w, seed_px * rng.uniform(0.5, 4.0), 3)
        edge = np.clip((m - rng.uniform(0.45, 0.6)) * rng.uniform(4, 20), 0, 1)[..., None]
        img = img * (1 - edge) + edge * c[None, None]
    return np.clip(img * (0.9 + 0.1 * noise(rng, h, w, 2.0))[..., None], 0, 1).astype(np.float32)


def _motif(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Coverage in [0, 1] (antialiased) of one random geometric motif: stripes, grid lines, checks or a dot
    lattice, period 0.4-4 seed diameters."""
    p = max(2.5, seed_px * float(np.exp(rng.uniform(np.log(0.4), np.log(4.0)))))
    u, v = _rotated(h, w, p, rng.uniform(0, np.pi) if rng.random() < 0.6 else 0.0)
    kind = int(rng.integers(4))
    if kind == 0:  # stripes
        sd = (rng.uniform(0.1, 0.6) / 2 - np.abs(u - np.round(u))) * p
    elif kind == 1:  # grid lines: graph paper, a cutting mat
        half = rng.uniform(0.03, 0.2) / 2
        sd = (half - np.minimum(np.abs(u - np.round(u)), np.abs(v - np.round(v)))) * p
    elif kind == 2:  # checks
        sd = np.minimum(np.abs(u - np.round(u)), np.abs(v - np.round(v))) * p
        sd = np.where((np.floor(u) + np.floor(v)) % 2 == 0, sd, -sd)
    else:  # dots on a square or staggered lattice
        vs = v + (0.5 * np.round(u) if rng.random() < 0.5 else 0.0)
        fu, fv = u - np.round(u), vs - np.round(vs)
        sd = (rng.uniform(0.12, 0.42) - np.sqrt(fu * fu + fv * fv)) * p
    return np.clip(sd + 0.5, 0, 1).astype(np.float32)


@background("pattern", "train")
def pattern(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Printed or moulded geometric patterns drawn at random: stripes, grid lines, checks or dot lattices, period
    0.4-4 seed diameters at any angle, in random colours, one motif or two overlaid (graph paper, cutting mats,
    prints, perforated sheets)."""
    img = tint(np.ones((h, w), np.float32), random_colour(rng, (0.0, 0.8), (0.3, 0.95)))
    for _ in range(1 if rng.random() < 0.6 else 2):
        m = _motif(rng, h, w, seed_px)[..., None] * rng.uniform(0.5, 1.0)
        img = img * (1 - m) + m * random_colour(rng, (0.0, 0.9), (0.1, 0.95))[None, None]
    fine = 0.92 + 0.08 * noise(rng, h, w, max(1.5, seed_px * 0.1))
    return np.clip(img * (fine * _folds(rng, h, w, rng.uniform(0.0, 0.2)))[..., None], 0, 1).astype(np.float32)


@background("burlap", "heldout")
def burlap(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Jute sacking: a coarse loose weave with dark gaps, tan (never trained on)."""
    p = max(2.5, seed_px * rng.uniform(0.4, 0.9))
    pat = 0.25 + 0.75 * _weave(rng, h, w, p, rng.uniform(0.4, 0.7), False)
    return tint(pat, np.array([0.62, 0.5, 0.32]) * rng.uniform(0.8, 1.2))


@background("concrete", "heldout")
def concrete(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Concrete floor: grey with aggregate specks of a tenth to half a seed (never trained on)."""
    img = tint(0.55 + 0.3 * fbm(rng, h, w, seed_px * 3, 5), np.full(3, rng.uniform(0.5, 0.8)))
    n = int(h * w / (seed_px * seed_px) * 0.3)
    _blobs(rng, img, n, (seed_px * 0.1, seed_px * 0.5), lambda: np.full(3, rng.uniform(0.2, 0.9)), shade=False)
    return np.clip(img, 0, 1)


@background("denim", "heldout")
def denim(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Denim: a blue diagonal twill (never trained on)."""
    p = max(2.0, seed_px * rng.uniform(0.12, 0.35))
    pat = 0.5 + 0.5 * _weave(rng, h, w, p, 0.1, True)
    return tint(pat * _folds(rng, h, w, 0.2), np.array([0.2, 0.3, 0.55]) * rng.uniform(0.7, 1.3))


@background("gravel", "heldout")
def gravel(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Fine gravel: packed grey and beige pebbles 1.5-4 seed diameters across (never trained on)."""
    img = tint(0.4 + 0.2 * fbm(rng, h, w, seed_px, 3), np.array([0.45, 0.43, 0.4]))
    n = int(h * w / (seed_px * seed_px * 4))
    _blobs(rng, img, n, (seed_px * 1.5, seed_px * 4),
           lambda: np.array([0.6, 0.58, 0.54]) * rng.uniform(0.5, 1.4) * rng.uniform(0.9, 1.1, 3))
    return np.clip(img, 0, 1)


@background("sieve", "heldout")
def sieve(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A wire sieve or mesh tray: shiny round wires on a square grid of 0.6-1.6 seed diameters over a dark or light
    underside (never trained on)."""
    period = max(3.0, seed_px * rng.uniform(0.6, 1.6))
    u, v = _rotated(h, w, period, rng.uniform(0, np.pi / 2))
    r = rng.uniform(0.08, 0.2)
    du, dv = np.abs(u - np.round(u)), np.abs(v - np.round(v))
    wire = np.maximum(np.clip(1 - du / r, 0, 1), np.clip(1 - dv / r, 0, 1)) ** 0.5
    under = rng.uniform(0.03, 0.2) if rng.random() < 0.6 else rng.uniform(0.6, 0.9)
    metal = np.array([0.72, 0.7, 0.66]) * rng.uniform(0.7, 1.2)
    img = tint(1.0 - wire, np.full(3, under)) + tint(wire * (0.8 + 0.2 * noise(rng, h, w, 3)), metal)
    return np.clip(img, 0, 1)


@background("tablecloth", "heldout")
def tablecloth(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A printed tablecloth: checks or polka dots 0.5-3 seed diameters across in two colours, on a fine weave (never
    trained on)."""
    c0, c1 = random_colour(rng, (0.0, 0.3), (0.7, 0.95)), random_colour(rng, (0.4, 0.9), (0.3, 0.8))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    p = seed_px * rng.uniform(0.5, 3.0)
    if rng.random() < 0.5:
        m = ((np.floor(xx / p) + np.floor(yy / p)) % 2).astype(np.float32)
    else:
        fx, fy = xx / p - np.round(xx / p), yy / p - np.round(yy / p)
        m = np.clip((rng.uniform(0.2, 0.4) - np.sqrt(fx * fx + fy * fy)) * p, 0, 1)
    weave = 0.85 + 0.15 * _weave(rng, h, w, max(2.0, seed_px * 0.15), 0.1, False)
    img = (tint(1 - m, c0) + tint(m, c1)) * (weave * _folds(rng, h, w, 0.15))[..., None]
    return np.clip(img, 0, 1).astype(np.float32)


@background("cork", "validation")
def cork(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A cork board or mat: pressed brown granules 0.2-0.8 seed diameters across with dark pores (validation)."""
    c = np.array([0.6, 0.42, 0.26]) * rng.uniform(0.7, 1.2)
    img = tint(0.55 + 0.3 * fbm(rng, h, w, seed_px * 2, 3), c)
    size = (seed_px * 0.2, seed_px * 0.8)
    n = int(h * w / (np.mean(size) ** 2) * rng.uniform(0.4, 0.9))
    _blobs(rng, img, n, size, lambda: c * rng.uniform(0.6, 1.35), shade=False)
    pores = np.clip((noise(rng, h, w, max(1.5, seed_px * 0.25)) - 0.82) * 6, 0, 1)
    return np.clip(img * (1 - 0.7 * pores)[..., None], 0, 1).astype(np.float32)


@background("tiles", "validation")
def tiles(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Ceramic floor or wall tiles: squares 2-6 seed diameters across, one or two glazes with fine speckle, grout
    lines 0.1-0.3 seeds wide (validation)."""
    a = rng.uniform(0, np.pi / 2) if rng.random() < 0.3 else 0.0
    p = seed_px * rng.uniform(2.0, 6.0)
    u, v = _rotated(h, w, p, a)
    g = rng.uniform(0.1, 0.3) * seed_px / p / 2
    grout = np.maximum(np.abs(u - np.round(u)) < g, np.abs(v - np.round(v)) < g).astype(np.float32)
    c0 = random_colour(rng, (0.0, 0.6), (0.4, 0.95))
    c1 = c0 if rng.random() < 0.5 else random_colour(rng, (0.0, 0.6), (0.4, 0.95))
    which = ((np.floor(u) + np.floor(v)) % 2)[..., None]
    glaze = tint(np.ones((h, w), np.float32), c0) * (1 - which) + tint(np.ones((h, w), np.float32), c1) * which
    speck = 0.92 + 0.08 * noise(rng, h, w, max(1.2, seed_px * 0.1))
    img = glaze * speck[..., None]
    gc = np.full(3, rng.uniform(0.3, 0.8), np.float32)
    grout = cv2.GaussianBlur(grout, (0, 0), 0.6)[..., None]
    return np.clip(img * (1 - grout) + gc * grout, 0, 1).astype(np.float32)


@background("felt", "validation")
def felt(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """Felt or a short-pile carpet: matted fibres, short strokes a quarter to one seed long in every direction, any
    colour (validation)."""
    g = np.zeros((h, w), np.float32)
    n = int(h * w / (seed_px * seed_px) * rng.uniform(3, 8))
    L = seed_px * rng.uniform(0.25, 1.0)
    xs, ys = rng.uniform(0, w, n), rng.uniform(0, h, n)
    ang = rng.uniform(0, np.pi, n)
    vals = rng.uniform(0.3, 1.0, n)
    pts = np.stack([np.stack([xs - np.cos(ang) * L / 2, ys - np.sin(ang) * L / 2], 1),
                    np.stack([xs + np.cos(ang) * L / 2, ys + np.sin(ang) * L / 2], 1)], 1)
    for q, val in zip(np.round(pts * 4).astype(np.int32), vals):
        cv2.line(g, tuple(q[0]), tuple(q[1]), float(val), 1, cv2.LINE_AA, shift=2)
    g = 0.45 + 0.55 * np.clip(cv2.GaussianBlur(g, (0, 0), 0.5), 0, 1)
    return np.clip(tint(g * _folds(rng, h, w, 0.15), random_colour(rng, (0.1, 0.8), (0.3, 0.9))), 0, 1)


@background("basket", "validation")
def basket(rng: Rng, h: int, w: int, seed_px: float) -> np.ndarray:
    """A woven basket or rattan mat: flat strips 1-3 seed diameters wide, over and under, straw to brown
    (validation)."""
    p = max(4.0, seed_px * rng.uniform(1.0, 3.0))
    pat = 0.35 + 0.65 * _weave(rng, h, w, p, rng.uniform(0.05, 0.25), bool(rng.random() < 0.4))
    grain = 0.85 + 0.15 * fbm(rng, h, w, max(1.5, seed_px * 0.15), 2)
    return tint(pat * grain, np.array([0.78, 0.64, 0.4]) * rng.uniform(0.6, 1.15))
