"""Accuracy and cost of the ``fast`` detector's seed-size estimate (``cnn.scale = auto``) on rescaled images.

For every dataset (a simulated seedmap dataset with GT, or a COCO label file whose image entries carry ``seed_px``),
a few images (left camera) are rescaled by each factor (cv2.resize, INTER_AREA down / INTER_LINEAR up). The true seed
size is the median geometric mean of the GT box sides of the detectable seeds (instances of at least
min_visible_seed_px(width) visible px; COCO: the image's ``seed_px``) times the factor. Per image and factor: the
estimate, its relative error and time, and the box F1 (IoU 0.5, greedy; GT boxes scaled) of the detector with
``cnn.scale = auto`` and with the true seed size forced (``cnn.seed_px``). A band section: box F1 of the network at
scale 1 on rescaled images (what SCALE_BAND is chosen from). A ``--curve`` section (COCO photos at their own size):
box F1 with the input scale at 2^(k/8) x the true seed size's, at the scale auto picks and at the seed-size
estimate's. A timing section: one estimate on a synthetic ~18 MP
image (a frame upscaled 4x, cropped to 4912x3684).

    python benchmarks/bench_autoscale.py --dataset /work/ref/demo_data --dataset ARM_SCAN:arm --frames 2
    python benchmarks/bench_autoscale.py --dataset photos/labels.json   # COCO labels with per-image seed_px

A dataset ``PATH:arm`` runs the shipped arm network. Writes benchmarks/results/autoscale.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seedmap.detect.autoscale import estimate_seed_px  # noqa: E402
from seedmap.detect.base import make_detector  # noqa: E402
from seedmap.detect.config import min_visible_seed_px  # noqa: E402
from seedmap.eval.detect_metrics import frame_metrics, prf  # noqa: E402

FACTORS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)
#: ``--curve``: input scales relative to the one that brings the true seed size to the network's
CURVE_REL = tuple(float(2.0 ** (k / 8)) for k in range(-4, 5))
BAND_FACTORS = (0.5, 0.6, 0.7, 0.8, 1.0, 1.2, 1.4, 1.7, 2.0)


def resize(img: np.ndarray, f: float) -> np.ndarray:
    h, w = img.shape[:2]
    size = (max(1, int(round(w * f))), max(1, int(round(h * f))))
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)


def seedmap_images(path: Path, n: int) -> list[dict]:
    """``n`` left images of a simulated dataset spread over it, with GT boxes, areas and detectable mask."""
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(path)
    out = []
    for i in np.linspace(0, len(ds) - 1, n).round().astype(int):
        img = ds[int(i)].left
        gt = ds.gt_instances(int(i), "left")
        keep = gt.area >= min_visible_seed_px(img.shape[1])
        b = gt.boxes[keep]
        true = float(np.median(np.sqrt((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])))) if len(b) else None
        out.append({"name": f"{path.name}/left/{int(i):06d}", "image": img, "true": true, "boxes": gt.boxes,
                    "area": gt.area, "min_area": min_visible_seed_px(img.shape[1])})
    return out


def coco_images(path: Path, n: int) -> list[dict]:
    """``n`` images of a COCO label file (images next to it) with their ``seed_px`` and annotation boxes."""
    from seedmap.io.images import read_rgb

    coco = json.loads(path.read_text(encoding="utf-8"))
    anns: dict[int, list] = {}
    for a in coco["annotations"]:
        anns.setdefault(a["image_id"], []).append(a)
    ims = [im for im in coco["images"] if im.get("seed_px")]
    out = []
    for k in np.linspace(0, len(ims) - 1, min(n, len(ims))).round().astype(int):
        im = ims[int(k)]
        a = anns.get(im["id"], [])
        bb = np.array([x["bbox"] for x in a], np.float64).reshape(-1, 4)
        boxes = np.concatenate([bb[:, :2], bb[:, :2] + bb[:, 2:]], axis=1)
        area = np.array([x.get("area", x["bbox"][2] * x["bbox"][3]) for x in a], np.float64)
        out.append({"name": im["file_name"], "image": read_rgb(path.parent / im["file_name"]),
                    "true": float(im["seed_px"]), "boxes": boxes, "area": area, "min_area": 0.0})
    return out


def f1(det, item: dict, f: float) -> tuple[int, int, int]:  # noqa: ANN001 - a Detections
    """(tp, n_det, n_gt) of ``det`` against the item's GT scaled by ``f``."""
    b = np.asarray(item["boxes"], np.float64) * f
    gt = SimpleNamespace(boxes=b, area=np.asarray(item["area"], np.float64) * f * f,
                         center_visible=np.zeros(len(b), bool), center_uv=(b[:, :2] + b[:, 2:]) / 2)
    m, _ = frame_metrics(det, gt, min_gt_area=item["min_area"] * f * f)
    return m.tp, m.n_det, m.n_gt


