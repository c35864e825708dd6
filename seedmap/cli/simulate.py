"""``seedmap simulate range|stats|panicle|photos``: simulated datasets with ground truth (seedmap.sim)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, simulate_app


@simulate_app.command("range")
def simulate_range_cmd(
    out: Path = typer.Option(..., "--out", "-o", help="Dataset folder to create."),
    length: Optional[float] = typer.Option(None, "--length", help="Range length in metres (default 4.0)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (every random choice flows from it)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="paper1 .. paper8 (the paper's range lengths)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    preview: bool = typer.Option(False, "--preview", help="Write preview.png (frames with GT centres)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a dataset seedmap simulated."),
    stats: bool = typer.Option(False, "--stats", help="Print and save stats.json (realism self-check)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Render a simulated sorghum range (stereo images + full ground truth) into OUT."""
    from seedmap.config import load_config
    from seedmap.errors import ConfigError
    from seedmap.sim.config import SimConfig, preset_dict
    from seedmap.sim.range import simulate_range

    base = preset_dict(preset) if preset else {}
    extra = list(set_ or [])
    if length is not None:
        if not length > 0:
            raise ConfigError(f"--length must be positive, got {length}")
        extra.append(f"world.length={length}")
    if seed is not None:
        extra.append(f"seed={seed}")
    cfg = load_config(SimConfig, config, extra, base=base)
    path = simulate_range(cfg, out, overwrite=overwrite, progress=not quiet, preview=preview, stats=stats,
                          inputs=[config])
    if stats:
        import json

        from seedmap.sim.stats import print_stats

        print_stats(json.loads((path / "stats.json").read_text()))
    typer.echo(f"wrote {path}")


@simulate_app.command("stats")
def simulate_stats_cmd(
    dataset: Path = typer.Argument(..., help="A simulated seedmap dataset."),
    save: bool = typer.Option(False, "--save", help="Also write DATASET/stats.json."),
) -> None:
    """Print the realism self-check of an existing simulated dataset."""
    from seedmap.sim.stats import dataset_stats, print_stats, write_stats

    st = dataset_stats(dataset)
    print_stats(st)
    if save:
        write_stats(dataset, st)


@simulate_app.command("panicle")
def simulate_panicle_cmd(
    out: Path = typer.Option(..., "--out", "-o", help="Dataset folder to create."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (panicle, arm errors, image noise)."),
    views: Optional[int] = typer.Option(None, "--views", help="Number of views around the panicle (default 36)."),
    exposure: Optional[str] = typer.Option(
        None, "--exposure", help="auto (default: exposed for the scan's stand-off) or a gain factor; 1.0 = the "
                                 "field ranges' gain, flash-saturated at the arm's stand-off."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a dataset seedmap simulated."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Simulate a UR5 arm circling one panicle with the stereo camera (images, joints.csv, arm.yaml, GT)."""
    from seedmap.config import load_config
    from seedmap.errors import ConfigError
    from seedmap.sim.panicle_scan import PanicleScanConfig, simulate_panicle

    extra = list(set_ or [])
    if seed is not None:
        extra.append(f"seed={seed}")
    if views is not None:
        extra.append(f"arm.views={views}")
    if exposure is not None:
        extra.append(f"exposure={exposure}")
    try:
        cfg = load_config(PanicleScanConfig, config, extra)
    except ConfigError:
        # a scan's gt/ holds config.yaml (the panicle's scene) next to scan.yaml (the scan): the natural guess
        # 'gt/config.yaml' said "unknown config key 'preset'"
        if config is not None and (config.parent / "scan.yaml").is_file() and config.name != "scan.yaml":
            raise ConfigError("this is the simulated scene's config; a scan is repeated from the scan.yaml "
                              f"next to it (--config {config.parent / 'scan.yaml'})", config) from None
        raise
    path = simulate_panicle(cfg, out, overwrite=overwrite, progress=not quiet, inputs=[config])
    typer.echo(f"wrote {path}")


@simulate_app.command("photos")
def simulate_photos_cmd(
    out: Path = typer.Option(..., "--out", "-o", help="Folder to create: images + labels.json (COCO)."),
    count: Optional[int] = typer.Option(None, "--count", "-n", help="Number of photos (default 20)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (photo i depends only on it and i)."),
    split: Optional[str] = typer.Option(None, "--split", help="train (default), validation or heldout: the "
                                                              "last two draw backgrounds, lights and varieties never "
                                                              "used for training (validation to choose settings, "
                                                              "heldout to measure)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace photos seedmap simulated."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Simulate labelled grain photos: loose grain, piles and panicles on varied backgrounds and light (COCO)."""
    from seedmap.config import load_config
    from seedmap.errors import ConfigError
    from seedmap.sim.photos import PhotoSimConfig, simulate_photos

    extra = list(set_ or [])
    for key, v in (("count", count), ("seed", seed), ("split", split)):
        if v is not None:
            extra.append(f"{key}={v}")
    cfg = load_config(PhotoSimConfig, config, extra)
    try:
        path = simulate_photos(cfg, out, overwrite=overwrite, progress=not quiet, inputs=[config])
    except ValueError as e:
        raise ConfigError(str(e)) from None
    typer.echo(f"wrote {path} ({cfg.count} photos, labels.json)")
