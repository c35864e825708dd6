"""``run_slam``: dataset -> matcher features -> :class:`SemanticSlam` -> metrics and map files.

A thin loop around the core (KISS-ICP style): open the dataset, build the detector (seed
matcher only) and matcher by name, register every frame until the track is lost, optionally
batch-optimise, then write everything atomically into ``out``:

``config.yaml`` (resolved), ``metrics.json`` (``asdict(SlamMetrics)``), ``trajectory.tum`` and
``trajectory.kitti`` (final estimate; ``trajectory_online.tum`` the per-frame iSAM2 estimate),
``landmarks.csv`` + ``landmarks.ply`` (seed id / landmark id / panicle cluster id / in_graph per point),
``topview.png``, ``matches_per_frame.csv`` and ``report.md``.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import signal
import threading
import time
from dataclasses import asdict, dataclass, field
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from seedmap import outputs
from seedmap.config import dump_config
from seedmap.detect.base import default_detector_name
from seedmap.errors import SeedmapError
from seedmap.eval.slam_metrics import SlamMetrics, compute_slam_metrics
from seedmap.progress import Progress
from seedmap.records import Trajectory
from seedmap.slam.config import SlamConfig
from seedmap.slam.stream import Prefetch, prepare

__all__ = ["SlamResult", "SlamMetrics", "run_slam", "range_length_of"]


@dataclass
class SlamResult:
    """Outcome of :func:`run_slam` (``metrics`` is what ``metrics.json`` holds)."""

    metrics: SlamMetrics
    trajectory: Trajectory
    out: Path | None = None
    #: per-frame surviving match counts: keys ``frame``, ``stereo``, ``temporal``, ``inliers``
    matches_per_frame: dict[str, np.ndarray] = field(default_factory=dict)
    #: why a ``follow`` run ended: ``idle`` (no new frame within the timeout), ``interrupted`` (Ctrl-C),
    #: ``lost`` or ``max_frames``; None for a dataset run
    stop_reason: str | None = None
    #: ``follow``: the most frames that were waiting (written but not yet processed) at any frame
    max_waiting: int = 0


def range_length_of(dataset: str | Path) -> float | None:
    """Range length from the simulator's record when available (else None)."""
    try:
        from seedmap.sim import range_length
    except ImportError:
        return None
    try:
        v = range_length(dataset)
    except Exception:  # a dataset without the simulator's config is not an error here
        return None
    return float(v) if v is not None else None


def _detector_for(name: str, dataset: Path, config=None):
    """The seed detector ``name`` with the run's ``detect`` settings (a DetectConfig; None = defaults)."""
    from seedmap.detect import make_detector

    return make_detector(name, dataset=dataset, config=config)


