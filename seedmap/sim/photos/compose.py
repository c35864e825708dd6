"""One simulated grain photo: a background, lit seeds and look-alikes laid out on it, seen through a camera.

:func:`render_photo` draws a photo's conditions (background, light, varieties, layout, camera) from its random
generator and the split (``train``, ``validation`` or ``heldout``), renders it and returns the image, the instance
map of the visible seeds and the conditions. Layouts: ``loose`` grain on a surface (scattered or clumped), a ``pile``
(overlapping), a ``panicle`` (seeds packed around branches, glumes beneath) in front of canopy, sky or night.
Method and parameters: docs/method/photos.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from seedmap.sim.photos.objects import (Light, Thing, draw, footprint, make_chaff, make_glume, make_seed, make_stone,
                                        make_straw, varieties)
from seedmap.sim.photos.textures import BACKGROUNDS, backgrounds

Rng = np.random.Generator

#: backgrounds panicles stand in front of (every other background is a surface grain lies on)
PANICLE_BACKGROUNDS = ("canopy", "night", "sky")
#: a seed is labelled when at least this fraction of its footprint is visible
MIN_VISIBLE_FRACTION = 0.4
#: validation and held-out photos: probability that the light, and each variety, is one of the split's own (never
#: trained on)
HELDOUT_P = 0.5
#: lights: name -> split
LIGHTS = {"flash": "train", "daylight": "train", "overcast": "train", "scanner": "train", "window": "train",
          "fluorescent": "validation", "ring": "validation", "lamp": "heldout", "dusk": "heldout"}
#: training photos: probability of a strong colour cast (a white balance left on the wrong light) ...
CAST_P = 0.35
#: ... and of a dim exposure (under-exposed, noisy)
DIM_P = 0.25


def make_light(name: str, rng: Rng) -> tuple[Light, np.ndarray]:
    """The light ``name`` with random direction/strength, and its white-balance gains (R, G, B)."""
    def towards(elev_deg: float) -> np.ndarray:
        az, el = rng.uniform(0, 2 * np.pi), np.radians(elev_deg)
        return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])

    wb = rng.normal(1.0, 0.06, 3)
    if name == "flash":
        d = np.array([rng.normal(0, 0.1), rng.normal(0, 0.1), 1.0])
        return Light(d / np.linalg.norm(d), 0.04, 1.0, 0.7, 30.0, 0.45, 0.05), wb
    if name == "daylight":
        return Light(towards(rng.uniform(30, 70)), 0.3, 0.85, 0.35, 20.0, 0.55, 0.06), wb * [1.0, 1.0, 1.05]
    if name == "overcast":
        return Light(towards(rng.uniform(70, 90)), 0.7, 0.35, 0.08, 8.0, 0.3, 0.5), wb * [0.95, 1.0, 1.08]
    if name == "window":  # side light through a window: neutral, low, soft-edged shadows
        return Light(towards(rng.uniform(15, 40)), 0.25, 0.9, 0.25, 15.0, 0.6, 0.25), wb
    if name == "scanner":
        return Light(np.array([0.0, 0.3, 0.954]), 0.35, 0.75, 0.3, 15.0, 0.2, 0.15), np.ones(3)
    if name == "fluorescent":  # overhead tubes: diffuse, soft shadows, a green cast
        return Light(towards(rng.uniform(60, 85)), 0.45, 0.6, 0.15, 12.0, 0.4, 0.3), wb * [0.9, 1.06, 0.96]
    if name == "ring":  # a ring light around the lens: frontal, soft, almost no shadow
        return Light(np.array([0.0, 0.0, 1.0]), 0.3, 0.75, 0.25, 10.0, 0.15, 0.3), wb
    if name == "lamp":  # a desk lamp low at the side: warm, long hard shadows
        return Light(towards(rng.uniform(12, 28)), 0.12, 1.0, 0.4, 25.0, 0.7, 0.04), np.array([1.35, 1.0, 0.6])
    if name == "dusk":  # dim, cool, noisy
        return Light(towards(rng.uniform(40, 80)), 0.5, 0.4, 0.05, 8.0, 0.25, 0.4), np.array([0.8, 0.95, 1.25])
    raise ValueError(f"unknown light {name!r}")


@dataclass
class Photo:
    """A rendered photo: sRGB ``image`` (h, w, 3 uint8), ``ids`` (h, w int32: k + 1 = visible seed k, 0 = other),
    the labelled seeds' indices into ``ids``, and the conditions it was drawn with."""

    image: np.ndarray
    ids: np.ndarray
    seeds: list[int]
    conditions: dict
    lossless: bool


