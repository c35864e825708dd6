"""Whole fields: find every range below a folder and run SLAM on each (``seedmap batch``).

A *range* is any path one of seedmap's loaders recognises (:func:`seedmap.io.detect_format`). Each range
runs :func:`seedmap.slam.pipeline.run_slam` into ``out/<path of the range relative to the field>/``, in
spawned local processes or as Ray tasks. A range whose folder has ``metrics.json`` is not run again
(resume); a range that raises is recorded as ``failed`` and the batch goes on. ``summary.csv`` /
``summary.md`` / ``summary.json`` are rewritten after every finished range.
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Callable, Iterable

from seedmap import outputs
from seedmap.detect.base import default_detector_name
from seedmap.errors import ConfigError, InputError
from seedmap.progress import Progress
from seedmap.workers import process_pool

__all__ = ["RangeResult", "BatchSummary", "find_ranges", "run_batch", "summarize_result_dir"]

BAG_SUFFIXES = (".bag", ".db3", ".mcap")


@dataclass
class RangeResult:
    """One row of the field summary (units: metres, seconds)."""

    range: str  # path relative to the field folder ("." when the field itself is one range)
    status: str  # ok | failed
    resumed: bool = False  # True: an earlier batch had finished it; numbers read from its metrics.json
    mdm_m: float | None = None
    mdm_fraction: float | None = None
    gt_mdm_m: float | None = None
    range_length_m: float | None = None
    ate_rmse_m: float | None = None
    frames: int | None = None
    frames_tracked: int | None = None
    landmarks: int | None = None
    seeds_mapped: int | None = None  # distinct ground-truth seed ids among the landmarks (None without GT)
    panicles_mapped: int | None = None  # landmark clusters (cluster_id >= 0 in landmarks.csv)
    wall_s: float | None = None
    error: str | None = None


@dataclass
class BatchSummary:
    """A whole batch: where it ran, how, and one :class:`RangeResult` per range (in field order)."""

    field: str
    out: str
    matcher: str
    detector: str
    executor: str
    workers: int
    wall_s: float
    ranges: list[RangeResult]

    @property
    def n_ok(self) -> int:
        return sum(r.status == "ok" for r in self.ranges)

    @property
    def n_failed(self) -> int:
        return sum(r.status == "failed" for r in self.ranges)


# ---------------------------------------------------------------------------------------------------
# discovery
# ---------------------------------------------------------------------------------------------------
def find_ranges(field: str | Path, exclude: Iterable[str | Path] = ()) -> list[Path]:
    """Every dataset below ``field`` (sorted), not descending into a recognised dataset, hidden
    folders or ``exclude`` (e.g. the output folder when it lies inside the field)."""
    from seedmap.io import detect_format

    field = Path(field)
    if not field.is_dir():
        if field.exists() and detect_format(field) is not None:
            return [field]
        raise InputError("field folder not found", field)
    skip = {Path(p).resolve() for p in exclude}
    found: list[Path] = []

    def walk(d: Path) -> None:
        if d.resolve() in skip:
            return
        if detect_format(d) is not None:
            found.append(d)
            return
        try:
            entries = sorted(d.iterdir())
        except OSError:
            return
        for e in entries:
            if e.name.startswith("."):
                continue
            if e.is_dir():
                walk(e)
            elif e.suffix.lower() in BAG_SUFFIXES and e.resolve() not in skip and detect_format(e) is not None:
                found.append(e)

    walk(field)
    return found


def _rel(field: Path, rng: Path) -> str:
    rel = rng.relative_to(field).as_posix() if rng != field else "."
    return rel


def _out_dir(out: Path, rel: str) -> Path:
    return out / "range" if rel == "." else out / rel


# ---------------------------------------------------------------------------------------------------
# one range (runs in a worker process / Ray task)
# ---------------------------------------------------------------------------------------------------
def summarize_result_dir(result: str | Path, rel: str, wall_s: float | None = None, resumed: bool = False) -> RangeResult:
    """The summary row of a finished ``seedmap slam`` result folder (metrics.json + landmarks.csv)."""
    result = Path(result)
    try:
        m = json.loads((result / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:  # ValueError: not JSON, or not UTF-8
        raise InputError(f"unreadable metrics.json ({e.__class__.__name__})", result / "metrics.json") from None
    seeds = panicles = None
    lm = result / "landmarks.csv"
    if lm.is_file():
        with lm.open(newline="") as f:
            rows = list(csv.DictReader(f))
        sids = {int(r["seed_id"]) for r in rows if r.get("seed_id", "-1") not in ("", "-1")}
        seeds = len(sids) if sids else None
        panicles = len({int(r["cluster_id"]) for r in rows if r.get("cluster_id", "-1") not in ("", "-1")})
    if wall_s is None:
        # an earlier batch's range: its SLAM time from the per-frame total (frames processed)
        if m.get("ms_per_frame") and m.get("frames_tracked"):
            wall_s = m["ms_per_frame"].get("total_per_frame", 0.0) * m["frames_tracked"] / 1e3
    return RangeResult(
        range=rel, status="ok", resumed=resumed, mdm_m=m.get("mdm_m"), mdm_fraction=m.get("mdm_fraction"),
        gt_mdm_m=m.get("gt_mdm_m"), range_length_m=m.get("range_length_m"), ate_rmse_m=m.get("ate_rmse_m"),
        frames=m.get("frames"), frames_tracked=m.get("frames_tracked"), landmarks=m.get("landmarks"),
        seeds_mapped=seeds, panicles_mapped=panicles, wall_s=wall_s,
    )


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    from seedmap.errors import SeedmapError

    if isinstance(e, SeedmapError):
        return text[:300]
    return f"{type(e).__name__}: {text}"[:300]


def run_one_range(dataset: str, out_dir: str, rel: str, matcher: str, detector: str, cfg_data: dict,
                  threads: int = 1) -> dict:
    """Run SLAM on one range; never raises (a failure comes back as ``status=failed``).

    Returns ``asdict(RangeResult)`` (plain data, so it crosses process and Ray boundaries)."""
    t0 = time.perf_counter()
    try:
        # BLAS/OpenMP/torch threads per worker: OMP_NUM_THREADS etc. are set for the workers by
        # run_batch (env inherited by spawned processes); Ray workers get them here, before any import
        for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(k, str(max(1, threads)))
        from seedmap.slam.config import SlamConfig
        from seedmap.slam.pipeline import run_slam

        cfg = SlamConfig.model_validate(cfg_data)
        # no metrics.json here (else the range was skipped): anything left is an unfinished run
        run_slam(dataset, Path(out_dir), matcher=matcher, detector=detector, config=cfg, overwrite=True,
                 progress=False)
        wall = time.perf_counter() - t0
        return asdict(summarize_result_dir(out_dir, rel, wall_s=wall))
    except Exception as e:  # noqa: BLE001 - a failing range is recorded, never stops the field
        return asdict(RangeResult(range=rel, status="failed", wall_s=time.perf_counter() - t0, error=_one_line(e)))


# ---------------------------------------------------------------------------------------------------
# summary files
# ---------------------------------------------------------------------------------------------------
_COLS = [f.name for f in fields(RangeResult)]


def _fmt(v: Any, nd: int = 3) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def summary_csv(s: BatchSummary) -> str:
    """``summary.csv``: one row per range (the :class:`RangeResult` fields)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_COLS)
    for r in s.ranges:
        w.writerow([_fmt(getattr(r, c), 4) if isinstance(getattr(r, c), float) else _fmt(getattr(r, c))
                    for c in _COLS])
    return buf.getvalue()


