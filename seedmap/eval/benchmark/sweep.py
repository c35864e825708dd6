"""The robustness sweep (``seedmap benchmark sweep``): every method along each field condition's strength.

:func:`sweep_grid` expands the configuration into points (condition, strength, world seed) and the ranges they
render; points that render the same range (every strength 0, the ``calm`` rung) share it. :func:`run_sweep` runs
every method on every range through :func:`run_benchmark` (renders and runs are cached, so a sweep resumes) and
writes the sweep's tables and plots (:mod:`.sweep_report`). Method: ``docs/method/sweep.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from pydantic import Field, field_validator

from seedmap import outputs
from seedmap.config import ConfigModel, config_to_yaml, dump_config
from seedmap.eval.benchmark.run import run_benchmark
from seedmap.eval.benchmark.spec import CSV_FIELDS, BenchmarkConfig, RangeSpec, RunRecord, default_methods, \
    sim_cache_name
from seedmap.eval.benchmark.sweep_report import write_sweep_reports
from seedmap.sim.conditions import LADDER, STRENGTHS

#: methods a sweep runs by default: seeds with each shipped detector (``fast``; ``gt``, the ORACLE), ORB-SLAM3 and
#: the descriptor baselines
SWEEP_METHODS = ("seeds+fast", "seeds+gt", "orbslam3", "sift", "orb", "akaze")
#: the ``condition`` of the ladder's points (its strength is the rung's index: calm 0 .. rough 3)
LADDER_NAME = "ladder"
#: columns of the sweep's ``results.csv``: the point, then the benchmark record's columns
SWEEP_FIELDS = ["condition", "level", "strength", "seed", *CSV_FIELDS]


class SweepConfig(ConfigModel):
    """What ``seedmap benchmark sweep`` runs; written as ``config.yaml`` next to the results."""

    conditions: list[str] = Field(default_factory=lambda: list(STRENGTHS),
                                  description="conditions swept one at a time (docs/method/conditions.md)")
    strengths: list[float] = Field(default_factory=lambda: [0.0, 0.5, 1.0, 2.0],
                                   description="strengths of each condition (0 = off, 1 = typical, at most 3)")
    ladder: bool = Field(False, description="also run the calm < breeze < windy < rough presets")
    seeds: list[int] = Field(default_factory=lambda: [40, 41],
                             description="world seeds: every point is rendered and run on each")
    length: float = Field(0.5, gt=0, le=20, description="range length in metres")
    benchmark: BenchmarkConfig = Field(default_factory=lambda: BenchmarkConfig(methods=list(SWEEP_METHODS)))

    @field_validator("conditions")
    @classmethod
    def _known(cls, v: list[str]) -> list[str]:
        bad = [c for c in v if c not in STRENGTHS]
        if bad:
            raise ValueError(f"unknown condition {bad[0]!r} (known: {', '.join(STRENGTHS)})")
        return list(dict.fromkeys(v))

    @field_validator("strengths")
    @classmethod
    def _in_range(cls, v: list[float]) -> list[float]:
        if not v:
            raise ValueError("give at least one strength")
        bad = [s for s in v if not 0 <= s <= 3]
        if bad:
            raise ValueError(f"strength {bad[0]:g} is outside 0..3 (0 = off, 1 = typical)")
        return sorted(set(float(s) for s in v))

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: list[int]) -> list[int]:
        if not v:
            raise ValueError("give at least one world seed")
        if any(s < 0 for s in v):
            raise ValueError("world seeds must be non-negative")
        return list(dict.fromkeys(v))


@dataclass
class SweepPoint:
    """One point of the sweep on one world seed, and the range it renders."""

    condition: str  # a condition of STRENGTHS, or LADDER_NAME
    level: str  # the strength as written ("0.5"), or the ladder's rung
    strength: float  # the strength, or the rung's index on the ladder
    seed: int
    range: RangeSpec


def _level(s: float) -> str:
    return f"{s:g}"


def sweep_grid(cfg: SweepConfig) -> list[SweepPoint]:
    """Every (condition, strength, seed) point, then the ladder's rungs when ``cfg.ladder``; ranges with the same
    simulator overrides are one :class:`RangeSpec` (strength 0 and ``calm`` render the default range)."""
    data = Path(cfg.benchmark.data_dir)
    base = (f"world.length={cfg.length:g}", *cfg.benchmark.sim_overrides)
    ranges: dict[tuple[int, tuple[str, ...]], RangeSpec] = {}

    def range_of(seed: int, extra: tuple[str, ...], tag: str) -> RangeSpec:
        ov = base + extra
        if (seed, ov) not in ranges:
            ranges[(seed, ov)] = RangeSpec(f"s{seed}-{tag}", "sweep", data / sim_cache_name("range", seed, ov),
                                           cfg.length, "", seed, ov)
        return ranges[(seed, ov)]

    points: list[SweepPoint] = []
    for c in cfg.conditions:
        for s in cfg.strengths:
            for seed in cfg.seeds:
                extra = (f"conditions.{c}={_level(s)}",) if s > 0 else ()
                tag = f"{c}{_level(s)}" if s > 0 else "calm"
                points.append(SweepPoint(c, _level(s), s, seed, range_of(seed, extra, tag)))
    if cfg.ladder:
        for i, rung in enumerate(LADDER):
            for seed in cfg.seeds:
                extra = (f"conditions.preset={rung}",) if any(LADDER[rung].values()) else ()
                points.append(SweepPoint(LADDER_NAME, rung, float(i), seed, range_of(seed, extra, rung)))
    return points


def unique_ranges(points: list[SweepPoint]) -> list[RangeSpec]:
    """The ranges of ``points``, each once, in order of first use."""
    out: dict[str, RangeSpec] = {}
    for p in points:
        out.setdefault(p.range.name, p.range)
    return list(out.values())


def sweep_rows(points: list[SweepPoint], records: list[RunRecord]) -> list[dict]:
    """One row per (point, method): the point's columns then the record's (:data:`SWEEP_FIELDS`)."""
    by: dict[str, list[RunRecord]] = {}
    for r in records:
        by.setdefault(r.range_name, []).append(r)
    rows = []
    for p in points:
        for r in by.get(p.range.name, []):
            d = asdict(r)
            rows.append({"condition": p.condition, "level": p.level, "strength": p.strength, "seed": p.seed,
                         **{k: d[k] for k in CSV_FIELDS}})
    return rows


def run_sweep(cfg: SweepConfig, out: str | Path, progress: bool = True) -> list[dict]:
    """Render what is missing, run every method at every point, write the sweep's report into ``out``.

    The benchmark's own folder is ``out/bench`` (one run folder per range and method); resumable like it.
    Returns the rows of ``results.csv``.
    """
    out = Path(out)
    methods = default_methods(cfg.benchmark)  # unknown methods fail before any folder is written
    points = sweep_grid(cfg)
    outputs.resume_dir(out, "sweep")
    dump_config(cfg, out / "config.yaml")
    records = run_benchmark(unique_ranges(points), out / "bench", cfg.benchmark, methods, progress)
    rows = sweep_rows(points, records)
    write_sweep_reports(rows, out, cfg.model_dump(mode="json"), config_to_yaml(cfg))
    return rows
