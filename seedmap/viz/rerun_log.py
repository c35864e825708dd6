"""Record a run into a rerun ``.rrd`` file (open it with ``rerun FILE.rrd`` or app.rerun.io).

Why rerun: a SLAM or reconstruction run is a time series of images, 2D detections, matches, poses
and a growing 3D map; rerun shows all of them on one timeline, so a wrong match or a jump of the
trajectory can be traced to the frame that caused it. :class:`RerunLogger` is a thin, typed layer
over ``rerun.RecordingStream`` (rerun-sdk 0.41) with seedmap's entity layout:

* ``cam/left``, ``cam/right`` - images; ``.../keypoints`` (ellipse centres), ``.../ellipses``
  (fitted seed ellipses as closed line strips: rerun's ``Ellipses2D`` has no rotation),
  ``cam/left/stereo_matches`` (left keypoint -> its right partner's column, drawn in the left image)
  and ``cam/left/temporal_matches`` (previous-frame position -> current position);
* ``world/camera`` - the current left-camera pose (``Transform3D`` + ``Pinhole``, optical frame
  x right, y down, z forward), ``world/trajectory/<name>`` - 3D line strips (estimate, ground truth);
* ``world/landmarks`` - the seed map (``Points3D``; landmark ids as class ids, so the viewer colours
  each seed consistently over time);
* ``recon/views/<k>`` - per-view clouds and camera poses, ``recon/cloud`` the merged cloud,
  ``recon/seeds`` the seed centres.

Timeline ``frame`` (sequence = dataset frame index) and ``time`` (seconds, dataset timestamps).
With ``path=None`` every method is a no-op, so pipelines call it unconditionally. The file is
written under a temporary name and renamed on :meth:`close` (never a half-written ``.rrd``).
"""

from __future__ import annotations

import contextlib
import os
import weakref
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from seedmap.errors import InputError
from seedmap.outputs import check_not_input, check_output_file, check_output_parent, is_rerun_recording
from seedmap.records import Detections, Matches, StereoCalib, Trajectory

__all__ = ["RerunLogger", "check_rrd_path", "ellipse_polylines", "rrd_entity_paths"]

# colours (RGB) used consistently across entities
_C_KP = (255, 210, 0)
_C_ELL = (0, 230, 120)
_C_STEREO = (0, 160, 255)
_C_TEMPORAL = (255, 60, 200)
_C_TRAJ = {"estimate": (255, 120, 0), "ground truth": (60, 200, 60), "online": (120, 120, 255)}


def _discard(rec: Any, tmp: Path) -> None:
    """Finalizer of an unclosed logger (error, interpreter exit): drop the partial file."""
    with contextlib.suppress(Exception):
        rec.disconnect()
    with contextlib.suppress(FileNotFoundError, TypeError):
        os.unlink(tmp)


def check_rrd_path(path: str | Path, inputs: Iterable[str | Path | None] = (), overwrite: bool = False) -> None:
    """Fail early (one line) when a ``--rerun`` file cannot be written there, is (or lies inside) an input, or
    exists and is not a recording seedmap wrote (replaced only with ``overwrite``); creates its folder."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        check_not_input(path, inputs, "rerun recording")
        raise InputError("is a folder; --rerun wants a file name such as run.rrd", path)
    check_output_file(path, inputs, overwrite, is_rerun_recording, what="rerun recording")
    _probe(path)


def _probe(path: Path) -> None:
    """Create the recording's folder and check that a file can be written there."""
    if path.is_dir():
        raise InputError("is a folder; --rerun wants a file name such as run.rrd", path)
    check_output_parent(path, "rerun recording")  # a file where a folder of the path should be
    probe = path.with_name(f".{path.name}.{os.getpid()}.probe")
    try:  # os.access() says yes to root where the file system refuses (/proc, ro mounts)
        path.parent.mkdir(parents=True, exist_ok=True)
        probe.touch()
        probe.unlink()
    except OSError as e:
        raise InputError(f"cannot write the rerun recording here ({e.strerror or e})", path) from None


