"""``seedmap detect``: seeds (boxes, ellipses, keypoints) in every frame of a dataset (seedmap.detect)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import List, Optional

import typer

from seedmap.cli.app import ConfigOpt, SetOpt, app
from seedmap.errors import SeedmapError


@app.command("detect")
def detect_cmd(
    dataset: Path = typer.Argument(..., help="Dataset (seedmap layout or any supported format), an image file, "
                                             "or a folder of images (PNG/JPEG/TIFF...)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (must not exist unless --overwrite)."),
    detector: Optional[str] = typer.Option(None, "--detector", "-d",
                                           help="gt (ORACLE, simulated data) | fast (CNN + refiner) | "
                                                "frcnn-pix2pix | default (the --config's detector, else "
                                                "default = the best available)."),
    weights: Optional[Path] = typer.Option(None, "--weights",
                                           help="Weights: .safetensors of frcnn-pix2pix, .onnx of fast."),
    overlay: bool = typer.Option(False, "--overlay", help="Also write PNGs with the fitted ellipses drawn."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing seedmap detect result."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Detect seeds (boxes, ellipses, keypoints) in every frame or image: JSON lines + COCO JSON (+ overlays).

    The fast detector estimates the seeds' size (once per dataset; per image of a folder, then one size for the
    folder when its images agree; once per folder with --set cnn.scale=folder) and resizes the images when it
    differs from the network's; to set it: --set cnn.seed_px=N (px) or --set cnn.scale=F."""
    from seedmap.config import load_config
    from seedmap.detect import is_oracle_detector
    from seedmap.detect.run import DetectRunConfig, run_detect
    from seedmap.io.photos import is_photo_input

    cfg = load_config(DetectRunConfig, config, set_ or [])
    if is_photo_input(dataset, cfg.dataset.format):  # images: the photo network unless --config/--set say otherwise
        from seedmap.detect.config import PHOTO_DEFAULTS

        cfg = load_config(DetectRunConfig, config, set_ or [], base=copy.deepcopy(PHOTO_DEFAULTS))
    detector = detector or cfg.detector or "default"  # a result's config.yaml records what ran
    if weights is None and cfg.weights and detector == cfg.detector:
        weights = Path(cfg.weights)
    # the oracle reads seedmap's GT layout: say so for real data (run_detect says it for images)
    if is_oracle_detector(detector) and not is_photo_input(dataset, cfg.dataset.format):
        from seedmap.io.seedmap_dataset import SeedmapDataset

        SeedmapDataset(dataset)
    if weights is not None:  # only these two read --weights; the others would silently use their own
        from seedmap.detect import default_detector_name

        name = default_detector_name() if detector in ("default", "auto") else detector
        if name not in ("fast", "frcnn-pix2pix"):
            raise SeedmapError(f"--weights is read by --detector fast (.onnx) and frcnn-pix2pix only; "
                               f"{name!r} would ignore {weights} (use --detector fast --weights FILE)")
    p = run_detect(dataset, out, detector, weights, cfg, overlay=overlay, overwrite=overwrite,
                   inputs=[config, weights])
    line = scale_summary(p)
    if line:
        typer.echo(line)
    typer.echo(f"detections written to {p}")


def scale_summary(out: Path) -> str:
    """One line on the ``fast`` detector's seed size and input scale in a detect result (empty for others)."""
    import json

    from seedmap.detect.io import COCO_NAME

    meta = json.loads((out / "meta.json").read_text(encoding="utf-8"))
    if "scale_source" not in meta:
        return ""
    how = {"auto": "estimated", "scale": "set by cnn.scale", "seed_px": "set by cnn.seed_px",
           "network": "set by the network's images_seed_px"}[meta["scale_source"]]
    images = json.loads((out / COCO_NAME).read_text(encoding="utf-8"))["images"]
    per = [im for im in images if "cnn_scale" in im]
    if len({(im["seed_px"], im["cnn_scale"]) for im in per}) > 1:  # photos: one estimate each
        px = sorted(im["seed_px"] for im in per if im["seed_px"] is not None)
        sc = sorted(im["cnn_scale"] for im in per)
        size = f"{px[0]:.3g}-{px[-1]:.3g} px" if px else "no seeds found"
        agreed = ""
        if meta.get("folder_seed_px") is not None:
            agreed = (f"; the folder agreed on {meta['folder_seed_px']:.3g} px "
                      f"({meta['photos_rerun']} of {len(per)} photos ran again at it)")
        return f"seed size ({how}, per image): {size}; network input scale {sc[0]:.3g}-{sc[-1]:.3g}{agreed}"
    px = meta["seed_px_estimate"] if meta["scale_source"] == "auto" else meta["seed_px"]
    size = f"{px:.3g} px" if px is not None else "no seeds found"
    every = f", all {len(per)} images" if len(per) > 1 else ""
    return f"seed size ({how}{every}): {size}; network input scale {meta['cnn_scale']:.3g}"
