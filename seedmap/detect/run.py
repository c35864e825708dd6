"""``seedmap detect`` and ``seedmap eval detect`` as library functions."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from seedmap import outputs
from seedmap.detect.autoscale import folder_agreement
from seedmap.detect.base import Detector, default_detector_name, is_oracle_detector, make_detector
from seedmap.detect.config import DetectConfig
from seedmap.detect.ellipse import draw_ellipses
from seedmap.detect.io import detection_image_sizes, detection_record, read_detections, write_detection_files
from seedmap.errors import InputError
from seedmap.io.atomic import atomic_write_text
from seedmap.io.images import write_png
from seedmap.io.photos import PhotoSet, is_photo_input
from seedmap.progress import track

#: ``cnn.scale = folder``: the folder's seed size is the median estimate on this many photos spread over it
FOLDER_SAMPLE = 9


class DetectRunConfig(DetectConfig):
    """What ``seedmap detect`` writes as a result's ``config.yaml``: the detector settings plus which detector
    and weights ran, so that ``seedmap detect DATA --config RESULT/config.yaml`` repeats the run (the
    ``--detector`` / ``--weights`` options override them). A plain :class:`DetectConfig` file (no ``detector``
    key, e.g. a SLAM config's ``detect`` section) loads too: None means the options' defaults (the best
    available detector, its shipped weights)."""

    #: registry name (gt | fast | frcnn-pix2pix); ``default`` is resolved when written
    detector: str | None = None
    #: weights file read by fast (.onnx) or frcnn-pix2pix (.safetensors); None = the shipped ones
    weights: str | None = None


def run_detect(dataset: str | Path, out: str | Path, detector: str = "default", weights: str | Path | None = None,
               config: DetectConfig | None = None, overlay: bool = False, overwrite: bool = False,
               progress: bool = True, frames: slice | None = None, inputs: Sequence[str | Path | None] = ()) -> Path:
    """Detect seeds in every frame and camera of ``dataset``, or in every image of an image file or folder
    (:mod:`seedmap.io.photos`); write the detection files into ``out``.

    ``out`` gets ``detections.jsonl`` + ``detections_coco.json`` (see :mod:`seedmap.detect.io`),
    ``config.yaml`` (the resolved detector config), ``meta.json`` (detector name, oracle flag, timing, the
    ``fast`` detector's input scale, seed size and how it was set: a stereo sequence's from its first frame, a photo
    folder's from its last photo (with ``cnn.scale = folder`` the folder's); each photo's own is in its
    ``detections_coco.json`` image entry) and, with ``overlay``, ``overlay/{left,right}/NNNNNN.png`` (images:
    ``overlay/NAME.png``) with the ellipses drawn. Images keep their names relative to ``dataset``.
    ``inputs``: more files the command read (``--config``, ``--weights``): ``out`` is never one of them.
    """
    from seedmap.config import dump_config

    cfg = config or DetectConfig()
    if isinstance(cfg, DetectRunConfig):  # the detector's own settings only (they forbid unknown keys)
        cfg = DetectConfig.model_validate(cfg.model_dump(exclude={"detector", "weights"}))
    ins = [dataset, *inputs, *outputs.dataset_option_files(cfg.dataset)]
    outputs.check_output_dir(Path(out), "detect", ins, overwrite)
    photos = PhotoSet(dataset) if is_photo_input(dataset, cfg.dataset.format) else None
    if photos is not None and is_oracle_detector(detector):
        raise InputError(f"the {detector} oracle reads a simulated stereo dataset's ground truth; this is an "
                         "image or a folder of images (use --detector fast)", dataset)
    seq = photos if photos is not None else cfg.dataset.open(dataset)
    det = make_detector(detector, dataset=seq if is_oracle_detector(detector) else None, weights=weights, config=cfg)
    idx = list(range(len(seq)))[frames] if frames is not None else list(range(len(seq)))
    if not idx:
        raise InputError("dataset has no frames", dataset)
    with outputs.output_dir(Path(out), "detect", ins, overwrite) as tmp:
        run = _detect_photos if photos is not None else _detect_frames
        records, t_det, folder = run(det, seq, idx, tmp if overlay else None, progress)
        write_detection_files(tmp, records)
        used = default_detector_name() if detector in ("default", "auto") else detector
        run_cfg = DetectRunConfig.model_validate({**cfg.model_dump(), "detector": used,
                                                 "weights": str(Path(weights).resolve()) if weights else None})
        dump_config(run_cfg, tmp / "config.yaml")
        meta = {"detector": det.name, "oracle": bool(det.is_oracle), "dataset": str(Path(dataset).resolve()),
                "weights": str(weights) if weights else None, "frames": len(idx),
                "refiner": str(getattr(det, "refiner", None).path) if hasattr(getattr(det, "refiner", None), "path")
                else None,
                "images": len(records), "detections": int(sum(r["n"] for r in records)),
                ("ms_per_image" if photos is not None else "ms_per_stereo_frame"): 1000.0 * t_det / len(idx),
                **det.settings(), **folder}
        atomic_write_text(tmp / "meta.json", json.dumps(meta, indent=2))
    return Path(out)


def _detect_frames(det: Detector, seq, idx: list[int], overlay_dir: Path | None,  # noqa: ANN001 - a StereoSequence
                   progress: bool) -> tuple[list[dict], float, dict]:
    """Detection records of the stereo frames ``idx`` (left and right), the seconds spent detecting and no
    folder entries for meta.json."""
    records, t_det = [], 0.0
    for i in track(idx, f"detect ({det.name})", "frame", enabled=progress):
        frame = seq[i]
        t0 = time.perf_counter()
        sd = det.detect_stereo(frame)
        t_det += time.perf_counter() - t0
        for cam, d, img in (("left", sd.left, frame.left), ("right", sd.right, frame.right)):
            records.append(detection_record(i, cam, d, frame.timestamp, f"{cam}/{i:06d}.png",
                                            img.shape[1], img.shape[0]))
            if overlay_dir is not None:
                write_png(overlay_dir / "overlay" / cam / f"{i:06d}.png", draw_ellipses(img, d.ellipses))
    return records, t_det, {}


def _detect_photos(det: Detector, photos: PhotoSet, idx: list[int], overlay_dir: Path | None,
                   progress: bool) -> tuple[list[dict], float, dict]:
    """Detection records (camera ``mono``, the image's own name) of the images ``idx``, the seconds spent
    detecting and meta.json's folder entries (with ``cnn.scale = auto``: ``folder_seed_px`` / ``folder_run_px``, the
    sizes the folder agreed on or None, and ``photos_rerun``). Overlays are ``overlay/NAME.png`` (NAME with its
    suffix replaced; kept when two names share a stem). With ``cnn.scale = auto`` each photo's seed size is estimated
    in it; when the folder agrees on one (:func:`seedmap.detect.autoscale.folder_agreement`) the photos that ran at
    another size (or found no seeds) run again at the folder's."""
    stems = [str(Path(n).with_suffix(".png")) for n in photos.names]
    over = stems if len(set(stems)) == len(stems) else [n if n.endswith(".png") else n + ".png" for n in photos.names]
    t_det = 0.0
    reset = getattr(det, "reset_scale", None)  # the fast detector: a fresh seed-size estimate per photo
    per_photo = reset is not None and getattr(det, "scale_source", None) == "auto"
    source = "photo" if per_photo else getattr(det, "scale_source", None)  # each record's seed_px_from
    if per_photo and det.cfg.scale == "folder":
        t0 = time.perf_counter()
        det.set_seed_px_estimate(*folder_seed_px(det, photos, idx, progress))
        t_det += time.perf_counter() - t0
        per_photo, source = False, "folder"  # one seed size for every photo

    def one(k: int, label: str) -> tuple[dict, float]:
        i = idx[k]
        img = photos.image(i)
        t0 = time.perf_counter()
        d = det.detect(img)
        dt = time.perf_counter() - t0
        rec = detection_record(i, "mono", d, 0.0, photos.names[i], img.shape[1], img.shape[0])
        if reset is not None:
            s = det.settings()
            px = s["seed_px_estimate"] if s["scale_source"] == "auto" else s["seed_px"]
            rec.update(seed_px=None if px is None else round(float(px), 3), cnn_scale=round(s["cnn_scale"], 6),
                       seed_px_from=label)
        if overlay_dir is not None:
            write_png(overlay_dir / "overlay" / over[i], draw_ellipses(img, d.ellipses))
        return rec, dt

    records, estimates = [], []
    for k in track(range(len(idx)), f"detect ({det.name})", "image", enabled=progress):
        if per_photo:
            reset()
        rec, dt = one(k, source)
        records.append(rec)
        t_det += dt
        if per_photo:
            estimates.append((det.seed_px_estimate, det.run_px_estimate))
    if not per_photo:
        return records, t_det, {}
    agreed = folder_agreement(estimates)
    if agreed is None:
        return records, t_det, {"folder_seed_px": None, "folder_run_px": None, "photos_rerun": 0}
    seed_px, run_px, redo = agreed
    det.set_seed_px_estimate(seed_px, run_px)  # kept for every photo below: detect() estimates only without a scale
    for k in track(np.flatnonzero(redo).tolist(), "detect (the folder's seed size)", "image", enabled=progress):
        records[k], dt = one(k, "folder")
        t_det += dt
    return records, t_det, {"folder_seed_px": round(seed_px, 3), "folder_run_px": round(run_px, 3),
                            "photos_rerun": int(redo.sum())}


