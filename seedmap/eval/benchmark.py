"""The paper's comparison (its Tables 1 and 2), reproducible in one command.

``seedmap benchmark paper`` simulates the eight ranges of the paper's lengths (simulator presets
``paper1`` .. ``paper8``, fixed seeds 101 .. 108 unless ``--seeds`` says otherwise) into a cache
folder, runs every method through the *same* SLAM pipeline (:func:`seedmap.slam.pipeline.run_slam`)
and writes a Table-1-like comparison: maximum distance mapped (MDM) per range and method with the
mean fraction of range mapped, our ground-truth-validated MDM and ATE beside it, the published
numbers (real field data) side by side, per-method timing, a bar chart and per-frame plots of the
surviving matches. ``seedmap benchmark run DATASET...`` does the same on the user's own datasets
(without GT the GT-validated columns are "–").

Methods: ``seeds+<detector>`` for every available detector (``gt`` = ground-truth oracle, ``fast``;
``frcnn-pix2pix`` only when trained weights exist) and the descriptor baselines ``sift``, ``surf``,
``orb``, ``akaze``. A baseline the installed OpenCV lacks becomes an "n/a" row with the reason.

``--scenes`` adds harder held-out variations of every range (different seed = preset seed + 1000,
stronger wind, exposure swings, mostly loose panicles, more leaves); they are reported in their own
table, never averaged with the paper ranges.

Design for a 2-core machine: simulated ranges are cached (``data_dir``; a finished dataset is
reused), ranges and methods run as separate jobs in a ``ProcessPoolExecutor`` (``workers``), each
job single-threaded, and the run resumes: a method's result folder that already holds
``metrics.json`` is not recomputed.

Cell conventions: "fail" = the method mapped nothing (MDM 0), "n/a" = method unavailable,
"error" = the run raised (message in ``results.csv`` and ``logs/``), "–" = not measurable here
(no ground truth or unknown range length).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
from pydantic import Field

from seedmap.associate.features import KINDS as FEATURE_KINDS
from seedmap.associate.features import TUNED, FeatureMatcherConfig
from seedmap.config import ConfigModel, config_to_yaml, dump_config
from seedmap.errors import ConfigError, InputError, SeedmapError
from seedmap.eval.published import (
    PAPER_RANGE_LENGTHS,
    PUBLISHED_MDM,
    PUBLISHED_TITLES,
    published_fraction,
    published_key,
    published_mean_fraction,
)
from seedmap.io.atomic import atomic_write_bytes, atomic_write_text

#: Harder held-out scene variations (simulator config overrides) used by ``--scenes``.
DEFAULT_SCENE_OVERRIDES: tuple[str, ...] = (
    "wind.panicle_amplitude_deg=5.0",  # stronger wind (default 1.5 deg)
    "wind.leaf_amplitude_deg=9.0",  # (default 3 deg)
    "imaging.exposure_jitter=0.25",  # exposure swings frame to frame (default 0.04)
    "panicle.loose_fraction=0.9",  # mostly loose panicles (default 0.4)
    "world.leaves_min=8",  # more leaf occlusion (default 5..8 leaves per plant)
    "world.leaves_max=12",
)
#: Seed offset of the held-out scene variations (preset seed + this).
SCENE_SEED_OFFSET = 1000


class BenchmarkConfig(ConfigModel):
    """What ``seedmap benchmark`` runs; written as ``config.yaml`` next to the results."""

    data_dir: str = Field("data/benchmark", description="cache of simulated ranges (reused when finished)")
    presets: list[str] = Field(default_factory=lambda: [f"paper{k}" for k in range(1, 9)])
    seeds: list[int] | None = Field(None, description="simulator seed per preset (default: the preset's own)")
    sim_overrides: list[str] = Field(default_factory=list, description="simulator key=value for every range")
    scenes: bool = Field(False, description="also run the harder held-out scene variations")
    scene_overrides: list[str] = Field(default_factory=lambda: list(DEFAULT_SCENE_OVERRIDES))
    methods: list[str] | None = Field(
        None, description="methods to run (default: seeds+<every available detector>, sift, surf, orb, akaze)")
    detectors: list[str] | None = Field(None, description="detectors for the seeds matcher (default: available)")
    slam_overrides: list[str] = Field(default_factory=list, description="SlamConfig key=value for every run")
    features: FeatureMatcherConfig = Field(default_factory=FeatureMatcherConfig)
    feature_tuning: dict[str, dict[str, Any]] = Field(
        default_factory=lambda: {k: dict(v) for k, v in TUNED.items()},
        description="per-kind overrides of `features` (default: the values tuned on the training range)")
    workers: int = Field(2, ge=1, le=64)
    html_reports: bool = Field(
        False, description="also write each run's report.html (about 2.7 s CPU per run on a paper range; "
                           "report.md, topview.png and the benchmark's own plots are always written)")

    def features_for(self, kind: str) -> FeatureMatcherConfig:
        """The descriptor-baseline parameters used for ``kind`` (base + its tuned overrides)."""
        upd = self.feature_tuning.get(kind, {})
        return FeatureMatcherConfig.model_validate({**self.features.model_dump(), **upd})


# ------------------------------------------------------------------------------------------------
# records
# ------------------------------------------------------------------------------------------------


@dataclass
class RangeSpec:
    """One dataset of the benchmark (simulated from a preset, or the user's own)."""

    name: str
    scenario: str  # "paper", "scenes" or "user"
    dataset: Path
    length_m: float | None = None
    preset: str | None = None
    seed: int | None = None
    sim_overrides: tuple[str, ...] = ()
    paper_index: int | None = None  # 0..7: row of the published table


@dataclass
class MethodSpec:
    """A matcher (+ detector for the seeds matcher); ``unavailable`` holds the n/a reason."""

    name: str
    matcher: str
    detector: str | None = None
    unavailable: str | None = None


@dataclass
class RunRecord:
    """One (range, method) outcome: the SlamMetrics fields the tables need plus status."""

    scenario: str
    range_name: str
    method: str
    status: str  # "ok", "n/a", "error"
    note: str = ""
    range_length_m: float | None = None
    frames: int | None = None
    frames_tracked: int | None = None
    mdm_m: float | None = None
    mdm_fraction: float | None = None
    gt_mdm_m: float | None = None
    gt_mdm_fraction: float | None = None
    ate_rmse_m: float | None = None
    rpe_trans_rmse_m: float | None = None
    lost_frame: int | None = None
    lost_reason: str | None = None
    ms_per_frame: float | None = None
    published_mdm_m: float | None = None
    published_failed: bool = False
    paper_index: int | None = None  # row of the published table (paper scenario only)
    stereo_matches: list[int] = field(default_factory=list)
    temporal_matches: list[int] = field(default_factory=list)
    inlier_matches: list[int] = field(default_factory=list)


_PER_FRAME = ("stereo_matches", "temporal_matches", "inlier_matches")
CSV_FIELDS = [f.name for f in fields(RunRecord) if f.name not in _PER_FRAME]


# ------------------------------------------------------------------------------------------------
# planning
# ------------------------------------------------------------------------------------------------


def _safe(s: str) -> str:
    return "".join(c if c.isalnum() or c in "-_.+" else "_" for c in s)


def _sim_cache_name(preset: str, seed: int, overrides: Sequence[str]) -> str:
    import hashlib

    h = hashlib.sha1("\n".join(overrides).encode()).hexdigest()[:8] if overrides else "default"
    return f"{preset}-s{seed}-{h}"


def paper_ranges(cfg: BenchmarkConfig) -> list[RangeSpec]:
    """The simulated ranges of the paper benchmark (and their harder variations with ``scenes``)."""
    from seedmap.config import load_config
    from seedmap.sim.config import SimConfig, preset_dict

    if cfg.seeds is not None and len(cfg.seeds) != len(cfg.presets):
        raise ConfigError(f"--seeds gives {len(cfg.seeds)} seeds for {len(cfg.presets)} ranges; give one per range")
    out: list[RangeSpec] = []
    data = Path(cfg.data_dir)
    for k, preset in enumerate(cfg.presets):
        base = preset_dict(preset)
        seed = int(cfg.seeds[k]) if cfg.seeds is not None else int(base.get("seed", 0))
        ov = tuple(cfg.sim_overrides)
        length = float(load_config(SimConfig, base=base, overrides=list(ov)).world.length)
        idx = int(preset[5:]) - 1 if preset.startswith("paper") and preset[5:].isdigit() else None
        if idx is not None and not 0 <= idx < len(PAPER_RANGE_LENGTHS):
            idx = None
        out.append(RangeSpec(preset, "paper", data / _sim_cache_name(preset, seed, ov), length, preset, seed, ov,
                             idx))
    if cfg.scenes:
        for spec in list(out):
            seed = int(spec.seed or 0) + SCENE_SEED_OFFSET
            ov = tuple(cfg.sim_overrides) + tuple(cfg.scene_overrides)
            load_config(SimConfig, base=preset_dict(spec.preset or ""), overrides=list(ov))  # fail early
            out.append(RangeSpec(f"{spec.name}-hard", "scenes", data / _sim_cache_name(spec.preset, seed, ov),
                                 spec.length_m, spec.preset, seed, ov, spec.paper_index))
    return out


def user_ranges(datasets: Sequence[str | Path]) -> list[RangeSpec]:
    """The user's own datasets (any format :func:`seedmap.io.open_dataset` reads)."""
    out: list[RangeSpec] = []
    seen: set[str] = set()
    for d in datasets:
        p = Path(d)
        if not p.exists():
            raise InputError("dataset not found", p)
        name = _safe(p.resolve().name) or "dataset"
        while name in seen:
            name += "_"
        seen.add(name)
        out.append(RangeSpec(name, "user", p))
    return out


def _dataset_has_gt(path: Path) -> bool:
    try:
        from seedmap.io import open_dataset

        return open_dataset(path).gt_trajectory() is not None
    except SeedmapError:
        return False


def default_methods(cfg: BenchmarkConfig, with_gt: bool = True) -> list[MethodSpec]:
    """``seeds+<detector>`` for each available detector, then every descriptor baseline.

    ``frcnn-pix2pix`` joins only when trained weights (and torch) are present; the ``gt`` oracle
    only where the data has ground truth; the detector that ``fast`` stands for (``fast-cnn`` or
    ``fast-classic``, :func:`seedmap.detect.fast.fast_alias`) is not run a second time under its own name.
    """
    from seedmap.associate.features import available_kinds
    from seedmap.detect import available_detectors, default_detector_name

    if cfg.detectors is not None:
        dets = list(cfg.detectors)
    else:
        from seedmap.detect.fast import fast_alias

        dets = []
        same_as_fast = fast_alias()  # `fast` is one of these two; running both would repeat a method
        for d in available_detectors():
            if d == "frcnn-pix2pix" and default_detector_name() != "frcnn-pix2pix":
                continue  # no trained weights shipped
            if d == same_as_fast:
                continue
            dets.append(d)
        dets.sort(key=lambda d: {"gt": 0, "fast": 1}.get(d, 2))
    avail = available_kinds()
    methods: list[MethodSpec] = []
    for d in dets:
        why = None if (d != "gt" or with_gt) else "n/a — oracle needs ground truth"
        methods.append(MethodSpec(f"seeds+{d}", "seeds", d, why))
    for k in FEATURE_KINDS:
        methods.append(MethodSpec(k, k, None, avail.get(k)))
    if cfg.methods is not None:
        by_name = {m.name: m for m in methods}
        chosen = []
        for name in cfg.methods:
            if name in by_name:
                chosen.append(by_name[name])
            elif name.startswith("seeds+"):
                chosen.append(MethodSpec(name, "seeds", name.split("+", 1)[1]))
            else:
                raise ConfigError(f"unknown benchmark method {name!r} (known: {', '.join(by_name)})")
        methods = chosen
    return methods


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
    """Simulate one range into ``out`` (atomic; reused when already finished)."""
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig, preset_dict
    from seedmap.config import load_config

    if SeedmapDataset.is_dataset(Path(out)):
        return out
    cfg = load_config(SimConfig, base=preset_dict(preset), overrides=[*overrides, f"seed={int(seed)}"])
    simulate_range(cfg, Path(out), overwrite=False, progress=False)
    return out


def slam_job(dataset: str, out: str, matcher: str, detector: str | None, slam_overrides: Sequence[str],
             features: dict, log: str, html_report: bool = False) -> tuple[str, str]:
    """Run one method on one dataset through :func:`run_slam`; ``(status, note)``, never raises."""
    try:
        from seedmap.slam.pipeline import run_slam

        config = _slam_config(slam_overrides, features if matcher in FEATURE_KINDS else None)
        out_p = Path(out)
        run_slam(dataset, out_p, matcher=matcher, detector=detector or "gt", config=config,
                 overwrite=out_p.exists(), progress=False, html_report=html_report)
        return "ok", ""
    except SeedmapError as e:
        msg = str(e)
        return ("n/a" if msg.startswith("n/a") else "error"), msg
    except Exception as e:  # a crash in one run must not end the benchmark; keep the trace
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(log), traceback.format_exc())
        return "error", f"{type(e).__name__}: {e}".splitlines()[0][:300]


