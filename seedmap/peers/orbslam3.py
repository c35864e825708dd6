"""ORB-SLAM3 (stereo, through the optional ``pyorbslam3`` wheel) run on a seedmap dataset, scored like seedmap.

The dataset is read with seedmap's own loaders (the same rectified pinhole pairs every method sees); an ORB-SLAM3
settings file is written from the calibration; ORB-SLAM3 tracks every frame in a child process
(:mod:`seedmap.peers.orbslam3_track`); the per-frame tracking states give the tracked segments. The first segment
(from initialisation to the first frame not tracked ``OK``) is the trajectory the benchmark scores, exactly like a
seedmap run that stops when lost; the longest segment (ORB-SLAM3 starts a new map after a loss) is reported too.
How the peer is run and why: ``docs/method/orbslam3.md``.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from pydantic import Field

from seedmap import outputs
from seedmap.config import ConfigModel, dump_config
from seedmap.errors import InputError, SeedmapError
from seedmap.io.atomic import atomic_write_text
from seedmap.records import StereoCalib, Trajectory

#: ``n/a`` reason of the method when the wheel is missing (the benchmark shows it instead of a number).
NOT_INSTALLED = "n/a — install seedmap[peers]"
#: The vocabulary shipped with seedmap (gzipped DBoW2 text; ORB-SLAM3 reads only plain text).
SHIPPED_VOCABULARY = Path(__file__).with_name("data") / "orbvoc_sim.txt.gz"
#: ORB-SLAM3's tracking states (``Tracking::eTrackingState``).
STATE_NAMES = {-1: "SYSTEM_NOT_READY", 0: "NO_IMAGES_YET", 1: "NOT_INITIALIZED", 2: "OK", 3: "RECENTLY_LOST",
               4: "LOST", 5: "OK_KLT"}
STATE_OK = 2


class OrbSlam3Config(ConfigModel):
    """The ORB-SLAM3 peer of ``seedmap benchmark`` (method ``orbslam3``)."""

    vocabulary: str | None = Field(
        None, description="DBoW2 text vocabulary, e.g. the official ORBvoc.txt (default: seedmap's, trained on "
                          "simulated ranges never benchmarked)")
    features: int = Field(2000, ge=100, le=20000, description="ORB features per image (ORBextractor.nFeatures)")
    th_depth: float = Field(35.0, gt=0, description="close/far stereo point threshold in baselines (ThDepth)")


def unavailable() -> str | None:
    """``None`` when ``pyorbslam3`` imports, else the benchmark's n/a reason."""
    try:
        import pyorbslam3  # noqa: F401
    except ModuleNotFoundError:
        return NOT_INSTALLED
    except ImportError as e:  # installed, but a system library it needs is missing (e.g. libGL)
        return f"{NOT_INSTALLED} ({str(e).splitlines()[0][:160]})"
    return None


def fps_of(timestamps: np.ndarray) -> float:
    """Frame rate from the frame times (1 / median interval; 10 when unknown), at least 1."""
    t = np.asarray(timestamps, float)
    dt = np.diff(t)
    dt = dt[dt > 0]
    return max(1.0, round(1.0 / float(np.median(dt)), 3)) if len(dt) else 10.0


def settings_text(calib: StereoCalib, fps: float, cfg: OrbSlam3Config) -> str:
    """ORB-SLAM3 settings of a rectified stereo pair (its original format: ``Camera.*``, ``Camera.bf``, ``ThDepth``).

    Zero distortion: seedmap's loaders rectify. ``Camera.RGB: 1``: frames are RGB. The ORB extractor is ORB-SLAM3's
    stereo default (scale 1.2, 8 levels, FAST 20 then 7). The viewer keys are required by the parser, unused."""
    rows = [
        "%YAML:1.0", "---",
        'Camera.type: "PinHole"',
        f"Camera.fx: {float(calib.fx)!r}", f"Camera.fy: {float(calib.fy)!r}",
        f"Camera.cx: {float(calib.cx)!r}", f"Camera.cy: {float(calib.cy)!r}",
        "Camera.k1: 0.0", "Camera.k2: 0.0", "Camera.p1: 0.0", "Camera.p2: 0.0",
        f"Camera.width: {int(calib.width)}", f"Camera.height: {int(calib.height)}",
        f"Camera.fps: {float(fps)!r}",
        f"Camera.bf: {float(calib.fx * calib.baseline)!r}",
        "Camera.RGB: 1",
        f"ThDepth: {float(cfg.th_depth)!r}",
        f"ORBextractor.nFeatures: {int(cfg.features)}",
        "ORBextractor.scaleFactor: 1.2", "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500.0",
    ]
    return "\n".join(rows) + "\n"


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "seedmap"


