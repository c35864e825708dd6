"""Running a benchmark: simulation and SLAM jobs in worker processes, resuming, reading results back."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, Future, wait
from pathlib import Path
from typing import Any, Sequence

from seedmap import outputs
from seedmap.associate.features import KINDS as FEATURE_KINDS
from seedmap.config import dump_config
from seedmap.errors import ConfigError, SeedmapError
from seedmap.eval.benchmark.report import write_reports
from seedmap.eval.benchmark.spec import (
    BenchmarkConfig,
    MethodSpec,
    RangeSpec,
    RunRecord,
    dataset_has_gt,
    default_methods,
    safe_name,
)
from seedmap.eval.published import PUBLISHED_MDM, published_key
from seedmap.io import detect_format, open_dataset
from seedmap.io.atomic import atomic_write_text
from seedmap.peers import PEERS
from seedmap.progress import Progress
from seedmap.workers import process_pool

# ------------------------------------------------------------------------------------------------
# jobs (run in worker processes: top-level functions, plain arguments)
# ------------------------------------------------------------------------------------------------


def _worker_init() -> None:
    """One thread per worker: the pool already uses every core."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        import cv2

        cv2.setNumThreads(1)
    except Exception:  # pragma: no cover - cv2 always present
        pass


def simulate_job(preset: str, seed: int, overrides: Sequence[str], out: str) -> str:
    """Simulate one range into ``out`` (atomic; reused when already finished); ``preset`` "" = the simulator's
    defaults."""
    from seedmap.config import load_config
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig, preset_dict

    if is_dataset(Path(out)):
        return out
    cfg = load_config(SimConfig, base=preset_dict(preset) if preset else {}, overrides=[*overrides, f"seed={int(seed)}"])
    simulate_range(cfg, Path(out), overwrite=False, progress=False)
    return out


def slam_job(dataset: str, out: str, matcher: str, detector: str | None, slam_overrides: Sequence[str],
             features: dict, log: str, html_report: bool = False) -> tuple[str, str]:
    """Run one method on one dataset through :func:`run_slam` (a peer through its registry entry, ``features``
    then holding the peer's config); ``(status, note)``, never raises."""
    try:
        from seedmap.slam.pipeline import run_slam

        out_p = Path(out)
        if matcher in PEERS:
            PEERS[matcher].run(dataset, out_p, features, _slam_config(slam_overrides, None),
                               overwrite=out_p.exists(), progress=False)
            return "ok", ""
        config = _slam_config(slam_overrides, features if matcher in FEATURE_KINDS else None)
        run_slam(dataset, out_p, matcher=matcher, detector=detector or "gt", config=config,
                 overwrite=out_p.exists(), progress=False, html_report=html_report, phenotype=False)
        return "ok", ""
    except SeedmapError as e:
        msg = str(e)
        return ("n/a" if msg.startswith("n/a") else "error"), msg
    except Exception as e:  # a crash in one run must not end the benchmark; keep the trace
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(log), traceback.format_exc())
        return "error", f"{type(e).__name__}: {e}".splitlines()[0][:300]


def _slam_config(overrides: Sequence[str], features: dict | None):
    """SlamConfig from overrides; its ``features`` section holds the descriptor-baseline parameters."""
    from seedmap.config import load_config
    from seedmap.slam.config import SlamConfig

    if not features:
        return load_config(SlamConfig, overrides=list(overrides))
    return load_config(SlamConfig, base={"features": features}, overrides=list(overrides))


def run_slam_jobs(jobs: list[tuple], workers: int, progress: bool, label: str) -> list[tuple[str, str]]:
    """Run :func:`slam_job` argument tuples (in a spawn pool when ``workers > 1``); results in order."""
    out: list[tuple[str, str]] = [("error", "not run")] * len(jobs)
    with Progress(len(jobs), label, "run", progress and bool(jobs)) as bar:
        if workers <= 1:
            for i, a in enumerate(jobs):
                out[i] = slam_job(*a)
                bar.advance()
        else:
            with process_pool(workers, _worker_init) as pool:  # killed with this process
                futs = {pool.submit(slam_job, *a): i for i, a in enumerate(jobs)}
                while futs:
                    done, _ = wait(list(futs), return_when=FIRST_COMPLETED)
                    for f in done:
                        out[futs.pop(f)] = f.result()
                        bar.advance()
    return out


# ------------------------------------------------------------------------------------------------
# reading results back (the same code path for fresh and resumed runs)
# ------------------------------------------------------------------------------------------------


def _num(x: Any) -> float | None:
    if x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _read_matches_csv(path: Path) -> tuple[list[int], list[int], list[int]]:
    """Stereo, temporal and RANSAC-inlier match counts per frame from ``matches_per_frame.csv``."""
    if not path.is_file():
        return [], [], []
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    if not rows:
        return [], [], []
    cols = list(rows[0])
    sc = next((c for c in cols if "stereo" in c.lower()), None)
    tc = next((c for c in cols if "temporal" in c.lower()), None)
    ic = next((c for c in cols if "inlier" in c.lower()), None)

    def col(c: str | None) -> list[int]:
        if c is None:
            return []
        return [int(float(r[c])) if r.get(c) not in (None, "") else 0 for r in rows]

    return col(sc), col(tc), col(ic)