def summary_markdown(s: BatchSummary) -> str:
    """``summary.md``: a headline and a table of the ranges."""
    ok = [r for r in s.ranges if r.status == "ok"]
    fr = [r.mdm_fraction for r in ok if r.mdm_fraction is not None]
    lines = [
        f"# Field summary: {s.field}",
        "",
        f"{len(s.ranges)} ranges: {s.n_ok} ok, {s.n_failed} failed. Matcher `{s.matcher}`, detector "
        f"`{s.detector}`, {s.executor} executor with {s.workers} worker(s), {s.wall_s:.1f} s wall time.",
        "",
    ]
    if fr:
        lines += [f"Mean MDM fraction over finished ranges: {100 * sum(fr) / len(fr):.1f} %.", ""]
    lines += ["| range | status | MDM (m) | fraction | ATE (m) | frames tracked | landmarks | GT seeds | panicles "
              "| wall (s) | error |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in s.ranges:
        frac = "" if r.mdm_fraction is None else f"{100 * r.mdm_fraction:.1f} %"
        tracked = "" if r.frames is None else f"{r.frames_tracked} / {r.frames}"
        status = r.status + (" (earlier run)" if r.resumed else "")
        err = (r.error or "").replace("|", "\\|")
        lines.append(f"| {r.range} | {status} | {_fmt(r.mdm_m)} | {frac} | {_fmt(r.ate_rmse_m, 4)} | {tracked} | "
                     f"{_fmt(r.landmarks)} | {_fmt(r.seeds_mapped)} | {_fmt(r.panicles_mapped)} | "
                     f"{_fmt(r.wall_s, 1)} | {err} |")
    return "\n".join(lines) + "\n"


def write_summary(s: BatchSummary, out: Path) -> None:
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(out / "summary.csv", summary_csv(s))
    atomic_write_text(out / "summary.md", summary_markdown(s))
    data = {k: v for k, v in asdict(s).items()}
    data["n_ok"], data["n_failed"] = s.n_ok, s.n_failed
    atomic_write_text(out / "summary.json", json.dumps(data, indent=2) + "\n")


# ---------------------------------------------------------------------------------------------------
# executors
# ---------------------------------------------------------------------------------------------------
def _thread_env(threads: int) -> dict[str, str | None]:
    """Limit BLAS/OpenMP threads of the workers (inherited env); returns the old values."""
    old: dict[str, str | None] = {}
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        old[k] = os.environ.get(k)
        if k not in os.environ:
            os.environ[k] = str(threads)
    return old


def _restore_env(old: dict[str, str | None]) -> None:
    for k, v in old.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


def _run_local(jobs: list[tuple], workers: int, done: Callable[[dict], None]) -> None:
    if workers <= 1:
        for job in jobs:
            done(run_one_range(*job))
        return
    with process_pool(min(workers, len(jobs))) as ex:  # spawned workers, killed with this process
        futs = [ex.submit(run_one_range, *job) for job in jobs]
        for fut in as_completed(futs):
            done(fut.result())


def _run_ray(jobs: list[tuple], workers: int, address: str, done: Callable[[dict], None]) -> None:
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install 'seedmap[cluster]'") from None
    started = False
    if not ray.is_initialized():
        if address == "local":
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                     configure_logging=False)
        else:
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
            except ConnectionError as e:
                raise ConfigError(f"cannot connect to the Ray cluster at {address!r} ({_one_line(e)})") from None
        started = True
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(run_one_range)
        pending = [remote.remote(*job) for job in jobs]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                done(ray.get(ref))
    finally:
        if started:
            ray.shutdown()


