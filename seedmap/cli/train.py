"""``seedmap train ...``: the learned detectors, their refiners, the count calibration, ONNX export."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, train_app
from seedmap.errors import SeedmapError
from seedmap.outputs import check_output_file, check_resume_dir, is_seedmap_json, mark

#: ``train fast-cnn --init`` default: the network a fine-tune starts from (a shipped file name or a path)
DEFAULT_INIT = "fast_cnn_photo.onnx"
#: ``train fast-cnn --steps`` default (a fine-tune; the shipped networks were trained 5000 steps from scratch)
DEFAULT_STEPS = 1500
#: ``train fast-cnn --lr`` default
DEFAULT_LR = 2e-3
#: ``train fast-cnn --threads`` default (torch CPU threads: two threads on a busy 2-core machine ran 16x slower)
DEFAULT_THREADS = 1
#: fraction of a COCO fine-tune's crops from simulated rehearsal photos (seedmap.detect.replay)
DEFAULT_REPLAY = 0.5


def _train_common(kind: str, data: List[Path], out: Path, val: Optional[Path], images_root: Optional[Path],
                  preset: Optional[str], config: Optional[Path], set_: Optional[List[str]], resume: bool,
                  overwrite: bool) -> None:
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.config import load_config
    from seedmap.detect.labels import open_labelled, open_labelled_many
    from seedmap.detect.learned import train as tr
    from seedmap.detect.learned.presets import preset as preset_config

    cls = tr.DetectorTrainConfig if kind == "detector" else tr.SegmenterTrainConfig
    cfg = load_config(cls, config, set_ or [], base=preset_config(kind, preset))
    area = getattr(cfg, "min_gt_area", 3)
    src = open_labelled_many(data, images_root, min_area_px=area)
    vsrc = open_labelled(val, images_root, min_area_px=area) if val is not None else None
    fn = tr.train_detector if kind == "detector" else tr.train_segmenter
    p = fn(src, out, cfg, val_source=vsrc, resume=resume, overwrite=overwrite,
           inputs=[*data, val, images_root, config])
    typer.echo(f"{kind} weights written to {p} (metrics: {out / (kind + '_metrics.jsonl')})")


PresetOpt = typer.Option(None, "--preset", help="Training recipe: paper (full VGG16 / pix2pix, the defaults) or lite "
                                                "(reduced width, CPU-trainable: frcnn-pix2pix-lite).")


@train_app.command("detector")
def train_detector_cmd(
    data: List[Path] = typer.Argument(..., help="Simulated dataset folders (GT masks) or COCO .json files with "
                                               "boxes, read as one training set."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for detector.safetensors, checkpoint, metrics."),
    val: Optional[Path] = typer.Option(None, "--val", help="Held-out data (default: last val_fraction of DATA)."),
    images_root: Optional[Path] = typer.Option(None, "--images-root", help="COCO: folder of the image files."),
    resume: bool = typer.Option(False, "--resume", help="Continue from detector_checkpoint.safetensors."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Start over in a folder that holds weights."),
    preset: Optional[str] = PresetOpt,
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Train the Faster R-CNN (VGG16) seed detector (needs the learned extra, torch; a GPU for full training)."""
    _train_common("detector", data, out, val, images_root, preset, config, set_, resume, overwrite)


