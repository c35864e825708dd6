"""Benchmark of the semantic association and the SLAM back-end (CPU).

Writes benchmarks/results/bench_slam.json:

* association time (stereo + temporal, wall and CPU) for 500 / 1,000 / 2,000 keypoints per
  image, for the paper's method (``refine=none``) and the displacement-field matcher (``field``,
  the SLAM default), on synthetic panicles at the default 1434 px width;
* frames/s of association + motion + back-end (iSAM2) per frame on a short synthetic sequence;
* the baseline measured in the same run: one SIFT detection + brute-force kNN match (cv2) of the
  same stereo pair (seeds drawn as blobs); results are reported as ratios to it;
* with ``--dataset DIR`` (repeatable): ``stages``, the whole ``seedmap slam`` pipeline on the dataset's images,
  ms per frame per stage (see :mod:`bench_slam_stages`) for ``fast`` seeds with and without the prefetch thread,
  the ORB + brute-force baseline and ORB-SLAM3 (when ``pyorbslam3`` and its vocabulary are there), one after the
  other in the same run.

Run: ``.venv/bin/python benchmarks/bench_slam.py [--quick] [--dataset DIR ...]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from seedmap.associate import SeedMatcher, SemanticConfig
from seedmap.records import StereoDetections
from seedmap.slam.config import SlamConfig
from seedmap.slam.core import SemanticSlam
from seedmap.slam.synthetic import make_range, observe

OUT = Path(__file__).parent / "results" / "bench_slam.json"


def _subsample(d: StereoDetections, n: int, rng: np.random.Generator) -> StereoDetections:
    """Keep the seeds whose ids are among ``n`` ids common to both images (same seeds left/right)."""
    common = np.intersect1d(d.left.seed_ids, d.right.seed_ids)
    keep = rng.choice(common, size=min(n, len(common)), replace=False)
    sub = []
    for det in (d.left, d.right):
        idx = np.flatnonzero(np.isin(det.seed_ids, keep))
        sub.append(det.subset(idx))
    return StereoDetections(d.index, d.timestamp, sub[0], sub[1])


def _blob_image(kp: np.ndarray, w: int, h: int, rng: np.random.Generator) -> np.ndarray:
    img = np.zeros((h, w), np.uint8)
    for (u, v), r, g in zip(kp, rng.uniform(2.0, 3.5, len(kp)), rng.integers(120, 255, len(kp)), strict=True):
        cv2.circle(img, (int(round(u)), int(round(v))), int(round(r)), int(g), -1, cv2.LINE_AA)
    return cv2.GaussianBlur(img, (3, 3), 0.8)


def _time2(fn, reps: int, setup=None) -> tuple[float, float]:
    """Best wall and best CPU (process) seconds over ``reps`` runs (the machine is shared);
    ``setup()`` runs untimed before each run."""
    best, best_cpu = np.inf, np.inf
    for _ in range(reps):
        if setup is not None:
            setup()
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return best, best_cpu


def _row(res: dict, mode: str, m: SeedMatcher, fa, fb, b: StereoDetections, t_st: float, c_st: float,
         t_sift: float, c_sift: float, reps: int) -> None:
    """Time the temporal matching, score both against the synthetic ids, append and print the row."""
    t_tm, c_tm = _time2(lambda: m.match_temporal(fa, fb), reps)
    st, tm = fb.stereo, m.match_temporal(fa, fb)
    prec = float(np.mean(fb.seed_ids_left[st.idx_a] == fb.seed_ids_right[st.idx_b])) if len(st) else None
    tprec = float(np.mean(fa.seed_ids_left[tm.idx_a] == fb.seed_ids_left[tm.idx_b])) if len(tm) else None
    row = {"refine": mode, "keypoints_left": len(b.left), "stereo_s": t_st, "temporal_s": t_tm,
           "stereo_cpu_s": c_st, "temporal_cpu_s": c_tm,
           "stereo_vs_sift_ratio": t_st / t_sift, "association_frames_per_s": 1.0 / (t_st + t_tm),
           "association_vs_sift_ratio": (t_st + t_tm) / t_sift,
           "association_cpu_vs_sift_cpu_ratio": (c_st + c_tm) / c_sift,
           "stereo_matches": len(st), "temporal_matches": len(tm),
           "stereo_precision_synthetic": prec, "temporal_precision_synthetic": tprec}
    res["association"].append(row)
    print(row, flush=True)


def _cpu_model() -> str | None:
    """The CPU's model name (Linux ``/proc/cpuinfo``; None elsewhere): timings from different CPUs do not compare."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="a shorter synthetic range for the back-end timing")
    ap.add_argument("--dataset", action="append", type=Path, default=[],
                    help="also time the whole pipeline per stage on this dataset (repeatable)")
    ap.add_argument("--orb-vocab", type=Path, default=None,
                    help="ORB-SLAM3 vocabulary (default: the one seedmap ships for its orbslam3 method)")
    ap.add_argument("--repeats", type=int, default=1, help="whole-pipeline runs per method (best kept)")
    args = ap.parse_args()
    reps = 3  # best of three even with --quick: one shot of a few ms is noise
    rng = np.random.default_rng(0)
    rg = make_range(rng, length=0.4, seeds_per_panicle=400)
    calib = rg.calib
    observe(rg, 3, rng, miss=0.03)  # keeps the random stream of earlier benchmark runs
    d0, d1 = observe(rg, 4, rng, miss=0.03), observe(rg, 5, rng, miss=0.03)

    # baseline: one SIFT + brute-force kNN stereo match of a drawn stereo pair (same keypoints)
    sub = _subsample(d1, 2000, rng)
    left = _blob_image(sub.left.keypoints, calib.width, calib.height, rng)
    right = _blob_image(sub.right.keypoints, calib.width, calib.height, rng)
    sift = cv2.SIFT_create()
    bf = cv2.BFMatcher(cv2.NORM_L2)

    def sift_match() -> None:
        _, da = sift.detectAndCompute(left, None)
        _, db = sift.detectAndCompute(right, None)
        if da is not None and db is not None:
            bf.knnMatch(da, db, k=2)

    t_sift, c_sift = _time2(sift_match, reps)
    res = {"machine": platform.processor() or platform.machine(), "cpu_model": _cpu_model(),
           "image": [calib.width, calib.height],
           "baseline_sift_bf_stereo_s": t_sift, "baseline_sift_bf_stereo_cpu_s": c_sift, "association": []}
    for mode in ("none", "field"):
        cfg = SemanticConfig(refine=mode, temporal_prediction=mode != "none")
        for n in (500, 1000, 2000):
            a, b = _subsample(d0, n, np.random.default_rng(n)), _subsample(d1, n, np.random.default_rng(n + 1))
            m = SeedMatcher(calib, cfg=cfg)

            def history() -> object:
                m.reset()
                return m.features_from_detections(a)

            fa = history()
            t_st, c_st = _time2(lambda: m.features_from_detections(b), reps, history)
            fa = history()
            fb = m.features_from_detections(b)
            _row(res, mode, m, fa, fb, b, t_st, c_st, t_sift, c_sift, reps)

    # per-frame pipeline on a short synthetic sequence (~1,000 keypoints per image)
    for mode in ("none", "field"):
        cfg = SlamConfig()
        cfg.association.refine = mode
        cfg.association.temporal_prediction = mode != "none"
        rng2 = np.random.default_rng(1)
        rs = make_range(rng2, length=0.2 if args.quick else 0.4, seeds_per_panicle=150)
        m = SeedMatcher(rs.calib, cfg=cfg.association)
        slam = SemanticSlam(rs.calib, m, cfg, first_pose=rs.gt.poses[0])
        dets = [observe(rs, i, rng2) for i in range(len(rs.gt))]
        t0, c0 = time.perf_counter(), time.process_time()
        ok = 0
        for d in dets:
            r = slam.register_frame(m.features_from_detections(d))
            ok += r.ok
            if not r.ok:
                break
        dt = time.perf_counter() - t0
        dc = time.process_time() - c0
        row = {"refine": mode, "frames": len(dets), "frames_ok": ok, "keypoints_per_image": int(np.mean([len(d.left) for d in dets])),
               "frames_per_s": ok / dt, "ms_per_frame": 1e3 * dt / max(ok, 1), "cpu_ms_per_frame": 1e3 * dc / max(ok, 1),
               "ms_per_frame_vs_sift_ratio": (dt / max(ok, 1)) / t_sift}
        res.setdefault("pipeline", []).append(row)
        print(row, flush=True)
    if args.dataset:
        from bench_slam_stages import stage_rows

        res["stages"] = [stage_rows(d, args.orb_vocab, args.repeats) for d in args.dataset]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