# ---------------------------------------------------------------------------------------------------
# the batch
# ---------------------------------------------------------------------------------------------------
def check_names(matcher: str, detector: str | None) -> None:
    """Refuse an unknown ``--matcher`` / ``--detector`` before anything runs (else every range failed alike)."""
    from seedmap.associate import FEATURE_MATCHERS, SEED_MATCHERS
    from seedmap.detect import available_detectors

    key = matcher.strip().lower()
    if key not in SEED_MATCHERS + FEATURE_MATCHERS:
        raise ConfigError(f"--matcher: unknown matcher {matcher!r} (known: {', '.join(SEED_MATCHERS + FEATURE_MATCHERS)})")
    if key in SEED_MATCHERS and detector not in (None, "default", "auto") and detector not in available_detectors():
        raise ConfigError(f"--detector: unknown detector {detector!r} (known: {', '.join(available_detectors())})")


def run_batch(
    field: str | Path,
    out: str | Path,
    matcher: str | None = None,
    detector: str | None = None,
    config: Any = None,
    workers: int = 1,
    ray: str | None = None,
    progress: bool = True,
    inputs: Iterable[str | Path | None] = (),
) -> BatchSummary:
    """Run SLAM on every range below ``field`` into ``out/<relative path>/`` and write the summary.

    ``workers``: parallel local processes (or Ray CPUs for ``ray='local'``); ``ray``: a Ray cluster
    address (``'auto'``, ``'ray://host:10001'``) or ``'local'`` to start one here - on a real cluster
    ``field`` and ``out`` must be paths every node sees (a shared file system) and the nodes need
    seedmap installed. Ranges with a finished ``metrics.json`` are skipped (resume); a failing range is
    recorded, never raised. ``inputs``: more files the command read (``--config``).
    """
    from seedmap.config import dump_config
    from seedmap.slam.config import SlamConfig

    field, out = Path(field), Path(out)
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    cfg = config or SlamConfig()
    # as run_slam: the arguments, else the config's (a result's config.yaml), else seeds / gt; the written
    # config.yaml names the ones used
    matcher = matcher if matcher is not None else (cfg.matcher if cfg.matcher is not None else "seeds")
    detector = detector if detector is not None else (cfg.detector if cfg.detector is not None
                                                      else default_detector_name())
    cfg = cfg.model_copy(update={"matcher": matcher, "detector": detector})
    check_names(matcher, detector)
    ranges = find_ranges(field, exclude=[out])
    if not ranges:
        raise InputError("no dataset found below this folder (no loader recognises any sub-folder)", field)
    field_root = field if field.is_dir() else field.parent
    # out may lie in the field (it is skipped), never in a range, never the field or around it; a batch folder
    # of its own is resumed, any other existing folder refused
    o, f = outputs.resolved(out), outputs.resolved(field_root)
    if o == f or o in f.parents:
        raise InputError(f"is or contains the field {field}; pick an output folder outside it", out)
    outputs.resume_dir(out, "batch", [*ranges, *inputs, *outputs.dataset_option_files(cfg.dataset)])
    dump_config(cfg, out / "config.yaml")

    t0 = time.perf_counter()
    results: dict[str, RangeResult] = {}
    jobs: list[tuple] = []
    cfg_data = cfg.model_dump(mode="json")
    threads = max(1, (os.cpu_count() or 1) // workers)
    for rng in ranges:
        rel = _rel(field_root, rng)
        od = _out_dir(out, rel)
        if (od / "metrics.json").is_file():
            try:
                results[rel] = summarize_result_dir(od, rel, resumed=True)
                continue
            except InputError:
                pass  # an unreadable metrics.json: run it again
        jobs.append((str(rng), str(od), rel, matcher, detector, cfg_data, threads))
    order = [_rel(field_root, r) for r in ranges]
    executor = "sequential" if (ray is None and workers == 1) else ("ray" if ray else "processes")

    def summary() -> BatchSummary:
        return BatchSummary(str(field), str(out), matcher, detector, executor, workers,
                            time.perf_counter() - t0, [results[r] for r in order if r in results])

    with Progress(len(jobs), f"batch ({len(ranges) - len(jobs)} done earlier)", "range", progress) as bar:
        def done(row: dict) -> None:
            r = RangeResult(**row)
            results[r.range] = r
            write_summary(summary(), out)  # an interrupted batch still leaves a valid summary
            bar.note(f"{r.range}: {r.status}")
            bar.advance()

        old = _thread_env(threads)
        try:
            if jobs:
                if ray is not None:
                    _run_ray(jobs, workers, ray, done)
                else:
                    _run_local(jobs, workers, done)
        finally:
            _restore_env(old)
    s = summary()
    write_summary(s, out)
    return s