def run_slam(
    dataset: str | Path,
    out: Path | None,
    matcher: str | None = None,
    detector: str | None = None,
    config: SlamConfig | None = None,
    overwrite: bool = False,
    progress: bool = True,
    rerun: Path | None = None,
    html_report: bool = True,
    inputs: Sequence[str | Path] = (),
    follow: bool = False,
    idle_timeout_s: float = 10.0,
    phenotype: bool = True,
) -> SlamResult:
    """Run the SLAM pipeline on ``dataset`` and write the results into ``out`` (None: no files).

    ``rerun``: also record the run (images, matches, poses, growing seed map) into this ``.rrd`` file.
    ``html_report``: also write ``report.html`` (the benchmark skips it: ~2.7 s CPU per run).
    ``inputs``: more files the command read (``--config``); ``out`` and ``rerun`` are never one of them or the
    dataset (see :mod:`seedmap.outputs`).
    ``follow``: ``dataset`` is a folder a robot is writing (:mod:`seedmap.slam.follow`): frames are processed as
    they become complete, ``out`` gets the online trajectory per frame and the map every few frames, and the run
    ends after ``idle_timeout_s`` without a new frame or on Ctrl-C, with the complete outputs of what it
    processed (no ground truth is read).
    ``phenotype``: with seeds, also write the phenotype table of the map (:mod:`seedmap.phenotype.run`:
    panicles.csv, panicles.json, thumbs/, phenotype.html)."""
    from seedmap.associate import make_matcher
    from seedmap.io.stereo_order import check_stereo_order
    from seedmap.io.trajectory import gt_overlapping
    from seedmap.slam.core import SemanticSlam

    cfg = config or SlamConfig()
    # matcher / detector: the arguments, else the config's (a result's config.yaml), else seeds / the best real
    # detector; the resolved ones go into the written config.yaml so that --config repeats the run
    matcher = matcher if matcher is not None else (cfg.matcher if cfg.matcher is not None else "seeds")
    detector = detector if detector is not None else (cfg.detector if cfg.detector is not None
                                                      else default_detector_name())
    cfg = cfg.model_copy(update={"matcher": matcher, "detector": detector})
    ins = [dataset, *inputs, *outputs.dataset_option_files(cfg.dataset)]
    if out is not None:
        out = Path(out)
        outputs.check_output_dir(out, "slam", ins, overwrite)
    if rerun is not None:
        from seedmap.viz.rerun_log import check_rrd_path

        check_rrd_path(rerun, [*ins, *([out] if out is not None else [])], overwrite)
    stop = threading.Event()  # follow: set by Ctrl-C (between frames), by the idle timeout or at the end
    if follow:
        from seedmap.slam.follow import FolderFollower

        ds = FolderFollower(dataset, idle_timeout_s, stop)
        calib, gt, n = ds.calib, None, cfg.max_frames
        indices = ds.indices() if n is None else itertools.islice(ds.indices(), n)
        load = ds.load
    else:
        ds = cfg.dataset.open(dataset)
        calib = ds.calib
        gt = gt_overlapping(ds.timestamps, ds.gt_trajectory(), dataset)
        n = len(ds) if cfg.max_frames is None else min(len(ds), cfg.max_frames)
        if n == 0:
            raise SeedmapError("dataset has no frames", dataset)
        indices, load = range(n), ds.__getitem__
    det = _detector_for(detector, Path(dataset), cfg.detect) if matcher.strip().lower() == "seeds" else None
    m = make_matcher(matcher, calib, detector=det, cfg=cfg)
    first = np.eye(4)  # the prior on the first pose: GT at the first frame's time when GT covers it
    if gt is not None and not follow:
        from seedmap.eval.slam_metrics import gt_pose_at

        g0 = gt_pose_at(ds.timestamps[0], gt, ds.timestamps)
        first = first if g0 is None else g0
    from seedmap.viz.run_hooks import SlamRerun

    rlog = SlamRerun(rerun, calib, m, gt)  # a no-op without --rerun
    slam = SemanticSlam(calib, rlog.matcher, cfg, first_pose=first)

    rows: list[dict] = []
    timings: dict[str, list[float]] = {}
    # decode + detection of frame i+1 overlap the association of frame i (seedmap.slam.stream)
    detect = getattr(m, "detect_frame", None)
    seeds_seen = None  # the left image's seeds of every frame, for the phenotype table's views
    if phenotype and out is not None and det is not None and detect is not None:
        from seedmap.phenotype.run import FrameSeeds

        seeds_seen = FrameSeeds()
    frames = Prefetch(prepare(load, detect), indices, cfg.prefetch_frames, stop=stop)
    live = _live_writer(out, overwrite) if follow and out is not None else None
    stop_reason = None
    max_waiting = 0
    t_all = time.perf_counter()
    with Progress(n, f"slam {matcher}", "frame", progress) as bar, _stop_on_ctrl_c(stop, follow) as ctrl_c:
        for i, p in enumerate(frames):
            frame = p.frame
            if i == 0:
                check_stereo_order(frame.left, frame.right, dataset)
            feats = m.features(frame, p.det) if detect is not None else m.features(frame)
            if seeds_seen is not None:
                seeds_seen.add(frame.index, frame.timestamp, p.det.left.ellipses)
            res = slam.register_frame(feats)
            tm = {**p.timings_ms, **feats.timings_ms, **res.timings_ms}
            for k, v in tm.items():
                timings.setdefault(k, []).append(v)
            rows.append({"frame": i, "keypoints_left": len(feats.kp_left), "keypoints_right": len(feats.kp_right),
                         "stereo": res.n_stereo, "temporal": res.n_temporal, "inliers": res.n_inliers,
                         "landmarks_seen": res.n_landmarks_seen, "ok": int(res.ok)})
            if follow:
                waiting = ds.announced() - (i + 1)
                rows[-1]["waiting"] = waiting
                _report_behind(waiting, max_waiting, bar)
                max_waiting = max(max_waiting, waiting)
                if live is not None and res.ok:
                    live.frame(frame.timestamp, res.T_world_cam, slam)
            rlog.frame(frame, feats, res, slam)
            bar.advance()
            if not res.ok:
                stop_reason = "lost"
                frames.close()
                break
        if follow and stop_reason is None:
            stop_reason = "interrupted" if ctrl_c.is_set() else ("max_frames" if n is not None and len(rows) >= n
                                                                  else "idle")
        stop.set()
    if live is not None:
        live.close()
    if follow and not rows:
        if live is not None:  # nothing processed: no result folder left behind
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise SeedmapError(f"no complete frame appeared within {idle_timeout_s:g} s", dataset)
    if follow:
        n = len(rows)
    t0 = time.perf_counter()
    traj, values, backend_name = slam.finalize()
    t_final = (time.perf_counter() - t0) * 1e3
    online = slam.online_trajectory()
    ms = {k: float(np.mean(v)) for k, v in timings.items()}
    ms["final_batch_total"] = t_final
    ms["total_per_frame"] = (time.perf_counter() - t_all) * 1e3 / max(len(rows), 1)
    lm = slam.landmarks(values)
    rlog.finish(traj, lm)
    metrics = compute_slam_metrics(
        traj, gt, frames=n, lost_frame=slam.lost_frame, lost_reason=slam.lost_reason,
        range_length=range_length_of(dataset), ms_per_frame=ms, online=online,
        matcher=matcher, detector=detector if det is not None else "", backend=backend_name, landmarks=len(lm),
        oracle_detector=bool(getattr(det, "is_oracle", False)),
    )
    mpf = {k: np.asarray([r[k] for r in rows], np.int64) for k in ("frame", "stereo", "temporal", "inliers")}
    result = SlamResult(metrics, traj, out, mpf, stop_reason, max_waiting)
    if out is not None:
        from seedmap.slam.outputs import write_outputs

        with outputs.output_dir(out, "slam", ins, overwrite or live is not None) as tmp:
            dump_config(cfg, tmp / "config.yaml")
            write_outputs(tmp, result, online, gt, lm, rows, cfg, dataset)
            if seeds_seen is not None:
                _write_phenotype(tmp, cfg, calib, seeds_seen, load, dataset, detector)
            if html_report:
                from seedmap.viz.run_hooks import slam_html_report

                slam_html_report(tmp, result, gt, lm, rows, timings, dataset)
    return result