def vocabulary_file(cfg: OrbSlam3Config) -> tuple[Path, str]:
    """``(plain-text vocabulary path, label for the tables)``; the shipped one is unpacked once into the cache."""
    from seedmap.peers.orb_vocabulary import check_vocabulary_header

    if cfg.vocabulary is not None:
        p = Path(cfg.vocabulary).expanduser()
        check_vocabulary_header(p)
        return p, f"{p.name} (user)"
    data = SHIPPED_VOCABULARY.read_bytes()
    sha = hashlib.sha1(data).hexdigest()[:12]
    target = _cache_dir() / f"orbvoc_sim-{sha}.txt"
    if not target.is_file():
        tmp = target.with_name(f".{target.name}.{os.getpid()}.partial")
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_bytes(gzip.decompress(data))
            os.replace(tmp, target)
        except OSError as e:
            if tmp.parent.is_dir():
                tmp.unlink(missing_ok=True)
            raise InputError(f"cannot unpack the shipped ORB vocabulary here ({e.strerror or e}); set XDG_CACHE_HOME "
                             "or orbslam3.vocabulary", target.parent) from None
    return target, "seedmap sim vocabulary (orbvoc_sim)"


@dataclass
class Segment:
    """Frames ``start .. end-1`` tracked ``OK`` without a break; ``length_m``: estimated path length over them."""

    start: int
    end: int
    length_m: float


def segments(states: np.ndarray, poses: np.ndarray) -> list[Segment]:
    """Maximal runs of consecutive ``OK`` frames with a pose (ORB-SLAM3 may relocalise or start a new map after)."""
    ok = (np.asarray(states) == STATE_OK) & np.isfinite(poses).all(axis=(1, 2))
    out: list[Segment] = []
    i = 0
    while i < len(ok):
        if not ok[i]:
            i += 1
            continue
        j = i
        while j < len(ok) and ok[j]:
            j += 1
        p = poses[i:j, :3, 3]
        out.append(Segment(i, j, float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if j - i > 1 else 0.0))
        i = j
    return out


def first_track(states: np.ndarray, poses: np.ndarray, timestamps: np.ndarray, gt: Trajectory | None
                ) -> tuple[Trajectory, int | None, str | None]:
    """The scored trajectory (first segment, anchored like seedmap's prior), the frame lost at and why."""
    from seedmap.eval.slam_metrics import gt_pose_at
    from seedmap.geometry import invert

    segs = segments(states, poses)
    if not segs:
        seen = ", ".join(sorted({STATE_NAMES.get(int(s), str(s)) for s in states}))
        return Trajectory(np.zeros(0), np.zeros((0, 4, 4))), 0, f"ORB-SLAM3 never tracked a frame (states: {seen})"
    s = segs[0]
    # the first tracked frame at its ground-truth pose, as seedmap's first-pose prior
    g0 = gt_pose_at(timestamps[s.start], gt, timestamps)
    anchor = np.eye(4) if g0 is None else g0
    rel = invert(poses[s.start]) @ poses[s.start:s.end]
    traj = Trajectory(timestamps[s.start:s.end], anchor[None] @ rel)
    if s.end >= len(states):
        return traj, None, None
    return traj, int(s.end), f"ORB-SLAM3 state {STATE_NAMES.get(int(states[s.end]), states[s.end])}"


def _run_child(job: dict, folder: Path, n: int, progress: bool) -> dict[str, np.ndarray]:
    """Run :mod:`seedmap.peers.orbslam3_track` on ``job``; its output in ``folder/orbslam3.log``."""
    from seedmap.progress import Progress

    jp = folder / "orbslam3_job.json"
    atomic_write_text(jp, json.dumps(job, indent=2) + "\n")
    log = folder / "orbslam3.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[2]),
                                                         os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    with open(log, "w") as lf, Progress(n, "slam orbslam3", "frame", progress) as bar:
        proc = subprocess.Popen([sys.executable, "-m", "seedmap.peers.orbslam3_track", str(jp)],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("seedmap-progress "):
                bar.advance()
            else:
                lf.write(line)
        rc = proc.wait()
    jp.unlink()
    npz = Path(job["out"])
    if rc != 0 or not npz.is_file():
        tail = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()][-1:] or ["no output"]
        raise SeedmapError(f"ORB-SLAM3 ended with exit code {rc} ({tail[0][:200]})")
    with np.load(npz) as z:
        res = {k: z[k] for k in z.files}
    npz.unlink()
    return res


