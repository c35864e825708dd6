"""``seedmap phenotype`` (one row per panicle from a slam result) and ``seedmap eval phenotype``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, app, eval_app
from seedmap.outputs import check_output_file, is_seedmap_json


def _config(config: Optional[Path], set_: Optional[List[str]]):
    from seedmap.config import load_config
    from seedmap.phenotype.config import PhenotypeConfig

    return load_config(PhenotypeConfig, config, set_ or [])


@app.command("phenotype")
def phenotype_cmd(
    result: Path = typer.Argument(..., help="A folder written by `seedmap slam`."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default RESULT/../NAME_phenotype)."),
    plots: Optional[Path] = typer.Option(None, "--plots", help="CSV plot,start,end (m along the row): per-plot summary."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a phenotype folder seedmap wrote."),
) -> None:
    """One row per panicle (position, height, length, width, volume, tilt, seed count, quality): panicles.csv."""
    from seedmap.config import dump_config
    from seedmap.io.atomic import atomic_write_text
    from seedmap.outputs import output_dir
    from seedmap.phenotype.table import (COLUMNS, PLOT_COLUMNS, phenotype_result, plot_summaries, read_plots,
                                         rows_csv)

    cfg = _config(config, set_)
    out = out if out is not None else result.parent / f"{result.name}_phenotype"
    plot_list = read_plots(plots) if plots is not None else None
    rows, frame, cal = phenotype_result(result, cfg)
    with output_dir(out, "phenotype", inputs=[result, plots, config], overwrite=overwrite) as tmp:
        atomic_write_text(tmp / "panicles.csv", rows_csv(rows, COLUMNS))
        plot_rows = plot_summaries(rows, plot_list) if plot_list is not None else None
        if plot_rows is not None:
            atomic_write_text(tmp / "plots.csv", rows_csv(plot_rows, PLOT_COLUMNS))
        summary = {"panicles": len(rows), "panicles_ok": sum(r["quality"] == "ok" for r in rows),
                   "height_source": frame.height_source, "calibration": cfg.calibration,
                   "seeds_est": float(sum(r["seeds_est"] for r in rows))}
        atomic_write_text(tmp / "summary.json", json.dumps(summary, indent=2) + "\n")
        dump_config(cfg, tmp / "config.yaml")
        from seedmap.phenotype.report import write_phenotype_report
        write_phenotype_report(tmp, rows, plot_rows, title=f"seedmap phenotype: {result.name}")
    typer.echo(f"{len(rows)} panicles ({summary['panicles_ok']} ok), height from the {frame.height_source}, "
               f"~{summary['seeds_est']:.0f} seeds: {out / 'panicles.csv'}, report {out / 'phenotype.html'}")


@eval_app.command("phenotype")
def eval_phenotype_cmd(
    result: Path = typer.Argument(..., help="A folder written by `seedmap slam`."),
    dataset: Path = typer.Argument(..., help="The simulated dataset it ran on (gt/seeds.csv)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the scores and per-panicle errors here."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a --json file seedmap wrote."),
) -> None:
    """Panicle detection precision/recall and the errors of position, height, length, width and seed count."""
    from seedmap.io.atomic import atomic_write_text
    from seedmap.phenotype.evaluate import evaluate_phenotype

    if json_out is not None:
        check_output_file(json_out, [result, dataset, config], overwrite, lambda p: is_seedmap_json(p, "matched"),
                          what="JSON file")
    m = evaluate_phenotype(result, dataset, _config(config, set_))
    for k, v in m.items():
        if k != "per_panicle":
            typer.echo(f"{k:28s} {v:.4f}" if isinstance(v, float) else f"{k:28s} {v}")
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(m, indent=1, default=float) + "\n")
        typer.echo(f"scores in {json_out}")
