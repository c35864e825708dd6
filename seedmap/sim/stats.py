"""Realism self-check of a simulated dataset (from its ground truth) and a preview contact sheet."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from seedmap.errors import InputError
from seedmap.geometry import invert
from seedmap.io.atomic import atomic_write_text
from seedmap.io.images import write_png
from seedmap.io.seedmap_dataset import SeedmapDataset


def range_length(dataset_path: str | Path) -> float | None:
    """The simulated range length (m) recorded in ``gt/config.yaml`` (None for real/unknown data)."""
    p = Path(dataset_path) / "gt" / "config.yaml"
    if not p.is_file():
        return None
    try:
        d = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError:
        return None
    try:
        v = d.get("world", {}).get("length", d.get("length"))
        return float(v) if v is not None else None
    except (AttributeError, TypeError, ValueError):
        return None


def dataset_stats(path: str | Path) -> dict:
    """Numbers that say whether a simulated range looks like the field data.

    seeds per panicle (min/mean/max), seed diameter in px (projected true size of visible seeds:
    median, p10; and mask-equivalent diameter), visible seeds per frame (left), GT pixel shift per
    frame (median over seeds seen in consecutive frames, then median over frames), and the fraction
    of frames with a panicle in view (>= 1 visible seed / >= 50 visible seeds).
    """
    path = Path(path)
    ds = SeedmapDataset(path)
    if not ds.has_gt:
        raise InputError("dataset has no ground truth (gt/poses_tum.txt); stats need a simulated dataset", path)
    seeds = ds.gt_seeds()
    traj = ds.gt_trajectory()
    calib = ds.calib
    _, per_pan = np.unique(seeds.panicle_id, return_counts=True) if len(seeds) else (None, np.zeros(0, int))
    visible, diam_true, diam_mask, shifts = [], [], [], []
    prev: dict[int, float] | None = None
    mean_r = seeds.radii.mean(axis=1) if len(seeds) else np.zeros(0)
    n = len(ds)
    for i in range(n):
        inst = ds.gt_instances(i, "left")
        visible.append(len(inst))
        if len(inst):
            Tcw = invert(traj.poses[i])
            pc = seeds.xyz[inst.seed_id] @ Tcw[:3, :3].T + Tcw[:3, 3]
            ok = inst.area >= 4
            diam_true.append((2 * mean_r[inst.seed_id] * calib.fx / pc[:, 2])[ok])
            diam_mask.append(2 * np.sqrt(inst.area[ok] / np.pi))
        cur = {int(s): float(u) for s, u in zip(inst.seed_id, inst.center_uv[:, 0], strict=True)}
        if prev is not None:
            common = set(cur) & set(prev)
            if common:
                shifts.append(float(np.median([abs(cur[s] - prev[s]) for s in common])))
        prev = cur
    vis = np.array(visible)
    dt = np.concatenate(diam_true) if diam_true else np.zeros(0)
    dm = np.concatenate(diam_mask) if diam_mask else np.zeros(0)

    def q(a: np.ndarray, p: float) -> float | None:
        return float(np.percentile(a, p)) if len(a) else None

    return {
        "dataset": str(path),
        "frames": int(n),
        "range_length_m": range_length(path),
        "image_size": [calib.width, calib.height],
        "fx_px": float(calib.fx),
        "panicles": int(len(per_pan)),
        "seeds_total": int(len(seeds)),
        "seeds_per_panicle_min": int(per_pan.min()) if len(per_pan) else 0,
        "seeds_per_panicle_mean": float(per_pan.mean()) if len(per_pan) else 0.0,
        "seeds_per_panicle_max": int(per_pan.max()) if len(per_pan) else 0,
        "seed_diameter_px_median": q(dt, 50),
        "seed_diameter_px_p10": q(dt, 10),
        "seed_mask_diameter_px_median": q(dm, 50),
        "visible_seeds_per_frame_mean": float(vis.mean()) if n else 0.0,
        "visible_seeds_per_frame_median": float(np.median(vis)) if n else 0.0,
        "visible_seeds_per_frame_max": int(vis.max()) if n else 0,
        "pixel_shift_per_frame_median": float(np.median(shifts)) if shifts else None,
        "frames_with_panicle_fraction": float(np.mean(vis >= 1)) if n else 0.0,
        "frames_with_50_seeds_fraction": float(np.mean(vis >= 50)) if n else 0.0,
    }


def write_stats(path: str | Path, stats: dict) -> Path:
    """Write ``stats.json`` into the dataset folder ``path``."""
    p = Path(path) / "stats.json"
    atomic_write_text(p, json.dumps(stats, indent=2) + "\n")
    return p


def print_stats(stats: dict) -> None:
    """Print the stats as a table on the terminal."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"simulation self-check: {stats.get('dataset', '')}")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    for k, v in stats.items():
        if k == "dataset":
            continue
        if isinstance(v, float):
            txt = f"{v:.3f}"
        elif v is None:
            txt = "n/a"
        else:
            txt = str(v)
        table.add_row(k, txt)
    Console().print(table)


def write_preview(path: str | Path, n: int = 9, width: int = 480) -> Path:
    """``preview.png``: a grid of ``n`` evenly spaced left frames with the GT centres of the seeds
    whose centre is visible drawn as green dots."""
    import cv2

    ds = SeedmapDataset(path)
    idx = np.unique(np.linspace(0, len(ds) - 1, min(n, len(ds))).round().astype(int))
    tiles = []
    for i in idx:
        img = ds[i].left.copy()
        s = width / img.shape[1]
        small = cv2.resize(img, (width, int(round(img.shape[0] * s))), interpolation=cv2.INTER_AREA)
        if (Path(path) / "gt").is_dir():
            inst = ds.gt_instances(int(i), "left")
            uv = inst.center_uv[inst.center_visible]
            px = np.floor((uv + 0.5) * s).astype(int)
            ok = (px[:, 0] >= 0) & (px[:, 0] < small.shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < small.shape[0])
            small[px[ok, 1], px[ok, 0]] = (0, 255, 0)
        cv2.putText(small, f"frame {i}", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 0), 1, cv2.LINE_AA)
        tiles.append(small)
    cols = 3
    h, w = tiles[0].shape[:2]
    rows = (len(tiles) + cols - 1) // cols
    sheet = np.zeros((rows * h, cols * w, 3), np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, cols)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile
    out = Path(path) / "preview.png"
    write_png(out, sheet)
    return out