@train_app.command("segmenter")
def train_segmenter_cmd(
    data: List[Path] = typer.Argument(..., help="Simulated dataset folders (GT masks) or COCO .json files with "
                                               "masks, read as one training set."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for segmenter.safetensors/.onnx, checkpoint, metrics."),
    val: Optional[Path] = typer.Option(None, "--val", help="Held-out data (default: last val_fraction of DATA)."),
    images_root: Optional[Path] = typer.Option(None, "--images-root", help="COCO: folder of the image files."),
    resume: bool = typer.Option(False, "--resume", help="Continue from segmenter_checkpoint.safetensors."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Start over in a folder that holds weights."),
    preset: Optional[str] = PresetOpt,
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Train the pix2pix seed segmenter (U-Net + PatchGAN) on box crops (needs the learned extra, torch)."""
    _train_common("segmenter", data, out, val, images_root, preset, config, set_, resume, overwrite)


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
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a calibration file seedmap wrote."),
) -> None:
    """Fit a count calibration (seedmap.recon.calibrate) from reconstructions with known counts; use it with
    `seedmap count RESULT --set count.calibration=FILE` or `seedmap reconstruct ... --set count.calibration=FILE`."""
    from seedmap.config import load_config
    from seedmap.progress import track
    from seedmap.recon.calibrate import count_domain, fit_count_calibration, read_true_counts, save_count_calibration
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import recount_calibrated

    if out.suffix.lower() != ".json":
        raise SeedmapError(f"{out}: the calibration file must end in .json")
    # never one of the results or the counts; --overwrite replaces only a calibration seedmap wrote
    check_output_file(out, [*results, counts], overwrite, lambda p: is_seedmap_json(p, "domain"),
                      what="calibration file")
    names = tuple(f.strip() for f in features.split(",") if f.strip())
    truth_by: dict[str, float] = {}
    if counts is not None:
        truth_by = read_true_counts(counts)
    feats, truth, samples, domain = [], [], [], None
    for r in track(results, "counting", "result"):
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

    The defaults reproduce the shipped refiner (README, seed detection)."""
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.detect.train_refiner import CnnRefinerTrainConfig, train_cnn_refiner, validate
    from seedmap.io.atomic import atomic_write_text

    if steps < 1:
        raise SeedmapError(f"--steps must be >= 1, got {steps}")
    if not 0.0 < candidates < 1.0:  # a sigmoid peak score: 2 gave 'no CNN peaks in the training datasets'
        raise SeedmapError(f"--candidates must be a peak score in (0, 1), got {candidates:g}")
    for d in data:
        if not (d.is_dir() or (d.is_file() and d.suffix.lower() == ".json")):
            raise SeedmapError(f"{d}: dataset folder or COCO .json file not found")
    for d in val or []:
        if not d.is_dir():
            raise SeedmapError(f"{d}: validation dataset folder not found (--val scores simulated datasets)")
    check_resume_dir(out, "training", [*data, *(val or []), weights, images_root], strict=False)
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
    mark(out, "training")
    typer.echo(f"cnn-refiner written to {onnx_path} (weights and config: {target})")


@train_app.command("fast-cnn")
def train_fast_cnn_cmd(
    data: List[Path] = typer.Argument(..., help="Simulated training datasets with GT masks (e.g. data/det_s1) or "
                                                "COCO .json label files (boxes; masks used where present)."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for fast_cnn.onnx, checkpoint.safetensors, metrics."),
    val: Optional[List[Path]] = typer.Option(None, "--val", help="Held-out datasets or COCO files (default: the "
                                                                 "last frame / image of each)."),
    images_root: Optional[Path] = typer.Option(None, "--images-root",
                                               help="Folder of the COCO files' images (default: beside each file)."),
    steps: int = typer.Option(DEFAULT_STEPS, "--steps", help="Training steps (the shipped networks: 5000 from "
                                                                 "scratch)."),
    batch: int = typer.Option(12, "--batch", help="Crops per step."),
    crop: int = typer.Option(96, "--crop", help="Crop size (px)."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the initialisation and crops."),
    threads: int = typer.Option(DEFAULT_THREADS, "--threads", help="torch CPU threads."),
    c1: int = typer.Option(8, "--c1", help="Channels at full resolution."),
    c2: int = typer.Option(16, "--c2", help="Channels at half resolution."),
    c3: int = typer.Option(0, "--c3", help="Channels of a quarter-resolution context stage (0 = none; the shipped "
                                           "photo network: 32)."),
    seed_px: Optional[float] = typer.Option(None, "--seed-px", help="From scratch (--init none): the seed size (px) "
                                                                    "the network operates at; labelled images are "
                                                                    "resized to it (default: 5, the field "
                                                                    "network's)."),
    off_scale: float = typer.Option(0.0, "--off-scale", help="Fraction of crops shown at 0.3-0.5x or 2.2-3.2x "
                                                             "with their seeds as background (the network then "
                                                             "fires on its own seed size only)."),
    iou_weight: float = typer.Option(1.0, "--iou-weight", help="Weight of the box 1-GIoU loss (0 = L1 only)."),
    scale_prob: float = typer.Option(0.5, "--scale-prob", help="Fraction of crops rescaled by 0.8-1.7x."),
    replay: float = typer.Option(DEFAULT_REPLAY, "--replay", help="On COCO labels: fraction of the crops taken from "
                                                                  "simulated rehearsal photos, so that a fine-tune "
                                                                  "on a few photos keeps what the network knew "
                                                                  "(0 = none)."),
    heat_min_area: float = typer.Option(10.0, "--heat-min-area",
                                        help="Seeds with fewer visible px are no heatmap peaks (4-px slivers "
                                             "up to it are ignored)."),
    arm_fraction: Optional[float] = typer.Option(None, "--arm-fraction",
                                                 help="Fraction of the crops from arm-scan datasets (seedmap "
                                                      "simulate panicle) when ranges are given too (default: "
                                                      "every image alike)."),
    init: str = typer.Option(DEFAULT_INIT, "--init", help="Start from these fast_cnn .onnx weights (fine-tuning; "
                                                           "default: the shipped photo network); none = a random "
                                                           "initialisation (training from scratch)."),
    lr: float = typer.Option(DEFAULT_LR, "--lr", help="Adam learning rate (cosine decay to 3 % over the steps)."),
    val_fraction: float = typer.Option(0.2, "--val-fraction",
                                       help="COCO without --val: fraction of the labelled images held out (at "
                                            "least 1), drawn with --seed."),
    resume: bool = typer.Option(False, "--resume", help="Continue from OUT/checkpoint.safetensors."),
) -> None:
    """Train the fast detector's CNN (CenterNet-style heatmap + box; torch on CPU) and export it to ONNX.

    By default it fine-tunes the shipped photo network. On your own labelled images (COCO boxes, polygons or RLE
    masks): LABELS.json --images-root DIR; the images are resized so that the labelled seeds have the network's
    seed size, the held-out images' box F1 before and after is printed, and `seedmap detect --weights
    OUT/fast_cnn.onnx` runs the network at that scale. The shipped networks were trained with --init none
    (recipes: docs/method/detection.md)."""
    from seedmap.detect.learned import require_torch

    require_torch()
    from seedmap.detect.runtime import shipped_or_path
    from seedmap.detect.train_cnn import CnnTrainConfig, train_cnn

    init_p = None if init.strip().lower() == "none" else shipped_or_path(init)
    if init_p is not None and not init_p.is_file():
        raise SeedmapError(f"{init_p}: --init weights not found (a fast_cnn .onnx file, or none)")
    if seed_px is not None and (init_p is not None or not 2.0 <= seed_px <= 64.0):
        raise SeedmapError("--seed-px needs --init none (a fine-tune keeps its network's seed size) and a size of "
                           f"2-64 px, got {seed_px:g}" if init_p is None else
                           "--seed-px needs --init none (a fine-tune keeps its starting network's seed size)")
    if not 0.0 <= off_scale < 1.0:
        raise SeedmapError(f"--off-scale must be in [0, 1), got {off_scale:g}")
    if c3 < 0:
        raise SeedmapError(f"--c3 must be >= 0, got {c3}")
    if not 0.0 < val_fraction < 1.0:
        raise SeedmapError(f"--val-fraction must be in (0, 1), got {val_fraction:g}")
    for name, v in (("--steps", steps), ("--batch", batch), ("--crop", crop)):
        if v < 1:
            raise SeedmapError(f"{name} must be >= 1, got {v}")
    if not (math.isfinite(lr) and lr > 0):
        raise SeedmapError(f"--lr must be a finite number > 0, got {lr:g}")
    for d in list(data) + list(val or []):
        if d.suffix.lower() == ".json":
            if not d.is_file():
                raise SeedmapError(f"{d}: COCO label file not found")
        elif not d.is_dir():
            raise SeedmapError(f"{d}: dataset folder not found")
    check_resume_dir(out, "training", [*data, *(val or []), init_p, images_root], strict=False)
    if (out / "fast_cnn.onnx").exists() and not resume:
        raise SeedmapError(f"{out / 'fast_cnn.onnx'} exists (use --resume to continue, or another --out)")
    cfg = CnnTrainConfig(steps=steps, batch=batch, crop=crop, seed=seed, threads=threads, c1=c1, c2=c2, c3=c3,
                         seed_px=seed_px, off_scale=off_scale,
                         iou_weight=iou_weight, scale_prob=scale_prob, replay=replay, heat_min_area=heat_min_area,
                         arm_fraction=arm_fraction, lr=lr, val_fraction=val_fraction,
                         init_weights=str(init_p) if init_p else None)
    m = train_cnn(list(data), out, list(val) if val else None, cfg, resume=resume, images_root=images_root)
    mark(out, "training")
    f = m["final"] or {}
    typer.echo(f"fast-cnn written to {out / 'fast_cnn.onnx'} ({m['steps']} steps, {m['cpu_s']:.0f} s CPU; "
               f"held-out loss {f.get('val_loss', float('nan')):.3f}, box L1 {f.get('val_box_l1_px', float('nan')):.2f} px)")
    if "images_seed_px" in m:
        typer.echo(f"labelled seeds {m['images_seed_px']:.1f} px: images resized {m['labels_scale']:.3g}x to the "
                   f"network's {m['seed_px']:g}-px seeds (seedmap detect --weights applies the same scale)")
    if "val_f1" in m:
        c = m["val_counts"]
        before = (f"{m['val_f1_before']:.3f} before (the --init network), " if "val_f1_before" in m else "")
        typer.echo(f"held-out box F1 (IoU >= 0.5, {c['images']} images, {c['n_gt']} seeds): {before}"
                   f"{m['val_f1']:.3f} after (P {m['val_precision']:.3f}, R {m['val_recall']:.3f}, "
                   f"threshold {m['val_threshold']:g})")


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


@train_app.command("orb-vocabulary")
def train_orb_vocabulary_cmd(
    images: List[Path] = typer.Argument(..., help="Training images: image files, folders of images or dataset "
                                                  "folders (their rectified left images)."),
    out: Path = typer.Option(..., "--out", "-o", help="Vocabulary file to write (DBoW2 text, like ORBvoc.txt; "
                                                      "a name ending in .gz is gzipped)."),
    k: int = typer.Option(10, "--k", help="Branching factor of the k-means tree (DBoW2's k)."),
    levels: Optional[int] = typer.Option(None, "--levels", "-L",
                                         help="Depth of the tree (default: about 20 training features per word)."),
    features: int = typer.Option(2000, "--features", help="ORB features per image (ORB-SLAM3's nFeatures)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the k-means++ initialisation."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a vocabulary file."),
) -> None:
    """Train an ORB vocabulary for ORB-SLAM3 (`seedmap benchmark --methods orbslam3 --set
    orbslam3.vocabulary=FILE`): ORB-SLAM3's ORB features, a DBoW2 k-means tree, TF-IDF weights."""
    import gzip

    from seedmap.io.atomic import atomic_write_bytes
    from seedmap.peers import orb_vocabulary as ov
    from seedmap.progress import Progress, track

    if not 2 <= k <= 20 or (levels is not None and not 1 <= levels <= 10) or not 100 <= features <= 20000:
        raise SeedmapError("--k must be 2..20, --levels 1..10 and --features 100..20000 (DBoW2's and ORB-SLAM3's "
                           "limits)")

    def is_vocabulary(p: Path) -> bool:
        """A DBoW2 text vocabulary (gzipped or not): the only kind of file --overwrite replaces."""
        try:
            with (gzip.open(p, "rb") if p.suffix == ".gz" else open(p, "rb")) as fh:
                head = fh.readline(200).split()
            return len(head) == 4 and all(x.isdigit() for x in head)
        except (OSError, EOFError):
            return False

    check_output_file(out, images, overwrite, is_vocabulary, what="vocabulary file")
    todo = ov.training_images(images)
    per_image = [ov.orb_descriptors(load(), features) for _, load in track(todo, "ORB features", "image")]
    n_desc = sum(len(d) for d in per_image)
    L = levels if levels is not None else ov.levels_for(n_desc, k)
    with Progress(n_desc, f"k-means tree k={k} L={L}", "feature") as bar:
        voc = ov.train_vocabulary(per_image, k, L, seed, bar.advance)
    text = ov.vocabulary_text(voc).encode()
    atomic_write_bytes(out, gzip.compress(text, mtime=0) if out.suffix == ".gz" else text)
    typer.echo(f"ORB vocabulary written to {out}: {len(todo)} images, {n_desc} features, k={k}, L={L}, "
               f"{voc.n_words} words")