def _place(rng: Rng, n: int, sample, d: float, min_dist: float) -> np.ndarray:  # noqa: ANN001
    """Up to ``n`` points from ``sample(k) -> (k, 2)`` at least ``min_dist * d`` apart (grid-hashed rejection)."""
    cell = max(min_dist * d, 1.0)
    grid: dict[tuple[int, int], list[int]] = {}
    pts: list[np.ndarray] = []
    for p in sample(n * 3):
        if len(pts) >= n:
            break
        gx, gy = int(p[0] // cell), int(p[1] // cell)
        ok = True
        for i in range(gx - 1, gx + 2):
            for j in range(gy - 1, gy + 2):
                for q in grid.get((i, j), ()):
                    if (pts[q][0] - p[0]) ** 2 + (pts[q][1] - p[1]) ** 2 < cell * cell:
                        ok = False
                        break
        if ok:
            grid.setdefault((gx, gy), []).append(len(pts))
            pts.append(p)
    return np.array(pts).reshape(-1, 2)


def _layout(rng: Rng, kind: str, h: int, w: int, d: float, vars_: list[str], empty: bool) -> list[Thing]:
    """Seeds and look-alikes of one photo, in drawing order (first = bottom)."""
    under: list[Thing] = []
    seeds: list[Thing] = []
    over: list[Thing] = []
    area = h * w / (np.pi / 4 * d * d)
    if kind == "panicle":
        n_pan = int(rng.integers(1, 4))
        for _ in range(n_pan):
            L, W = d * rng.uniform(15, 35), d * rng.uniform(5, 12)
            cx, cy, ang = rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h, rng.uniform(0, np.pi)
            ca, sa = np.cos(ang), np.sin(ang)
            under.append(Thing(cx, cy, L / 2, d * 0.25, ang, d * 0.3, np.array([0.45, 0.4, 0.25]), 0.2, "rod"))
            for t in np.linspace(-0.45, 0.45, int(L / d / 2)):
                bx, by = cx + ca * t * L, cy + sa * t * L
                under.append(make_straw(rng, bx, by, d * 0.4))
            if empty:
                continue

            def sample(k: int, cx=cx, cy=cy, L=L, W=W, ca=ca, sa=sa) -> np.ndarray:  # noqa: ANN001
                r = np.sqrt(rng.random(k))
                t = rng.uniform(0, 2 * np.pi, k)
                u, v = r * np.cos(t) * L / 2, r * np.sin(t) * W / 2
                return np.c_[cx + u * ca - v * sa, cy + u * sa + v * ca]

            n = int(0.8 * (L * W / d / d))
            for p in _place(rng, n, sample, d, rng.uniform(0.6, 0.85)):
                if rng.random() < 0.5:
                    under.append(make_glume(rng, p[0] + rng.normal(0, d * 0.2), p[1] + rng.normal(0, d * 0.2), d))
                seeds.append(make_seed(rng, p[0], p[1], d, vars_[int(rng.integers(len(vars_)))]))
    else:
        cover = rng.uniform(0.03, 0.3)
        n = 0 if empty else int(cover * area)
        clumped = rng.random() < (0.7 if kind == "pile" else 0.3)
        if clumped:
            k = max(1, int(rng.integers(1, 6)))
            cs = rng.uniform([0.1 * w, 0.1 * h], [0.9 * w, 0.9 * h], (k, 2))
            spread = d * rng.uniform(2, 8)

            def sample(m: int) -> np.ndarray:
                return cs[rng.integers(k, size=m)] + rng.normal(0, spread, (m, 2))
        else:
            def sample(m: int) -> np.ndarray:
                return rng.uniform([0, 0], [w, h], (m, 2))
        min_d = rng.uniform(0.55, 0.8) if kind == "pile" else rng.uniform(0.8, 1.6)
        for p in _place(rng, n, sample, d, min_d):
            seeds.append(make_seed(rng, p[0], p[1], d, vars_[int(rng.integers(len(vars_)))]))
    # look-alikes scattered over the photo: glumes, stones, straw, chaff; a few lie on top of seeds
    n_neg = int(area * rng.uniform(0.0, 0.04)) + (int(rng.integers(3, 15)) if empty else 0)
    makers = (make_glume, make_stone, make_straw, make_chaff)
    pw = rng.dirichlet(np.ones(4))
    for _ in range(n_neg):
        t = makers[int(rng.choice(4, p=pw))](rng, rng.uniform(0, w), rng.uniform(0, h), d)
        (over if rng.random() < 0.25 else under).append(t)
    order = rng.permutation(len(seeds))
    return under + [seeds[i] for i in order] + over


def _camera(rng: Rng, lin: np.ndarray, wb: np.ndarray, d: float, light: str, dim: bool = False) -> np.ndarray:
    """Linear radiance -> sRGB uint8: white balance, auto exposure (``dim``: under-exposed), defocus/motion blur,
    noise, gamma."""
    img = lin * wb[None, None].astype(np.float32)
    p99 = float(np.percentile(img, 99.5))
    dim = dim or light == "dusk"
    target = rng.uniform(0.3, 0.55) if dim else rng.uniform(0.75, 1.05)
    img *= target / max(p99, 1e-3)
    if rng.random() < 0.5:
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.3, 0.12 * d + 0.4))
    if rng.random() < 0.15:
        k = max(2, int(rng.uniform(0.1, 0.35) * d))
        ker = np.zeros((k * 2 + 1, k * 2 + 1), np.float32)
        ker[k, :] = 1.0 / (2 * k + 1)
        ang = rng.uniform(0, 180)
        ker = cv2.warpAffine(ker, cv2.getRotationMatrix2D((k, k), ang, 1.0), ker.shape[::-1])
        img = cv2.filter2D(img, -1, ker / max(ker.sum(), 1e-6))
    sig = rng.uniform(0.002, 0.015) * (3.0 if dim else 1.0)
    img = img + rng.normal(0, 1, img.shape).astype(np.float32) * (sig + 0.02 * np.sqrt(np.clip(img, 0, None)))
    srgb = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(np.clip(img, 0.0031308, None), 1 / 2.4) - 0.055)
    return np.clip(srgb * 255 + 0.5, 0, 255).astype(np.uint8)