def _write_phenotype(folder: Path, cfg: SlamConfig, calib, seeds_seen, load, dataset,  # noqa: ANN001
                     detector: str) -> None:
    """The phenotype table of the map just written into ``folder``, each panicle's view from the seeds the
    run detected (:mod:`seedmap.phenotype.run`)."""
    from seedmap.phenotype.run import Images, phenotype_result, write_phenotype

    idx, ts = seeds_seen.timestamps()
    images = Images(calib, idx, ts, seeds_seen, lambda f: load(f).left)
    ph = phenotype_result(folder, cfg.phenotype, images)
    write_phenotype(folder, ph, images, title=f"seedmap slam: {Path(dataset).name}, panicles",
                    dataset=str(Path(dataset).resolve()), detector=detector)


def _live_writer(out: Path, overwrite: bool):  # noqa: ANN202 - seedmap.slam.follow.LiveWriter
    """The live output folder of a ``follow`` run (an old seedmap slam result there is replaced first)."""
    import shutil

    from seedmap.slam.follow import LiveWriter

    if out.exists() and overwrite:  # check_output_dir allowed it: a seedmap slam result
        shutil.rmtree(out)
    return LiveWriter(out)


#: a follow run says it falls behind when this many written frames wait (one more than the prefetch holds)
BEHIND_FRAMES = 3


def _report_behind(waiting: int, before: int, bar: Progress) -> None:
    if waiting >= BEHIND_FRAMES and before < BEHIND_FRAMES:
        logging.getLogger("seedmap.slam").warning(f"falling behind the camera: {waiting} frames waiting")
    elif waiting >= BEHIND_FRAMES:
        bar.note(f"{waiting} frames waiting")


@contextlib.contextmanager
def _stop_on_ctrl_c(stop: threading.Event, enabled: bool) -> Iterator[threading.Event]:
    """With ``enabled`` (and in the main thread): the first Ctrl-C sets ``stop`` (the run ends after the frame in
    progress and writes its outputs), a second one interrupts as usual. Yields the event "Ctrl-C was pressed"."""
    pressed = threading.Event()
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield pressed
        return

    def on_int(signum: int, frame: object) -> None:
        if pressed.is_set():
            raise KeyboardInterrupt
        pressed.set()
        stop.set()

    old = signal.signal(signal.SIGINT, on_int)
    try:
        yield pressed
    finally:
        signal.signal(signal.SIGINT, old)


def metrics_to_json(m: SlamMetrics) -> str:
    return json.dumps(asdict(m), indent=2, default=float)
