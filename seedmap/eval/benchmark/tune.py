"""Tuning the descriptor baselines on one training range (``seedmap benchmark tune``)."""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from seedmap import outputs
from seedmap.associate.features import KINDS as FEATURE_KINDS
from seedmap.associate.features import FeatureMatcherConfig
from seedmap.config import dump_config
from seedmap.eval.benchmark.report import fmt_cell, md_table
from seedmap.eval.benchmark.run import is_dataset, load_run, run_slam_jobs, simulate_job
from seedmap.eval.benchmark.spec import BenchmarkConfig, MethodSpec, RangeSpec, RunRecord, safe_name, sim_cache_name
from seedmap.io.atomic import atomic_write_text

#: The training range: not one of the evaluated ranges (own seed), default world, 2 m.
TRAIN_RANGE = {"preset": "paper1", "seed": 900, "overrides": ("world.length=2.0",)}

#: One-factor-at-a-time variations around the facts.md defaults, per kind ("common" for all).
TUNING_GRID: dict[str, list[dict[str, Any]]] = {
    "common": [{"ratio": 0.7}, {"ratio": 0.75}, {"ratio": 0.85}, {"ratio": 0.9}, {"clahe": True},
               {"gate_first": True}],
    "sift": [{"sift_contrast_threshold": 0.02}, {"sift_contrast_threshold": 0.01}, {"sift_nfeatures": 3000}],
    "orb": [{"orb_nfeatures": 2000}, {"orb_nfeatures": 5000}, {"orb_fast_threshold": 10},
            {"orb_fast_threshold": 5}],
    "akaze": [{"akaze_threshold": 0.0005}],
    "surf": [{"surf_hessian": 200.0}],
}


@dataclass
class TuneRow:
    """One tuning run: a baseline kind, its parameter overrides and the run's record."""

    kind: str
    label: str
    overrides: dict[str, Any]
    record: RunRecord

    def score(self) -> tuple[float, float, float, float]:
        """Ranking: GT-validated fraction, fraction mapped, mean RANSAC-verified matches per frame
        pair (separates settings that all get lost early), then lower ATE."""
        r = self.record
        if r.status != "ok":
            return (-1.0, -1.0, -1.0, -math.inf)
        inl = r.inlier_matches[1:]
        mean_inl = float(np.mean(inl)) if inl else 0.0
        return (r.gt_mdm_fraction or 0.0, r.mdm_fraction or 0.0, mean_inl,
                -(r.ate_rmse_m if r.ate_rmse_m is not None else math.inf))


def _label(ov: dict[str, Any]) -> str:
    return ",".join(f"{k}={v}" for k, v in ov.items()) or "defaults (facts.md)"