def _slam_config(overrides: Sequence[str], features: dict | None):
    """SlamConfig from overrides, plus a ``features`` section for the descriptor baselines.

    ``make_matcher`` hands the SLAM config to ``FeatureMatcher``, which reads its ``gates`` (shared
    with the seed matcher) and ``features``. When ``SlamConfig`` has no ``features`` field, a
    subclass adds one, so the resolved ``config.yaml`` of every run records the parameters used.
    """
    from seedmap.config import load_config
    from seedmap.slam.config import SlamConfig

    if not features:
        return load_config(SlamConfig, overrides=list(overrides))
    cls = SlamConfig if "features" in SlamConfig.model_fields else _slam_config_with_features()
    return load_config(cls, base={"features": features}, overrides=list(overrides))


_SLAM_WITH_FEATURES: list[type] = []


def _slam_config_with_features() -> type:
    from seedmap.slam.config import SlamConfig

    if not _SLAM_WITH_FEATURES:
        class BaselineSlamConfig(SlamConfig):
            """SlamConfig + the descriptor-baseline parameters (``features``)."""

            features: FeatureMatcherConfig = Field(default_factory=FeatureMatcherConfig)

        _SLAM_WITH_FEATURES.append(BaselineSlamConfig)
    return _SLAM_WITH_FEATURES[0]


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