def ellipse_polylines(ellipses: np.ndarray, n_pts: int = 24) -> np.ndarray:
    """Closed outlines of ``cv2.fitEllipse`` ellipses: rows ``(cx, cy, major, minor, angle_deg)`` with
    full axis lengths in pixels -> ``(N, n_pts + 1, 2)`` pixel polylines (first point repeated)."""
    e = np.asarray(ellipses, np.float64).reshape(-1, 5)
    t = np.linspace(0.0, 2 * np.pi, n_pts + 1)
    a, b = e[:, 2:3] / 2.0, e[:, 3:4] / 2.0
    th = np.deg2rad(e[:, 4:5])
    x, y = a * np.cos(t), b * np.sin(t)
    u = e[:, 0:1] + x * np.cos(th) - y * np.sin(th)
    v = e[:, 1:2] + x * np.sin(th) + y * np.cos(th)
    return np.stack([u, v], axis=-1)


class RerunLogger:
    """Writes one rerun recording to ``path`` (``.rrd``); ``None`` disables it (every call a no-op).

    ``jpeg_quality`` (1-100) compresses logged images (a 4096x3000 pair is ~35 MB raw per frame);
    ``None`` logs them raw. ``image_scale`` < 1 downsamples images before logging - 2D overlays are
    scaled with them, so they stay aligned. ``world_coordinates``: a ``rerun.ViewCoordinates`` name for
    the world axes (``RDF`` for SLAM worlds, ``RIGHT_HAND_Z_UP`` for an arm's base frame).
    """

    def __init__(self, path: str | Path | None, application_id: str = "seedmap", jpeg_quality: int | None = 85,
                 image_scale: float = 1.0, world_coordinates: str = "RDF") -> None:
        self.path = Path(path) if path is not None else None
        self.jpeg_quality = jpeg_quality
        self.image_scale = float(image_scale)
        self._rec: Any = None
        self._tmp: Path | None = None
        self._traj: dict[str, list[np.ndarray]] = {}
        if self.path is None:
            return
        import rerun as rr

        _probe(self.path)  # the command checked the path against its inputs and --overwrite
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        self._rec = rr.RecordingStream(application_id)
        self._rec.save(str(self._tmp))
        # not closed (an exception unwound the pipeline, or the interpreter exits): no partial .rrd
        self._finalizer = weakref.finalize(self, _discard, self._rec, self._tmp)
        # world axes: "RDF" = seedmap's SLAM world (the first left-camera optical frame, y down);
        # "RIGHT_HAND_Z_UP" for the arm scans (robot base frame)
        self._rec.log("world", getattr(rr.ViewCoordinates, world_coordinates), static=True)
        if world_coordinates != "RDF":
            self._rec.log("recon", getattr(rr.ViewCoordinates, world_coordinates), static=True)

    # -- lifecycle -------------------------------------------------------------------------------
    @property
    def enabled(self) -> bool:
        return self._rec is not None

    def close(self) -> Path | None:
        """Flush, close the file and move it to ``path``; returns the path (None when disabled)."""
        if self._rec is None:
            return None
        rec, self._rec = self._rec, None
        self._finalizer.detach()
        rec.flush()
        rec.disconnect()  # closes the file sink (writes the footer)
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the recording (an error happened): no file is left behind."""
        if self._rec is None:
            return
        self._rec = None
        self._finalizer()

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # -- helpers ---------------------------------------------------------------------------------
    def set_frame(self, index: int, timestamp: float | None = None) -> None:
        """Everything logged next belongs to frame ``index`` (and ``timestamp`` seconds)."""
        if self._rec is None:
            return
        self._rec.set_time("frame", sequence=int(index))
        if timestamp is not None and np.isfinite(timestamp):
            self._rec.set_time("time", duration=float(timestamp))

    def _image(self, img: np.ndarray):
        import cv2
        import rerun as rr

        a = np.asarray(img)
        if self.image_scale != 1.0:
            h, w = a.shape[:2]
            a = cv2.resize(a, (max(1, round(w * self.image_scale)), max(1, round(h * self.image_scale))),
                           interpolation=cv2.INTER_AREA)
        im = rr.Image(a, color_model="RGB" if a.ndim == 3 else "L")
        if self.jpeg_quality is not None and a.dtype == np.uint8:
            im = im.compress(jpeg_quality=int(self.jpeg_quality))
        return im

    def _px(self, uv: np.ndarray) -> np.ndarray:
        """Full-image pixel coordinates -> logged-image pixels (pixel-centre convention)."""
        uv = np.asarray(uv, np.float64)
        if self.image_scale == 1.0:
            return uv
        return (uv + 0.5) * self.image_scale - 0.5

    # -- per-frame 2D ----------------------------------------------------------------------------
    def log_stereo_frame(
        self,
        index: int,
        timestamp: float,
        left: np.ndarray | None = None,
        right: np.ndarray | None = None,
        kp_left: np.ndarray | None = None,
        kp_right: np.ndarray | None = None,
        stereo: Matches | None = None,
        temporal: Matches | None = None,
        prev_kp_left: np.ndarray | None = None,
        det_left: Detections | None = None,
        det_right: Detections | None = None,
    ) -> None:
        """One stereo frame: images, keypoints (``(N, 2)`` px), fitted ellipses (from ``det_*``),
        stereo matches (``idx_a`` into ``kp_left``, ``idx_b`` into ``kp_right``) and temporal matches
        (``idx_a`` into ``prev_kp_left``, ``idx_b`` into ``kp_left``)."""
        if self._rec is None:
            return
        import rerun as rr

        rec = self._rec
        self.set_frame(index, timestamp)
        if kp_left is None and det_left is not None:
            kp_left = det_left.keypoints
        if kp_right is None and det_right is not None:
            kp_right = det_right.keypoints
        for side, img, kp, det in (("left", left, kp_left, det_left), ("right", right, kp_right, det_right)):
            if img is not None:
                rec.log(f"cam/{side}", self._image(img))
            if kp is not None:
                rec.log(f"cam/{side}/keypoints", rr.Points2D(self._px(np.reshape(kp, (-1, 2))), colors=_C_KP,
                                                            radii=1.5))
            if det is not None and len(det):
                strips = self._px(ellipse_polylines(det.ellipses))
                rec.log(f"cam/{side}/ellipses", rr.LineStrips2D(list(strips), colors=_C_ELL, radii=0.6))
        if stereo is not None and kp_left is not None and kp_right is not None:
            a = np.reshape(kp_left, (-1, 2))[stereo.idx_a]
            b = np.reshape(kp_right, (-1, 2))[stereo.idx_b]
            strips = np.stack([self._px(a), self._px(np.c_[b[:, 0], a[:, 1]])], axis=1)
            rec.log("cam/left/stereo_matches", rr.LineStrips2D(list(strips), colors=_C_STEREO, radii=0.5))
        if temporal is not None and prev_kp_left is not None and kp_left is not None:
            a = np.reshape(prev_kp_left, (-1, 2))[temporal.idx_a]
            b = np.reshape(kp_left, (-1, 2))[temporal.idx_b]
            strips = np.stack([self._px(a), self._px(b)], axis=1)
            rec.log("cam/left/temporal_matches", rr.LineStrips2D(list(strips), colors=_C_TEMPORAL, radii=0.5))

    def log_scalars(self, index: int, values: dict[str, float], prefix: str = "stats") -> None:
        """Per-frame numbers (match counts, timings) as time series ``<prefix>/<name>``."""
        if self._rec is None:
            return
        import rerun as rr

        self._rec.set_time("frame", sequence=int(index))
        for k, v in values.items():
            if v is not None and np.isfinite(float(v)):
                self._rec.log(f"{prefix}/{k}", rr.Scalars(float(v)))

    # -- 3D --------------------------------------------------------------------------------------
    def log_camera(self, T_world_cam: np.ndarray, calib: StereoCalib | None = None,
                   entity: str = "world/camera") -> None:
        """A left-camera pose ``T_world_cam`` (4x4, metres) and, with ``calib``, its frustum."""
        if self._rec is None:
            return
        import rerun as rr

        T = np.asarray(T_world_cam, np.float64)
        self._rec.log(entity, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        if calib is not None:
            self._rec.log(entity, rr.Pinhole(image_from_camera=calib.K, resolution=[calib.width, calib.height],
                                             camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.05))

    def log_pose(self, index: int, timestamp: float, T_world_cam: np.ndarray, calib: StereoCalib | None = None,
                 name: str = "estimate") -> None:
        """Append a pose to the growing trajectory ``name`` (and move the camera for the estimate)."""
        if self._rec is None or T_world_cam is None:
            return
        import rerun as rr

        self.set_frame(index, timestamp)
        T = np.asarray(T_world_cam, np.float64)
        pts = self._traj.setdefault(name, [])
        pts.append(T[:3, 3].copy())
        if name == "estimate":
            self.log_camera(T, calib)
        if len(pts) >= 2:
            self._rec.log(f"world/trajectory/{name}",
                          rr.LineStrips3D([np.asarray(pts)], colors=_C_TRAJ.get(name, (200, 200, 200)), radii=0.002))

    def log_trajectory(self, name: str, traj: Trajectory | None, static: bool = True) -> None:
        """A whole trajectory (e.g. ground truth or the final batch estimate) as one 3D line strip."""
        if self._rec is None or traj is None or len(traj) == 0:
            return
        import rerun as rr

        self._rec.log(f"world/trajectory/{name.replace(' ', '_')}",
                      rr.LineStrips3D([traj.positions], colors=_C_TRAJ.get(name, (200, 200, 200)), radii=0.002),
                      static=static)

    def log_landmarks(self, xyz: np.ndarray, ids: np.ndarray | None = None, entity: str = "world/landmarks",
                      labels: bool = False, static: bool = False) -> None:
        """The seed map: ``(N, 3)`` metres; ``ids`` become class ids (consistent colours per seed)."""
        if self._rec is None:
            return
        import rerun as rr

        xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
        kw: dict[str, Any] = {"radii": 0.002}
        if ids is not None:
            ids = np.asarray(ids, np.int64).reshape(-1)
            kw["class_ids"] = (ids % 65535).astype(np.uint16)  # rerun class ids are u16
            if labels:
                kw["labels"] = [str(int(i)) for i in ids]
        self._rec.log(entity, rr.Points3D(xyz, **kw), static=static)

    def log_cloud(self, entity: str, xyz: np.ndarray, rgb: np.ndarray | None = None, radius: float = 0.0005,
                  T_world_cam: np.ndarray | None = None, static: bool = True) -> None:
        """A point cloud (``(N, 3)`` m, optional ``(N, 3)`` uint8 colours); with ``T_world_cam`` the
        points are in that camera's frame and the entity carries the transform."""
        if self._rec is None:
            return
        import rerun as rr

        if T_world_cam is not None:
            T = np.asarray(T_world_cam, np.float64)
            self._rec.log(entity, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=static)
            entity = f"{entity}/points"
        kw: dict[str, Any] = {"radii": radius}
        if rgb is not None:
            kw["colors"] = np.asarray(rgb, np.uint8).reshape(-1, 3)
        self._rec.log(entity, rr.Points3D(np.asarray(xyz, np.float64).reshape(-1, 3), **kw), static=static)

    def log_reconstruction(
        self,
        poses: np.ndarray,
        calib: StereoCalib | None = None,
        view_clouds: list[tuple[np.ndarray, np.ndarray | None]] | None = None,
        cloud_xyz: np.ndarray | None = None,
        cloud_rgb: np.ndarray | None = None,
        seeds_xyz: np.ndarray | None = None,
        timestamps: np.ndarray | None = None,
        fk_poses: np.ndarray | None = None,
        views_in_world: bool = True,
    ) -> None:
        """A panicle reconstruction: per view (on the frame timeline) its camera pose and cloud; the
        merged cloud and the seed centres (static). ``view_clouds[k] = (xyz, rgb)`` in the world frame
        when ``views_in_world`` else in view ``k``'s camera frame."""
        if self._rec is None:
            return
        poses = np.asarray(poses, np.float64).reshape(-1, 4, 4)
        for k, T in enumerate(poses):
            self.set_frame(k, None if timestamps is None else float(timestamps[k]))
            self.log_camera(T, calib, entity="recon/camera")
            self.log_camera(T, None, entity=f"recon/views/{k}/pose")
            if view_clouds is not None and k < len(view_clouds):
                xyz, rgb = view_clouds[k]
                self.log_cloud(f"recon/views/{k}/cloud", xyz, rgb, T_world_cam=None if views_in_world else T,
                               static=False)
        if len(poses):
            self.log_trajectory("estimate", Trajectory(np.arange(len(poses), dtype=float), poses))
        if fk_poses is not None and len(fk_poses):
            self.log_trajectory("forward kinematics", Trajectory(np.arange(len(fk_poses), dtype=float), fk_poses))
        if cloud_xyz is not None:
            self.log_cloud("recon/cloud", cloud_xyz, cloud_rgb)
        if seeds_xyz is not None:
            import rerun as rr

            s = np.asarray(seeds_xyz, np.float64).reshape(-1, 3)
            self._rec.log("recon/seeds", rr.Points3D(s, radii=0.0015, colors=(255, 40, 40),
                                                     class_ids=np.arange(len(s)) % 65535), static=True)


def rrd_entity_paths(path: str | Path) -> dict[str, int]:
    """Entity paths of the first recording in an ``.rrd`` file and their row counts (reads it back
    with ``rerun.chunk.RrdReader``; used by tests and to check a log)."""
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(str(path)).stream():
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts
