"""The ``seedmap`` command: one typer app, thin wrappers over the package's pipelines.

Every command that writes results writes into a fresh folder atomically (temporary name, then
rename) together with its resolved config. User errors print one line and exit with code 2.
"""

from __future__ import annotations

import json
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


@simulate_app.command("range")
def simulate_range_cmd(
    out: Path = typer.Option(..., "--out", "-o", help="Dataset folder to create."),
    length: Optional[float] = typer.Option(None, "--length", help="Range length in metres (default 4.0)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (every random choice flows from it)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="paper1 .. paper8 (the paper's range lengths)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    preview: bool = typer.Option(False, "--preview", help="Write preview.png (frames with GT centres)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing dataset folder."),
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
    path = simulate_range(cfg, out, overwrite=overwrite, progress=not quiet, preview=preview, stats=stats)
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


# ================================================================================================
# detect / train / eval detect (seedmap.detect)
# ================================================================================================


@app.command("detect")
def detect_cmd(
    dataset: Path = typer.Argument(..., help="Dataset folder (seedmap layout or any supported format)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (must not exist unless --overwrite)."),
    detector: Optional[str] = typer.Option(None, "--detector", "-d",
                                           help="gt (ORACLE, simulated data) | fast (CNN + refiner) | "
                                                "frcnn-pix2pix | default (the --config's detector, else "
                                                "default = the best available)."),
    weights: Optional[Path] = typer.Option(None, "--weights",
                                           help="Weights: .safetensors of frcnn-pix2pix, .onnx of fast."),
    overlay: bool = typer.Option(False, "--overlay", help="Also write PNGs with the fitted ellipses drawn."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output folder."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Detect seeds (boxes, ellipses, keypoints) in every frame: JSON lines + COCO JSON (+ overlays)."""
    from seedmap.config import load_config
    from seedmap.detect.run import DetectRunConfig, run_detect

    cfg = load_config(DetectRunConfig, config, set_ or [])
    detector = detector or cfg.detector or "default"  # a result's config.yaml records what ran
    if weights is None and cfg.weights and detector == cfg.detector:
        weights = Path(cfg.weights)
    if detector == "gt":  # the oracle reads seedmap's GT layout: say so for real data (was a TypeError traceback)
        from seedmap.io.seedmap_dataset import SeedmapDataset

        SeedmapDataset(dataset)
    if weights is not None:  # only these two read --weights; the others would silently use their own
        from seedmap.detect import default_detector_name

        name = default_detector_name() if detector in ("default", "auto") else detector
        if name not in ("fast", "frcnn-pix2pix"):
            raise SeedmapError(f"--weights is read by --detector fast (.onnx) and frcnn-pix2pix only; "
                               f"{name!r} would ignore {weights} (use --detector fast --weights FILE)")
    p = run_detect(dataset, out, detector, weights, cfg, overlay=overlay, overwrite=overwrite)
    typer.echo(f"detections written to {p}")


@eval_app.command("detect")
def eval_detect_cmd(
    dataset: Path = typer.Argument(..., help="Simulated dataset with ground truth."),
    detections: Path = typer.Argument(..., help="Folder written by `seedmap detect`."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Metrics JSON (default DETECTIONS/detect_metrics.json)."),
    iou: float = typer.Option(0.5, "--iou", help="Box IoU threshold for a true positive."),
    matching: str = typer.Option("greedy", "--matching", help="greedy | hungarian one-to-one matching."),
    min_gt_area: Optional[int] = typer.Option(
        None, "--min-gt-area",
        help="Ignore GT instances with fewer visible pixels (default: the detectable-seed size, "
             "10 px at 1434 px wide, scaled with the image: seedmap.detect.config; 0 scores every sliver)."),
    per_frame: bool = typer.Option(False, "--per-frame", help="Also print the per-frame table."),
) -> None:
    """Precision, recall, F1 (box IoU) and keypoint error (px) against GT, per frame and overall."""
    from rich.console import Console
    from rich.table import Table

    from seedmap.detect.run import run_eval_detect

    if matching not in ("greedy", "hungarian"):
        raise SeedmapError(f"--matching must be greedy or hungarian, got {matching!r}")
    if not 0.0 < iou <= 1.0:  # --iou 2 scored every detection a miss, exit 0
        raise SeedmapError(f"--iou must be in (0, 1], got {iou:g}")
    m, path = run_eval_detect(dataset, detections, out, iou, matching, min_gt_area)

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


def _train_common(kind: str, data: Path, out: Path, val: Optional[Path], images_root: Optional[Path],
                  config: Optional[Path], set_: Optional[List[str]], resume: bool, overwrite: bool) -> None:
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.config import load_config
    from seedmap.detect.labels import open_labelled
    from seedmap.detect.learned import train as tr

    cls = tr.DetectorTrainConfig if kind == "detector" else tr.SegmenterTrainConfig
    cfg = load_config(cls, config, set_ or [])
    src = open_labelled(data, images_root)
    vsrc = open_labelled(val, images_root) if val is not None else None
    fn = tr.train_detector if kind == "detector" else tr.train_segmenter
    p = fn(src, out, cfg, val_source=vsrc, resume=resume, overwrite=overwrite)
    typer.echo(f"{kind} weights written to {p} (metrics: {out / (kind + '_metrics.jsonl')})")


@train_app.command("detector")
def train_detector_cmd(
    data: Path = typer.Argument(..., help="Simulated dataset folder (GT masks) or a COCO .json with boxes."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for detector.safetensors, checkpoint, metrics."),
    val: Optional[Path] = typer.Option(None, "--val", help="Held-out data (default: last val_fraction of DATA)."),
    images_root: Optional[Path] = typer.Option(None, "--images-root", help="COCO: folder of the image files."),
    resume: bool = typer.Option(False, "--resume", help="Continue from detector_checkpoint.safetensors."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Start over in a folder that holds weights."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Train the Faster R-CNN (VGG16) seed detector (needs the learned extra, torch; a GPU for full training)."""
    _train_common("detector", data, out, val, images_root, config, set_, resume, overwrite)


@train_app.command("segmenter")
def train_segmenter_cmd(
    data: Path = typer.Argument(..., help="Simulated dataset folder (GT masks) or a COCO .json with masks."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for segmenter.safetensors/.onnx, checkpoint, metrics."),
    val: Optional[Path] = typer.Option(None, "--val", help="Held-out data (default: last val_fraction of DATA)."),
    images_root: Optional[Path] = typer.Option(None, "--images-root", help="COCO: folder of the image files."),
    resume: bool = typer.Option(False, "--resume", help="Continue from segmenter_checkpoint.safetensors."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Start over in a folder that holds weights."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Train the pix2pix seed segmenter (U-Net + PatchGAN) on box crops (needs the learned extra, torch)."""
    _train_common("segmenter", data, out, val, images_root, config, set_, resume, overwrite)


@train_app.command("count-calibration")
def train_count_calibration_cmd(
    results: List[Path] = typer.Argument(..., help="`seedmap reconstruct` results folders of panicles whose true "
                                                   "count is known (all with the same detector and settings)."),
    out: Path = typer.Option(..., "--out", "-o", help="Calibration file (.json) to write."),
    counts: Optional[Path] = typer.Option(None, "--counts", help="CSV `result,count` of true counts (e.g. by hand; "
                                                                 "result = folder path or name); default: the "
                                                                 "simulator's countable seeds in each metrics.json."),
    features: str = typer.Option("obs_fraction,seed_diam_mm", "--features",
                                 help="Comma-separated features (obs_fraction, seed_diam_mm; empty = a constant "
                                      "ratio only, for few panicles)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing calibration file."),
) -> None:
    """Fit a count calibration (seedmap.recon.calibrate) from reconstructions with known counts; use it with
    `seedmap count RESULT --set count.calibration=FILE` or `seedmap reconstruct ... --set count.calibration=FILE`."""
    from rich.progress import track

    from seedmap.config import load_config
    from seedmap.recon.calibrate import count_domain, fit_count_calibration, save_count_calibration
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import recount_calibrated

    if out.exists() and not overwrite:
        raise SeedmapError(f"{out} exists (use --overwrite to replace it)")
    if out.suffix.lower() != ".json":
        raise SeedmapError(f"{out}: the calibration file must end in .json")
    names = tuple(f.strip() for f in features.split(",") if f.strip())
    truth_by: dict[str, float] = {}
    if counts is not None:
        truth_by = _read_true_counts(counts)
    feats, truth, samples, domain = [], [], [], None
    for r in track(results, description="counting", transient=True):
        cfg_path = r / "config.yaml"
        if not cfg_path.is_file():
            raise SeedmapError(f"{cfg_path}: not found (is this a `seedmap reconstruct` results folder?)")
        cfg = load_config(ReconConfig, cfg_path, ["count.calibration=none"])
        if cfg.count.method != "multiview":
            raise SeedmapError(f"{r}: counted with method {cfg.count.method!r}; calibrations are for multiview")
        dom = count_domain(cfg)
        if domain is None:
            domain = dom
        elif (why := domain.mismatch(dom)) is not None:
            raise SeedmapError(f"{r}: differs from {results[0]}, which ran with {why}")
        if counts is not None:
            g = truth_by.get(str(r).rstrip("/"), truth_by.get(r.name))
            if g is None:
                raise SeedmapError(f"{counts}: no count for {r} (rows are `result,count`)")
        else:
            try:
                g = json.loads((r / "metrics.json").read_text())["gt"]["count_gt_countable"]
            except (OSError, ValueError, KeyError, TypeError):
                raise SeedmapError(f"{r / 'metrics.json'}: no ground-truth count (simulated scans have one; "
                                   "for your own panicles pass --counts)") from None
        _, cal = recount_calibrated(r, cfg)
        feats.append(cal.features)
        truth.append(float(g))
        samples.append(str(r))
    cal = fit_count_calibration(feats, truth, domain, samples, names,
                                truth_name=f"counts in {counts}" if counts is not None
                                else "GT countable seeds (>= 12 px in the left and right image of >= 2 views)")
    save_count_calibration(cal, out)
    f = cal.fit
    typer.echo(f"count calibration written to {out} ({len(feats)} panicles): MAPE raw {f['raw_mape_pct']:.2f} % -> "
               f"calibrated {f['calibrated_mape_pct']:.2f} % (leave-one-out {f['loo_mape_pct']:.2f} %)")


def _read_true_counts(path: Path) -> dict[str, float]:
    """``result,count`` rows (a header row is skipped) -> {result: count}."""
    import csv

    if not path.is_file():
        raise SeedmapError(f"{path}: counts file not found")
    out: dict[str, float] = {}
    with path.open(newline="") as fh:
        for i, row in enumerate(csv.reader(fh)):
            if not row or not "".join(row).strip():
                continue
            if len(row) != 2:
                raise SeedmapError(f"{path}: line {i + 1}: expected `result,count`, got {len(row)} fields")
            try:
                v = float(row[1])
            except ValueError:
                if i == 0:
                    continue  # header
                raise SeedmapError(f"{path}: line {i + 1}: count {row[1]!r} is not a number") from None
            if not v > 0:
                raise SeedmapError(f"{path}: line {i + 1}: count must be > 0, got {row[1]}")
            out[row[0].strip().rstrip("/")] = v
    if not out:
        raise SeedmapError(f"{path}: no `result,count` rows")
    return out


@train_app.command("cnn-refiner")
def train_cnn_refiner_cmd(
    data: List[Path] = typer.Argument(..., help="Training data: simulated datasets with GT masks (e.g. data/det_s40) "
                                                "or COCO .json files with instance masks."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for cnn_refiner.onnx (+ .safetensors) and metrics.json."),
    images_root: Optional[Path] = typer.Option(None, "--images-root",
                                               help="Folder of the COCO files' images (default: beside each file)."),
    val: Optional[List[Path]] = typer.Option(None, "--val", help="Validation datasets: box F1 per threshold."),
    weights: Optional[Path] = typer.Option(None, "--weights", help="The fast_cnn network whose peaks it refines "
                                                                   "(default: the shipped field network)."),
    candidates: float = typer.Option(0.25, "--candidates", help="The network's peak threshold for candidates."),
    patch_r: int = typer.Option(6, "--patch-r", help="Half size of the RGB patch (px)."),
    hidden: str = typer.Option("128,64", "--hidden", help="Hidden layer widths, comma-separated."),
    steps: int = typer.Option(30000, "--steps", help="Training steps (batch 512)."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the initialisation and batches."),
    min_gt_area: Optional[float] = typer.Option(None, "--min-gt-area",
                                                help="Visible px a GT seed needs to be a positive (default: the "
                                                     "detectable-seed size at the image width)."),
    thresholds: str = typer.Option("0.25,0.3,0.35,0.4,0.45", "--thresholds",
                                   help="--val: refined-score thresholds to report."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing refiner in OUT."),
) -> None:
    """Train the fast CNN's learned second stage (rescoring + box residual per heatmap peak; torch on CPU).

    The defaults reproduce the shipped refiner (README, seed detection, session 12)."""
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.detect.train_refiner import CnnRefinerTrainConfig, train_cnn_refiner, validate
    from seedmap.io.atomic import atomic_write_text

    for d in data:
        if not (d.is_dir() or (d.is_file() and d.suffix.lower() == ".json")):
            raise SeedmapError(f"{d}: dataset folder or COCO .json file not found")
    for d in val or []:
        if not d.is_dir():
            raise SeedmapError(f"{d}: validation dataset folder not found (--val scores simulated datasets)")
    target = out / "cnn_refiner.safetensors"
    if target.exists() and not overwrite:
        raise SeedmapError(f"{target} exists (use --overwrite to replace it)")
    try:
        hid = tuple(int(v) for v in hidden.split(",") if v.strip())
        ts = [float(v) for v in thresholds.split(",") if v.strip()]
    except ValueError:
        raise SeedmapError(f"--hidden {hidden!r} / --thresholds {thresholds!r}: comma-separated numbers expected") from None
    cfg = CnnRefinerTrainConfig(candidates=candidates, patch_r=patch_r, hidden=hid, steps=steps, seed=seed,
                                min_gt_area=min_gt_area)
    # creates OUT only when the weights are written
    onnx_path = train_cnn_refiner(list(data), target, cfg, weights, images_root=images_root)
    metrics = {"refiner": str(onnx_path), "train": [str(d) for d in data]}
    if val:
        metrics["validation"] = validate(list(val), onnx_path, ts, weights)
        for k, v in metrics["validation"]["pooled"].items():
            typer.echo(f"validation {k}: P {v['precision']:.4f} R {v['recall']:.4f} F1 {v['f1']:.4f}")
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=1))
    typer.echo(f"cnn-refiner written to {onnx_path} (weights and config: {target})")


@train_app.command("fast-cnn")
def train_fast_cnn_cmd(
    data: List[Path] = typer.Argument(..., help="Simulated training datasets with GT masks (e.g. data/det_s1)."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for fast_cnn.onnx, checkpoint.safetensors, metrics."),
    val: Optional[List[Path]] = typer.Option(None, "--val", help="Held-out datasets (default: last frame of each)."),
    steps: int = typer.Option(5000, "--steps", help="Training steps."),
    batch: int = typer.Option(12, "--batch", help="Crops per step."),
    crop: int = typer.Option(96, "--crop", help="Crop size (px)."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the initialisation and crops."),
    threads: int = typer.Option(1, "--threads", help="torch CPU threads."),
    c1: int = typer.Option(8, "--c1", help="Channels at full resolution (session 3: 12)."),
    c2: int = typer.Option(16, "--c2", help="Channels at half resolution (session 3: 24)."),
    iou_weight: float = typer.Option(1.0, "--iou-weight", help="Weight of the box 1-GIoU loss (0 = L1 only)."),
    scale_prob: float = typer.Option(0.5, "--scale-prob", help="Fraction of crops rescaled by 0.8-1.7x."),
    heat_min_area: float = typer.Option(10.0, "--heat-min-area",
                                        help="Seeds with fewer visible px are no heatmap peaks (4-px slivers "
                                             "up to it are ignored)."),
    arm_fraction: Optional[float] = typer.Option(None, "--arm-fraction",
                                                 help="Fraction of the crops from arm-scan datasets (seedmap "
                                                      "simulate panicle) when ranges are given too (default: "
                                                      "every image alike)."),
    init: Optional[Path] = typer.Option(None, "--init", help="Start from these fast_cnn .onnx weights "
                                                              "(fine-tuning) instead of a random initialisation."),
    lr: float = typer.Option(2e-3, "--lr", help="Adam learning rate (cosine decay to 3 % over the steps)."),
    resume: bool = typer.Option(False, "--resume", help="Continue from OUT/checkpoint.safetensors."),
) -> None:
    """Train the fast detector's CNN (CenterNet-style heatmap + box; torch on CPU) and export it to ONNX.

    The defaults reproduce the shipped weights (session 4) from data/det_s1 and det_s31-35, --val data/det_s36."""
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.detect.train_cnn import CnnTrainConfig, train_cnn

    for d in list(data) + list(val or []):
        if d.is_file() and d.suffix.lower() == ".json":  # said 'dataset folder not found' of an existing file
            raise SeedmapError(f"{d}: fast-cnn trains on simulated datasets (GT masks); COCO labels are read by "
                               "`seedmap train detector` and `seedmap train segmenter`")
        if not d.is_dir():
            raise SeedmapError(f"{d}: dataset folder not found")
    if (out / "fast_cnn.onnx").exists() and not resume:
        raise SeedmapError(f"{out / 'fast_cnn.onnx'} exists (use --resume to continue, or another --out)")
    cfg = CnnTrainConfig(steps=steps, batch=batch, crop=crop, seed=seed, threads=threads, c1=c1, c2=c2,
                         iou_weight=iou_weight, scale_prob=scale_prob, heat_min_area=heat_min_area,
                         arm_fraction=arm_fraction, lr=lr,
                         init_weights=str(init) if init else None)
    m = train_cnn(list(data), out, list(val) if val else None, cfg, resume=resume)
    f = m["final"] or {}
    typer.echo(f"fast-cnn written to {out / 'fast_cnn.onnx'} ({m['steps']} steps, {m['cpu_s']:.0f} s CPU; "
               f"held-out loss {f.get('val_loss', float('nan')):.3f}, box L1 {f.get('val_box_l1_px', float('nan')):.2f} px)")


@train_app.command("export")
def train_export_cmd(
    weights: Path = typer.Argument(..., help="Weights folder (detector/segmenter.safetensors) or one such file."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Folder for the .onnx files (default: beside the weights)."),
    score_threshold: float = typer.Option(0.05, "--score-threshold", help="Detector boxes below this are dropped in the graph."),
    nms_iou: float = typer.Option(0.3, "--nms-iou", help="NMS IoU baked into the detector graph (learned.nms_iou)."),
    max_detections: int = typer.Option(3000, "--max-detections", help="Box cap baked into the graph (learned.max_detections)."),
) -> None:
    """Export trained weights to ONNX (detector.onnx, segmenter.onnx) for onnxruntime; frcnn-pix2pix then uses them."""
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.detect.learned.export import export_weights

    for p in export_weights(weights, out, score_threshold=score_threshold, nms_iou=nms_iou,
                            max_detections=max_detections):
        typer.echo(f"exported {p}")


# ================================================================================================
# slam / demo / eval associate / eval slam (seedmap.associate, seedmap.slam)
# ================================================================================================


def _slam_config(config: Optional[Path], overrides: Optional[List[str]]):
    from seedmap.config import load_config
    from seedmap.slam.config import SlamConfig

    return load_config(SlamConfig, config, overrides or [])


def _print_slam_metrics(m, title: str) -> None:
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
                                           "(default: the --config's detector, else gt = oracle)."),
    matcher: Optional[str] = typer.Option(None, "--matcher", "-m", help="seeds | sift | orb | akaze | surf "
                                          "(default: the --config's matcher, else seeds)"),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing result folder."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    rerun: Optional[Path] = typer.Option(None, "--rerun", help="Also record the run into this rerun .rrd file "
                                         "(view it with `rerun FILE.rrd`)."),
) -> None:
    """Semantic stereo SLAM: trajectory, seed map and metrics (MDM, ATE, RPE) into --out."""
    from seedmap.slam.pipeline import run_slam

    cfg = _slam_config(config, set_)
    res = run_slam(dataset, out, matcher=matcher, detector=detector, config=cfg, overwrite=overwrite,
                   progress=not quiet, rerun=rerun)
    _print_slam_metrics(res.metrics, f"seedmap slam: {dataset.name} ({res.metrics.matcher})")
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
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / "metrics.json").is_file())):
        raise SeedmapError(f"{out}: exists and is not a seedmap slam result, which the demo would replace "
                           "(pass another --out)")
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
    _print_slam_metrics(res.metrics, f"seedmap demo: seeds matcher, detector {detector}")
    typer.echo(f"results in {out} (report.md, topview.png, landmarks.ply, trajectory.tum)")


@eval_app.command("associate")
def eval_associate_cmd(
    dataset: Path = typer.Argument(..., help="Simulated dataset with ground truth."),
    detector: str = typer.Option("gt", "--detector", "-d", help="Detector whose keypoints carry GT ids (gt)."),
    matcher: str = typer.Option("seeds", "--matcher", "-m"),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    max_frames: Optional[int] = typer.Option(None, "--max-frames", help="Only the first N frames."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write the report as JSON here."),
) -> None:
    """Stereo and temporal match precision / recall against ground-truth seed ids."""
    from rich.console import Console
    from rich.table import Table

    from seedmap.eval.associate_metrics import evaluate_association, write_report

    cfg = _slam_config(config, set_)
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
) -> None:
    """Recompute MDM, GT-validated MDM, ATE and RPE of a result folder against the dataset's GT."""
    from seedmap.slam.evaluate import evaluate_result_dir

    m = evaluate_result_dir(result, dataset, json_out)
    _print_slam_metrics(m, f"eval slam: {result.name}")


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
            if not s["available"]:
                t.add_row(m, "n/a", "n/a", "n/a", "n/a")
                continue
            t.add_row(m, pct(s["mean_fraction"]), pct(s["mean_gt_fraction"]),
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


# ================================================================================================
# reconstruct / count / simulate panicle (seedmap.recon)
# ================================================================================================


@simulate_app.command("panicle")
def simulate_panicle_cmd(
    out: Path = typer.Option(..., "--out", "-o", help="Dataset folder to create."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (panicle, arm errors, image noise)."),
    views: Optional[int] = typer.Option(None, "--views", help="Number of views around the panicle (default 36)."),
    exposure: Optional[str] = typer.Option(
        None, "--exposure", help="auto (default: exposed for the scan's stand-off) or a gain factor; 1.0 = the "
                                 "flash-saturated field gain of the scans of sessions 1-6."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing dataset folder."),
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
    path = simulate_panicle(cfg, out, overwrite=overwrite, progress=not quiet)
    typer.echo(f"wrote {path}")


@app.command("reconstruct")
def reconstruct_cmd(
    dataset: Path = typer.Argument(..., help="Arm scan: stereo pairs in any format seedmap reads (seedmap layout, "
                                             "image folder + calibration, bag) + joints.csv + arm.yaml (or "
                                             "--set joints=FILE --set arm=FILE)."),
    out: Path = typer.Option(..., "--out", "-o", help="Results folder to create."),
    register: Optional[str] = typer.Option(None, "--register", help="fk | full | seeds (default seeds)."),
    detector: Optional[str] = typer.Option(None, "--detector", help="Detector name (default gt = ORACLE)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing results folder."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    rerun: Optional[Path] = typer.Option(None, "--rerun", help="Also record the run into this rerun .rrd file "
                                         "(view it with `rerun FILE.rrd`)."),
) -> None:
    """3D model of one panicle from an arm scan: SGBM clouds, FK + ICP registration, seed count."""
    from seedmap.config import load_config
    from seedmap.errors import ConfigError
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import run_reconstruct

    extra = list(set_ or [])
    if register is not None:
        if register not in ("fk", "full", "seeds"):
            raise ConfigError(f"--register must be fk, full or seeds, got {register!r}")
        extra.append(f"registration.mode={register}")
    if detector is not None:
        extra.append(f"detector={detector}")
    cfg = load_config(ReconConfig, config, extra)
    if rerun is not None:  # the recording is written after the results: refuse a bad path before any work
        from seedmap.viz.rerun_log import check_rrd_path

        check_rrd_path(rerun)
    path, m = run_reconstruct(dataset, out, cfg, overwrite=overwrite, progress=not quiet, rerun=rerun)
    q = m["quality"]
    cal = m.get("seed_count_calibrated")
    typer.echo(f"{m['mode']}: {m['seed_count']} seeds" + (f" (calibrated estimate {cal:.0f})" if cal is not None
                                                          else "") + f", {m['cloud_points']} points, "
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
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing --out folder."),
) -> None:
    """Seed count of a reconstruction, re-run from its folder (default method multiview on detections.csv;
    e.g. --set count.mv_link_px=2.5, or --set count.method=rays for the 3D de-duplication)."""
    import json

    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from seedmap.config import dump_config, load_config
    from seedmap.errors import InputError
    from seedmap.io.atomic import atomic_output_dir, atomic_write_text
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import recount_calibrated, seeds_csv_text

    base_cfg = results / "config.yaml"
    if config is None and not base_cfg.is_file():
        raise InputError("config.yaml not found (is this a `seedmap reconstruct` results folder?)", base_cfg)
    if config is None and (results / "trajectory.tum").is_file() and not (results / "cloud.ply").is_file():
        raise InputError("a `seedmap slam` result folder; count needs a `seedmap reconstruct` one", results)
    cfg = load_config(ReconConfig, config if config is not None else base_cfg, list(set_ or []))
    c, cal = recount_calibrated(results, cfg)
    t = Table(title=f"seed count: {results}")
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
        with atomic_output_dir(out, overwrite=overwrite) as tmp:
            dump_config(cfg, tmp / "config.yaml")
            atomic_write_text(tmp / "seeds.csv", seeds_csv_text(c))
            atomic_write_text(tmp / "count.json", json.dumps({"results": str(results), **cal.as_dict()}, indent=2))
        typer.echo(f"wrote {out}")


# ================================================================================================
# bag-info / batch (seedmap.io, seedmap.viz)
# ================================================================================================


@app.command("bag-info")
def bag_info_cmd(
    bag: Path = typer.Argument(..., help="ROS1 .bag, ROS2 bag folder, .db3 or .mcap file."),
    sequence: bool = typer.Option(False, "--sequence", help="Also open it as a stereo sequence (topics, sync, calib)."),
    left_topic: Optional[str] = typer.Option(None, "--left-topic", help="Left image topic (else guessed)."),
    right_topic: Optional[str] = typer.Option(None, "--right-topic", help="Right image topic (else guessed)."),
    sync_tol: float = typer.Option(0.01, "--sync-tol", help="Stereo time-sync tolerance (s)."),
) -> None:
    """List a bag's topics, message types and counts (no ROS installation needed)."""
    from rich.console import Console
    from rich.table import Table

    from seedmap.io.rosbag import RosbagSequence, bag_info

    info = bag_info(bag)
    table = Table(title=f"{bag}  ({info.message_count} messages, {info.duration_s:.2f} s)")
    table.add_column("topic")
    table.add_column("type")
    table.add_column("count", justify="right")
    for t in info.topics:
        table.add_row(t.topic, t.msgtype, str(t.count))
    console = Console()
    console.print(table)
    if sequence:
        with RosbagSequence(bag, left_topic=left_topic, right_topic=right_topic, sync_tol_s=sync_tol) as seq:
            c = seq.calib
            console.print(f"stereo: {seq.left_topic} + {seq.right_topic}: {len(seq)} pairs, {seq.dropped} dropped; "
                          f"calib {c.width}x{c.height} fx={c.fx:.2f} baseline={c.baseline:.4f} m "
                          f"({'rectified' if seq.maps is None else 'rectified at load'})")
            # seq.warnings were reported on stderr as the loader found them (seedmap.io.common.LoaderWarnings)


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
                                           "(default: the --config's detector, else gt = oracle)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """SLAM on every range of a field (resumable; failing ranges are recorded, not fatal)."""
    from seedmap.batch import run_batch, summary_markdown

    cfg = _slam_config(config, set_)
    s = run_batch(field, out, matcher=matcher, detector=detector, config=cfg, workers=workers, ray=ray,
                  progress=not quiet)
    typer.echo(summary_markdown(s))
    typer.echo(f"summary in {out / 'summary.md'} ({s.n_ok} ok, {s.n_failed} failed)")
    if s.n_failed and not s.n_ok:  # one failing range is recorded, not fatal; a field where none ran is
        raise SeedmapError(f"all {s.n_failed} ranges failed (errors in {out / 'summary.md'})")


def main() -> None:
    """Console entry point: user errors become one line on stderr and exit code 2."""
    import logging

    log = logging.getLogger("seedmap")  # loader warnings (grey images converted, frames dropped): one line each
    for h in [h for h in log.handlers if getattr(h, "seedmap_cli", False)]:
        log.removeHandler(h)  # a previous main() in this process (tests): bind to the current sys.stderr
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("warning: %(message)s"))
    handler.seedmap_cli = True  # type: ignore[attr-defined]
    log.addHandler(handler)
    log.propagate = False
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