# ------------------------------------------------------------------------------------------------
# the run
# ------------------------------------------------------------------------------------------------


def run_dir_of(out: Path, spec: RangeSpec, method: MethodSpec) -> Path:
    return Path(out) / "runs" / spec.scenario / spec.name / _safe(method.name)


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
    from seedmap.io.atomic import check_output_parent

    out = Path(out)
    check_output_parent(out)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, out / "config.yaml")
    if not ranges:
        raise ConfigError("the benchmark has no datasets to run")
    t_start = time.perf_counter()

    per_range: dict[str, list[MethodSpec]] = {}
    for spec in ranges:
        if methods is not None:
            per_range[spec.name] = list(methods)
        else:
            has_gt = spec.scenario != "user" or _dataset_has_gt(spec.dataset)
            per_range[spec.name] = default_methods(cfg, with_gt=has_gt)

    results: dict[tuple[str, str], RunRecord] = {}
    todo_slam: list[tuple[RangeSpec, MethodSpec]] = []
    need_sim: list[RangeSpec] = []
    for spec in ranges:
        if spec.scenario != "user" and not _is_dataset(spec.dataset):
            need_sim.append(spec)
        for m in per_range[spec.name]:
            rd = run_dir_of(out, spec, m)
            if m.unavailable:
                results[(spec.name, m.name)] = _na_record(spec, m, m.unavailable)
            elif (rd / "metrics.json").is_file():
                results[(spec.name, m.name)] = load_run(rd, spec, m)
            elif spec not in need_sim:
                todo_slam.append((spec, m))
    n_total = len(need_sim) + len(todo_slam) + sum(
        1 for s in need_sim for m in per_range[s.name] if not m.unavailable
        and not (run_dir_of(out, s, m) / "metrics.json").is_file())

    def slam_args(spec: RangeSpec, m: MethodSpec) -> tuple:
        rd = run_dir_of(out, spec, m)
        log = out / "logs" / f"{spec.scenario}-{spec.name}-{_safe(m.name)}.log"
        feats = (cfg.features_for(m.matcher).model_dump(mode="json", exclude={"gates"})
                 if m.matcher in FEATURE_KINDS else {})
        return (str(spec.dataset), str(rd), m.matcher, m.detector, list(cfg.slam_overrides), feats, str(log),
                cfg.html_reports)

    bar = _Progress(progress, n_total)
    try:
        if cfg.workers <= 1:
            for spec in need_sim:
                bar.describe(f"simulating {spec.name}")
                simulate_job(spec.preset or "", int(spec.seed or 0), spec.sim_overrides, str(spec.dataset))
                bar.advance()
                todo_slam.extend((spec, m) for m in per_range[spec.name] if not m.unavailable
                                 and not (run_dir_of(out, spec, m) / "metrics.json").is_file())
            for spec, m in todo_slam:
                bar.describe(f"{spec.name}: {m.name}")
                status, note = slam_job(*slam_args(spec, m))
                results[(spec.name, m.name)] = _finish(out, spec, m, status, note)
                bar.advance()
        else:
            import multiprocessing as mp

            ctx = mp.get_context("spawn")
            with ProcessPoolExecutor(max_workers=cfg.workers, mp_context=ctx, initializer=_worker_init) as pool:
                pending: dict[Future, tuple[str, RangeSpec, MethodSpec | None]] = {}
                # simulations first (the long jobs), SLAM runs of already cached ranges fill the gaps
                for spec in need_sim:
                    f = pool.submit(simulate_job, spec.preset or "", int(spec.seed or 0), spec.sim_overrides,
                                    str(spec.dataset))
                    pending[f] = ("sim", spec, None)
                for spec, m in todo_slam:
                    pending[pool.submit(slam_job, *slam_args(spec, m))] = ("slam", spec, m)
                bar.describe(f"{len(need_sim)} ranges to simulate, {len(todo_slam)} runs queued")
                while pending:
                    done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                    for f in done:
                        kind, spec, m = pending.pop(f)
                        bar.advance()
                        if kind == "sim":
                            f.result()  # a failed simulation is a real error: stop with its message
                            bar.describe(f"simulated {spec.name}")
                            for mm in per_range[spec.name]:
                                if mm.unavailable or (run_dir_of(out, spec, mm) / "metrics.json").is_file():
                                    continue
                                pending[pool.submit(slam_job, *slam_args(spec, mm))] = ("slam", spec, mm)
                        else:
                            assert m is not None
                            status, note = f.result()
                            results[(spec.name, m.name)] = _finish(out, spec, m, status, note)
                            bar.describe(f"{spec.name}: {m.name} {status}")
    finally:
        bar.close()

    ordered = [results[(s.name, m.name)] for s in ranges for m in per_range[s.name] if (s.name, m.name) in results]
    for spec in ranges:  # datasets that could not be loaded for every method
        for m in per_range[spec.name]:
            if (spec.name, m.name) not in results:
                ordered.append(_na_record(spec, m, "error: not run"))
    write_reports(ordered, out, cfg, wall_s=time.perf_counter() - t_start)
    return ordered


