"""``seedmap phenotype`` (one row per panicle from a slam result), ``seedmap eval phenotype`` and
``seedmap train phenotype-calibration``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, app, eval_app, train_app
from seedmap.errors import InputError
from seedmap.outputs import check_output_file, is_seedmap_json


def _config(config: Optional[Path], set_: Optional[List[str]]):
    from seedmap.config import load_config
    from seedmap.phenotype.config import PhenotypeConfig

    return load_config(PhenotypeConfig, config, set_ or [])


DataOpt = typer.Option(None, "--data", help="The dataset the result was mapped from (default: the one it records); "
                                            "its images give each panicle's best view and seed count.")
DetectorOpt = typer.Option(None, "--detector", "-d", help="Seed detector for the views (default: the result's).")


@app.command("phenotype")
def phenotype_cmd(
    result: Path = typer.Argument(..., help="A folder written by `seedmap slam`."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default RESULT/../NAME_phenotype)."),
    data: Optional[Path] = DataOpt,
    detector: Optional[str] = DetectorOpt,
    plots: Optional[Path] = typer.Option(None, "--plots", help="CSV plot,start,end (m along the row): per-plot summary."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a phenotype folder seedmap wrote."),
) -> None:
    """One row per panicle (position, height, length, width, volume, tilt, seed count, quality): panicles.csv,
    thumbnails of each panicle's best view, phenotype.html. `seedmap slam` writes the same into its result."""
    from seedmap.config import dump_config
    from seedmap.outputs import output_dir
    from seedmap.phenotype.run import phenotype_result, result_images, write_phenotype
    from seedmap.phenotype.table import read_plots

    cfg = _config(config, set_)
    out = out if out is not None else result.parent / f"{result.name}_phenotype"
    plot_list = read_plots(plots) if plots is not None else None
    if not result.is_dir():
        raise InputError("result folder not found", result)
    images = result_images(result, data, detector)
    ph = phenotype_result(result, cfg, images)
    with output_dir(out, "phenotype", inputs=[result, plots, config, data], overwrite=overwrite) as tmp:
        write_phenotype(tmp, ph, images, plot_list, title=f"seedmap phenotype: {result.name}",
                        result=str(result.resolve()))
        dump_config(cfg, tmp / "config.yaml")
    s = ph.summary()
    typer.echo(f"{s['panicles']} panicles ({s['panicles_ok']} ok), height from the {s['height_source']}, "
               f"~{s['seeds_est']:.0f} seeds (calibration {s['calibration']}): {out / 'panicles.csv'}, "
               f"report {out / 'phenotype.html'}")


@eval_app.command("phenotype")
def eval_phenotype_cmd(
    result: Path = typer.Argument(..., help="A folder written by `seedmap slam`."),
    dataset: Path = typer.Argument(..., help="The simulated dataset it ran on (gt/seeds.csv)."),
    detector: Optional[str] = DetectorOpt,
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the scores and per-panicle errors here."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a --json file seedmap wrote."),
) -> None:
    """Panicle detection precision/recall and the errors of position, height, length, width and seed count."""
    from seedmap.io.atomic import atomic_write_text
    from seedmap.phenotype.evaluate import evaluate_phenotype
    from seedmap.phenotype.run import result_images

    if json_out is not None:
        check_output_file(json_out, [result, dataset, config], overwrite, lambda p: is_seedmap_json(p, "matched"),
                          what="JSON file")
    if not result.is_dir():
        raise InputError("result folder not found", result)
    m = evaluate_phenotype(result, dataset, _config(config, set_), result_images(result, dataset, detector))
    for k, v in m.items():
        if k != "per_panicle":
            typer.echo(f"{k:28s} {v:.4f}" if isinstance(v, float) else f"{k:28s} {v}")
    if json_out is not None:
        atomic_write_text(json_out, json.dumps(m, indent=1, default=float) + "\n")
        typer.echo(f"scores in {json_out}")


@train_app.command("phenotype-calibration")
def train_phenotype_calibration_cmd(
    sources: List[Path] = typer.Argument(..., help="panicles.csv files with a seeds_counted column filled in for "
                                                   "the panicles counted by hand, or `seedmap eval phenotype --json` "
                                                   "files of simulated runs."),
    out: Path = typer.Option(..., "--out", "-o", help="Calibration file (.json) to write."),
    features: str = typer.Option("seeds_in_view", "--features",
                                 help="Comma-separated panicle columns the count is fitted on (in logs): "
                                      "seeds_in_view, landmarks, length_m, width_m."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a calibration file seedmap wrote."),
) -> None:
    """Fit the seed-count calibration of the phenotype table; use it with `--set phenotype.calibration=FILE`
    (slam) or `--set calibration=FILE` (phenotype)."""
    from seedmap.io.atomic import atomic_write_text
    from seedmap.phenotype.calibrate import fit_calibration

    if out.suffix.lower() != ".json":
        raise InputError("the calibration file must end in .json", out)
    check_output_file(out, list(sources), overwrite, lambda p: is_seedmap_json(p, "sigma_log"),
                      what="calibration file")
    cal = fit_calibration(sources, [f.strip() for f in features.split(",") if f.strip()])
    atomic_write_text(out, json.dumps(cal, indent=2) + "\n")
    typer.echo(f"calibration written to {out}: {cal['panicles']} panicles, sigma_log {cal['sigma_log']:.3f}, "
               f"leave-one-out MAPE {100 * cal['loo_mape']:.1f} %")
