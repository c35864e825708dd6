"""The paper's method comparison (its Tables 1 and 2), reproducible in one command (``seedmap benchmark``).

:mod:`.spec` says what runs (config, ranges, methods, records), :mod:`.run` runs it, :mod:`.report` writes
the tables and plots, :mod:`.tune` tunes the descriptor baselines. How the benchmark works and what its
columns mean: ``docs/method/benchmark.md``.
"""

from seedmap.associate.features import KINDS as FEATURE_KINDS
from seedmap.eval.benchmark.report import (
    bar_chart_png,
    matches_plot_png,
    published_table,
    records_csv,
    scenario_tables,
    side_by_side_table,
    summarize,
    table1_csv,
    write_reports,
)
from seedmap.eval.benchmark.run import load_run, run_benchmark, run_dir_of, simulate_job, slam_job
from seedmap.eval.benchmark.spec import (
    CSV_FIELDS,
    SCENE_OVERRIDES,
    SCENE_SEED_OFFSET,
    BenchmarkConfig,
    MethodSpec,
    RangeSpec,
    RunRecord,
    default_methods,
    paper_ranges,
    user_ranges,
)
from seedmap.eval.benchmark.tune import TRAIN_RANGE, TUNING_GRID, TuneRow, training_range, tune_baselines

__all__ = [
    "CSV_FIELDS",
    "FEATURE_KINDS",
    "SCENE_OVERRIDES",
    "SCENE_SEED_OFFSET",
    "TRAIN_RANGE",
    "TUNING_GRID",
    "BenchmarkConfig",
    "MethodSpec",
    "RangeSpec",
    "RunRecord",
    "TuneRow",
    "bar_chart_png",
    "default_methods",
    "load_run",
    "matches_plot_png",
    "paper_ranges",
    "published_table",
    "records_csv",
    "run_benchmark",
    "run_dir_of",
    "scenario_tables",
    "side_by_side_table",
    "simulate_job",
    "slam_job",
    "summarize",
    "table1_csv",
    "training_range",
    "tune_baselines",
    "user_ranges",
    "write_reports",
]