def _is_dataset(p: Path) -> bool:
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


class _Progress:
    """A rich progress bar (or nothing) over benchmark jobs."""

    def __init__(self, enabled: bool, total: int) -> None:
        self._p = None
        if enabled and total > 0:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._p = Progress(TextColumn("benchmark"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                               TextColumn("{task.description}"))
            self._p.start()
            self._task = self._p.add_task("", total=total)

    def describe(self, text: str) -> None:
        if self._p is not None:
            self._p.update(self._task, description=text)

    def advance(self) -> None:
        if self._p is not None:
            self._p.advance(self._task)

    def close(self) -> None:
        if self._p is not None:
            self._p.stop()


# ------------------------------------------------------------------------------------------------
# tables and plots
# ------------------------------------------------------------------------------------------------


def _fmt_m(rec: RunRecord | None, attr: str = "mdm_m", digits: int = 2) -> str:
    if rec is None:
        return ""
    if rec.status == "n/a":
        return "n/a"
    if rec.status != "ok":
        return "error"
    v = getattr(rec, attr)
    if v is None:
        return "–"
    if attr in ("mdm_m", "gt_mdm_m") and v <= 0.0:
        return "fail"
    return f"{v:.{digits}f}"


def _mean(vals: Iterable[float | None]) -> float | None:
    v = [x for x in vals if x is not None]
    return float(np.mean(v)) if v else None


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.0f}%"


