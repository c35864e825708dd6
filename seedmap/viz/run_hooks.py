"""Hooks the SLAM and reconstruction pipelines call: ``report.html`` in every result folder and the
optional rerun recording (``--rerun FILE.rrd``).

They live here, not in the pipelines, so a pipeline needs one call per hook and stays readable; every
hook takes the records the pipeline already has (no re-computation, except reading one or two
dataset frames for the overlay thumbnails).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from seedmap.detect.base import detector_label
from seedmap.records import StereoCalib, Trajectory
from seedmap.viz.rerun_log import RerunLogger

THUMB_WIDTH = 480  # px, overlay thumbnails in report.html


# ---------------------------------------------------------------------------------------------------
# SLAM
# ---------------------------------------------------------------------------------------------------
class _TapMatcher:
    """Delegates to a matcher and remembers the last temporal matches (for drawing them)."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self.last_temporal = None

    def match_temporal(self, prev, cur):
        self.last_temporal = self._inner.match_temporal(prev, cur)
        return self.last_temporal

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class SlamRerun:
    """Per-frame rerun logging for ``run_slam`` (a no-op when ``path`` is None).

    Use :attr:`matcher` in place of the pipeline's matcher (it records temporal matches), call
    :meth:`frame` after each ``register_frame`` and :meth:`finish` with the final trajectory/map.
    """

    def __init__(self, path: str | Path | None, calib: StereoCalib, matcher: Any, gt: Trajectory | None = None,
                 image_scale: float = 1.0) -> None:
        self.log = RerunLogger(path, image_scale=image_scale)
        self.calib = calib
        self.matcher = _TapMatcher(matcher) if self.log.enabled else matcher
        self._prev_kp: np.ndarray | None = None
        if self.log.enabled and gt is not None:
            self.log.log_trajectory("ground truth", gt)

    def frame(self, frame: Any, feats: Any, res: Any, slam: Any = None) -> None:
        """Log one processed frame: images, keypoints, stereo + temporal matches, pose, seed map."""
        if not self.log.enabled:
            return
        temporal = self.matcher.last_temporal if self._prev_kp is not None else None
        self.log.log_stereo_frame(frame.index, frame.timestamp, frame.left, frame.right, kp_left=feats.kp_left,
                                  kp_right=feats.kp_right, stereo=feats.stereo, temporal=temporal,
                                  prev_kp_left=self._prev_kp)
        self.log.log_scalars(frame.index, {"keypoints_left": len(feats.kp_left), "stereo": res.n_stereo,
                                           "temporal": res.n_temporal, "inliers": res.n_inliers}, "stats/matches")
        self.log.log_scalars(frame.index, {**getattr(feats, "timings_ms", {}), **res.timings_ms}, "stats/ms")
        if res.ok and res.T_world_cam is not None:
            self.log.log_pose(frame.index, frame.timestamp, res.T_world_cam, self.calib)
            if slam is not None:
                lm = slam.landmarks()
                self.log.log_landmarks(lm.xyz, lm.ids)
        self._prev_kp = feats.kp_left
        self.matcher.last_temporal = None

    def finish(self, traj: Trajectory | None = None, lm: Any = None) -> Path | None:
        """The final (batch) trajectory and map as static entities; closes the file."""
        if not self.log.enabled:
            return None
        if traj is not None:
            self.log.log_trajectory("final", traj)
        if lm is not None:
            self.log.log_landmarks(lm.xyz, lm.ids, entity="world/landmarks_final", static=True)
        return self.log.close()

    def abort(self) -> None:
        self.log.abort()


def _thumb(img: np.ndarray, pts: np.ndarray | None = None, color=(255, 60, 0)) -> np.ndarray:
    """Downscaled copy of ``img`` with ``pts`` (full-image pixels) drawn as small circles."""
    import cv2

    s = min(1.0, THUMB_WIDTH / img.shape[1])
    out = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
    out = np.ascontiguousarray(out)
    if pts is not None:
        for u, v in (np.asarray(pts, float).reshape(-1, 2) + 0.5) * s - 0.5:
            if np.isfinite(u) and np.isfinite(v):
                cv2.circle(out, (int(round(u)), int(round(v))), 2, color, 1, lineType=cv2.LINE_AA)
    return out


def _landmark_overlays(dataset: str | Path, traj: Trajectory, frame_ids: Sequence[int], lm_xyz: np.ndarray,
                       n: int = 2) -> dict[str, np.ndarray]:
    """First and last tracked frame with the map's landmarks reprojected through the estimated pose."""
    from seedmap.io import open_dataset

    out: dict[str, np.ndarray] = {}
    if len(traj) == 0 or len(frame_ids) == 0:
        return out
    try:
        ds = open_dataset(dataset)
    except Exception:  # the report is a convenience: no thumbnails rather than no results
        return out
    picks = sorted({0, len(traj) - 1})[:n]
    for j in picks:
        k = int(frame_ids[j])
        if k >= len(ds):
            continue
        T = np.linalg.inv(traj.poses[j])
        pc = lm_xyz @ T[:3, :3].T + T[:3, 3]
        uv, _ = ds.calib.project(pc)
        inside = np.isfinite(uv).all(1) & (uv[:, 0] >= 0) & (uv[:, 0] < ds.calib.width) & (uv[:, 1] >= 0) \
            & (uv[:, 1] < ds.calib.height)
        out[f"frame {k}: {int(inside.sum())} landmarks reprojected (estimated pose)"] = _thumb(ds[k].left, uv[inside])
    return out


# stages that only run from the second frame on (no previous frame to match against)
_FROM_SECOND_FRAME = ("temporal_match", "motion")


