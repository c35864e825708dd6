"""``seedmap benchmark paper|run|sweep|tune``: the paper's method comparison (seedmap.eval.benchmark)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, benchmark_app
from seedmap.errors import SeedmapError


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
    from seedmap.eval.benchmark.report import method_label

    summ = summarize(records)
    con = Console()
    for sc, per in summ.items():
        t = Table(title=f"{sc}: mean fraction of range mapped")
        for col in ("method", "MDM", "GT-validated", "ATE (m)", "ms/frame"):
            t.add_column(col)
        for m, s in per.items():
            def pct(v):
                return "–" if v is None else f"{100 * v:.0f}%"
            if not s["available"]:
                t.add_row(method_label(m), "n/a", "n/a", "n/a", "n/a")
                continue
            t.add_row(method_label(m), pct(s["mean_fraction"]), pct(s["mean_gt_fraction"]),
                      "–" if s["mean_ate_m"] is None else f"{s['mean_ate_m']:.3f}",
                      "n/a" if s["ms_per_frame"] is None else f"{s['ms_per_frame']:.0f}")
        con.print(t)
    con.print(f"tables, plots and per-run results in {out} (report.md)")
    failed = [r for r in records if r.status == "error"]
    if failed:  # the tables showed "–" for a failed run, like a run without ground truth
        first = failed[0].note.removeprefix("error: ")
        msg = f"{len(failed)} of {len(records)} runs failed (first: {failed[0].range_name} {failed[0].method}: {first})"
        if not any(r.status == "ok" for r in records):
            raise SeedmapError(f"{msg}; details in {out / 'results.csv'}")
        typer.secho(f"warning: {msg}; see {out / 'results.csv'}", err=True, fg=typer.colors.YELLOW)


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


def _list_option(text: Optional[str], what: str, kind: type = str) -> Optional[str]:
    """A comma list option as a YAML list for ``--set`` (``None`` when not given); one line when malformed."""
    if text is None:
        return None
    items = [x.strip() for x in text.split(",") if x.strip()]
    if kind is float:
        try:
            items = [f"{float(x):g}" for x in items]
        except ValueError:
            raise SeedmapError(f"{what} must be comma-separated numbers, got {text!r}") from None
    return "[" + ",".join(items) + "]"


@benchmark_app.command("sweep")
def benchmark_sweep(
    out: Path = typer.Option(Path("results/sweep"), "--out", "-o", help="Results folder (resumes if present)."),
    conditions: Optional[str] = typer.Option(None, "--conditions",
                                             help="Comma list of wind,vibration,blur,flicker,wet,drops (default all)."),
    strengths: Optional[str] = typer.Option(None, "--strengths", help="Comma list (default 0,0.5,1,2; at most 3)."),
    ladder: bool = typer.Option(False, "--ladder", help="Also run the calm, breeze, windy, rough presets."),
    seeds: Optional[str] = typer.Option(None, "--seeds", help="World seeds, each point on every one (default 40,41)."),
    length: Optional[float] = typer.Option(None, "--length", help="Range length in metres (default 0.5)."),
    methods: Optional[str] = typer.Option(None, "--methods",
                                          help="Comma list (default seeds+fast,seeds+gt,orbslam3,sift,orb,akaze)."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", help="Parallel processes (default 2)."),
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="Cache of simulated ranges."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Every method along each field condition's strength (and the ladder): where each one fails first."""
    from seedmap.config import load_config
    from seedmap.eval.benchmark.sweep import SweepConfig, run_sweep

    cli = {"conditions": _list_option(conditions, "--conditions"),
           "strengths": _list_option(strengths, "--strengths", float),
           "ladder": True if ladder else None, "seeds": _parse_int_list(seeds, "--seeds"), "length": length,
           "benchmark.methods": _list_option(methods, "--methods"), "benchmark.workers": workers,
           "benchmark.data_dir": data_dir}
    cfg = load_config(SweepConfig, config, [*(set_ or []), *(f"{k}={v}" for k, v in cli.items() if v is not None)])
    rows = run_sweep(cfg, out)
    from seedmap.eval.benchmark.sweep_report import failure_table, sweep_summary

    typer.echo("where each method fails first (mean GT-validated fraction mapped below 50 %):")
    typer.echo(failure_table(sweep_summary(rows)).rstrip())
    errors = [r for r in rows if r["status"] == "error"]
    if errors:
        typer.secho(f"warning: {len(errors)} of {len(rows)} runs failed; see {out / 'results.csv'}", err=True,
                    fg=typer.colors.YELLOW)
    typer.echo(f"tables and plots in {out} (report.md)")


@benchmark_app.command("tune")
def benchmark_tune(
    dataset: Optional[Path] = typer.Argument(None, help="Training dataset (default: simulate the training range)."),
    out: Path = typer.Option(Path("results/tune"), "--out", "-o", help="Results folder (resumes if present)."),
    kinds: str = typer.Option("sift,surf,orb,akaze", "--kinds", help="Baselines to tune."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", help="Parallel processes (default 2)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Tune the descriptor baselines (ratio, CLAHE, feature counts, ...) on ONE training range."""
    from seedmap.eval.benchmark import FEATURE_KINDS, training_range, tune_baselines

    cfg = _bench_config(config, set_, workers=workers, feature_tuning="{}")
    ks = [k.strip().lower() for k in kinds.split(",") if k.strip()]
    bad = [k for k in ks if k not in FEATURE_KINDS]
    if bad:
        raise SeedmapError(f"--kinds: unknown baseline {bad[0]!r} (known: {', '.join(FEATURE_KINDS)})")
    ds = dataset if dataset is not None else training_range(cfg)
    summary = tune_baselines(ds, out, ks, cfg)
    for k, v in summary.items():
        typer.echo(f"{k}: {v.get('note') or v['overrides'] or 'facts.md defaults are best'}")
    typer.echo(f"details in {out / 'tune.md'}")
