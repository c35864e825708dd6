"""Detector speed on CPU: frames/s per detector and image size, as a ratio to cv2.GaussianBlur.

Detectors: the ``fast`` CNN (onnxruntime, with its refiner) at full resolution with 1 and 2 threads, on gated
tiles and whole-image, and per stereo frame with the left and right image in sequence or concurrently
(``cnn.stereo_threads``); the ``gt`` oracle with ``--dataset``; the untrained ``frcnn-pix2pix`` at half resolution.
``--cnn-weights OTHER.onnx`` adds the same rows for another network; repeat it to time several candidates against
the shipped network in one run (their CPU ratios then share one baseline). ``--cnn-set KEY=VALUE`` adds the rows for
the shipped network with a detector override (e.g. ``cnn.refiner=none``).

The baseline (a 5x5-sigma-2 Gaussian blur of the same RGB image) is timed in the same run, so the
ratio ``detector_ms / blur_ms`` is comparable across machines and loads. Also times one training
iteration of the full-width VGG16 Faster R-CNN and of pix2pix on CPU, to estimate full training time.

    .venv/bin/python benchmarks/bench_detect.py [--dataset data/det_s2] [--no-learned] [--repeats 10]
        [--cnn-weights OTHER.onnx ...] [--cnn-set cnn.refiner=none ...] [--interleave 40]

Writes benchmarks/results/bench_detect.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import cv2
import numpy as np


def _time(fn, repeats: int) -> float:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)) * 1000.0


def _cpu_time_1thread(fn, repeats: int) -> float:
    """Median CPU time (ms) of ``fn`` with OpenCV on one thread: robust to other jobs on the host
    (wall time on a shared 2-core machine is not), and an upper bound of single-core wall time."""
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        fn()
        ts = []
        for _ in range(repeats):
            t0 = time.process_time()
            fn()
            ts.append(time.process_time() - t0)
    finally:
        cv2.setNumThreads(n)
    return float(np.median(ts)) * 1000.0


def _image(dataset: str | None, width: int, height: int) -> tuple[np.ndarray, str]:
    if dataset:
        from seedmap.io.seedmap_dataset import SeedmapDataset

        ds = SeedmapDataset(dataset)
        i = int(np.argmax([len(ds.gt_instances(k, "left")) for k in range(len(ds))])) if ds.has_gt else 0
        img = ds[i].left
        src = f"{dataset} frame {i}"
    else:
        from seedmap.detect.synth import random_seeds, render_seeds

        rng = np.random.default_rng(0)
        img, _ = render_seeds(random_seeds(rng, 1434, 1050, 8, 250, 5.0), 1434, 1050, rng, supersample=1)
        src = "synthetic"
    if img.shape[1] != width:
        img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    return img, src


def _interleaved(a, cnn_sets: list) -> dict:  # noqa: ANN001 - argparse namespace
    """CPU ms per full-resolution image of each network (1 onnxruntime thread), timed round-robin: every round runs
    each network once on the same image, so a change of the host's load hits all of them alike (sequential timing
    on a loaded host can be off by 20 %)."""
    from seedmap.detect import make_detector

    img, src = _image(a.dataset, 1434, 1050)
    res = {"image": src, "rounds": a.interleave, "networks": {}}
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        for tile, label in ((None, "gated tiles"), (0, "whole image")):
            dets = {}
            for wl, wo in cnn_sets:
                ov = ["cnn.threads=1"] + ([f"cnn.tile={tile}"] if tile is not None else []) + wo
                dets[wl.strip(" []") or "shipped"] = make_detector("fast", overrides=ov)
            ts = {k: [] for k in dets}
            for d in dets.values():
                d.detect(img)  # warm-up
            rounds = a.interleave if tile is None else max(3, a.interleave // 4)
            for _ in range(rounds):
                for k, d in dets.items():
                    t0 = time.process_time()
                    d.detect(img)
                    ts[k].append(time.process_time() - t0)
            med = {k: float(np.median(v)) * 1000.0 for k, v in ts.items()}
            res["networks"][label] = {k: {"cpu_ms": med[k], "ratio_vs_shipped": med[k] / med["shipped"],
                                          "cpu_ms_p25_p75": [float(np.percentile(ts[k], 25)) * 1000.0,
                                                             float(np.percentile(ts[k], 75)) * 1000.0]}
                                      for k in med}
            print({"interleaved": label, **{k: round(v["ratio_vs_shipped"], 3)
                                            for k, v in res["networks"][label].items()}}, flush=True)
    finally:
        cv2.setNumThreads(n)
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default=None)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--no-learned", action="store_true")
    ap.add_argument("--cnn-weights", action="append", default=[],
                    help="another fast_cnn.onnx to time next to the shipped one (repeatable: several in one run)")
    ap.add_argument("--cnn-set", action="append", default=[],
                    help="also time the shipped network with this detector override (key=value; repeatable)")
    ap.add_argument("--interleave", type=int, default=0,
                    help="also time the shipped and every --cnn-weights network round-robin for this many rounds "
                         "(1 thread; CPU ms per image, median) and report each one's ratio to the shipped network")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_detect.json"))
    a = ap.parse_args()

    from seedmap.detect import make_detector
    from seedmap.detect.cnn import default_cnn_path
    from seedmap.detect.config import CnnConfig

    rows = []
    cnn_sets = ([("", [])] + [(f" [{w}]", [f"cnn.weights={w}"]) for w in a.cnn_weights]
                + [(f" [{o}]", [o]) for o in a.cnn_set])
    for scale in (1.0,):  # the CNN works at the pixel scale it was trained on (full resolution)
        w, h = int(round(1434 * scale)), int(round(1050 * scale))
        img, src = _image(a.dataset, w, h)
        blur_ms = _time(lambda: cv2.GaussianBlur(img, (0, 0), 2.0), a.repeats * 3)
        cpu_blur = _cpu_time_1thread(lambda: cv2.GaussianBlur(img, (0, 0), 2.0), a.repeats * 3)
        variants = []
        if default_cnn_path().is_file():
            variants += [(f"fast{wl} ({t} onnxruntime thread{'s' if t > 1 else ''}, {label})", "fast",
                          [f"cnn.threads={t}", f"cnn.tile={tile}"] + wo)
                         for wl, wo in cnn_sets
                         for t in (1, 2) for tile, label in ((CnnConfig().tile, "gated tiles"), (0, "whole image"))]
        for label, name, ov in variants:
            det = make_detector(name, overrides=ov)
            ms = _time(lambda: det.detect(img), a.repeats)
            n = len(det.detect(img))
            # CPU time of all threads (onnxruntime's included): robust to the other jobs on the host
            cpu_ms = _cpu_time_1thread(lambda: det.detect(img), a.repeats)
            rows.append({"detector": label, "width": w, "height": h, "ms": ms, "fps": 1000.0 / ms,
                         "blur_ms": blur_ms, "ratio_vs_blur": ms / blur_ms, "detections": n, "image": src,
                         "cpu_ms_1thread": cpu_ms, "fps_1core_from_cpu_time": 1000.0 / cpu_ms,
                         "blur_cpu_ms_1thread": cpu_blur, "ratio_vs_blur_cpu": cpu_ms / cpu_blur})
            print(rows[-1], flush=True)
    if default_cnn_path().is_file():
        # one stereo frame (left + right image): in sequence, or the two images on two threads
        from seedmap.records import StereoFrame

        if a.dataset:
            from seedmap.io.seedmap_dataset import SeedmapDataset

            fr = SeedmapDataset(a.dataset)[0]
        else:
            img, _ = _image(None, 1434, 1050)
            fr = StereoFrame(0, 0.0, img, img[:, ::-1].copy())
        blur_ms = _time(lambda: cv2.GaussianBlur(fr.left, (0, 0), 2.0), a.repeats * 3)
        for wl, wo in cnn_sets:
            for st in (1, 2):
                det = make_detector("fast", overrides=[f"cnn.stereo_threads={st}"] + wo)
                ms = _time(lambda: det.detect_stereo(fr), a.repeats)
                det.detect_stereo(fr)
                ts = []
                for _ in range(a.repeats):
                    t0 = time.process_time()
                    det.detect_stereo(fr)
                    ts.append(time.process_time() - t0)
                cpu_ms = float(np.median(ts)) * 1000.0
                rows.append({"detector": f"fast{wl} stereo frame ({'left and right concurrently, 2 threads' if st > 1 else 'left then right, 1 thread'})",
                             "width": fr.left.shape[1], "height": fr.left.shape[0], "ms_per_stereo_frame": ms,
                             "ms": ms / 2, "fps": 2000.0 / ms, "cpu_ms_per_stereo_frame": cpu_ms,
                             "blur_ms": blur_ms, "ratio_vs_blur": ms / 2 / blur_ms,
                             "note": "ms and fps per image (half a stereo frame); CPU time of all threads"})
                print(rows[-1], flush=True)
    if a.dataset:
        from seedmap.io.seedmap_dataset import SeedmapDataset

        ds = SeedmapDataset(a.dataset)
        if ds.has_gt:
            gt = make_detector("gt", dataset=ds)
            img = ds[0].left
            blur_ms = _time(lambda: cv2.GaussianBlur(img, (0, 0), 2.0), a.repeats * 3)
            ms = _time(lambda: gt.detect_frame(0, "left"), a.repeats)
            cpu_ms = _cpu_time_1thread(lambda: gt.detect_frame(0, "left"), a.repeats)
            rows.append({"detector": "gt (oracle, reads PNG masks)", "width": img.shape[1], "height": img.shape[0],
                         "ms": ms, "fps": 1000.0 / ms, "blur_ms": blur_ms, "ratio_vs_blur": ms / blur_ms,
                         "cpu_ms_1thread": cpu_ms})
            print(rows[-1], flush=True)
    interleaved = _interleaved(a, cnn_sets) if a.interleave > 0 and default_cnn_path().is_file() else {}
    training = {}
    if not a.no_learned:
        try:
            import torch
        except ImportError:
            torch = None
        if torch is not None:
            from seedmap.detect.learned.crops import extract_crops
            from seedmap.detect.learned.detector import LearnedDetector
            from seedmap.detect.learned.models import (
                CROP_PAD,
                DetectorArch,
                PatchDiscriminator,
                SegmenterArch,
                UNetGenerator,
                build_frcnn,
                set_input_scale,
            )

            torch.manual_seed(0)
            darch, sarch = DetectorArch(), SegmenterArch()
            model = build_frcnn(darch)
            ld = LearnedDetector(model, darch, UNetGenerator(sarch.crop_size, sarch.ngf), sarch)
            for scale in (0.5,):  # full resolution x2 upscale takes minutes per frame on 2 cores
                w, h = int(round(1434 * scale)), int(round(1050 * scale))
                img, src = _image(a.dataset, w, h)
                blur_ms = _time(lambda: cv2.GaussianBlur(img, (0, 0), 2.0), 5)
                t0 = time.perf_counter()
                boxes, _ = ld.boxes(img)
                t_det = (time.perf_counter() - t0) * 1000
                rng = np.random.default_rng(0)
                fake = np.c_[rng.uniform(0, w - 8, (2000, 2)), np.zeros((2000, 2))]
                fake[:, 2:] = fake[:, :2] + 6
                crops, _, _ = extract_crops(img, fake, sarch.crop_size, CROP_PAD)
                t0 = time.perf_counter()
                ld.masks(crops)
                t_seg = (time.perf_counter() - t0) * 1000
                rows.append({"detector": "frcnn-pix2pix (untrained weights; timing only)", "width": w, "height": h,
                             "upscale": darch.upscale, "ms_detector": t_det, "ms_segmenter_2000_crops": t_seg,
                             "ms": t_det + t_seg, "fps": 1000.0 / (t_det + t_seg), "blur_ms": blur_ms,
                             "ratio_vs_blur": (t_det + t_seg) / blur_ms})
                print(rows[-1], flush=True)
            # training iterations on CPU
            crop = 256
            img, _ = _image(a.dataset, 1434, 1050)
            x = [torch.from_numpy(np.ascontiguousarray(img[:crop, :crop])).permute(2, 0, 1).float() / 255]
            b = torch.tensor([[10.0, 10, 16, 16], [40, 40, 46, 47]] * 50) + torch.arange(100).repeat_interleave(4)\
                .reshape(100, 4).float() % 200
            tg = [{"boxes": b, "labels": torch.ones(len(b), dtype=torch.int64)}]
            set_input_scale(model, crop, crop, darch.upscale)
            model.train()
            opt = torch.optim.AdamW(model.parameters(), 1e-4)

            def det_step() -> None:
                loss = sum(model(x, tg).values())
                opt.zero_grad()
                loss.backward()
                opt.step()

            s_det = _time(det_step, 2) / 1000
            gen, disc = UNetGenerator(sarch.crop_size, sarch.ngf), PatchDiscriminator(sarch.ndf)
            og = torch.optim.Adam(gen.parameters(), 2e-4)
            cx = torch.rand(64, 3, 32, 32) * 2 - 1
            cy = (torch.rand(64, 1, 32, 32) > 0.5).float() * 2 - 1

            def seg_step() -> None:
                f = gen(cx)
                loss = (f - cy).abs().mean() * 100 + disc(cx, f).mean()
                og.zero_grad()
                loss.backward()
                og.step()

            s_seg = _time(seg_step, 3) / 1000
            training = {
                "detector_s_per_iter_cpu": s_det, "detector_iter": f"batch 1, {crop}x{crop} crop upscaled x2",
                "detector_params_M": sum(p.numel() for p in model.parameters()) / 1e6,
                "detector_est_hours_20k_iters_cpu": s_det * 20000 / 3600,
                "segmenter_s_per_iter_cpu": s_seg, "segmenter_iter": "batch 64, 32x32 crops",
                "segmenter_params_M": sum(p.numel() for p in gen.parameters()) / 1e6,
                "segmenter_est_hours_5k_iters_cpu": s_seg * 5000 / 3600,
            }
            print(training, flush=True)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    import os

    res = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "load_avg_1m": os.getloadavg()[0], "rows": rows, "interleaved": interleaved, "training": training,
           "note": "ms = median wall time per image; ratio_vs_blur = ms / cv2.GaussianBlur(sigma 2) ms of the same "
                   "image in the same run. The host was shared with other jobs (see load_avg_1m)."}
    out.write_text(json.dumps(res, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
