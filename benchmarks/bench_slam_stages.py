"""Whole-pipeline SLAM speed per stage on one dataset's images (``bench_slam.py --dataset DIR``).

Methods, one after the other in the same process on the same images:

* ``seeds (fast), prefetch``: the default ``seedmap slam`` (decode + detection of frame t+1 overlap the
  association of frame t);
* ``seeds (fast), sequential``: the same with ``prefetch_frames=0`` (every stage one after the other);
* ``ORB + BF``: the descriptor baseline's front-end (``--matcher orb``: ORB detection of both images,
  brute-force stereo and temporal matching) on every frame, the ratio's baseline (its SLAM loses track on
  seed-textured rows, so its back-end is left out);
* ``ORB-SLAM3``: ``pyorbslam3`` stereo tracking (``seedmap[peers]``; the settings and the vocabulary of the
  ``orbslam3`` benchmark method, seedmap.peers.orbslam3: 2,000 ORB features, the shipped vocabulary unless
  ``--orb-vocab``), when the package is installed; skipped otherwise. Two rows as for the seeds: ``ORB-SLAM3,
  prefetch`` decodes frame t+1 in the same kind of thread (seedmap.slam.stream.Prefetch, one frame ahead) while
  frame t is tracked, as the seeds' default does, and ``ORB-SLAM3, sequential`` decodes, then tracks.

Stage times are wall ms per frame as the pipeline records them (``decode``, ``detection``, ``stereo``,
``temporal``, ``motion``, ``backend``; ``final`` is the final batch optimisation per frame). With the prefetch
thread ``decode`` and ``detection`` overlap the rest, so the stages add up to more than ``wall_ms_per_frame``
(the loop's wall time per frame, image decode included, final optimisation excluded).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from seedmap.slam.config import SlamConfig
from seedmap.slam.pipeline import run_slam

#: the pipeline's timing keys -> the stage names of the JSON
STAGES = {"load": "decode", "detect": "detection", "stereo_match": "stereo", "temporal_match": "temporal",
          "motion": "motion", "backend": "backend"}


def _seedmap_row(name: str, dataset: Path, matcher: str, detector: str | None, cfg: SlamConfig) -> dict:
    """One ``run_slam`` of the whole pipeline (no files written)."""
    t0, c0 = time.perf_counter(), time.process_time()
    r = run_slam(dataset, None, matcher=matcher, detector=detector, config=cfg, progress=False,
                 html_report=False)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    m = r.metrics
    ms = m.ms_per_frame
    n = max(m.frames_tracked, 1)
    row = {"method": name, "frames": m.frames, "frames_tracked": m.frames_tracked,
           "stages_ms": {v: float(ms[k]) for k, v in STAGES.items() if k in ms},
           "final_ms_per_frame": float(ms.get("final_batch_total", 0.0)) / n,
           "wall_ms_per_frame": float(ms["total_per_frame"]),
           "cpu_ms_per_frame": 1e3 * cpu / n, "run_wall_s": wall,
           "ate_rmse_m": m.ate_rmse_m, "mdm_fraction": m.mdm_fraction}
    print(row, flush=True)
    return row


def _orb_bf_row(dataset: Path) -> dict:
    """The ORB + brute-force front-end on every frame: decode, ORB detection of both images, stereo and
    temporal matching (its SLAM loses track on seed-textured rows; its per-frame cost is the baseline)."""
    from seedmap.associate import make_matcher

    cfg = SlamConfig()
    ds = cfg.dataset.open(dataset)
    m = make_matcher("orb", ds.calib, cfg=cfg)
    tm: dict[str, list[float]] = {}
    prev = None
    t_start, c0 = time.perf_counter(), time.process_time()
    for i in range(len(ds)):
        t0 = time.perf_counter()
        f = ds[i]
        tm.setdefault("load", []).append((time.perf_counter() - t0) * 1e3)
        cur = m.features(f)
        if prev is not None:
            m.match_temporal(prev, cur)
        for k, v in cur.timings_ms.items():
            tm.setdefault(k, []).append(v)
        prev = cur
    wall, cpu = time.perf_counter() - t_start, time.process_time() - c0
    n = len(ds)
    row = {"method": "ORB + BF", "frames": n, "frames_tracked": None,
           "stages_ms": {v: float(np.mean(tm[k])) for k, v in STAGES.items() if k in tm},
           "final_ms_per_frame": 0.0, "wall_ms_per_frame": 1e3 * wall / n, "cpu_ms_per_frame": 1e3 * cpu / n,
           "run_wall_s": wall, "ate_rmse_m": None, "mdm_fraction": None}
    print(row, flush=True)
    return row


def _orb_vocab(explicit: Path | None) -> tuple[str, str] | None:
    """``(vocabulary path, label)`` for ORB-SLAM3 (``explicit``, else seedmap's shipped one), None without
    ``pyorbslam3``."""
    from seedmap.peers.orbslam3 import OrbSlam3Config, unavailable, vocabulary_file

    if unavailable() is not None:
        return None
    path, label = vocabulary_file(OrbSlam3Config(vocabulary=None if explicit is None else str(explicit)))
    return str(path), label


def _orbslam3_row(dataset: Path, vocab: str, prefetch: int) -> dict:
    """ORB-SLAM3 stereo tracking of every frame; ``prefetch`` frames decoded ahead in a thread (0: none)."""
    import pyorbslam3

    from seedmap.peers.orbslam3 import OrbSlam3Config, fps_of, settings_text
    from seedmap.slam.stream import Prefetch

    ds = SlamConfig().dataset.open(dataset)

    def decode(i: int) -> tuple:
        t0 = time.perf_counter()
        f = ds[i]
        return f, time.perf_counter() - t0

    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        settings = Path(tmp) / "stereo.yaml"
        settings.write_text(settings_text(ds.calib, fps_of(ds.timestamps), OrbSlam3Config()))
        t0 = time.perf_counter()
        slam = pyorbslam3.Slam(vocab, str(settings), pyorbslam3.Sensor.STEREO)
        t_vocab = time.perf_counter() - t0
        load, track, ok = [], [], 0
        c0, w0 = time.process_time(), time.perf_counter()
        for f, t_load in Prefetch(decode, range(len(ds)), prefetch):
            t1 = time.perf_counter()
            r = slam.track_stereo(f.left, f.right, float(f.timestamp))
            load.append(t_load)
            track.append(time.perf_counter() - t1)
            ok += r.pose_wc is not None
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        slam.shutdown()
    n = len(track)
    row = {"method": f"ORB-SLAM3, {'prefetch' if prefetch else 'sequential'}", "frames": n, "frames_tracked": ok,
           "stages_ms": {"decode": 1e3 * float(np.mean(load)), "tracking": 1e3 * float(np.mean(track))},
           "final_ms_per_frame": 0.0, "wall_ms_per_frame": 1e3 * wall / max(n, 1),
           "cpu_ms_per_frame": 1e3 * cpu / max(n, 1), "run_wall_s": time.perf_counter() - t_start,
           "vocabulary_load_s": t_vocab, "ate_rmse_m": None, "mdm_fraction": None}
    print(row, flush=True)
    return row


def _best(rows: list[dict]) -> dict:
    return min(rows, key=lambda r: r["wall_ms_per_frame"])


def stage_rows(dataset: Path, orb_vocab: Path | None = None, repeats: int = 1) -> dict:
    """All methods on ``dataset`` (``repeats`` runs each, interleaved, the fastest kept) and the ratios of the
    seeds' wall ms per frame to the ORB + BF baseline's (and to ORB-SLAM3's when it ran)."""
    seq = SlamConfig(prefetch_frames=0)
    load_before = os.getloadavg()[0]
    runs: dict[str, list[dict]] = {}
    vocab = _orb_vocab(orb_vocab)
    for _ in range(max(1, repeats)):
        for name, matcher, det, cfg in (("seeds (fast), prefetch", "seeds", "fast", SlamConfig()),
                                        ("seeds (fast), sequential", "seeds", "fast", seq)):
            runs.setdefault(name, []).append(_seedmap_row(name, dataset, matcher, det, cfg))
        runs.setdefault("ORB + BF", []).append(_orb_bf_row(dataset))
        if vocab is not None:
            for depth in (1, 0):
                row = _orbslam3_row(dataset, vocab[0], depth)
                runs.setdefault(row["method"], []).append(row)
    rows = [_best(v) for v in runs.values()]
    by = {r["method"]: r for r in rows}
    seeds = by["seeds (fast), prefetch"]["wall_ms_per_frame"]
    out = {"dataset": Path(dataset).name, "cpu_count": os.cpu_count(), "repeats": max(1, repeats), "rows": rows,
           # the machine's 1-minute load average before and after (other work running makes every time longer)
           "load_average": [load_before, os.getloadavg()[0]],
           "seeds_vs_orb_bf_ratio": seeds / by["ORB + BF"]["wall_ms_per_frame"],
           "prefetch_vs_sequential_ratio": seeds / by["seeds (fast), sequential"]["wall_ms_per_frame"],
           "orbslam3": f"ran, {vocab[1]}" if vocab is not None else "skipped: pyorbslam3 not installed"}
    if "ORB-SLAM3, prefetch" in by:  # like for like: both decode the next frame in a thread, and both do not
        out["seeds_vs_orbslam3_ratio"] = seeds / by["ORB-SLAM3, prefetch"]["wall_ms_per_frame"]
        out["sequential_seeds_vs_orbslam3_ratio"] = (by["seeds (fast), sequential"]["wall_ms_per_frame"]
                                                     / by["ORB-SLAM3, sequential"]["wall_ms_per_frame"])
    return out
