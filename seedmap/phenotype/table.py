"""The phenotype table of a ``seedmap slam`` result: landmarks -> panicles -> one row per panicle."""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.phenotype.config import PhenotypeConfig
from seedmap.phenotype.shape import RowFrame, ellipsoid_volume, hull_volume, panicle_shape

#: columns of landmarks.csv the table needs
LANDMARK_COLUMNS = ("landmark_id", "cluster_id", "x", "y", "z", "n_obs")
#: columns of panicles.csv, in order
COLUMNS = ("panicle_id", "x_m", "y_m", "height_m", "length_m", "width_m", "hull_volume_cm3",
           "ellipsoid_volume_cm3", "tilt_deg", "landmarks", "frames", "seeds_in_view", "view_frame", "seeds_est",
           "seeds_sd", "quality")
#: a panicle reaching this close (m) to either end of the mapped stretch of row may be cut at the view border
EDGE_M = 0.02
#: ... and is flagged ``cut`` when it was also seen in fewer than this fraction of the median panicle's frames
CUT_FRAMES_FRACTION = 0.5
#: most panicles one landmark cluster is split into
MAX_SPLIT = 4
#: clusters stacked along the height are fragments of one panicle when their along-row spans overlap by this
#: fraction of the narrower span and the height gap between them is below MERGE_GAP_M (m)
MERGE_OVERLAP = 0.5
MERGE_GAP_M = 0.05
#: panicle columns a seed-count calibration may use (in logs)
COUNT_FEATURES = ("landmarks", "length_m", "width_m", "seeds_in_view")
#: folder of the shipped seed-count calibrations
CALIBRATIONS = Path(__file__).parent / "calibrations"


@dataclass
class Landmarks:
    """The seed map of a result folder: world positions (m), DBSCAN cluster ids (-1 noise), observations."""

    xyz: np.ndarray
    cluster: np.ndarray
    n_obs: np.ndarray


def read_landmarks(path: Path) -> Landmarks:
    """``landmarks.csv`` as arrays; a missing or malformed file is one line."""
    import pandas as pd

    if not path.is_file():
        raise InputError("landmarks.csv not found (is this a `seedmap slam` result folder?)", path)
    try:
        df = pd.read_csv(path)
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"malformed landmarks table ({str(e).splitlines()[0]})", path) from None
    missing = [c for c in LANDMARK_COLUMNS if c not in df.columns]
    if missing:
        raise InputError(f"landmarks table lacks the columns {','.join(missing)}", path)
    try:
        xyz = df[["x", "y", "z"]].to_numpy(np.float64)
        cl = df["cluster_id"].to_numpy(np.int64)
        obs = df["n_obs"].to_numpy(np.int64)
    except (ValueError, TypeError):
        raise InputError("landmarks table has a non-numeric value", path) from None
    if not np.all(np.isfinite(xyz)):
        raise InputError("landmarks table has NaN or inf coordinates", path)
    return Landmarks(xyz, cl, obs)


def load_calibration(name: str) -> dict:
    """A seed-count calibration: a JSON file path, or the name of a shipped one."""
    p = Path(name) if name.endswith(".json") else CALIBRATIONS / f"{name}.json"
    if not p.is_file():
        shipped = ", ".join(sorted(q.stem for q in CALIBRATIONS.glob("*.json")))
        raise InputError(f"seed-count calibration not found (shipped: {shipped})", p)
    try:
        cal = json.loads(p.read_text(encoding="utf-8"))
        float(cal["intercept"]), float(cal["sigma_log"])
        if not set(cal["coef"]) <= set(COUNT_FEATURES):
            raise KeyError
        [float(v) for v in cal["coef"].values()]
    except (ValueError, KeyError, TypeError, AttributeError, UnicodeDecodeError):
        raise InputError("not a seed-count calibration (JSON with intercept, coef of "
                         f"{'/'.join(COUNT_FEATURES)}, sigma_log)", p) from None
    return cal


def estimate_seeds(features: dict, cal: dict) -> tuple[float, float]:
    """Seed count and its 1-sigma uncertainty: ``log N = intercept + sum coef_k log(feature_k)`` with
    log-normal residuals of standard deviation ``sigma_log``."""
    if any(not features[k] > 0 for k in cal["coef"]):  # zero, or NaN (no view)
        return 0.0, 0.0
    n = math.exp(float(cal["intercept"]) + sum(float(c) * math.log(features[k]) for k, c in cal["coef"].items()))
    return n, n * math.sqrt(math.expm1(float(cal["sigma_log"]) ** 2))


def join_fragments(xz: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """Cluster ids with fragments of one panicle (stacked along the height, see :data:`MERGE_OVERLAP`) joined:
    connected components (scipy) of the fragment graph."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ids = np.unique(cluster[cluster >= 0])
    if len(ids) < 2:
        return cluster
    lo = np.array([xz[cluster == c].min(axis=0) for c in ids])
    hi = np.array([xz[cluster == c].max(axis=0) for c in ids])
    over = np.minimum(hi[:, None, 0], hi[None, :, 0]) - np.maximum(lo[:, None, 0], lo[None, :, 0])
    narrow = np.minimum(hi[:, None, 0] - lo[:, None, 0], hi[None, :, 0] - lo[None, :, 0])
    gap = np.maximum(lo[:, None, 1], lo[None, :, 1]) - np.minimum(hi[:, None, 1], hi[None, :, 1])
    i, j = np.nonzero((over >= MERGE_OVERLAP * np.maximum(narrow, 1e-9)) & (gap < MERGE_GAP_M))
    _, comp = connected_components(coo_matrix((np.ones(len(i)), (i, j)), shape=(len(ids), len(ids))))
    out = cluster.copy()
    lut = dict(zip(ids.tolist(), comp.tolist()))
    out[cluster >= 0] = [lut[c] for c in cluster[cluster >= 0].tolist()]
    return out


def split_clusters(xyz_row: np.ndarray, cluster: np.ndarray, cfg: PhenotypeConfig) -> list[tuple[np.ndarray, bool]]:
    """Landmark index arrays, one per panicle, and whether each may still hold merged panicles.

    Clusters with fewer than ``min_landmarks`` are dropped; one wider than ``split_width_m`` (across its
    principal axis, :func:`panicle_shape`) is split by k-means on the along-row coordinate (scipy),
    k = ceil(width / split_width_m), when every part keeps ``min_landmarks``."""
    from scipy.cluster.vq import kmeans2

    x_along = xyz_row[:, 0]
    out: list[tuple[np.ndarray, bool]] = []
    for c in np.unique(cluster[cluster >= 0]):
        idx = np.flatnonzero(cluster == c)
        if len(idx) < cfg.min_landmarks:
            continue
        extent = panicle_shape(xyz_row[idx]).width_m
        if extent <= cfg.split_width_m:
            out.append((idx, False))
            continue
        k = min(MAX_SPLIT, math.ceil(extent / cfg.split_width_m))
        _, lab = kmeans2(x_along[idx].reshape(-1, 1), k, minit="++", seed=0)
        parts = [idx[lab == j] for j in range(k)]
        if all(len(p) >= cfg.min_landmarks for p in parts):
            out += [(p, panicle_shape(xyz_row[p]).width_m > cfg.split_width_m) for p in parts]
        else:
            out.append((idx, True))
    out.sort(key=lambda t: float(np.median(x_along[t[0]])))
    return out


def panicle_groups(lm: Landmarks, frame: RowFrame, cfg: PhenotypeConfig) -> list[tuple[np.ndarray, bool]]:
    """Landmark index arrays, one per panicle, sorted along the row, and whether each may hold merged panicles."""
    p = frame.to_row(lm.xyz)
    return split_clusters(p, join_fragments(p[:, [0, 2]], lm.cluster), cfg)


def panicle_rows(lm: Landmarks, frame: RowFrame, cfg: PhenotypeConfig, cal: dict,
                 groups: list[tuple[np.ndarray, bool]], views: list | None = None) -> list[dict]:
    """One dict per panicle (``groups`` of :func:`panicle_groups`) with the :data:`COLUMNS`; ``views``: the
    best view of each (:mod:`seedmap.phenotype.views`), None without images (``seeds_in_view`` is then NaN)."""
    if not groups:
        return []
    p = frame.to_row(lm.xyz)
    lo, hi = float(p[:, 0].min()), float(p[:, 0].max())
    frames = [int(lm.n_obs[idx].max()) for idx, _ in groups]
    median_frames = float(np.median(frames))
    rows = []
    for i, ((idx, merged), nf) in enumerate(zip(groups, frames)):
        q = p[idx]
        s = panicle_shape(q)
        flags = []
        at_edge = q[:, 0].min() < lo + EDGE_M or q[:, 0].max() > hi - EDGE_M
        if at_edge and nf < CUT_FRAMES_FRACTION * median_frames:
            flags.append("cut")
        if merged:
            flags.append("merged")
        if len(idx) < cfg.few_landmarks:
            flags.append("few")
        view = views[i] if views is not None else None
        in_view = float(view.count) if view is not None else float("nan")
        n, sd = estimate_seeds({"landmarks": len(idx), "length_m": s.length_m, "width_m": s.width_m,
                                "seeds_in_view": in_view}, cal)
        rows.append({
            "panicle_id": i, "x_m": s.centre[0],
            # seeds seen from one side: the mean of a round cross-section's front half lies width/pi nearer
            "y_m": s.centre[1] + s.width_m / math.pi,
            "height_m": s.centre[2] - frame.ground(float(s.centre[0]), float(s.centre[1])), "length_m": s.length_m, "width_m": s.width_m,
            "hull_volume_cm3": hull_volume(q) * 1e6,
            "ellipsoid_volume_cm3": ellipsoid_volume(s.length_m, s.width_m) * 1e6,
            "tilt_deg": s.tilt_deg, "landmarks": len(idx), "frames": nf,
            "seeds_in_view": view.count if view is not None else "", "view_frame": view.frame if view is not None else "",
            "seeds_est": n, "seeds_sd": sd, "quality": "+".join(flags) or "ok",
        })
    return rows


def rows_csv(rows: list[dict], columns: tuple[str, ...] | list[str]) -> str:
    """CSV text: floats with 4 decimals (mm, 0.1 cm^3, seeds to 0.0001: plenty)."""
    buf = io.StringIO()
    buf.write(",".join(columns) + "\n")
    for r in rows:
        buf.write(",".join(f"{r[c]:.4f}" if isinstance(r[c], float) else str(r[c]) for c in columns) + "\n")
    return buf.getvalue()


def read_plots(path: Path) -> list[tuple[str, float, float]]:
    """A plots CSV (``plot,start,end``: metres along the row) as ``(plot, start, end)`` tuples."""
    if not path.is_file():
        raise InputError("plots file not found", path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rd = csv.DictReader(f)
            if rd.fieldnames is None or not {"plot", "start", "end"} <= set(rd.fieldnames):
                raise InputError("plots CSV needs the columns plot,start,end (metres along the row)", path)
            plots = [(r["plot"], float(r["start"]), float(r["end"])) for r in rd]
    except (ValueError, TypeError, UnicodeDecodeError):
        raise InputError("plots CSV has a start or end that is not a number", path) from None
    for name, a, b in plots:
        if not (math.isfinite(a) and math.isfinite(b) and b > a):
            raise InputError(f"plot {name!r}: end must be a number greater than start", path)
    return plots


PLOT_COLUMNS = ("plot", "start_m", "end_m", "panicles", "panicles_ok", "height_m", "length_m", "width_m",
                "seeds_est", "seeds_per_panicle")


def plot_summaries(rows: list[dict], plots: list[tuple[str, float, float]]) -> list[dict]:
    """Per plot: panicles whose centre lies in ``[start, end)``, their mean height/length/width, seed sum."""
    out = []
    for name, a, b in plots:
        inside = [r for r in rows if a <= r["x_m"] < b]
        mean = (lambda k: float(np.mean([r[k] for r in inside])) if inside else float("nan"))  # noqa: E731
        seeds = float(sum(r["seeds_est"] for r in inside))
        out.append({"plot": name, "start_m": a, "end_m": b, "panicles": len(inside),
                    "panicles_ok": sum(r["quality"] == "ok" for r in inside), "height_m": mean("height_m"),
                    "length_m": mean("length_m"), "width_m": mean("width_m"), "seeds_est": seeds,
                    "seeds_per_panicle": seeds / len(inside) if inside else float("nan")})
    return out