def draw_conditions(rng: Rng, split: str, long_side: tuple[int, int], seed_px: tuple[float, float]) -> dict:
    """A photo's background, size (w, h), seed diameter ``d`` (px), light and grain varieties, drawn from ``rng``."""
    held = split != "train"
    bgs = backgrounds(split) + (list(PANICLE_BACKGROUNDS) if held else [])
    bg = bgs[int(rng.integers(len(bgs)))]
    ls = int(rng.integers(long_side[0], long_side[1] + 1))
    aspect = rng.uniform(0.6, 1.0)
    w, h = (ls, int(ls * aspect)) if rng.random() < 0.7 else (int(ls * aspect), ls)
    d = float(np.exp(rng.uniform(np.log(seed_px[0]), np.log(seed_px[1]))))
    if bg == "flatbed":
        light = "scanner"
    elif bg == "night":
        light = "flash"
    else:
        pool = [k for k, s in LIGHTS.items() if s == "train" and k != "scanner"]
        if held and rng.random() < HELDOUT_P:
            pool = [k for k, s in LIGHTS.items() if s == split]
        light = pool[int(rng.integers(len(pool)))]
    tv, hv = varieties("train"), varieties(split)
    vars_ = []
    for _ in range(int(rng.integers(1, 4))):
        pool = hv if held and rng.random() < HELDOUT_P else tv
        vars_.append(pool[int(rng.integers(len(pool)))])
    return {"bg": bg, "w": w, "h": h, "d": d, "light": light, "varieties": vars_}


