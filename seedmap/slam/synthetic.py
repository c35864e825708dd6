"""Synthetic seed geometry for tests and benchmarks that need no renderer.

Panicles are clusters of seed centres on the visible (camera-facing) half of a spindle-shaped
envelope; a stereo rig moves along world +x in the simulator's convention (optical axis = world
+y, image x = world +x, image y = world -z). Keypoints are exact projections plus Gaussian pixel
noise, with independent detection misses per image, shuffled so that index order carries no
information.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seedmap.records import Detections, StereoCalib, StereoDetections, Trajectory

#: R_world_cam of the simulator's side-looking camera.
R_WORLD_CAM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def default_calib(scale: float = 0.35) -> StereoCalib:
    """facts.md intrinsics (4096x3000) scaled like the simulator's default."""
    return StereoCalib(2583.0, 2578.0, 2013.0, 1525.7, 0.11, 4096, 3000).scaled(scale)


@dataclass
class SyntheticRange:
    calib: StereoCalib
    seeds: np.ndarray  # (S, 3) world
    panicle: np.ndarray  # (S,)
    gt: Trajectory


def make_range(rng: np.random.Generator, length: float = 1.0, step: float = 0.04, standoff: float = 0.7,
               seeds_per_panicle: int = 250, panicle_spacing: float = 0.15, calib: StereoCalib | None = None,
               height: float = 1.0) -> SyntheticRange:
    """A row of panicles along x in [-0.6, length + 0.6] and camera poses every ``step`` m."""
    calib = calib or default_calib()
    cx = np.arange(-0.6, length + 0.6, panicle_spacing)
    pts, pid = [], []
    for j, x0 in enumerate(cx):
        c = np.array([x0 + rng.uniform(-0.03, 0.03), standoff + rng.uniform(-0.05, 0.05),
                      height + rng.uniform(-0.12, 0.12)])
        half_len, rad = rng.uniform(0.08, 0.13), rng.uniform(0.025, 0.04)
        s = rng.uniform(-1, 1, seeds_per_panicle)
        phi = rng.uniform(np.pi, 2 * np.pi, seeds_per_panicle)  # camera-facing half (y < centre)
        r = rad * np.sqrt(np.clip(1 - s**2, 0, 1))
        p = c + np.c_[r * np.cos(phi), r * np.sin(phi), s * half_len]
        pts.append(p)
        pid.append(np.full(seeds_per_panicle, j))
    n = int(round(length / step)) + 1
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = R_WORLD_CAM
    poses[:, 0, 3] = np.arange(n) * step
    poses[:, 2, 3] = height
    return SyntheticRange(calib, np.concatenate(pts), np.concatenate(pid), Trajectory(np.arange(n) * 0.2, poses))


def observe(rng_: SyntheticRange, i: int, rng: np.random.Generator, noise_px: float = 0.3,
            miss: float = 0.03) -> StereoDetections:
    """Keypoints of frame ``i`` in both images (seed ids attached, order shuffled)."""
    calib = rng_.calib
    T = rng_.gt.poses[i]
    pc = (rng_.seeds - T[:3, 3]) @ T[:3, :3]
    uv, ur = calib.project(pc)
    dets = []
    for cam in ("left", "right"):
        u = uv[:, 0] if cam == "left" else ur
        k = np.c_[u, uv[:, 1]] + rng.normal(0, noise_px, (len(u), 2))
        ok = (np.isfinite(k).all(1) & (k[:, 0] >= 0) & (k[:, 0] <= calib.width - 1)
              & (k[:, 1] >= 0) & (k[:, 1] <= calib.height - 1) & (rng.random(len(u)) >= miss))
        idx = rng.permutation(np.flatnonzero(ok))
        kk = k[idx]
        ell = np.c_[kk, np.full((len(kk), 2), 5.0), np.zeros(len(kk))]
        boxes = np.c_[kk - 2.5, kk + 2.5]
        dets.append(Detections(boxes, np.ones(len(kk)), ell, idx))
    return StereoDetections(i, float(rng_.gt.timestamps[i]), dets[0], dets[1])
