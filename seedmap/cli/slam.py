"""``seedmap slam`` and ``seedmap demo``: semantic stereo SLAM (seedmap.slam), and the config and metrics
table the other SLAM commands share."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, app
from seedmap.errors import SeedmapError


def slam_config(config: Optional[Path], overrides: Optional[List[str]]):
    from seedmap.config import load_config
    from seedmap.slam.config import SlamConfig

    return load_config(SlamConfig, config, overrides or [])


def print_slam_metrics(m, title: str) -> None:
    from rich.console import Console
    from rich.table import Table

    def f(v, unit="", pct=False):
        if v is None:
            return "–"
        return f"{100 * v:.1f} %" if pct else f"{v:.4f}{unit}"

    t = Table(title=title)
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_row("frames tracked / total", f"{m.frames_tracked} / {m.frames}")
    t.add_row("MDM", f"{f(m.mdm_m, ' m')} ({f(m.mdm_fraction, pct=True)})")
    t.add_row("GT-validated MDM", f"{f(m.gt_mdm_m, ' m')} ({f(m.gt_mdm_fraction, pct=True)})")
    t.add_row("ATE RMSE (SE3 / first pose)", f"{f(m.ate_rmse_m, ' m')} / {f(m.ate_first_pose_rmse_m, ' m')}")
    t.add_row("RPE trans RMSE", f(m.rpe_trans_rmse_m, " m"))
    t.add_row("lost", "never" if m.lost_frame is None else f"frame {m.lost_frame}: {m.lost_reason}")
    t.add_row("ms / frame", f"{m.ms_per_frame.get('total_per_frame', float('nan')):.1f}")
    Console().print(t)


@app.command("slam")
def slam_cmd(
    dataset: Path = typer.Argument(..., help="Stereo dataset (seedmap layout or any registered loader)."),
    out: Path = typer.Option(..., "--out", "-o", help="Result folder (written atomically)."),
    detector: Optional[str] = typer.Option(None, "--detector", "-d", help="Seed detector for --matcher seeds "
                                           "(default: the --config's detector, else the best real one; gt = the "
                                           "ORACLE)."),
    matcher: Optional[str] = typer.Option(None, "--matcher", "-m", help="seeds | sift | orb | akaze | surf "
                                          "(default: the --config's matcher, else seeds)"),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing seedmap slam result folder (and "
                                   "a --rerun recording seedmap wrote)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    rerun: Optional[Path] = typer.Option(None, "--rerun", help="Also record the run into this rerun .rrd file "
                                         "(view it with `rerun FILE.rrd`)."),
    follow: bool = typer.Option(False, "--follow", help="Live: DATASET is a folder a robot is writing (seedmap "
                                "layout; a frame counts once its times.txt line and both PNGs are complete); "
                                "--out gets the trajectory per frame and the map as it grows; stops after "
                                "--idle-timeout without a new frame or on Ctrl-C, with complete outputs."),
    idle_timeout: float = typer.Option(10.0, "--idle-timeout", min=0.1, help="--follow: stop after this many "
                                       "seconds without a new frame."),
) -> None:
    """Semantic stereo SLAM: trajectory, seed map and metrics (MDM, ATE, RPE) into --out."""
    from seedmap.slam.pipeline import run_slam

    cfg = slam_config(config, set_)
    res = run_slam(dataset, out, matcher=matcher, detector=detector, config=cfg, overwrite=overwrite,
                   progress=not quiet, rerun=rerun, inputs=[config] if config is not None else [],
                   follow=follow, idle_timeout_s=idle_timeout)
    from seedmap.detect import detector_label

    m = res.metrics
    det = f", detector {detector_label(m.detector, m.oracle_detector)}" if m.detector else ""
    print_slam_metrics(m, f"seedmap slam: {dataset.name} ({m.matcher}{det})")
    if follow:
        why = {"idle": f"no new frame for {idle_timeout:g} s", "interrupted": "Ctrl-C", "lost": "track lost",
               "max_frames": "max_frames reached"}[res.stop_reason]
        typer.echo(f"followed {dataset}: {m.frames_tracked} frames processed, stopped by {why}; at most "
                   f"{res.max_waiting} frames waiting")
    typer.echo(f"results in {out} (report.html)" + (f", rerun recording {rerun}" if rerun else ""))


@app.command("demo")
def demo_cmd(
    data: Path = typer.Option(Path("data/demo"), "--data", help="Where the demo range is simulated (kept)."),
    out: Path = typer.Option(Path("results/demo"), "--out", "-o", help="SLAM result folder (replaced)."),
    length: float = typer.Option(1.5, "--length", help="Demo range length (m)."),
    detector: Optional[str] = typer.Option(None, "--detector", help="Detector (default: best available)."),
) -> None:
    """Simulate a short range (once), detect seeds, run SLAM, print a summary table."""
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.slam.pipeline import run_slam

    # the demo replaces what it writes, so never a folder that is not its own (a EuRoC folder given as --data was
    # deleted and replaced by a simulated range; --out another folder would have been replaced by a SLAM result)
    if data.exists() and not SeedmapDataset.is_dataset(data) and (not data.is_dir() or any(data.iterdir())):
        raise SeedmapError(f"{data}: exists and is not a seedmap dataset; the demo simulates into a new or empty "
                           "folder (pass another --data; `seedmap slam` runs on your own data)")
    from seedmap.outputs import check_output_dir, output_kind

    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and output_kind(out) != "slam")):
        raise SeedmapError(f"{out}: exists and is not a seedmap slam result, which the demo would replace "
                           "(pass another --out)")
    check_output_dir(out, "slam", [data], overwrite=True)  # before simulating: never the data, nor around it
    if not SeedmapDataset.is_dataset(data):
        from seedmap.config import load_config
        from seedmap.sim import simulate_range
        from seedmap.sim.config import SimConfig

        typer.echo(f"simulating a {length:g} m range into {data} ...")
        sim_cfg = load_config(SimConfig, None, [f"world.length={length}"])
        simulate_range(sim_cfg, data, overwrite=True, progress=True)
    else:
        typer.echo(f"using the existing demo range {data}")
    if detector is None:
        from seedmap.detect import default_detector_name

        detector = default_detector_name()
    res = run_slam(data, out, matcher="seeds", detector=detector, overwrite=True, progress=True)
    from seedmap.detect import detector_label

    print_slam_metrics(res.metrics, f"seedmap demo: seeds matcher, detector {detector_label(detector)}")
    typer.echo(f"results in {out} (report.md, topview.png, landmarks.ply, trajectory.tum, panicles.csv, "
               "phenotype.html)")
