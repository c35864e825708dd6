"""``seedmap reconstruct`` and ``seedmap count``: one panicle from an arm scan (seedmap.recon)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, app


@app.command("reconstruct")
def reconstruct_cmd(
    dataset: Path = typer.Argument(..., help="Arm scan: stereo pairs in any format seedmap reads (seedmap layout, "
                                             "image folder + calibration, bag) + joints.csv + arm.yaml (or "
                                             "--set joints=FILE --set arm=FILE)."),
    out: Path = typer.Option(..., "--out", "-o", help="Results folder to create."),
    register: Optional[str] = typer.Option(None, "--register", help="fk | full | seeds (default seeds)."),
    detector: Optional[str] = typer.Option(None, "--detector", help="Detector name (default fast; gt = the "
                                                                    "simulator's ground truth, ORACLE)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing seedmap reconstruct result (and "
                                   "a --rerun recording seedmap wrote)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    rerun: Optional[Path] = typer.Option(None, "--rerun", help="Also record the run into this rerun .rrd file "
                                         "(view it with `rerun FILE.rrd`)."),
) -> None:
    """3D model of one panicle from an arm scan: SGBM clouds, FK + ICP registration, seed count."""
    from seedmap.config import load_config
    from seedmap.errors import ConfigError
    from seedmap.recon.config import ReconConfig
    from seedmap.detect import detector_label
    from seedmap.recon.pipeline import run_reconstruct

    extra = list(set_ or [])
    if register is not None:
        if register not in ("fk", "full", "seeds"):
            raise ConfigError(f"--register must be fk, full or seeds, got {register!r}")
        extra.append(f"registration.mode={register}")
    if detector is not None:
        extra.append(f"detector={detector}")
    cfg = load_config(ReconConfig, config, extra)
    path, m = run_reconstruct(dataset, out, cfg, overwrite=overwrite, progress=not quiet, rerun=rerun,
                              inputs=[config])
    q = m["quality"]
    cal = m.get("seed_count_calibrated")
    det = detector_label(cfg.detector, m["oracle_detector"])
    typer.echo(f"{m['mode']}, detector {det}: {m['seed_count']} seeds" + (f" (calibrated estimate {cal:.0f})"
                                                                         if cal is not None else "")
               + f", {m['cloud_points']} points, "
               f"cross-view seed distance {q['cross_view_seed_mm']:.2f} mm (GT-free quality, lower is better)")
    if "gt" in m:
        g = m["gt"]
        typer.echo(f"vs GT: pose {g['pose_trans_mm_mean']:.2f} mm / {g['pose_rot_deg_mean']:.3f} deg, cloud "
                   f"median {g['cloud_dist_mm_median']:.2f} mm p90 {g['cloud_dist_mm_p90']:.2f} mm, "
                   f"count {g['count']} vs {g['count_gt']} visible ({g['count_ape_pct']:.1f} %), "
                   f"{g['count_gt_countable']} countable ({g['count_countable_ape_pct']:.1f} %)")
    typer.echo(f"wrote {path} (report.html)" + (f", rerun recording {rerun}" if rerun else ""))


@app.command("count")
def count_cmd(
    results: Path = typer.Argument(..., help="A `seedmap reconstruct` results folder."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write seeds.csv + count.json to this new folder."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing seedmap count --out folder."),
) -> None:
    """Seed count of a reconstruction, re-run from its folder (default method multiview on detections.csv;
    e.g. --set count.mv_link_px=2.5, or --set count.method=density for the paper's 3D de-duplication)."""
    import json

    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from seedmap.config import dump_config, load_config
    from seedmap.errors import InputError
    from seedmap.io.atomic import atomic_write_text
    from seedmap.outputs import check_output_dir, output_dir
    from seedmap.recon.config import ReconConfig
    from seedmap.detect import detector_label
    from seedmap.recon.pipeline import recount_calibrated, seeds_csv_text

    base_cfg = results / "config.yaml"
    if config is None and not base_cfg.is_file():
        raise InputError("config.yaml not found (is this a `seedmap reconstruct` results folder?)", base_cfg)
    if config is None and (results / "trajectory.tum").is_file() and not (results / "cloud.ply").is_file():
        raise InputError("a `seedmap slam` result folder; count needs a `seedmap reconstruct` one", results)
    cfg = load_config(ReconConfig, config if config is not None else base_cfg, list(set_ or []))
    cal_file = cfg.count.calibration if cfg.count.calibration not in ("auto", "none") else None
    inputs = [results, config, cal_file]
    if out is not None:  # before any work
        check_output_dir(out, "count", inputs, overwrite)
    c, cal = recount_calibrated(results, cfg)
    t = Table(title=f"seed count: {results} (detector {detector_label(cfg.detector)})")
    for col in ("seeds", "calibrated estimate", "median diameter (mm)", "median views/seed", "median spread (mm)"):
        t.add_column(col)
    t.add_row(str(c.count), f"{cal.estimate:.0f}" if cal.estimate is not None else "-",
              f"{np.median(c.diameter) * 1000:.2f}" if c.count else "-",
              f"{np.median(c.n_views):.0f}" if c.count else "-",
              f"{np.median(c.spread) * 1000:.2f}" if c.count else "-")
    Console().print(t)
    if cal.estimate is None:
        typer.echo(f"no calibrated estimate: {cal.reason}")
    else:
        typer.echo(f"calibrated estimate: {Path(cal.source).name}, {cal.fitted}")
    if out is not None:
        with output_dir(out, "count", inputs, overwrite) as tmp:
            dump_config(cfg, tmp / "config.yaml")
            atomic_write_text(tmp / "seeds.csv", seeds_csv_text(c))
            atomic_write_text(tmp / "count.json", json.dumps({"results": str(results), **cal.as_dict()}, indent=2))
        typer.echo(f"wrote {out}")