def _methods_in(records: Sequence[RunRecord]) -> list[str]:
    seen: list[str] = []
    for r in records:
        if r.method not in seen:
            seen.append(r.method)
    return seen


def _ranges_in(records: Sequence[RunRecord]) -> list[str]:
    seen: list[str] = []
    for r in records:
        if r.range_name not in seen:
            seen.append(r.range_name)
    return seen


def summarize(records: Sequence[RunRecord]) -> dict[str, dict[str, dict[str, float | None]]]:
    """``{scenario: {method: {mean_fraction, mean_gt_fraction, mean_ate_m, ms_per_frame, ranges}}}``."""
    out: dict[str, dict[str, dict[str, float | None]]] = {}
    for sc in dict.fromkeys(r.scenario for r in records):
        rs = [r for r in records if r.scenario == sc]
        out[sc] = {}
        for m in _methods_in(rs):
            mr = [r for r in rs if r.method == m and r.status == "ok"]
            out[sc][m] = {
                "mean_fraction": _mean(r.mdm_fraction for r in mr),
                "mean_gt_fraction": _mean(r.gt_mdm_fraction for r in mr),
                "mean_ate_m": _mean(r.ate_rmse_m for r in mr),
                "ms_per_frame": _mean(r.ms_per_frame for r in mr),
                "ranges": float(len(mr)),
                "available": float(any(r.status != "n/a" for r in rs if r.method == m)),
            }
    return out


def _md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _range_label(recs: Sequence[RunRecord], name: str) -> str:
    L = next((r.range_length_m for r in recs if r.range_name == name and r.range_length_m), None)
    return f"{name} ({L:.2f})" if L else name


def scenario_tables(records: Sequence[RunRecord], scenario: str) -> str:
    """Markdown: Table-1-like MDM table, GT-validated MDM, ATE and timing for one scenario."""
    rs = [r for r in records if r.scenario == scenario]
    if not rs:
        return ""
    methods = _methods_in(rs)
    names = _ranges_in(rs)
    by = {(r.range_name, r.method): r for r in rs}
    summ = summarize(rs)[scenario]
    header = ["range (m)"] + methods
    parts = []

    def block(title: str, attr: str, frac_attr: str | None, digits: int = 2) -> str:
        rows = [[_range_label(rs, n)] + [_fmt_m(by.get((n, m)), attr, digits) for m in methods] for n in names]
        if frac_attr is not None:
            rows.append(["**mean fraction**"] + [
                "n/a" if all(by[(n, m)].status == "n/a" for n in names if (n, m) in by)
                else _pct(summ[m][frac_attr]) for m in methods])
        return f"**{title}**\n\n" + _md_table(header, rows)

    parts.append(block("Maximum distance mapped (m), this run", "mdm_m", "mean_fraction"))
    parts.append(block("GT-validated maximum distance mapped (m): position error within max(5 % of distance, "
                       "5 cm)", "gt_mdm_m", "mean_gt_fraction"))
    parts.append(block("ATE RMSE (m) over the tracked part", "ate_rmse_m", None, 3))
    timing = [["ms / frame (mean over ranges)"] + [
        "n/a" if summ[m]["ms_per_frame"] is None else f"{summ[m]['ms_per_frame']:.0f}" for m in methods]]
    parts.append("**Timing**\n\n" + _md_table(["method"] + methods, timing))
    notes = sorted({f"{r.method}: {r.note}" for r in rs if r.status != "ok" and r.note})
    if notes:
        parts.append("Notes: " + "; ".join(notes) + "\n")
    return "\n".join(parts)


