"""``seedmap batch``: SLAM on every range of a field (seedmap.batch)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, app
from seedmap.cli.slam import slam_config
from seedmap.errors import SeedmapError


@app.command("batch")
def batch_cmd(
    field: Path = typer.Argument(..., help="Field folder: every dataset below it (any loader) is one range."),
    out: Path = typer.Option(..., "--out", "-o", help="Results: out/<range path>/ + summary.csv/.md/.json."),
    workers: int = typer.Option(1, "--workers", "-j", help="Ranges run in parallel (processes or Ray CPUs)."),
    ray: Optional[str] = typer.Option(None, "--ray", help="Ray cluster address (auto, ray://host:10001) or "
                                      "'local' to start one here (needs Ray: the seedmap 'cluster' extra)."),
    matcher: Optional[str] = typer.Option(None, "--matcher", "-m", help="seeds | sift | orb | akaze | surf "
                                          "(default: the --config's matcher, else seeds)"),
    detector: Optional[str] = typer.Option(None, "--detector", "-d", help="Seed detector for --matcher seeds "
                                           "(default: the --config's detector, else the best real one; gt = the "
                                           "ORACLE)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """SLAM on every range of a field (resumable; failing ranges are recorded, not fatal)."""
    from seedmap.batch import run_batch, summary_markdown

    cfg = slam_config(config, set_)
    s = run_batch(field, out, matcher=matcher, detector=detector, config=cfg, workers=workers, ray=ray,
                  progress=not quiet, inputs=[config])
    typer.echo(summary_markdown(s))
    typer.echo(f"summary in {out / 'summary.md'} ({s.n_ok} ok, {s.n_failed} failed)")
    if s.n_failed and not s.n_ok:  # one failing range is recorded, not fatal; a field where none ran is
        first = next(r for r in s.ranges if r.status != "ok")
        raise SeedmapError(f"all {s.n_failed} ranges failed (first: {first.range}: {first.error}; errors in "
                           f"{out / 'summary.md'})")