def load_run(run_dir: Path, spec: RangeSpec, method: MethodSpec) -> RunRecord:
    """Read a finished result folder (``metrics.json`` = ``asdict(SlamMetrics)``) into a record."""
    m = json.loads((run_dir / "metrics.json").read_text())
    ms = m.get("ms_per_frame")
    if isinstance(ms, dict):
        # whole loop per frame (load + features + association + back-end); else the per-frame stages
        total = _num(ms.get("total_per_frame", ms.get("total")))
        if total is None:
            vals = [_num(v) for k, v in ms.items() if "final" not in k]
            total = sum(v for v in vals if v is not None) if vals else None
    else:
        total = _num(ms)
    stereo, temporal, inliers = _read_matches_csv(run_dir / "matches_per_frame.csv")
    rec = RunRecord(
        scenario=spec.scenario,
        range_name=spec.name,
        method=method.name,
        status="ok",
        range_length_m=_num(m.get("range_length_m")) or spec.length_m,
        frames=m.get("frames"),
        frames_tracked=m.get("frames_tracked"),
        mdm_m=_num(m.get("mdm_m")),
        mdm_fraction=_num(m.get("mdm_fraction")),
        gt_mdm_m=_num(m.get("gt_mdm_m")),
        gt_mdm_fraction=_num(m.get("gt_mdm_fraction")),
        ate_rmse_m=_num(m.get("ate_rmse_m")),
        rpe_trans_rmse_m=_num(m.get("rpe_trans_rmse_m")),
        lost_frame=m.get("lost_frame"),
        lost_reason=m.get("lost_reason"),
        ms_per_frame=total,
        stereo_matches=stereo,
        temporal_matches=temporal,
        inlier_matches=inliers,
    )
    if method.matcher in PEERS:
        rec.note = PEERS[method.matcher].note(run_dir)
    if rec.mdm_fraction is None and rec.mdm_m is not None and rec.range_length_m:
        rec.mdm_fraction = rec.mdm_m / rec.range_length_m
    _attach_published(rec, spec)
    return rec


def _attach_published(rec: RunRecord, spec: RangeSpec) -> None:
    key = published_key(rec.method)
    if spec.scenario == "paper":
        rec.paper_index = spec.paper_index
    if spec.scenario == "paper" and key is not None and spec.paper_index is not None:
        v = PUBLISHED_MDM[key][spec.paper_index]
        rec.published_mdm_m = v
        rec.published_failed = v is None


def is_dataset(p: Path) -> bool:
    """True when ``p`` is a finished seedmap dataset folder."""
    from seedmap.io.seedmap_dataset import SeedmapDataset

    return SeedmapDataset.is_dataset(Path(p))


def _na_record(spec: RangeSpec, m: MethodSpec, why: str) -> RunRecord:
    status = "n/a" if why.startswith("n/a") else "error"
    rec = RunRecord(spec.scenario, spec.name, m.name, status, why, range_length_m=spec.length_m)
    _attach_published(rec, spec)
    return rec


def _finish(out: Path, spec: RangeSpec, m: MethodSpec, status: str, note: str) -> RunRecord:
    rd = run_dir_of(out, spec, m)
    if status == "ok" and (rd / "metrics.json").is_file():
        return load_run(rd, spec, m)
    rec = _na_record(spec, m, note if status == "n/a" else f"error: {note}")
    rec.status = status
    return rec


# ------------------------------------------------------------------------------------------------
# the run
# ------------------------------------------------------------------------------------------------


def run_dir_of(out: Path, spec: RangeSpec, method: MethodSpec) -> Path:
    """Result folder of one (range, method) run below the benchmark folder ``out``."""
    return Path(out) / "runs" / spec.scenario / spec.name / safe_name(method.name)