#: photos of one setup: each photo's seed diameter varies by up to this factor around the setup's (camera distance)
SETUP_SIZE_JITTER = 1.1


def render_photo(rng: Rng, split: str, long_side: tuple[int, int], seed_px: tuple[float, float],
                 empty_fraction: float, setup: dict | None = None) -> Photo:
    """One photo of ``split`` (train | validation | heldout) with its conditions drawn from ``rng`` (module
    docstring), or, with ``setup`` (:func:`draw_conditions` of the setup), that background, light and those
    varieties, its seeds within SETUP_SIZE_JITTER of the setup's size."""
    c = draw_conditions(rng, split, long_side, seed_px)
    if setup is not None:
        j = float(np.exp(rng.uniform(-np.log(SETUP_SIZE_JITTER), np.log(SETUP_SIZE_JITTER))))
        c = {**c, "bg": setup["bg"], "light": setup["light"], "varieties": setup["varieties"], "d": setup["d"] * j}
    bg, w, h, d, light, vars_ = c["bg"], c["w"], c["h"], c["d"], c["light"], c["varieties"]
    kind = "panicle" if bg in PANICLE_BACKGROUNDS else ("pile" if rng.random() < 0.3 else "loose")
    empty = rng.random() < empty_fraction
    L, wb = make_light(light, rng)
    dim = False
    if split == "train" and setup is None:  # casts and dim exposures only in training photos
        if rng.random() < CAST_P:
            wb = wb * np.array([rng.uniform(0.75, 1.35), 1.0, rng.uniform(0.65, 1.3)])
        dim = bool(rng.random() < DIM_P)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (0.25 * (w * w + h * h))
    fall = {"flash": 0.55, "lamp": 0.35}.get(light, 0.15) * rng.uniform(0.3, 1.0)
    falloff = (1.0 - fall * r2).astype(np.float32)
    albedo = BACKGROUNDS[bg][1](rng, h, w, d)
    things = _layout(rng, kind, h, w, d, vars_, empty)
    # cast shadows on the background: footprints moved away from the light by their height, blurred
    shadow = np.zeros((h, w), np.float32)
    off = -L.direction[:2] / max(L.direction[2], 0.2)
    for t in things:
        footprint(t, shadow, off)
    shadow = cv2.GaussianBlur(shadow, (0, 0), max(0.3, L.shadow_blur * d))
    flat = L.ambient + L.diffuse * L.direction[2]
    if bg == "night":  # nothing behind the leaves reflects the flash
        flat = L.ambient + L.diffuse
    img = albedo * (flat * falloff * (1 - L.shadow * shadow))[..., None]
    ids = np.zeros((h, w), np.int32)
    full: dict[int, float] = {}
    k = 0
    for t in things:
        ident = 0
        if t.seed:
            k += 1
            ident = k
            full[k] = np.pi * t.a * t.b
        draw(t, img, ids, ident, L, falloff)
    out = _camera(rng, img, wb, d, light, dim)
    vis = np.bincount(ids.ravel(), minlength=k + 1)
    labelled = [i for i in range(1, k + 1) if vis[i] >= max(4.0, MIN_VISIBLE_FRACTION * full[i])]
    cond = {"background": bg, "light": light, "varieties": vars_, "layout": kind, "seed_diameter_px": round(d, 2),
            "empty": bool(empty), "dim": dim}
    return Photo(out, ids, labelled, cond, lossless=bg == "flatbed")
