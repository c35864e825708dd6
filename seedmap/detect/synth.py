"""Tiny synthetic seed images drawn with OpenCV, with exact instance masks.

Used by the tests and as a bootstrap training set for the learned models when no simulated
dataset is at hand. Seeds are shaded ellipses (flash lighting: bright centre, darker rim) packed
in clusters, partly overlapping, among green leaf strips on a dark background — the same visual
problem as the simulator's close-up flash images, in miniature. The right image of a stereo pair is
the left image re-drawn with every seed shifted by a constant disparity, so stereo GT is exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from seedmap.io.seedmap_dataset import DatasetWriter, Instances
from seedmap.records import StereoCalib, Trajectory

SEED_COLOURS = np.array([[235, 225, 190], [200, 160, 100], [170, 80, 50], [110, 70, 40]], np.float64)


@dataclass
class SynthSeeds:
    """Seeds of one synthetic scene: ellipses ``(N, 5)`` (full axes, major-axis angle) and colours."""

    ellipses: np.ndarray
    colours: np.ndarray
    seed_ids: np.ndarray


def random_seeds(rng: np.random.Generator, width: int, height: int, n_clusters: int = 3,
                 seeds_per_cluster: int = 40, seed_px: float = 6.0) -> SynthSeeds:
    """Seed ellipses packed around a few panicle-like clusters (touching, some overlap)."""
    ells, cols = [], []
    for _ in range(n_clusters):
        c = np.array([rng.uniform(0.15, 0.85) * width, rng.uniform(0.15, 0.85) * height])
        base = SEED_COLOURS[rng.integers(len(SEED_COLOURS))]
        spread = np.array([rng.uniform(1.5, 3.0), rng.uniform(3.0, 6.0)]) * seed_px
        for _ in range(seeds_per_cluster):
            p = c + rng.normal(0, 1, 2) * spread
            d = seed_px * rng.uniform(0.8, 1.2)
            ells.append([p[0], p[1], d * rng.uniform(1.0, 1.35), d * rng.uniform(0.8, 1.0), rng.uniform(0, 180)])
            cols.append(np.clip(base * rng.uniform(0.85, 1.15) + rng.normal(0, 8, 3), 0, 255))
    e = np.asarray(ells, np.float64).reshape(-1, 5)
    return SynthSeeds(e, np.asarray(cols).reshape(-1, 3), np.arange(len(e), dtype=np.int64))


def render_seeds(seeds: SynthSeeds, width: int, height: int, rng: np.random.Generator, shift_u: float = 0.0,
                 leaves: int = 3, noise: float = 3.0, supersample: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Render ``(rgb uint8, labels uint16)``; label ``k + 1`` is seed ``k`` (painter's order).

    The image is rendered at ``supersample`` x resolution and area-averaged (anti-aliasing); the
    label of a pixel is the seed hit by the ray through the pixel centre, as in the simulator.
    """
    s = supersample
    H, W = height * s, width * s
    img = np.zeros((H, W, 3), np.float64)
    img += rng.uniform(5, 20)
    lrng = np.random.default_rng(rng.integers(1 << 31))
    for _ in range(leaves):
        p0 = np.array([lrng.uniform(0, W), lrng.uniform(0, H)])
        p1 = p0 + lrng.normal(0, 1, 2) * W * 0.4
        col = (lrng.uniform(40, 70), lrng.uniform(90, 140), lrng.uniform(30, 60))
        cv2.line(img, tuple(int(v) for v in p0), tuple(int(v) for v in p1), col, int(lrng.uniform(4, 12) * s))
    lab = np.zeros((H, W), np.int32)
    yy, xx = np.mgrid[0:H, 0:W]
    # pixel (r, c) of the supersampled grid covers full-res u = (c + 0.5) / s - 0.5
    for k, (e, col) in enumerate(zip(seeds.ellipses, seeds.colours, strict=True)):
        cx, cy, ma, mi, ang = e
        cx += shift_u
        a, b = ma / 2, mi / 2
        r = int(np.ceil(a + 1))
        u0, u1 = int(max(np.floor(cx - r), 0)), int(min(np.ceil(cx + r) + 1, width))
        v0, v1 = int(max(np.floor(cy - r), 0)), int(min(np.ceil(cy + r) + 1, height))
        if u1 <= u0 or v1 <= v0:
            continue
        sl = (slice(v0 * s, v1 * s), slice(u0 * s, u1 * s))
        u = (xx[sl] + 0.5) / s - 0.5 - cx
        v = (yy[sl] + 0.5) / s - 0.5 - cy
        t = np.radians(ang)
        x = (u * np.cos(t) + v * np.sin(t)) / a
        y = (-u * np.sin(t) + v * np.cos(t)) / b
        rr = x * x + y * y
        inside = rr <= 1.0
        shade = 0.45 + 0.55 * np.sqrt(np.clip(1.0 - rr, 0, 1))
        spec = 40.0 * np.exp(-((x + 0.3) ** 2 + (y + 0.3) ** 2) / 0.05)
        val = col[None, None, :] * shade[..., None] + spec[..., None]
        img[sl][inside] = val[inside]
        lab[sl][inside] = k + 1
    img += rng.normal(0, noise, img.shape)
    small = cv2.resize(np.clip(img, 0, 255).astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    c = s // 2  # the sample nearest to the full-res pixel centre
    labels = lab[c::s, c::s][:height, :width].astype(np.uint16)
    return np.clip(np.round(small), 0, 255).astype(np.uint8), labels


def instances_of(labels: np.ndarray, seeds: SynthSeeds, shift_u: float = 0.0) -> Instances:
    """The GT instance table of a label image (box, true centre, area, center_visible)."""
    ids = np.unique(labels)
    ids = ids[ids > 0].astype(np.int64)
    from scipy import ndimage

    objs = ndimage.find_objects(labels.astype(np.int64))
    boxes = np.array([[objs[i - 1][1].start, objs[i - 1][0].start, objs[i - 1][1].stop, objs[i - 1][0].stop]
                      for i in ids], np.float64).reshape(-1, 4)
    area = np.bincount(labels.reshape(-1).astype(np.int64), minlength=int(ids.max(initial=0)) + 1)[ids]
    cen = seeds.ellipses[ids - 1, :2] + np.array([shift_u, 0.0])
    ci = np.round(cen).astype(int)
    h, w = labels.shape
    inside = (ci[:, 0] >= 0) & (ci[:, 0] < w) & (ci[:, 1] >= 0) & (ci[:, 1] < h)
    vis = np.zeros(len(ids), bool)
    vis[inside] = labels[ci[inside, 1], ci[inside, 0]] == ids[inside]
    return Instances(label=ids.astype(np.uint16), seed_id=seeds.seed_ids[ids - 1], panicle_id=np.zeros(len(ids),
                     np.int64), boxes=boxes, center_uv=cen, area=area.astype(np.int64), center_visible=vis)


def write_synthetic_dataset(root: Path, n_frames: int = 2, width: int = 320, height: int = 240, seed: int = 0,
                            seed_px: float = 6.0, disparity: float = 30.0, seeds_per_cluster: int = 40,
                            n_clusters: int = 3) -> Path:
    """A small seedmap-layout dataset of synthetic frames (GT masks, instances, poses)."""
    rng = np.random.default_rng(seed)
    root = Path(root)
    w = DatasetWriter(root)
    fx = width * 0.63
    calib = StereoCalib(fx=fx, fy=fx, cx=width / 2 - 0.5, cy=height / 2 - 0.5, baseline=0.11, width=width,
                        height=height)
    w.write_calib(calib)
    w.write_times(np.arange(n_frames) * 0.2)
    for i in range(n_frames):
        seeds = random_seeds(rng, width, height, n_clusters, seeds_per_cluster, seed_px)
        frng = np.random.default_rng(rng.integers(1 << 31))
        left, llab = render_seeds(seeds, width, height, np.random.default_rng(frng.integers(1 << 31)))
        right, rlab = render_seeds(seeds, width, height, np.random.default_rng(frng.integers(1 << 31)),
                                   shift_u=-disparity)
        w.write_frame(i, left, right)
        w.write_gt_instances(i, "left", llab, instances_of(llab, seeds))
        w.write_gt_instances(i, "right", rlab, instances_of(rlab, seeds, -disparity))
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    poses[:, 0, 3] = np.arange(n_frames) * 0.04
    w.write_gt_poses(Trajectory(np.arange(n_frames) * 0.2, poses))
    return root