def run_benchmark(
    ranges: Sequence[RangeSpec],
    out: str | Path,
    cfg: BenchmarkConfig,
    methods: Sequence[MethodSpec] | None = None,
    progress: bool = True,
) -> list[RunRecord]:
    """Simulate what is missing, run every (range, method), write tables and plots into ``out``.

    Resumable: finished datasets and finished result folders are reused. Returns the records in
    (range, method) order.
    """
    out = Path(out)
    if not ranges:
        raise ConfigError("the benchmark has no datasets to run")
    per_range: dict[str, list[MethodSpec]] = {}
    for spec in ranges:  # names and datasets are checked before the output folder exists
        if spec.scenario == "user" and detect_format(spec.dataset) is None:
            open_dataset(spec.dataset)  # raises the loader's one-line "no loader recognises this path"
        if methods is not None:
            per_range[spec.name] = list(methods)
        else:
            has_gt = spec.scenario != "user" or dataset_has_gt(spec.dataset)
            per_range[spec.name] = default_methods(cfg, with_gt=has_gt)
    for name in sorted({m.matcher for ms in per_range.values() for m in ms if not m.unavailable} & set(PEERS)):
        PEERS[name].check(getattr(cfg, name).model_dump(mode="json"))  # e.g. a vocabulary that is not one
    # a benchmark folder of its own is resumed; anything else (the user's folder, a dataset) is refused
    outputs.resume_dir(out, "benchmark", [s.dataset for s in ranges if s.scenario == "user"])
    dump_config(cfg, out / "config.yaml")
    t_start = time.perf_counter()

    def missing(spec: RangeSpec) -> list[MethodSpec]:
        """Available methods of ``spec`` without a finished result folder."""
        return [m for m in per_range[spec.name]
                if not m.unavailable and not (run_dir_of(out, spec, m) / "metrics.json").is_file()]

    results: dict[tuple[str, str], RunRecord] = {}
    todo_slam: list[tuple[RangeSpec, MethodSpec]] = []
    need_sim: list[RangeSpec] = []
    for spec in ranges:
        if spec.scenario != "user" and not is_dataset(spec.dataset):
            need_sim.append(spec)
        for m in per_range[spec.name]:
            rd = run_dir_of(out, spec, m)
            if m.unavailable:
                results[(spec.name, m.name)] = _na_record(spec, m, m.unavailable)
            elif (rd / "metrics.json").is_file():
                results[(spec.name, m.name)] = load_run(rd, spec, m)
            elif spec not in need_sim:
                todo_slam.append((spec, m))
    n_total = len(need_sim) + len(todo_slam) + sum(len(missing(s)) for s in need_sim)

    def slam_args(spec: RangeSpec, m: MethodSpec) -> tuple:
        rd = run_dir_of(out, spec, m)
        log = out / "logs" / f"{spec.scenario}-{spec.name}-{safe_name(m.name)}.log"
        feats: dict = {}
        if m.matcher in FEATURE_KINDS:
            feats = cfg.features_for(m.matcher).model_dump(mode="json", exclude={"gates"})
        elif m.matcher in PEERS:
            feats = getattr(cfg, m.matcher).model_dump(mode="json")
        return (str(spec.dataset), str(rd), m.matcher, m.detector, list(cfg.slam_overrides), feats, str(log),
                cfg.html_reports)

    with Progress(n_total, "benchmark", "job", progress and n_total > 0) as bar:
        if cfg.workers <= 1:
            for spec in need_sim:
                bar.note(f"simulating {spec.name}")
                simulate_job(spec.preset or "", int(spec.seed or 0), spec.sim_overrides, str(spec.dataset))
                bar.advance()
                todo_slam.extend((spec, m) for m in missing(spec))
            for spec, m in todo_slam:
                bar.note(f"{spec.name}: {m.name}")
                status, note = slam_job(*slam_args(spec, m))
                results[(spec.name, m.name)] = _finish(out, spec, m, status, note)
                bar.advance()
        else:
            with process_pool(cfg.workers, _worker_init) as pool:  # killed with this process
                pending: dict[Future, tuple[str, RangeSpec, MethodSpec | None]] = {}
                # simulations first (the long jobs), SLAM runs of already cached ranges fill the gaps
                for spec in need_sim:
                    f = pool.submit(simulate_job, spec.preset or "", int(spec.seed or 0), spec.sim_overrides,
                                    str(spec.dataset))
                    pending[f] = ("sim", spec, None)
                for spec, m in todo_slam:
                    pending[pool.submit(slam_job, *slam_args(spec, m))] = ("slam", spec, m)
                bar.note(f"{len(need_sim)} ranges to simulate, {len(todo_slam)} runs queued")
                while pending:
                    done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                    for f in done:
                        kind, spec, m = pending.pop(f)
                        bar.advance()
                        if kind == "sim":
                            f.result()  # a failed simulation is a real error: stop with its message
                            bar.note(f"simulated {spec.name}")
                            for mm in missing(spec):
                                pending[pool.submit(slam_job, *slam_args(spec, mm))] = ("slam", spec, mm)
                        else:
                            assert m is not None
                            status, note = f.result()
                            results[(spec.name, m.name)] = _finish(out, spec, m, status, note)
                            bar.note(f"{spec.name}: {m.name} {status}")

    ordered = [results[(s.name, m.name)] for s in ranges for m in per_range[s.name] if (s.name, m.name) in results]
    for spec in ranges:  # datasets that could not be loaded for every method
        for m in per_range[spec.name]:
            if (spec.name, m.name) not in results:
                ordered.append(_na_record(spec, m, "error: not run"))
    write_reports(ordered, out, cfg, wall_s=time.perf_counter() - t_start)
    return ordered
