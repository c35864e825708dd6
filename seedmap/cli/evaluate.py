"""``seedmap eval detect|associate|slam``: results against ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, eval_app
from seedmap.cli.slam import print_slam_metrics, slam_config
from seedmap.errors import SeedmapError
from seedmap.outputs import check_output_file, dataset_option_files, is_seedmap_json


def _check_json_out(path: Path, inputs: list, overwrite: bool, key: str) -> None:
    """A JSON output file: never an input; replaced (``--overwrite``) only when seedmap wrote it (it has ``key``)."""
    check_output_file(path, inputs, overwrite, lambda p: is_seedmap_json(p, key), what="JSON file")


@eval_app.command("detect")
def eval_detect_cmd(
    dataset: Path = typer.Argument(..., help="Simulated dataset with ground truth, or a COCO label file (.json) of "
                                             "the detected images (names relative to what was detected)."),
    detections: Path = typer.Argument(..., help="Folder written by `seedmap detect` (or its detections_coco.json)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Metrics JSON (default DETECTIONS/detect_metrics.json)."),
    iou: float = typer.Option(0.5, "--iou", help="Box IoU threshold for a true positive."),
    matching: str = typer.Option("greedy", "--matching", help="greedy | hungarian one-to-one matching."),
    min_gt_area: Optional[int] = typer.Option(
        None, "--min-gt-area",
        help="Ignore GT instances with fewer visible pixels (default: the detectable-seed size, "
             "10 px at 1434 px wide, scaled with the image: seedmap.detect.config; 0 scores every sliver; "
             "COCO labels: every labelled seed counts)."),
    per_frame: bool = typer.Option(False, "--per-frame", help="Also print the per-frame table."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an --out metrics file seedmap wrote."),
) -> None:
    """Precision, recall, F1 (box IoU) and keypoint error (px) against GT, per frame and overall."""
    from rich.console import Console
    from rich.table import Table

    from seedmap.detect.run import run_eval_detect

    if matching not in ("greedy", "hungarian"):
        raise SeedmapError(f"--matching must be greedy or hungarian, got {matching!r}")
    if not 0.0 < iou <= 1.0:  # --iou 2 scored every detection a miss, exit 0
        raise SeedmapError(f"--iou must be in (0, 1], got {iou:g}")
    if min_gt_area is not None and min_gt_area < 0:
        raise SeedmapError(f"--min-gt-area must be >= 0 px, got {min_gt_area}")
    m, path = run_eval_detect(dataset, detections, out, iou, matching, min_gt_area, overwrite=overwrite)

    def _f(x: Optional[float], nd: int = 3) -> str:
        return "-" if x is None else f"{x:.{nd}f}"

    con = Console()
    if per_frame:
        t = Table(title="per frame")
        for c in ("frame", "camera", "det", "gt", "TP", "P", "R", "F1", "kp med px"):
            t.add_column(c, justify="right")
        for r in m.per_frame:
            t.add_row(str(r.frame), r.camera, str(r.n_det), str(r.n_gt), str(r.tp), _f(r.precision), _f(r.recall),
                      _f(r.f1), _f(r.kp_err_median_px, 2))
        con.print(t)
    t = Table(title=f"detection vs GT (IoU >= {m.iou_threshold}, {m.matching})")
    for c in ("images", "det", "gt", "TP", "precision", "recall", "F1", "kp med px", "kp mean px", "kp p90 px",
              "kp <= 1px"):
        t.add_column(c, justify="right")
    t.add_row(str(len(m.per_frame)), str(m.n_det), str(m.n_gt), str(m.tp), _f(m.precision), _f(m.recall), _f(m.f1),
              _f(m.kp_err_median_px, 2), _f(m.kp_err_mean_px, 2), _f(m.kp_err_p90_px, 2), _f(m.kp_within_1px))
    con.print(t)
    typer.echo(f"metrics written to {path}")


@eval_app.command("associate")
def eval_associate_cmd(
    dataset: Path = typer.Argument(..., help="Simulated dataset with ground truth."),
    detector: str = typer.Option("gt", "--detector", "-d", help="Detector whose keypoints carry GT ids (gt)."),
    matcher: str = typer.Option("seeds", "--matcher", "-m"),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    max_frames: Optional[int] = typer.Option(None, "--max-frames", help="Only the first N frames."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write the report as JSON here."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an --out report seedmap wrote."),
) -> None:
    """Stereo and temporal match precision / recall against ground-truth seed ids."""
    from rich.console import Console
    from rich.table import Table

    from seedmap.eval.associate_metrics import evaluate_association, write_report

    if max_frames is not None and max_frames < 1:
        raise SeedmapError(f"--max-frames must be >= 1, got {max_frames}")
    cfg = slam_config(config, set_)
    if out is not None:
        _check_json_out(out, [dataset, config, *dataset_option_files(cfg.dataset)], overwrite, "temporal")
    rep = evaluate_association(dataset, detector=detector, matcher=matcher, config=cfg, max_frames=max_frames)
    t = Table(title=f"association: {dataset.name} ({matcher}, detector {detector})")
    for c in ("", "matches", "correct", "possible", "precision", "recall", "recall (gated)"):
        t.add_column(c, justify="right")
    for name, s in (("stereo", rep.stereo), ("temporal", rep.temporal)):
        f = lambda v: "–" if v is None else f"{v:.4f}"  # noqa: E731
        t.add_row(name, str(s["matches"]), str(s["correct"]), str(s["possible"]), f(s["precision"]),
                  f(s["recall"]), f(s["recall_gated"]))
    Console().print(t)
    if rep.cpu_ms_per_frame:
        typer.echo("association CPU ms/frame: " + ", ".join(f"{k} {v:.0f}" for k, v in rep.cpu_ms_per_frame.items()))
    if out is not None:
        write_report(rep, out)
        typer.echo(f"report in {out}")


@eval_app.command("slam")
def eval_slam_cmd(
    result: Path = typer.Argument(..., help="A folder written by `seedmap slam`."),
    dataset: Path = typer.Argument(..., help="The dataset it ran on (with ground truth)."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the recomputed metrics here."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a --json metrics file seedmap wrote."),
) -> None:
    """Recompute MDM, GT-validated MDM, ATE and RPE of a result folder against the dataset's GT."""
    from seedmap.slam.evaluate import evaluate_result_dir

    if json_out is not None:
        _check_json_out(json_out, [result, dataset], overwrite, "frames_tracked")

    m = evaluate_result_dir(result, dataset, json_out)
    print_slam_metrics(m, f"eval slam: {result.name}")
