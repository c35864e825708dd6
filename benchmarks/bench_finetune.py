"""Fine-tuning the ``fast`` detector on a user's labels: held-out F1 before and after, and what the fine-tune costs.

With ``--train LABELS.json --test LABELS.json`` (COCO files, images beside them or under ``--train-root`` /
``--test-root``) it measures those; without, it first makes them from two simulated ranges the way a user's photos
would look (``--train-range``/``--test-range``, default /work/data/det_s2 and det_s21): the left images enlarged
``--upscale`` times (4: seeds ~20 px instead of ~5), saved as JPEG (quality 85), every GT seed of the detectable
size (seedmap.detect.config.min_visible_seed_px) labelled with its box and mask outline (polygon); ``--n-train``
images of the first range train, ``--n-test`` of the other are held out.

Steps, each through the real CLI in a subprocess (as a user runs it):

1. ``seedmap detect TEST_IMAGES`` with the shipped network at the true seed size (``--set cnn.seed_px=S``, S = the
   test labels' median box side), with its refiner and without, and ``seedmap eval detect TEST.json DET``: F1
   before;
2. ``seedmap train fast-cnn TRAIN.json --images-root ... --out MODEL`` with default settings (wall and CPU time of
   the process);
3. ``seedmap detect TEST_IMAGES --weights MODEL/fast_cnn.onnx`` (+ ``--set cnn.seed_px=`` the stored
   ``images_seed_px`` unless ``--auto-scale``, i.e. the detector reads the scale stored in the network) and
   ``seedmap eval detect``: F1 after, detect ms/image; and the same network at the test labels' median seed size.

Writes JSON (``--out``, default benchmarks/results/finetune.json).
Usage: ``python benchmarks/bench_finetune.py [--train L.json --test L.json] [--work DIR] [--threads 2]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path


def make_labels(dataset: Path, frames: list[int], out: Path, upscale: float) -> Path:
    """``out/images/*.jpg`` (left images of ``frames``, enlarged ``upscale`` x, JPEG q85) + ``out/labels.json``
    (COCO: every detectable GT seed's box and mask outline, in the enlarged pixels). Returns the label file."""
    import cv2
    import numpy as np

    from seedmap.detect.config import min_visible_seed_px
    from seedmap.io.images import read_rgb
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(dataset)
    (out / "images").mkdir(parents=True, exist_ok=True)
    images, anns = [], []
    for i in frames:
        rgb = read_rgb(ds.image_path(i, "left"))
        h, w = rgb.shape[:2]
        W, H = int(round(w * upscale)), int(round(h * upscale))
        big = cv2.resize(rgb, (W, H), interpolation=cv2.INTER_CUBIC)
        name = f"{dataset.name}_{i:06d}.jpg"
        cv2.imwrite(str(out / "images" / name), big[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
        images.append({"id": i + 1, "file_name": name, "width": W, "height": H})
        lab = ds.gt_label_image(i, "left")
        inst = ds.gt_instances(i, "left")
        min_area = min_visible_seed_px(w)
        for lbl, box, area in zip(inst.label, inst.boxes, inst.area):
            if area < min_area:
                continue
            x0, y0, x1, y1 = (int(v) for v in box)
            m = (lab[y0:y1, x0:x1] == lbl).astype(np.uint8)
            mb = cv2.resize(m, (int(round((x1 - x0) * upscale)), int(round((y1 - y0) * upscale))),
                            interpolation=cv2.INTER_NEAREST)
            cs, _ = cv2.findContours(mb, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            seg = []
            if cs:
                c = max(cs, key=cv2.contourArea).reshape(-1, 2).astype(float) + 0.5
                if len(c) >= 3:
                    seg = [(c + [x0 * upscale, y0 * upscale]).ravel().round(2).tolist()]
            bb = [x0 * upscale, y0 * upscale, (x1 - x0) * upscale, (y1 - y0) * upscale]
            a = {"id": len(anns) + 1, "image_id": i + 1, "category_id": 1, "bbox": bb,
                 "area": float(mb.sum()), "iscrowd": 0}
            if seg:
                a["segmentation"] = seg
            anns.append(a)
    p = out / "labels.json"
    p.write_text(json.dumps({"images": images, "annotations": anns, "categories": [{"id": 1, "name": "seed"}]}))
    return p


def _seedmap(args: list, threads: int) -> tuple[float, float]:
    """Run ``seedmap ARGS`` (this checkout's code); returns (wall s, CPU s of the process)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "OMP_NUM_THREADS": str(threads)}
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "seedmap.cli", *map(str, args)], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        sys.exit(f"seedmap {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    print(p.stdout.strip()[-1500:], flush=True)
    return wall, (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)


def _median_side(labels: Path) -> float:
    import numpy as np

    d = json.loads(labels.read_text())
    b = np.array([a["bbox"] for a in d["annotations"]], float)
    return float(np.median(np.sqrt(b[:, 2] * b[:, 3])))


def _detect_eval(images: Path, labels: Path, out: Path, extra: list, threads: int) -> dict:
    _seedmap(["detect", images, "--out", out, "--detector", "fast", *extra], threads)
    _seedmap(["eval", "detect", labels, out], threads)
    m = json.loads((out / "detect_metrics.json").read_text())
    meta = json.loads((out / "meta.json").read_text())
    return {"f1": m["f1"], "precision": m["precision"], "recall": m["recall"], "n_gt": m["n_gt"],
            "n_det": m["n_det"], "ms_per_image": meta.get("ms_per_image"), "cnn_scale": meta.get("cnn_scale")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", type=Path, help="COCO labels to fine-tune on (default: made from --train-range)")
    ap.add_argument("--test", type=Path, help="COCO labels of held-out images (default: made from --test-range)")
    ap.add_argument("--train-root", type=Path, help="folder of the --train images (default: images/ beside it)")
    ap.add_argument("--test-root", type=Path, help="folder of the --test images (default: images/ beside it)")
    ap.add_argument("--train-range", type=Path, default=Path("/work/data/det_s2"))
    ap.add_argument("--test-range", type=Path, default=Path("/work/data/det_s21"))
    ap.add_argument("--n-train", type=int, default=10)
    ap.add_argument("--n-test", type=int, default=6)
    ap.add_argument("--upscale", type=float, default=4.0)
    ap.add_argument("--work", type=Path, default=Path("bench_finetune_work"), help="folder for labels, runs")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads (training and detection)")
    ap.add_argument("--auto-scale", action="store_true",
                    help="detect with the fine-tuned network's stored scale (no --set cnn.seed_px)")
    ap.add_argument("--train-args", default="", help="extra `seedmap train fast-cnn` options (quoted)")
    ap.add_argument("--model", type=Path, help="reuse this fine-tuned MODEL folder (no training; the timings are "
                                               "then its train_metrics.json's training loop only)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "finetune.json")
    args = ap.parse_args()

    w = args.work
    w.mkdir(parents=True, exist_ok=True)
    train, test = args.train, args.test
    if train is None:
        train = make_labels(args.train_range, list(range(args.n_train)), w / "train", args.upscale)
    if test is None:
        test = make_labels(args.test_range, list(range(args.n_test)), w / "test", args.upscale)
    train_root = args.train_root or train.parent / "images"
    test_root = args.test_root or test.parent / "images"
    s_true = _median_side(test)
    th = args.threads
    runs = w / "runs"
    runs.mkdir(exist_ok=True)
    tag = time.strftime("%Y%m%d%H%M%S")
    before = _detect_eval(test_root, test, runs / f"before_{tag}", ["--set", f"cnn.seed_px={s_true:.3f}",
                                                                    "--set", f"cnn.threads={th}"], th)
    before_net = _detect_eval(test_root, test, runs / f"before_net_{tag}", ["--set", f"cnn.seed_px={s_true:.3f}",
                                                                            "--set", f"cnn.threads={th}",
                                                                            "--set", "cnn.refiner=none"], th)
    if args.model is None:
        model = runs / f"model_{tag}"
        wall, cpu = _seedmap(["train", "fast-cnn", train, "--images-root", train_root, "--out", model, "--threads",
                              th, *args.train_args.split()], th)
        tm = json.loads((model / "train_metrics.json").read_text())
    else:
        model = args.model
        tm = json.loads((model / "train_metrics.json").read_text())
        wall, cpu = tm["wall_s_this_run"], tm["cpu_s"]
    scale_args = [] if args.auto_scale else ["--set", f"cnn.seed_px={tm['images_seed_px']:.3f}"]
    after = _detect_eval(test_root, test, runs / f"after_{tag}", ["--weights", model / "fast_cnn.onnx",
                                                                  "--set", f"cnn.threads={th}", *scale_args], th)
    # the same network at the test labels' median seed size (what a detector that finds the scale would use)
    after_true = _detect_eval(test_root, test, runs / f"after_true_{tag}", ["--weights", model / "fast_cnn.onnx",
                                                                            "--set", f"cnn.threads={th}",
                                                                            "--set", f"cnn.seed_px={s_true:.3f}"], th)
    res = {
        "train_labels": str(train), "test_labels": str(test),
        "train_images": tm["train_images"], "heldout_in_training": tm.get("val_counts", {}).get("images"),
        "test_images": len(json.loads(test.read_text())["images"]),
        "test_seed_px_median": s_true, "labels_seed_px": tm.get("images_seed_px"), "labels_scale": tm.get("labels_scale"),
        "before_shipped_at_true_scale": before, "before_shipped_network_only": before_net, "after_finetune": after,
        "after_finetune_at_test_median_scale": after_true,
        "timings": "seedmap train fast-cnn process" if args.model is None else "training loop (train_metrics.json)",
        "train_command_defaults": {"steps": tm["steps"], "lr": tm["config"]["lr"], "threads": th,
                                   "extra": args.train_args},
        "finetune_wall_s": wall, "finetune_cpu_s": cpu,
        "train_val_f1_before": tm.get("val_f1_before"), "train_val_f1": tm.get("val_f1"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "command": " ".join(sys.argv),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=1))
    print(json.dumps({k: res[k] for k in ("before_shipped_at_true_scale", "before_shipped_network_only",
                                          "after_finetune", "finetune_wall_s",
                                          "finetune_cpu_s")}, indent=1))


if __name__ == "__main__":
    main()