def folder_seed_px(det: Detector, photos: PhotoSet, idx: list[int], progress: bool = False
                   ) -> tuple[float | None, float | None]:
    """``cnn.scale = folder``: the median seed size (px) the ``fast`` detector ``det`` estimates on up to
    FOLDER_SAMPLE of the photos ``idx``, evenly spread, and the median size it would run the network for
    (photos without seeds found do not count; None when no photo gave an estimate)."""
    pick = [idx[int(k)] for k in np.unique(np.linspace(0, len(idx) - 1, min(FOLDER_SAMPLE, len(idx))).round())]
    est, run = [], []
    for i in track(pick, "seed size", "image", enabled=progress):
        det.reset_scale()
        det.ensure_scale(photos.image(i))
        if det.seed_px_estimate is not None and det.run_px_estimate is not None:
            est.append(det.seed_px_estimate)
            run.append(det.run_px_estimate)
    det.reset_scale()
    return (float(np.median(est)), float(np.median(run))) if est else (None, None)


def run_eval_detect(dataset: str | Path, detections_dir: str | Path, out_json: str | Path | None = None,
                    iou_threshold: float = 0.5, matching: str = "greedy", min_gt_area: float | None = None,
                    progress: bool = True, overwrite: bool = False):
    """Evaluate a detections folder against a simulated dataset's GT, or against a COCO label file (``dataset`` a
    ``.json``: :func:`_eval_detect_labels`); writes ``detect_metrics.json``.

    ``min_gt_area=None`` ignores GT slivers below the detectable-seed size at the dataset's width
    (seedmap.detect.config.min_visible_seed_px, the same rule as the ``gt`` oracle); 0 scores all.
    An ``out_json`` of its own is never an input, and replaces only a metrics file seedmap wrote (``overwrite``)."""
    from seedmap.detect.config import min_visible_seed_px
    from seedmap.eval.detect_metrics import evaluate_detections
    from seedmap.io.seedmap_dataset import SeedmapDataset

    if out_json is not None:
        outputs.check_output_file(Path(out_json), [dataset, detections_dir], overwrite,
                                  lambda p: outputs.is_seedmap_json(p, "min_gt_area_px"), what="metrics file")
    if Path(dataset).suffix.lower() == ".json":
        return _eval_detect_labels(Path(dataset), Path(detections_dir), out_json, iou_threshold, matching,
                                   min_gt_area or 0.0)
    ds = SeedmapDataset(dataset)
    if not (Path(dataset) / "gt" / "instances").is_dir():
        raise InputError("dataset has no ground truth (gt/instances/) to evaluate against", dataset)
    dets = read_detections(detections_dir)
    missing = [k for k in dets if k[0] >= len(ds)]
    if missing:
        raise InputError(f"detections refer to frame {missing[0][0]} but the dataset has {len(ds)} frames",
                         detections_dir)
    other = detection_image_sizes(detections_dir) - {(int(ds.calib.width), int(ds.calib.height))}
    if other:
        w, h = sorted(other)[0]
        raise InputError(f"detections were made on {w}x{h} images but the dataset's are "
                         f"{ds.calib.width}x{ds.calib.height} (detections of another dataset?)", detections_dir)
    if min_gt_area is None:
        min_gt_area = min_visible_seed_px(ds.calib.width)
    m = evaluate_detections(ds, dets, iou_threshold, matching, min_gt_area, progress)  # type: ignore[arg-type]
    return m, _write_detect_metrics(m, Path(dataset), Path(detections_dir), out_json, float(min_gt_area))


