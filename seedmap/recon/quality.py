"""GT-free quality scores of a panicle reconstruction, so users can compare runs without ground truth.

* ``seed_spread_mm`` -- cross-view consistency of seed centres: for every counted seed seen from
  >= 2 views, the RMS distance of its per-view 3D centres to their mean; the median over seeds.
  Misregistered views scatter a seed's observations, so this grows with pose error.
* ``surface_thickness_mm`` -- sharpness of the merged cloud: for a random subset of points, the
  standard deviation along the smallest principal axis of the neighbours within
  ``radius``; the median. Misaligned views stack shifted copies of the surface ("blur").
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.recon.count import SeedCount


def surface_thickness(xyz: np.ndarray, radius: float = 0.002, samples: int = 3000, seed: int = 0) -> float:
    """Median local thickness (m) of a cloud (smallest-eigenvalue std of radius neighbourhoods)."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    if len(xyz) < 10:
        return float("nan")
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(xyz), size=min(samples, len(xyz)), replace=False)
    tree = cKDTree(xyz)
    out = []
    for nb in tree.query_ball_point(xyz[idx], radius):
        if len(nb) < 8:
            continue
        P = xyz[nb] - xyz[nb].mean(axis=0)
        ev = np.linalg.eigvalsh(P.T @ P / len(nb))
        out.append(np.sqrt(max(ev[0], 0.0)))
    return float(np.median(out)) if out else float("nan")


def quality_scores(cloud_xyz: np.ndarray, count: SeedCount, seed: int = 0) -> dict:
    """Both GT-free scores (mm); lower is better."""
    multi = count.n_views >= 2
    spread = float(np.median(count.spread[multi]) * 1000) if multi.any() else float("nan")
    return {"seed_spread_mm": spread, "surface_thickness_mm": surface_thickness(cloud_xyz, seed=seed) * 1000}
