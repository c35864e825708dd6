"""The ``seedmap`` command: one typer app, thin wrappers over the package's pipelines.

Every command that writes results writes into a fresh folder atomically (temporary name, then
rename) together with its resolved config. User errors print one line and exit with code 2.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import List, Optional

import typer

from seedmap import __version__
from seedmap.errors import SeedmapError

app = typer.Typer(
    name="seedmap",
    help="Semantic stereo SLAM and panicle 3D reconstruction with sorghum seeds as landmarks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
simulate_app = typer.Typer(help="Render simulated datasets with ground truth.", no_args_is_help=True)
train_app = typer.Typer(help="Train the learned detector and segmenter.", no_args_is_help=True)
eval_app = typer.Typer(help="Evaluate results against ground truth.", no_args_is_help=True)
app.add_typer(simulate_app, name="simulate")
app.add_typer(train_app, name="train")
app.add_typer(eval_app, name="eval")

ConfigOpt = typer.Option(None, "--config", "-c", help="YAML config file (defaults otherwise).")
SetOpt = typer.Option(None, "--set", "-s", help="Override a config value: --set section.key=value (repeatable).")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"seedmap {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """seedmap: maps of crop plants from stereo cameras, with sorghum seeds as landmarks."""


# ================================================================================================
# simulate (seedmap.sim)
# ================================================================================================


# ================================================================================================
# detect / train / eval detect (seedmap.detect)
# ================================================================================================


# ================================================================================================
# slam / demo / eval associate / eval slam (seedmap.associate, seedmap.slam)
# ================================================================================================


# ================================================================================================
# benchmark (seedmap.eval)
# ================================================================================================

benchmark_app = typer.Typer(help="The paper's method comparison (Tables 1 and 2), reproducible.",
                            no_args_is_help=True)
app.add_typer(benchmark_app, name="benchmark")


def _bench_config(config: Optional[Path], overrides: Optional[List[str]], **cli: object):
    """BenchmarkConfig from defaults <- YAML <- --set <- explicit CLI options (when given)."""
    from seedmap.config import load_config
    from seedmap.eval.benchmark import BenchmarkConfig

    extra = [f"{k}={v}" for k, v in cli.items() if v is not None]
    return load_config(BenchmarkConfig, config, [*(overrides or []), *extra])


def _parse_int_list(text: Optional[str], what: str) -> Optional[str]:
    if text is None:
        return None
    try:
        vals = [int(x) for x in text.replace(" ", "").split(",") if x]
    except ValueError:
        raise SeedmapError(f"{what} must be comma-separated integers, got {text!r}") from None
    return "[" + ",".join(str(v) for v in vals) + "]"


def _bench_print(records, out: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    from seedmap.eval.benchmark import summarize

    summ = summarize(records)
    con = Console()
    for sc, per in summ.items():
        t = Table(title=f"{sc}: mean fraction of range mapped")
        for col in ("method", "MDM", "GT-validated", "ATE (m)", "ms/frame"):
            t.add_column(col)
        for m, s in per.items():
            def pct(v):
                return "–" if v is None else f"{100 * v:.0f}%"
            t.add_row(m, pct(s["mean_fraction"]), pct(s["mean_gt_fraction"]),
                      "–" if s["mean_ate_m"] is None else f"{s['mean_ate_m']:.3f}",
                      "n/a" if s["ms_per_frame"] is None else f"{s['ms_per_frame']:.0f}")
        con.print(t)
    con.print(f"tables, plots and per-run results in {out} (report.md)")


@benchmark_app.command("paper")
def benchmark_paper(
    out: Path = typer.Option(Path("results/paper"), "--out", "-o", help="Results folder (resumes if present)."),
    seeds: Optional[str] = typer.Option(None, "--seeds", help="Simulator seed per range, e.g. 101,102,...,108."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", help="Parallel processes (default 2)."),
    scenes: bool = typer.Option(False, "--scenes", help="Also run harder held-out scene variations."),
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="Cache of simulated ranges."),
    methods: Optional[str] = typer.Option(None, "--methods", help="Comma list, e.g. seeds+gt,sift,orb."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Simulate the paper's eight ranges and compare every method (MDM, GT-validated MDM, ATE, timing)."""
    from seedmap.eval.benchmark import paper_ranges, run_benchmark

    cfg = _bench_config(
        config, set_, seeds=_parse_int_list(seeds, "--seeds"), workers=workers,
        scenes=True if scenes else None, data_dir=data_dir,
        methods=None if methods is None else "[" + ",".join(m.strip() for m in methods.split(",") if m) + "]")
    records = run_benchmark(paper_ranges(cfg), out, cfg)
    _bench_print(records, out)


@benchmark_app.command("run")
def benchmark_run(
    datasets: List[Path] = typer.Argument(..., help="Dataset folders (any supported format)."),
    out: Path = typer.Option(..., "--out", "-o", help="Results folder (resumes if present)."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", help="Parallel processes (default 2)."),
    methods: Optional[str] = typer.Option(None, "--methods", help="Comma list, e.g. seeds+fast,sift,orb."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Compare every method on your own datasets (GT-validated columns only where GT exists)."""
    from seedmap.eval.benchmark import run_benchmark, user_ranges

    cfg = _bench_config(
        config, set_, workers=workers,
        methods=None if methods is None else "[" + ",".join(m.strip() for m in methods.split(",") if m) + "]")
    records = run_benchmark(user_ranges(datasets), out, cfg)
    _bench_print(records, out)


# ================================================================================================
# reconstruct / count / simulate panicle (seedmap.recon)
# ================================================================================================


# ================================================================================================
# bag-info / batch (seedmap.io, seedmap.viz)
# ================================================================================================


def main() -> None:
    """Console entry point: user errors become one line on stderr and exit code 2."""
    try:
        app()
    except SeedmapError as e:
        typer.secho(f"error: {e}", err=True, fg=typer.colors.RED)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.secho("interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