def published_table() -> str:
    """The paper's Tables 1 and 2 (real field data), with their mean-fraction row."""
    keys = list(PUBLISHED_MDM)
    header = ["range (m)"] + [PUBLISHED_TITLES[k] for k in keys]
    rows = []
    for i, L in enumerate(PAPER_RANGE_LENGTHS):
        rows.append([f"paper{i + 1} ({L:.2f})"] + [
            "fail" if PUBLISHED_MDM[k][i] is None else f"{PUBLISHED_MDM[k][i]:.2f}" for k in keys])
    rows.append(["**mean fraction**"] + [_pct(published_mean_fraction(k)) for k in keys])
    return "**Published (real field data)** — the paper's Tables 1 and 2, not re-measured here\n\n" + _md_table(
        header, rows)


def side_by_side_table(records: Sequence[RunRecord]) -> str:
    """Mean fraction mapped per method: this run (paper ranges) next to the published value."""
    rs = [r for r in records if r.scenario == "paper"]
    if not rs:
        return ""
    summ = summarize(rs)["paper"]
    rows = []
    for m in _methods_in(rs):
        key = published_key(m)
        pub = _pct(published_mean_fraction(key)) if key else "–"
        s = summ[m]
        na = all(r.status == "n/a" for r in rs if r.method == m)
        rows.append([m, "n/a" if na else _pct(s["mean_fraction"]), "n/a" if na else _pct(s["mean_gt_fraction"]),
                     pub])
    rows.append(["orb-slam2 (not run here)", "–", "–", _pct(published_mean_fraction("orb-slam2"))])
    return "**Mean fraction of range mapped: simulated paper ranges vs published (real field data)**\n\n" + \
        _md_table(["method", "this run", "this run, GT-validated", "published (real field data)"], rows)