def tune_baselines(
    dataset: str | Path,
    out: str | Path,
    kinds: Sequence[str] = FEATURE_KINDS,
    cfg: BenchmarkConfig | None = None,
    progress: bool = True,
) -> dict[str, dict[str, Any]]:
    """Tune each descriptor baseline on ONE training dataset through the full SLAM pipeline.

    Stage 1 runs the facts.md defaults and every single-parameter variation of
    :data:`TUNING_GRID`; stage 2 combines the best value of every parameter that beat the
    defaults. The winner (by :meth:`TuneRow.score`) is returned per kind as ``{"overrides", "default",
    "best"}`` (``{"overrides", "note"}`` for an unavailable kind) and written to ``tune.json`` /
    ``tune.csv`` / ``tune.md``; finished runs are reused like the benchmark's.
    """
    from seedmap.associate.features import available_kinds

    cfg = cfg or BenchmarkConfig(feature_tuning={})
    out = Path(out)
    outputs.resume_dir(out, "tune", [dataset])  # its own folder is resumed; the user's folder or the data refused
    dump_config(cfg, out / "config.yaml")
    spec = RangeSpec(safe_name(Path(dataset).resolve().name), "tune", Path(dataset))
    avail = available_kinds()
    rows: list[TuneRow] = []
    summary: dict[str, dict[str, Any]] = {}

    def run_stage(cands: list[tuple[str, dict[str, Any]]], tag: str) -> list[TuneRow]:
        jobs, metas = [], []
        done_rows: list[TuneRow] = []
        for kind, ov in cands:
            m = MethodSpec(kind, kind)
            rd = out / "runs" / kind / safe_name(_label(ov))[:120]
            if (rd / "metrics.json").is_file():
                done_rows.append(TuneRow(kind, _label(ov), ov, load_run(rd, spec, m)))
                continue
            feats = FeatureMatcherConfig.model_validate({**cfg.features.model_dump(), **ov})
            jobs.append((str(dataset), str(rd), kind, None, list(cfg.slam_overrides),
                         feats.model_dump(mode="json", exclude={"gates"}), str(out / "logs" / f"{rd.name}.log"),
                         cfg.html_reports))
            metas.append((kind, ov, rd, m))
        for (kind, ov, rd, m), (status, note) in zip(metas, run_slam_jobs(jobs, cfg.workers, progress, tag),
                                                     strict=True):
            rec = load_run(rd, spec, m) if status == "ok" and (rd / "metrics.json").is_file() else \
                RunRecord("tune", spec.name, kind, status, note)
            done_rows.append(TuneRow(kind, _label(ov), ov, rec))
        return done_rows

    live = [k for k in kinds if avail.get(k) is None]
    stage1 = [(k, {}) for k in live] + [(k, ov) for k in live
                                        for ov in TUNING_GRID["common"] + TUNING_GRID.get(k, [])]
    rows += run_stage(stage1, "tuning: single-parameter variations")
    stage2 = []
    for k in live:
        kr = [r for r in rows if r.kind == k]
        base = next(r for r in kr if not r.overrides)
        best_per_param: dict[str, TuneRow] = {}
        for r in kr:
            if r.overrides and r.score() > base.score():
                (p,) = r.overrides
                if p not in best_per_param or r.score() > best_per_param[p].score():
                    best_per_param[p] = r
        combo = {p: r.overrides[p] for p, r in best_per_param.items()}
        if len(combo) > 1:
            stage2.append((k, combo))
    rows += run_stage(stage2, "tuning: combination of the improvements")
    for k in kinds:
        if avail.get(k) is not None:
            summary[k] = {"overrides": {}, "note": avail[k]}
            continue
        kr = [r for r in rows if r.kind == k]
        base = next(r for r in kr if not r.overrides)
        best = max(kr, key=lambda r: r.score())
        if best.score() <= base.score():
            best = base
        summary[k] = {
            "overrides": best.overrides,
            "default": {"mdm_fraction": base.record.mdm_fraction, "gt_mdm_fraction": base.record.gt_mdm_fraction,
                        "ate_rmse_m": base.record.ate_rmse_m, "ms_per_frame": base.record.ms_per_frame},
            "best": {"mdm_fraction": best.record.mdm_fraction, "gt_mdm_fraction": best.record.gt_mdm_fraction,
                     "ate_rmse_m": best.record.ate_rmse_m, "ms_per_frame": best.record.ms_per_frame},
        }
    # files
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["kind", "setting", "status", "mdm_m", "mdm_fraction", "gt_mdm_m", "gt_mdm_fraction", "ate_rmse_m",
                "ms_per_frame", "note"])
    for r in rows:
        rec = r.record
        w.writerow([r.kind, r.label, rec.status] + ["" if v is None else v for v in (
            rec.mdm_m, rec.mdm_fraction, rec.gt_mdm_m, rec.gt_mdm_fraction, rec.ate_rmse_m, rec.ms_per_frame)]
            + [rec.note])
    atomic_write_text(out / "tune.csv", buf.getvalue())
    atomic_write_text(out / "tune.json", json.dumps(summary, indent=2, default=str))
    md_rows = [[r.kind, r.label, fmt_cell(r.record, "mdm_m"), fmt_cell(r.record, "gt_mdm_m"),
                fmt_cell(r.record, "ate_rmse_m", 3), f"{r.score()[2]:.1f}",
                "" if r.record.ms_per_frame is None else f"{r.record.ms_per_frame:.0f}"] for r in rows]
    md = (f"# Baseline tuning on {dataset}\n\nSelection: GT-validated fraction mapped, then fraction mapped, "
          f"then RANSAC-verified matches per frame pair, then ATE.\n\n"
          + md_table(["kind", "setting", "MDM (m)", "GT-MDM (m)", "ATE (m)", "verified matches / pair", "ms/frame"],
                      md_rows)
          + "\n**Chosen**\n\n" + "\n".join(f"- {k}: {v.get('note') or _label(v['overrides'])}"
                                          for k, v in summary.items()) + "\n")
    atomic_write_text(out / "tune.md", md)
    return summary


def training_range(cfg: BenchmarkConfig) -> Path:
    """Simulate (or reuse) the tuning range: default world, own seed, 2 m (see :data:`TRAIN_RANGE`)."""
    ov = tuple(cfg.sim_overrides) + tuple(TRAIN_RANGE["overrides"])
    p = Path(cfg.data_dir) / sim_cache_name(f"train-{TRAIN_RANGE['preset']}", int(TRAIN_RANGE["seed"]), ov)
    if not is_dataset(p):
        simulate_job(str(TRAIN_RANGE["preset"]), int(TRAIN_RANGE["seed"]), ov, str(p))
    return p