def _write_detect_metrics(m, dataset: Path, detections: Path, out_json: str | Path | None,  # noqa: ANN001
                          min_gt_area: float) -> Path:
    """``detect_metrics.json`` (``out_json``, else beside the detections) with the detector's name from meta.json."""
    det_dir = detections if detections.is_dir() else detections.parent
    out = Path(out_json) if out_json else det_dir / "detect_metrics.json"
    d = m.to_dict()
    meta_p = det_dir / "meta.json"
    if meta_p.is_file():
        try:
            d["detector"] = json.loads(meta_p.read_text(encoding="utf-8")).get("detector")
        except ValueError:  # not JSON, or not UTF-8 text: the detector name is left out
            pass
    d["dataset"] = str(dataset.resolve())
    d["min_gt_area_px"] = float(min_gt_area)
    text = json.dumps(d, indent=2, default=lambda x: float(x) if isinstance(x, np.floating) else x)
    with outputs.os_errors(out):
        atomic_write_text(out, text)
    return out


def _read_coco_detections(path: Path) -> dict[str, tuple]:
    """``{image name: (Detections, width, height)}`` of a ``seedmap detect`` folder's ``detections_coco.json`` (or
    that file itself): boxes from ``bbox``, scores, keypoints from ``keypoints`` (else the box centre)."""
    from seedmap.detect.io import COCO_NAME
    from seedmap.io.text import read_text
    from seedmap.records import Detections

    p = path / COCO_NAME if path.is_dir() else path
    if not p.is_file():
        raise InputError(f"no {COCO_NAME} found (write one with `seedmap detect`)", p)
    try:
        d = json.loads(read_text(p, COCO_NAME))
        ims = {im["id"]: (str(im["file_name"]), int(im.get("width") or 0), int(im.get("height") or 0))
               for im in d["images"]}
        per: dict = {i: [] for i in ims}
        for a in d["annotations"]:
            x, y, w, h = (float(v) for v in a["bbox"])
            kp = a.get("keypoints") or [x + w / 2 - 0.5, y + h / 2 - 0.5]
            per[a["image_id"]].append((x, y, x + w, y + h, float(a.get("score", 1.0)), float(kp[0]), float(kp[1])))
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise InputError(f"not a seedmap detections COCO file ({type(e).__name__}: {e})", p) from None
    out = {}
    for i, (name, w, h) in ims.items():
        r = np.asarray(per[i], np.float64).reshape(-1, 7)
        bw, bh = r[:, 2] - r[:, 0], r[:, 3] - r[:, 1]
        ell = np.c_[r[:, 5], r[:, 6], np.maximum(bw, bh), np.minimum(bw, bh), np.zeros(len(r))]
        out[name] = (Detections(boxes=r[:, :4], scores=r[:, 4], ellipses=ell), w, h)
    return out


