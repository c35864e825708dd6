"""Synthetic multiview arm scans of a cylinder of seeds (keypoints only, no rendering)."""

from __future__ import annotations

import numpy as np

from seedmap.geometry import invert
from seedmap.recon.count import StereoKeypoints
from seedmap.records import StereoCalib

CALIB = StereoCalib(fx=645.75, fy=644.5, cx=502.875, cy=381.05, baseline=0.11, width=1024, height=750)

VIEWS = 24

SEED_D = 0.004


def look_at_axis(angle: float, radius: float = 0.3, height: float = 0.03) -> np.ndarray:
    """T_world_cam of a camera on a circle around the z axis, looking at the axis (y down = -z)."""
    c = np.array([radius * np.cos(angle), radius * np.sin(angle), height])
    z = -np.array([np.cos(angle), np.sin(angle), 0.0])
    y = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = c
    return T


def cylinder_seeds(rows: int = 15, per_row: int = 22, radius: float = 0.0135):
    """Touching 4 mm seeds on a cylinder around z (staggered rows): centres and outward normals."""
    k = np.arange(rows * per_row)
    z = SEED_D * 0.9 * (k // per_row)
    phi = (k % per_row + 0.5 * (k // per_row % 2)) * (2 * np.pi / per_row)
    centres = np.column_stack([radius * np.cos(phi), radius * np.sin(phi), z])
    return centres, np.column_stack([np.cos(phi), np.sin(phi), np.zeros(len(k))])


def scan(rng: np.random.Generator, noise_px: float = 0.3, drop: float = 0.1, clutter: float = 0.0,
         hidden_views: tuple[int, ...] = ()):
    """Per-view StereoKeypoints (true ids kept aside), poses, and the ids seen in left+right of >= 2 views."""
    centres, normals = cylinder_seeds()
    poses = np.stack([look_at_axis(2 * np.pi * v / VIEWS) for v in range(VIEWS)])
    views, ids_l, ids_r, seen_count = [], [], [], np.zeros(len(centres), int)
    for v in range(VIEWS):
        Tcw = invert(poses[v])
        cam = poses[v][:3, 3]
        ray = cam - centres
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        vis = np.sum(normals * ray, axis=1) > 0.3
        pc = centres @ Tcw[:3, :3].T + Tcw[:3, 3]
        uv, ur = CALIB.project(pc)
        keep_l = vis & (rng.random(len(centres)) > drop)
        keep_r = vis & (rng.random(len(centres)) > drop)
        if v in hidden_views:
            keep_l[:] = keep_r[:] = False
        il, ir = np.flatnonzero(keep_l), np.flatnonzero(keep_r)
        left = uv[il] + rng.normal(0, noise_px, (len(il), 2))
        right = np.column_stack([ur[ir], uv[ir, 1]]) + rng.normal(0, noise_px, (len(ir), 2))
        n_fake = int(clutter * len(il))
        if n_fake:  # false detections inside the panicle's image region
            lo, hi = left.min(axis=0), left.max(axis=0)
            left = np.vstack([left, lo + rng.random((n_fake, 2)) * (hi - lo)])
            right = np.vstack([right, lo - [237, 0] + rng.random((n_fake, 2)) * (hi - lo)])
            il = np.concatenate([il, np.full(n_fake, -1)])
            ir = np.concatenate([ir, np.full(n_fake, -2)])
        size = SEED_D * CALIB.fx / np.maximum(np.concatenate([pc[il[il >= 0], 2], np.full(n_fake, 0.3)]), 1e-6)
        views.append(StereoKeypoints(left, right, size))
        ids_l.append(il)
        ids_r.append(ir)
        seen_count[np.intersect1d(np.flatnonzero(keep_l), np.flatnonzero(keep_r))] += 1
    scan.ids_r = ids_r  # true ids of the right keypoints (checked by one test)
    return views, poses, ids_l, np.flatnonzero(seen_count >= 2), centres