def dataset_spec(spec: str, default: str = "field") -> tuple[Path, str, list[str]]:
    """``PATH[:arm|:photo|:field]`` -> the path, the network's domain (``default`` without a suffix) and the
    detector overrides it runs with (photos as `seedmap detect` runs them, PHOTO_DEFAULTS: the whole image in one
    pass)."""
    path, _, domain = spec.rpartition(":") if spec.endswith((":arm", ":photo", ":field")) else (spec, "", default)
    return Path(path), domain, [f"cnn.domain={domain}", *(["cnn.tile=0"] if domain == "photo" else [])]


def scale_curve(spec: str) -> dict:
    """Pooled box F1 of the network (``spec`` = labels.json[:domain], photo by default) on every labelled image with
    a ``seed_px``: run at CURVE_REL x the scale that brings its true seed size to the network's (``rel``), at the
    scale ``cnn.scale = auto`` picks (``auto``: the best ladder level of the score cue) and at the scale of the
    seed-size estimate itself (``estimate``)."""
    path, _, opts = dataset_spec(spec, "photo")
    det = make_detector("fast", overrides=opts)
    op = det.trained_seed_px
    t_rel, t_auto, t_est = np.zeros((len(CURVE_REL), 3), int), np.zeros(3, int), np.zeros(3, int)
    items = coco_images(path, 10 ** 6)
    for it in items:
        det.reset_scale()
        t_auto += f1(det.detect(it["image"]), it, 1.0)
        est = det.seed_px_estimate
        for k, r in enumerate(CURVE_REL):
            det.scale = min(op / it["true"] * r, 4.0)
            t_rel[k] += f1(det.detect(it["image"]), it, 1.0)
        det.scale = det.scale_for(est)
        t_est += f1(det.detect(it["image"]), it, 1.0)
    out = {"images": len(items), "rel": list(CURVE_REL), "f1_rel": [prf(*map(int, t))[2] for t in t_rel],
           "f1_auto": prf(*map(int, t_auto))[2], "f1_estimate": prf(*map(int, t_est))[2]}
    print(f"scale curve {spec}: {out}", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", action="append", required=True,
                    help="simulated dataset folder or COCO labels.json (repeatable); PATH:arm / PATH:photo = that network")
    ap.add_argument("--frames", type=int, default=2, help="images per dataset")
    ap.add_argument("--factors", default=",".join(map(str, FACTORS)))
    ap.add_argument("--no-f1", action="store_true", help="estimates only (no detection runs)")
    ap.add_argument("--band", action="store_true", help="also measure F1 at scale 1 on rescaled images")
    ap.add_argument("--curve", action="append", default=[],
                    help="COCO labels.json[:domain] (repeatable, default photo): box F1 of every image run at input "
                         "scales around its true seed size's, at the scale auto runs it at and at its seed-size "
                         "estimate's")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "autoscale.json"))
    a = ap.parse_args()
    factors = [float(x) for x in a.factors.split(",")]
    rows, band, dets = [], [], {}
    for spec in a.dataset:
        p, domain, opts = dataset_spec(spec)
        items = coco_images(p, a.frames) if p.suffix == ".json" else seedmap_images(p, a.frames)
        if domain not in dets:
            dets[domain] = make_detector("fast", overrides=opts)
        det = dets[domain]
        for it in items:
            if it["true"] is None:
                continue
            for f in factors:
                img = resize(it["image"], f)
                true = it["true"] * f
                t0 = time.perf_counter()
                est = estimate_seed_px(det.peaks, img, det.trained_seed_px, det.scale_cue, det.score_size).seed_px
                dt = time.perf_counter() - t0
                row = {"dataset": str(p), "domain": domain, "image": it["name"], "factor": f,
                       "width": img.shape[1], "height": img.shape[0], "true_seed_px": true, "est_seed_px": est,
                       "rel_err": None if est is None else est / true - 1.0, "estimate_s": dt}
                if not a.no_f1:
                    det.reset_scale()
                    row["auto_scale"] = det.ensure_scale(img)
                    row["auto"] = f1(det.detect(img), it, f)
                    forced = make_detector("fast", overrides=[*opts, f"cnn.seed_px={true}"]) \
                        if det.trained_seed_px / true <= 4 else None
                    row["true_scale"] = None if forced is None else forced.scale
                    row["forced"] = None if forced is None else f1(forced.detect(img), it, f)
                rows.append(row)
                e = row["rel_err"]
                print(f"{it['name']} x{f:g}: true {true:.2f} est {est if est is None else round(est, 2)} "
                      f"err {'-' if e is None else f'{e:+.3f}'} {dt * 1000:.0f} ms"
                      + ("" if a.no_f1 else f" F1 auto {prf(*row['auto'])[2]:.3f} forced "
                         f"{'-' if row['forced'] is None else round(prf(*row['forced'])[2], 3)}"), flush=True)
            if a.band:
                d1 = make_detector("fast", overrides=[*opts, "cnn.scale=1"])
                for f in BAND_FACTORS:
                    band.append({"dataset": str(p), "domain": domain, "image": it["name"], "factor": f,
                                 "seed_px": it["true"] * f, "scale1": f1(d1.detect(resize(it["image"], f)), it, f)})
    summary = {}
    for f in factors:
        e = [abs(r["rel_err"]) for r in rows if r["factor"] == f and r["rel_err"] is not None]
        s = {"n": len(e), "max_abs_err": max(e) if e else None, "median_abs_err": float(np.median(e)) if e else None,
             "missing": sum(1 for r in rows if r["factor"] == f and r["rel_err"] is None),
             "median_estimate_s": float(np.median([r["estimate_s"] for r in rows if r["factor"] == f]))}
        if not a.no_f1:
            for k in ("auto", "forced"):
                t = np.array([r[k] for r in rows if r["factor"] == f and r.get(k) is not None]).reshape(-1, 3).sum(0)
                s[f"f1_{k}"] = prf(*map(int, t))[2] if t.size else None
        summary[str(f)] = s
        print(f"x{f:g}: {s}")
    band_sum = {}
    for dom in sorted({b["domain"] for b in band}):
        for f in BAND_FACTORS:
            t = np.array([b["scale1"] for b in band if b["factor"] == f and b["domain"] == dom]).sum(0)
            band_sum[f"{dom} x{f:g}"] = prf(*map(int, t))[2]
    if band_sum:
        print("F1 at scale 1:", {k: round(v, 3) for k, v in band_sum.items()})
    curves = {spec: scale_curve(spec) for spec in a.curve}
    # one estimate on a synthetic 18 MP image
    p = dataset_spec(a.dataset[0])[0]
    it = (coco_images(p, 1) if p.suffix == ".json" else seedmap_images(p, 1))[0]
    big = resize(it["image"], 4.0)[:3684, :4912]
    det = next(iter(dets.values()))
    t0 = time.perf_counter()
    est = estimate_seed_px(det.peaks, big, det.trained_seed_px, det.scale_cue, det.score_size).seed_px
    big_t = {"width": big.shape[1], "height": big.shape[0], "estimate_s": time.perf_counter() - t0,
             "true_seed_px": it["true"] * 4.0, "est_seed_px": est}
    print("18 MP:", big_t)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": " ".join(sys.argv), "summary": summary, "band_f1_scale1": band_sum,
                               "big_image": big_t, "scale_curve": curves, "rows": rows, "band": band}, indent=1),
                   encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