def _eval_detect_labels(labels: Path, detections: Path, out_json: str | Path | None, iou_threshold: float,
                        matching: str, min_gt_area: float):  # noqa: ANN202 - (DetectMetrics, Path)
    """Score a ``seedmap detect`` output against a COCO label file: the label file's images are found among the
    detected images by name (the path relative to what was detected; else the bare file name when that is
    unique); detected images without labels are left out. Every labelled seed counts unless ``min_gt_area`` > 0."""
    from seedmap.detect.labels import read_coco_boxes
    from seedmap.eval.detect_metrics import evaluate_labelled

    gt = read_coco_boxes(labels)
    dets = _read_coco_detections(detections)
    by_base: dict = {}
    for name in dets:
        by_base.setdefault(Path(name).name, []).append(name)
    matched = {}
    for g in gt:
        name = g["file_name"]
        if name not in dets:
            cand = by_base.get(Path(name).name, [])
            if len(cand) != 1:
                raise InputError(f"image {name!r} has no detections in {detections} (detect the folder the labels' "
                                 "file names are relative to)", labels)
            name = cand[0]
        det, w, h = dets[name]
        if w and h and g["width"] and g["height"] and (w, h) != (int(g["width"]), int(g["height"])):
            raise InputError(f"image {g['file_name']!r} is {g['width']}x{g['height']} in the labels but the "
                             f"detections were made on {w}x{h} pixels", labels)
        matched[g["file_name"]] = det
    m = evaluate_labelled(gt, matched, iou_threshold, matching, min_gt_area)  # type: ignore[arg-type]
    return m, _write_detect_metrics(m, labels, detections, out_json, min_gt_area)
