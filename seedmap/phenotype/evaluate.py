"""``seedmap eval phenotype``: a phenotype table against the simulator's ground truth.

GT panicles are the panicle ids of ``gt/seeds.csv`` (seed centres at rest). A seed counts as *visible* when its
centre is visible in the left and the right image of the same frame in at least :data:`VISIBLE_FRAMES` frames
(a landmark needs two stereo observations). GT length, width and centre are measured with the same
:func:`~seedmap.phenotype.shape.panicle_shape` on all of the panicle's seeds, in the result's row frame.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.phenotype.shape import RowFrame, panicle_shape

#: frames with a stereo-visible centre that make a GT seed visible
VISIBLE_FRAMES = 2
#: GT panicles with fewer visible seeds are not expected in the table (recall ignores them; a match still counts)
MIN_VISIBLE_SEEDS = 20
#: largest centre distance (m) of a matched panicle: about half the smallest plant spacing
MATCH_M = 0.06


def visible_seed_counts(ds, n_frames: int) -> dict[int, int]:
    """Seed id -> frames in which its centre is visible in both images."""
    counts: dict[int, int] = {}
    for i in range(n_frames):
        left, right = ds.gt_instances(i, "left"), ds.gt_instances(i, "right")
        both = np.intersect1d(left.seed_id[left.center_visible], right.seed_id[right.center_visible])
        for s in both.tolist():
            counts[s] = counts.get(s, 0) + 1
    return counts


def gt_panicles(dataset: Path, frame: RowFrame) -> list[dict]:
    """One dict per GT panicle: id, centre (row frame), length, width, true and visible seed counts."""
    from seedmap.io import open_dataset

    ds = open_dataset(dataset)
    if not hasattr(ds, "gt_seeds"):
        raise InputError("dataset has no seed ground truth (gt/seeds.csv of a simulated range)", dataset)
    seeds = ds.gt_seeds()
    vis = visible_seed_counts(ds, len(ds))
    visible = np.array([vis.get(int(s), 0) >= VISIBLE_FRAMES for s in seeds.seed_id])
    xyz = frame.to_row(seeds.xyz)
    out = []
    for pid in np.unique(seeds.panicle_id):
        m = seeds.panicle_id == pid
        s = panicle_shape(xyz[m])
        out.append({"panicle_id": int(pid), "x_m": s.centre[0], "y_m": s.centre[1], "height_m": s.centre[2],
                    "length_m": s.length_m, "width_m": s.width_m, "seeds": int(m.sum()),
                    "seeds_visible": int(visible[m].sum())})
    return out


def match_panicles(est: list[dict], gt: list[dict], gate_m: float = MATCH_M) -> list[tuple[int, int]]:
    """One-to-one (Hungarian) matches ``(est index, gt index)`` of centres within ``gate_m`` (3D)."""
    from scipy.optimize import linear_sum_assignment

    if not est or not gt:
        return []
    a = np.array([[r["x_m"], r["y_m"], r["height_m"]] for r in est])
    b = np.array([[g["x_m"], g["y_m"], g["height_m"]] for g in gt])
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    big = 1e6
    ri, ci = linear_sum_assignment(np.where(d <= gate_m, d, big))
    return [(int(i), int(j)) for i, j in zip(ri, ci) if d[i, j] <= gate_m]


def _median(v: list[float]) -> float | None:
    return float(np.median(v)) if v else None


def score(est: list[dict], gt: list[dict]) -> dict:
    """Detection precision/recall and the errors of every column over matched panicles."""
    pairs = match_panicles(est, gt)
    expected = {j for j, g in enumerate(gt) if g["seeds_visible"] >= MIN_VISIBLE_SEEDS}
    matched_gt = {j for _, j in pairs}
    per = []
    for i, j in pairs:
        e, g = est[i], gt[j]
        per.append({
            "panicle_id": e["panicle_id"], "gt_panicle_id": g["panicle_id"], "quality": e["quality"],
            "landmarks": e["landmarks"], "length_m": e["length_m"], "width_m": e["width_m"],
            "seeds_in_view": e["seeds_in_view"], "seeds": g["seeds"], "seeds_visible": g["seeds_visible"],
            "seeds_est": e["seeds_est"],
            "position_err_m": math.dist((e["x_m"], e["y_m"], e["height_m"]), (g["x_m"], g["y_m"], g["height_m"])),
            "along_err_m": e["x_m"] - g["x_m"], "across_err_m": e["y_m"] - g["y_m"],
            "height_err_m": e["height_m"] - g["height_m"],
            "length_rel_err": e["length_m"] / g["length_m"] - 1.0, "width_rel_err": e["width_m"] / g["width_m"] - 1.0,
            "seeds_rel_err": e["seeds_est"] / g["seeds"] - 1.0,
            "landmarks_rel_err_visible": e["landmarks"] / max(g["seeds_visible"], 1) - 1.0,
        })
    n_true = sum(p["seeds"] for p in per)
    n_vis = sum(p["seeds_visible"] for p in per)
    ab = lambda k: _median([abs(p[k]) for p in per])  # noqa: E731
    return {
        "panicles_est": len(est), "panicles_gt": len(gt), "panicles_gt_expected": len(expected),
        "matched": len(pairs), "precision": len(pairs) / len(est) if est else None,
        "recall": len(expected & matched_gt) / len(expected) if expected else None,
        "position_err_median_m": ab("position_err_m"), "along_err_median_m": ab("along_err_m"),
        "across_err_median_m": ab("across_err_m"), "height_err_median_m": ab("height_err_m"),
        "length_rel_err_median": ab("length_rel_err"), "width_rel_err_median": ab("width_rel_err"),
        "seeds_mape": float(np.mean([abs(p["seeds_rel_err"]) for p in per])) if per else None,
        "landmarks_mape_visible": float(np.mean([abs(p["landmarks_rel_err_visible"]) for p in per])) if per else None,
        "visible_fraction": n_vis / n_true if n_true else None,
        "landmarks_per_visible_seed": sum(p["landmarks"] for p in per) / n_vis if n_vis else None,
        "per_panicle": per,
    }


def evaluate_phenotype(result: Path, dataset: Path, cfg, images=None) -> dict:  # noqa: ANN001
    """Phenotype table of ``result`` scored against ``dataset``'s GT (see :func:`score`); ``images``
    (:class:`seedmap.phenotype.run.Images`) for the seeds counted in each panicle's best view."""
    from seedmap.phenotype.run import phenotype_result

    ph = phenotype_result(result, cfg, images)
    m = score(ph.rows, gt_panicles(Path(dataset), ph.frame))
    m["height_source"] = ph.frame.height_source
    m["calibration"] = ph.calibration
    return m