def records_csv(records: Sequence[RunRecord]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in records:
        d = asdict(r)
        w.writerow({k: ("" if d[k] is None else d[k]) for k in CSV_FIELDS})
    return buf.getvalue()


def table1_csv(records: Sequence[RunRecord]) -> str:
    """Wide table: one row per (scenario, range); per method MDM, GT-MDM, ATE; published columns."""
    methods = _methods_in(records)
    pub_keys = list(PUBLISHED_MDM)
    header = ["scenario", "range", "length_m"]
    for m in methods:
        header += [f"{m} mdm_m", f"{m} gt_mdm_m", f"{m} ate_m", f"{m} ms_per_frame"]
    header += [f"published {PUBLISHED_TITLES[k]} mdm_m" for k in pub_keys]
    by = {(r.scenario, r.range_name, r.method): r for r in records}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for sc in dict.fromkeys(r.scenario for r in records):
        rs = [r for r in records if r.scenario == sc]
        for n in _ranges_in(rs):
            L = next((r.range_length_m for r in rs if r.range_name == n and r.range_length_m), None)
            row: list[Any] = [sc, n, "" if L is None else f"{L:.3f}"]
            for m in methods:
                r = by.get((sc, n, m))
                row += [_fmt_m(r, "mdm_m", 3), _fmt_m(r, "gt_mdm_m", 3), _fmt_m(r, "ate_rmse_m", 4),
                        "" if r is None or r.ms_per_frame is None else f"{r.ms_per_frame:.1f}"]
            pidx = next((r.paper_index for r in rs if r.range_name == n), None) if sc == "paper" else None
            for k in pub_keys:
                if pidx is None:
                    row.append("")
                else:
                    v = PUBLISHED_MDM[k][pidx]
                    row.append("fail" if v is None else f"{v:.2f}")
            w.writerow(row)
    return buf.getvalue()


def _png_bytes(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def bar_chart_png(records: Sequence[RunRecord]) -> bytes:
    """Grouped bars of the fraction of each range mapped per method (+ GT-validated dots, published)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(r.scenario for r in records))
    show_pub = "paper" in scenarios
    n_panels = len(scenarios) + (1 if show_pub else 0)
    fig, axes = plt.subplots(n_panels, 1, figsize=(11, 3.4 * n_panels), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for ax, sc in zip(axes[:, 0], scenarios, strict=False):
        rs = [r for r in records if r.scenario == sc]
        methods = [m for m in _methods_in(rs) if any(r.status == "ok" for r in rs if r.method == m)]
        names = _ranges_in(rs)
        by = {(r.range_name, r.method): r for r in rs}
        width = 0.8 / max(1, len(methods))
        summ = summarize(rs)[sc]
        x = np.arange(len(names))
        for j, m in enumerate(methods):
            vals = [by[(n, m)].mdm_fraction if (n, m) in by and by[(n, m)].mdm_fraction is not None else 0.0
                    for n in names]
            gts = [by[(n, m)].gt_mdm_fraction if (n, m) in by else None for n in names]
            mf = summ[m]["mean_fraction"]
            ax.bar(x + (j - (len(methods) - 1) / 2) * width, vals, width, color=cmap(j % 10),
                   label=f"{m} (mean {_pct(mf)})")
            gx = [x[i] + (j - (len(methods) - 1) / 2) * width for i, g in enumerate(gts) if g is not None]
            ax.plot(gx, [g for g in gts if g is not None], "k.", ms=5)
        ax.set_xticks(x, [_range_label(rs, n) for n in names], fontsize=8)
        ax.set_ylim(0, 1.08)
        ax.set_ylabel("fraction mapped")
        ax.set_title(f"{sc}: maximum distance mapped / range length (dots: GT-validated)", fontsize=10)
        if methods:  # every run failed: no bars, and matplotlib warns about an empty legend
            ax.legend(fontsize=7, ncol=4, loc="upper left")
    if show_pub:
        ax = axes[-1, 0]
        keys = list(PUBLISHED_MDM)
        width = 0.8 / len(keys)
        x = np.arange(len(PAPER_RANGE_LENGTHS))
        for j, k in enumerate(keys):
            ax.bar(x + (j - (len(keys) - 1) / 2) * width, published_fraction(k), width, color=cmap((j + 3) % 10),
                   hatch="//", alpha=0.8, label=f"{PUBLISHED_TITLES[k]} (mean {_pct(published_mean_fraction(k))})")
        ax.set_xticks(x, [f"paper{i + 1} ({L:.2f})" for i, L in enumerate(PAPER_RANGE_LENGTHS)], fontsize=8)
        ax.set_ylim(0, 1.08)
        ax.set_ylabel("fraction mapped")
        ax.set_title("published (real field data), the paper's Tables 1 and 2", fontsize=10)
        ax.legend(fontsize=7, ncol=3, loc="upper left")
    fig.tight_layout()
    data = _png_bytes(fig)
    plt.close(fig)
    return data


def matches_plot_png(records: Sequence[RunRecord], scenario: str, range_name: str) -> bytes | None:
    """Per-frame surviving matches of every method on one range: stereo (top), temporal and
    RANSAC-verified temporal inliers (bottom); a dotted vertical line marks where a method got lost."""
    rs = [r for r in records if r.scenario == scenario and r.range_name == range_name and r.status == "ok"
          and (r.stereo_matches or r.temporal_matches)]
    if not rs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.6), sharex=True)
    cmap = plt.get_cmap("tab10")
    for j, r in enumerate(rs):
        c = cmap(j % 10)
        if r.stereo_matches:
            ax1.plot(np.arange(len(r.stereo_matches)), r.stereo_matches, "-", color=c, lw=1.2, label=r.method)
        if r.temporal_matches:
            ax2.plot(np.arange(len(r.temporal_matches)), r.temporal_matches, "-", color=c, lw=1.2,
                     label=f"{r.method} temporal")
        if r.inlier_matches:
            ax2.plot(np.arange(len(r.inlier_matches)), r.inlier_matches, "--", color=c, lw=1.0,
                     label=f"{r.method} inliers")
        if r.lost_frame is not None:
            for ax in (ax1, ax2):
                ax.axvline(int(r.lost_frame), color=c, lw=0.8, ls=":")
    for ax, what in ((ax1, "stereo matches"), (ax2, "temporal matches")):
        ax.set_yscale("symlog", linthresh=10)
        ax.set_ylim(bottom=0)
        ax.set_ylabel(what)
        ax.legend(fontsize=7, ncol=2)
    ax2.set_xlabel("frame")
    ax1.set_title(f"{scenario} / {range_name}: surviving matches per frame (dotted: lost)", fontsize=10)
    fig.tight_layout()
    data = _png_bytes(fig)
    plt.close(fig)
    return data


def write_reports(records: Sequence[RunRecord], out: str | Path, cfg: BenchmarkConfig | None = None,
                  wall_s: float | None = None) -> dict[str, Path]:
    """Write results.csv, table1.csv, report.md, summary.json, mdm_bars.png, matches/*.png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}

    def put_text(name: str, text: str) -> None:
        atomic_write_text(out / name, text)
        written[name] = out / name

    put_text("results.csv", records_csv(records))
    put_text("table1.csv", table1_csv(records))
    summary = {"wall_s": wall_s, "scenarios": summarize(records)}
    put_text("summary.json", json.dumps(summary, indent=2))
    md = ["# seedmap benchmark\n"]
    if wall_s is not None:
        md.append(f"Wall time: {wall_s / 60:.1f} min.\n")
    titles = {"paper": "Simulated paper ranges (presets paper1..paper8)",
              "scenes": "Harder held-out scene variations (not averaged with the paper ranges)",
              "user": "Your datasets"}
    for sc in dict.fromkeys(r.scenario for r in records):
        md.append(f"## {titles.get(sc, sc)}\n")
        md.append(scenario_tables(records, sc))
    if any(r.scenario == "paper" for r in records):
        md.append("## Side by side with the paper\n")
        md.append(side_by_side_table(records))
        md.append(published_table())
    if cfg is not None:
        md.append("## Configuration\n\n```yaml\n" + config_to_yaml(cfg) + "```\n")
    md.append("Cells: fail = mapped nothing, n/a = method unavailable, error = run failed (see results.csv and "
              "logs/), – = needs ground truth or a known range length.\n")
    put_text("report.md", "\n".join(md))
    atomic_write_bytes(out / "mdm_bars.png", bar_chart_png(records))
    written["mdm_bars.png"] = out / "mdm_bars.png"
    for sc in dict.fromkeys(r.scenario for r in records):
        for n in _ranges_in([r for r in records if r.scenario == sc]):
            png = matches_plot_png(records, sc, n)
            if png is not None:
                p = out / "matches" / f"{sc}-{_safe(n)}.png"
                atomic_write_bytes(p, png)
                written[f"matches/{p.name}"] = p
    return written


# ------------------------------------------------------------------------------------------------
# tuning the baselines on one training range
# ------------------------------------------------------------------------------------------------

#: The training range for tuning: not one of the evaluated ranges (own seed), default world.
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


def _run_many(jobs: list[tuple], workers: int, progress: bool, label: str) -> list[tuple[str, str]]:
    """Run ``slam_job`` argument tuples, in a spawn pool when ``workers > 1``; results in order."""
    bar = _Progress(progress, len(jobs))
    out: list[tuple[str, str]] = [("error", "not run")] * len(jobs)
    try:
        bar.describe(label)
        if workers <= 1:
            for i, a in enumerate(jobs):
                out[i] = slam_job(*a)
                bar.advance()
        else:
            import multiprocessing as mp

            with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                     initializer=_worker_init) as pool:
                futs = {pool.submit(slam_job, *a): i for i, a in enumerate(jobs)}
                while futs:
                    done, _ = wait(list(futs), return_when=FIRST_COMPLETED)
                    for f in done:
                        out[futs.pop(f)] = f.result()
                        bar.advance()
    finally:
        bar.close()
    return out


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
    defaults. The winner (by :meth:`TuneRow.score`) is
    returned per kind as ``{"overrides", "default", "best", "runs"}`` and written to
    ``tune.json`` / ``tune.csv`` / ``tune.md``; results resume like the benchmark.
    """
    from seedmap.associate.features import available_kinds

    cfg = cfg or BenchmarkConfig(feature_tuning={})
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, out / "config.yaml")
    spec = RangeSpec(_safe(Path(dataset).resolve().name), "tune", Path(dataset))
    avail = available_kinds()
    rows: list[TuneRow] = []
    summary: dict[str, dict[str, Any]] = {}

    def run_stage(cands: list[tuple[str, dict[str, Any]]], tag: str) -> list[TuneRow]:
        jobs, metas = [], []
        done_rows: list[TuneRow] = []
        for kind, ov in cands:
            m = MethodSpec(kind, kind)
            rd = out / "runs" / kind / _safe(_label(ov))[:120]
            if (rd / "metrics.json").is_file():
                done_rows.append(TuneRow(kind, _label(ov), ov, load_run(rd, spec, m)))
                continue
            feats = FeatureMatcherConfig.model_validate({**cfg.features.model_dump(), **ov})
            jobs.append((str(dataset), str(rd), kind, None, list(cfg.slam_overrides),
                         feats.model_dump(mode="json", exclude={"gates"}), str(out / "logs" / f"{rd.name}.log"),
                         cfg.html_reports))
            metas.append((kind, ov, rd, m))
        for (kind, ov, rd, m), (status, note) in zip(metas, _run_many(jobs, cfg.workers, progress, tag),
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
    md_rows = [[r.kind, r.label, _fmt_m(r.record, "mdm_m"), _fmt_m(r.record, "gt_mdm_m"),
                _fmt_m(r.record, "ate_rmse_m", 3), f"{r.score()[2]:.1f}",
                "" if r.record.ms_per_frame is None else f"{r.record.ms_per_frame:.0f}"] for r in rows]
    md = (f"# Baseline tuning on {dataset}\n\nSelection: GT-validated fraction mapped, then fraction mapped, "
          f"then RANSAC-verified matches per frame pair, then ATE.\n\n"
          + _md_table(["kind", "setting", "MDM (m)", "GT-MDM (m)", "ATE (m)", "verified matches / pair", "ms/frame"],
                      md_rows)
          + "\n**Chosen**\n\n" + "\n".join(f"- {k}: {v.get('note') or _label(v['overrides'])}"
                                          for k, v in summary.items()) + "\n")
    atomic_write_text(out / "tune.md", md)
    return summary


def training_range(cfg: BenchmarkConfig) -> Path:
    """Simulate (or reuse) the tuning range: default world, own seed, 2 m (see :data:`TRAIN_RANGE`)."""
    ov = tuple(cfg.sim_overrides) + tuple(TRAIN_RANGE["overrides"])
    p = Path(cfg.data_dir) / _sim_cache_name(f"train-{TRAIN_RANGE['preset']}", int(TRAIN_RANGE["seed"]), ov)
    if not _is_dataset(p):
        simulate_job(str(TRAIN_RANGE["preset"]), int(TRAIN_RANGE["seed"]), ov, str(p))
    return p