def _aligned_timings(timings_ms: Mapping[str, Sequence[float]] | None, n: int) -> dict[str, np.ndarray]:
    """Per-frame stage times (ms lists, one entry per frame the stage ran) -> seconds, aligned to the
    ``n`` processed frames with NaN where a stage did not run (so the plot's x axis is the frame)."""
    out: dict[str, np.ndarray] = {}
    for k, v in (timings_ms or {}).items():
        v = np.asarray(v, float) / 1e3
        if len(v) > n:
            continue
        a = np.full(n, np.nan)
        if k in _FROM_SECOND_FRAME:
            a[n - len(v):] = v
        else:
            a[:len(v)] = v
        out[k] = a
    return out


def slam_html_report(folder: str | Path, result: Any, gt: Trajectory | None, lm: Any, rows: Sequence[Mapping],
                     timings_ms: Mapping[str, Sequence[float]] | None, dataset: str | Path,
                     clusters: np.ndarray | None = None) -> Path:
    """``folder/report.html`` of a SLAM run: metrics, trajectory vs GT, matches and time per frame,
    3D landmark map with the camera paths, landmark overlays on the first/last tracked frame."""
    from seedmap.viz.html_report import write_html_report

    m = result.metrics
    trajs = {"estimate": result.trajectory}
    if gt is not None and len(gt):
        trajs["ground truth"] = gt
    mpf = {k: [r[k] for r in rows] for k in ("stereo", "temporal", "inliers") if rows and k in rows[0]}
    timings = _aligned_timings(timings_ms, len(rows))
    colors = None
    if clusters is None and (Path(folder) / "landmarks.csv").is_file():  # written just before, same order
        import csv

        with (Path(folder) / "landmarks.csv").open(newline="") as f:
            clusters = np.asarray([int(r["cluster_id"]) for r in csv.DictReader(f)], np.int64)
    if clusters is not None and len(clusters) == len(lm.xyz):
        import matplotlib

        cmap = matplotlib.colormaps["tab20"]
        c = np.asarray([cmap(int(i) % 20)[:3] if i >= 0 else (0.6, 0.6, 0.6) for i in clusters])
        colors = (c * 255).astype(np.uint8)
    frame_ids = [int(r["frame"]) for r in rows if r.get("ok", 1)]
    images = _landmark_overlays(dataset, result.trajectory, frame_ids, lm.xyz) if len(lm.xyz) else {}
    det = detector_label(m.detector, m.oracle_detector) if m.detector else ""
    title = f"seedmap slam: {Path(dataset).name} ({m.matcher}{', ' + det if det else ''})"
    return write_html_report(Path(folder) / "report.html", title=title, metrics=m, trajectories=trajs,
                             matches_per_frame=mpf or None, timings=timings or None, points=lm.xyz,
                             point_colors=colors, images=images or None,
                             notes=f"dataset {dataset}; {len(lm.xyz)} landmarks (colour = panicle cluster)")


# ---------------------------------------------------------------------------------------------------
# reconstruction
# ---------------------------------------------------------------------------------------------------
def recon_rerun(path: str | Path | None, prep: Any, rec: Any) -> Path | None:
    """Record a panicle reconstruction: per-view clouds (camera frame) under their registered poses,
    camera path vs forward kinematics, merged cloud, counted seed centres."""
    if path is None:
        return None
    log = RerunLogger(path, world_coordinates="RIGHT_HAND_Z_UP")  # the arm's base frame is z-up
    try:
        views = [(v.cloud.xyz, v.cloud.rgb) if v is not None else (np.zeros((0, 3)), None) for v in prep.views]
        log.log_reconstruction(rec.poses, prep.calib, views, rec.cloud_xyz, rec.cloud_rgb, rec.count.xyz,
                               timestamps=rec.timestamps, fk_poses=rec.T_fk, views_in_world=False)
    except BaseException:
        log.abort()
        raise
    return log.close()


def recon_html_report(folder: str | Path, rec: Any, metrics: Mapping, dataset: str | Path,
                      calib: StereoCalib | None = None) -> Path:
    """``folder/report.html`` of a reconstruction: metrics, camera path (registered vs FK), timings,
    the coloured merged cloud with seed centres, the first view with its counted seeds reprojected."""
    from seedmap.viz.html_report import write_html_report

    ts = np.asarray(rec.timestamps, float)
    trajs = {"registered": Trajectory(ts, rec.poses), "forward kinematics": Trajectory(ts, rec.T_fk)}
    pts = np.concatenate([rec.cloud_xyz, rec.count.xyz])
    red = np.tile(np.array([[255, 0, 0]], np.uint8), (len(rec.count.xyz), 1))
    cols = np.concatenate([np.asarray(rec.cloud_rgb, np.uint8).reshape(-1, 3), red])
    per_view = {"observed seeds": np.bincount(rec.obs_view, minlength=len(rec.poses))}
    images: dict[str, np.ndarray] = {}
    try:
        from seedmap.io import open_dataset

        ds = open_dataset(dataset)
        T = np.linalg.inv(rec.poses[0])
        uv, _ = ds.calib.project(rec.count.xyz @ T[:3, :3].T + T[:3, 3])
        ok = np.isfinite(uv).all(1)
        images[f"view 0: {int(ok.sum())} counted seeds reprojected (registered pose)"] = _thumb(ds[0].left, uv[ok])
    except Exception:  # thumbnails are optional
        pass
    return write_html_report(Path(folder) / "report.html", title=f"seedmap reconstruct: {Path(dataset).name}",
                             metrics=metrics, trajectories=trajs, matches_per_frame=per_view, points=pts,
                             point_colors=cols, images=images or None,
                             notes=f"{rec.count.count} seeds counted (red in the 3D view), "
                                   f"{len(rec.cloud_xyz):,} cloud points; mode {rec.mode}")
