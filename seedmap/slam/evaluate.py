"""Recompute the metrics of a ``seedmap slam`` result folder against a dataset's ground truth."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.text import read_text
from seedmap.eval.slam_metrics import SlamMetrics, compute_slam_metrics


def evaluate_result_dir(result: str | Path, dataset: str | Path, json_out: Path | None = None) -> SlamMetrics:
    """Metrics from ``result/trajectory.tum`` (+ lost frame/reason and timings from its
    metrics.json) and the dataset's GT trajectory / range length."""
    from seedmap.io import open_dataset
    from seedmap.io.trajectory import read_tum
    from seedmap.slam.pipeline import range_length_of

    result = Path(result)
    if not result.is_dir():
        raise InputError("result folder not found", result)
    est = read_tum(result / "trajectory.tum")
    if not len(est):  # scored as a run with every metric '-', exit 0
        raise InputError("trajectory has no poses: nothing to evaluate (the run tracked no frame)",
                         result / "trajectory.tum")
    old: dict = {}
    mp = result / "metrics.json"
    if mp.is_file():
        try:
            old = json.loads(read_text(mp, "metrics.json"))
        except json.JSONDecodeError:
            raise InputError("metrics.json is not valid JSON", mp) from None
    ds = open_dataset(dataset)
    gt = ds.gt_trajectory()
    if gt is None:
        raise InputError("dataset has no ground-truth trajectory (gt/poses_tum.txt)", dataset)
    if len(est) and len(ds):  # a result of another dataset paired poses by nearest time and "evaluated" fine
        t = np.asarray(ds.timestamps, float)
        j = np.clip(np.searchsorted(t, est.timestamps), 1, len(t) - 1) if len(t) > 1 else np.zeros(len(est), int)
        off = np.minimum(np.abs(t[j] - est.timestamps), np.abs(t[j - 1] - est.timestamps)) if len(t) > 1 \
            else np.abs(t[0] - est.timestamps)
        bad = int(np.sum(off > 1e-3))  # trajectory.tum keeps microseconds
        if bad:
            raise InputError(f"{bad} of the {len(est)} poses in {result / 'trajectory.tum'} are at no frame time of "
                             "this dataset: is this the dataset the result was computed on?", dataset)
    online = read_tum(result / "trajectory_online.tum") if (result / "trajectory_online.tum").is_file() else None
    m = compute_slam_metrics(
        est, gt, frames=int(old.get("frames", len(ds))), lost_frame=old.get("lost_frame"),
        lost_reason=old.get("lost_reason"), range_length=range_length_of(dataset),
        ms_per_frame=old.get("ms_per_frame", {}), online=online, matcher=old.get("matcher", ""),
        detector=old.get("detector", ""), backend=old.get("backend", ""), landmarks=int(old.get("landmarks", 0)),
    )
    if json_out is not None:
        from seedmap.io.atomic import atomic_write_text

        atomic_write_text(Path(json_out), json.dumps(asdict(m), indent=2) + "\n")
    return m