def run_orbslam3(dataset: str | Path, out: Path, cfg: OrbSlam3Config | None = None, slam_cfg=None,
                 overwrite: bool = False, progress: bool = True):
    """Run ORB-SLAM3 on ``dataset`` and write a result folder like ``seedmap slam``'s into ``out``.

    Files: ``metrics.json`` (``SlamMetrics``), ``trajectory.tum`` (first tracked segment, ``T_world_cam``,
    optical frame), ``matches_per_frame.csv`` (state and tracked map points, ``inliers``, per frame),
    ``peer.json`` (vocabulary, segments), ``orbslam3_settings.yaml``, ``orbslam3.log``, ``report.md``,
    ``config.yaml``. ``slam_cfg``: a SlamConfig whose ``dataset`` options and ``max_frames`` apply."""
    from seedmap.eval.slam_metrics import compute_slam_metrics
    from seedmap.io.trajectory import gt_overlapping, write_tum
    from seedmap.slam.config import SlamConfig
    from seedmap.slam.outputs import report_markdown
    from seedmap.slam.pipeline import SlamResult, range_length_of

    if (why := unavailable()) is not None:
        raise SeedmapError(why)
    cfg = cfg or OrbSlam3Config()
    scfg = slam_cfg or SlamConfig()
    voc, voc_label = vocabulary_file(cfg)
    out = Path(out)
    ins = [dataset, voc, *outputs.dataset_option_files(scfg.dataset)]
    outputs.check_output_dir(out, "slam", ins, overwrite)
    ds = scfg.dataset.open(dataset)
    n = len(ds) if scfg.max_frames is None else min(len(ds), scfg.max_frames)
    if n == 0:
        raise InputError("dataset has no frames", dataset)
    ts = np.asarray(ds.timestamps, float)[:n]
    gt = gt_overlapping(ds.timestamps, ds.gt_trajectory(), dataset)
    with outputs.output_dir(out, "slam", ins, overwrite) as tmp:
        settings = tmp / "orbslam3_settings.yaml"
        atomic_write_text(settings, settings_text(ds.calib, fps_of(ts), cfg))
        job = {"dataset": str(dataset), "dataset_options": scfg.dataset.model_dump(mode="json"), "frames": n,
               "settings": str(settings), "vocabulary": str(voc), "out": str(tmp / "track.npz")}
        t0 = time.perf_counter()
        r = _run_child(job, tmp, n, progress)
        wall = (time.perf_counter() - t0) * 1e3
        states, poses = r["states"], r["poses"]
        traj, lost, why = first_track(states, poses, ts, gt)
        ms = {"load": float(np.mean(r["ms_load"])), "track": float(np.mean(r["ms_track"])),
              "total_per_frame": float(np.mean(r["ms_load"] + r["ms_track"])), "wall_with_start_per_frame": wall / n}
        version = str(r["version"])
        metrics = compute_slam_metrics(traj, gt, frames=n, lost_frame=lost, lost_reason=why,
                                       range_length=range_length_of(dataset), ms_per_frame=ms, matcher="orbslam3",
                                       detector="", backend=f"ORB-SLAM3 stereo (pyorbslam3 {version}), {voc_label}")
        segs = segments(states, poses)
        longest = max(segs, key=lambda s: s.length_m) if segs else None
        peer = {"method": "orbslam3", "pyorbslam3": version, "vocabulary": voc_label, "vocabulary_file": str(voc),
                "features": cfg.features, "th_depth": cfg.th_depth,
                "segments": [asdict(s) for s in segs],
                "longest_segment_m": longest.length_m if longest else 0.0,
                "longest_segment_frames": (longest.end - longest.start) if longest else 0,
                "states": {STATE_NAMES.get(int(k), str(k)): int(v) for k, v in zip(*np.unique(states, return_counts=True))}}
        atomic_write_text(tmp / "metrics.json", json.dumps(asdict(metrics), indent=2, default=float) + "\n")
        atomic_write_text(tmp / "peer.json", json.dumps(peer, indent=2) + "\n")
        write_tum(tmp / "trajectory.tum", traj)
        rows = "frame,timestamp,state,inliers,ok\n" + "".join(
            f"{i},{ts[i]:.6f},{STATE_NAMES.get(int(states[i]), states[i])},{int(r['points'][i])},"
            f"{int(states[i] == STATE_OK)}\n" for i in range(n))
        atomic_write_text(tmp / "matches_per_frame.csv", rows)
        dump_config(scfg, tmp / "config.yaml")
        dump_config(cfg, tmp / "orbslam3.yaml")
        md = report_markdown(metrics, dataset) + (
            f"\nVocabulary: {voc_label}. Tracked segments (frames, m): "
            + ", ".join(f"{s.start}-{s.end - 1} ({s.length_m:.2f})" for s in segs) + "\n")
        atomic_write_text(tmp / "report.md", md)
    return SlamResult(metrics, traj, out)


def peer_note(run_dir: Path) -> str:
    """The benchmark note of an ORB-SLAM3 result folder: vocabulary and longest tracked segment."""
    p = Path(run_dir) / "peer.json"
    if not p.is_file():
        return ""
    d = json.loads(p.read_text())
    n = len(d.get("segments", []))
    return (f"vocabulary: {d.get('vocabulary', '?')}; longest tracked segment {d.get('longest_segment_m', 0):.2f} m "
            f"({d.get('longest_segment_frames', 0)} frames, {n} segment{'s' if n != 1 else ''})")
