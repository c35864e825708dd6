"""The SLAM core: one verb per frame, ``SemanticSlam.register_frame(features)``, and its streaming form
``for res in SemanticSlam(calib, matcher, cfg).run(frames): ...``.

Front-end: triangulate the stereo matches, associate the current left keypoints with the previous
frame's, estimate the frame-to-frame motion from the 3D seeds with RANSAC (default: 1-point
translation, rotation left to the graph, see ``seedmap.slam.motion.ransac_translation``; option:
3-point Kabsch / Umeyama for the full SE(3)), and continue a
landmark track only through RANSAC-verified matches (a re-seen seed keeps its landmark id; a
wrong association cannot extend a track).

Back-end (GTSAM 4.3): ``Pose3`` per frame (``X(k)`` = ``T_world_cam`` of the left camera), ``Point3``
per landmark (``L(id)``), ``GenericStereoFactor3D`` with a Huber loss on ``Cal3_S2Stereo``, a prior
on the first pose and a ``BetweenFactorPose3`` per frame pair from the motion estimate (noise
sigmas ordered ``[rotation (rad); translation (m)]`` as GTSAM's Pose3 tangent space). A track
becomes a landmark (enters the graph, with all its buffered observations) once it has
``min_observations`` stereo observations with disparity ≥ ``min_disparity`` – a landmark seen once
is unconstrained along nothing but still poorly conditioned, and this rule keeps
``IndeterminantLinearSystemException`` away. The online back-end (``backend.online``, see
``seedmap.slam.backends``: iSAM2, a fixed-lag smoother, or none) updates once per frame; :meth:`finalize`
optionally re-solves the whole graph in batch (Levenberg–Marquardt or Dogleg).

Lost: fewer than ``lost.min_inliers`` verified 3D matches to the previous frame, or the optimiser
throws / moves the new pose more than ``MAX_CORRECTION_M`` away from the motion estimate.
After "lost" the object refuses further frames (the paper's maximum-distance-mapped protocol).
"""

from __future__ import annotations

import bisect
import time
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from seedmap.associate.base import FULL_RES_WIDTH, FrameFeatures, Matcher
from seedmap.records import Matches, StereoCalib, StereoFrame, Trajectory
from seedmap.slam.backends import OnlineBackend, make_online_backend
from seedmap.slam.config import SlamConfig
from seedmap.slam.motion import ransac_motion, ransac_translation

#: Huber threshold of the stereo factors (in sigmas; the usual 95 %-efficiency constant)
HUBER_K = 1.345
#: prior on the first pose: rotation (rad) and translation (m) sigmas, i.e. practically fixed
PRIOR_SIGMA_ROT_RAD = 1e-4
PRIOR_SIGMA_TRANS_M = 1e-4
#: a per-frame correction of the motion estimate larger than this (m) means the optimiser failed
MAX_CORRECTION_M = 0.10
#: least-squares refits of the RANSAC motion on its inliers
MOTION_REFINE_ITERS = 3


@dataclass
class FrameResult:
    """What happened to one frame."""

    index: int
    ok: bool
    T_world_cam: np.ndarray | None
    n_keypoints_left: int
    n_stereo: int
    n_temporal: int
    n_inliers: int
    n_landmarks_seen: int
    lost_reason: str | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class Landmarks:
    """Landmarks of the map: ids, world positions (m), number of observations, GT seed id (-1),
    and whether the landmark was a variable of the factor graph (``in_graph``) or a track outside the
    graph's per-frame budget, placed by its stereo observations from the optimised poses."""

    ids: np.ndarray
    xyz: np.ndarray
    n_obs: np.ndarray
    seed_ids: np.ndarray
    in_graph: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.in_graph is None:
            self.in_graph = np.ones(len(self.ids), bool)

    def __len__(self) -> int:
        return len(self.ids)


class _Track:
    __slots__ = ("obs", "admitted", "seed_ids")

    def __init__(self) -> None:
        self.obs: list[tuple[int, float, float, float]] = []  # (frame, uL, uR, v)
        self.admitted = False
        self.seed_ids: list[int] = []


def _pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, float))


class SemanticSlam:
    """Online stereo SLAM over matcher features (any :class:`~seedmap.associate.base.Matcher`)."""

    def __init__(self, calib: StereoCalib, matcher: Matcher, cfg: SlamConfig | None = None,
                 first_pose: np.ndarray | None = None) -> None:
        self.calib = calib
        self.matcher = matcher
        self.cfg = cfg or SlamConfig()
        self.rng = np.random.default_rng(self.cfg.seed)
        self.first_pose = np.eye(4) if first_pose is None else np.asarray(first_pose, float)
        s = calib.width / FULL_RES_WIDTH
        self._reproj_px = self.cfg.frontend.ransac_reproj_px * s
        self._min_disp = self.cfg.backend.min_disparity_px * s
        b = self.cfg.backend
        self.K = gtsam.Cal3_S2Stereo(calib.fx, calib.fy, 0.0, calib.cx, calib.cy, calib.baseline)
        self.stereo_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K), gtsam.noiseModel.Isotropic.Sigma(3, b.stereo_sigma_px)
        )
        self.prior_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.r_[np.full(3, PRIOR_SIGMA_ROT_RAD), np.full(3, PRIOR_SIGMA_TRANS_M)]
        )
        self.between_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.r_[np.full(3, b.between_sigma_rot_rad), np.full(3, b.between_sigma_trans_m)]
        )
        self.backend: OnlineBackend = make_online_backend(b.online, b.lag_frames)
        self.graph = gtsam.NonlinearFactorGraph()  # everything added so far (for the final batch)
        self.initial = gtsam.Values()
        self.frames: list[int] = []  # dataset indices of the registered frames, in order
        self.timestamps: list[float] = []
        self.online_poses: list[np.ndarray] = []
        self.tracks: dict[int, _Track] = {}
        self._next_track = 0
        self.prev: FrameFeatures | None = None
        self._prev_stereo_r: np.ndarray | None = None  # right idx per left kp (-1)
        self._prev_pts: np.ndarray | None = None  # (N, 3) per left kp (NaN)
        self._prev_track: np.ndarray | None = None  # track id per left kp (-1)
        self.lost = False
        self.lost_reason: str | None = None
        self.lost_frame: int | None = None

    # ------------------------------------------------------------------------------------------
    def _stereo_arrays(self, f: FrameFeatures) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per left keypoint: right index (-1), (uL, uR, v) obs and 3D point in the camera (NaN)."""
        n = len(f.kp_left)
        ridx = np.full(n, -1, np.int64)
        obs = np.full((n, 3), np.nan)
        pts = np.full((n, 3), np.nan)
        m = f.stereo
        if len(m):
            ul = f.kp_left[m.idx_a]
            ur = f.kp_right[m.idx_b, 0]
            disp = ul[:, 0] - ur
            ok = disp >= max(self._min_disp, 1e-6)
            a, b = m.idx_a[ok], m.idx_b[ok]
            ridx[a] = b
            obs[a] = np.c_[f.kp_left[a, 0], f.kp_right[b, 0], f.kp_left[a, 1]]
            pts[a] = self.calib.triangulate(f.kp_left[a], f.kp_right[b, 0])
        return ridx, obs, pts

    def _window(self, k: int, track: np.ndarray) -> list[int]:
        """The active window of frame ``k``: the registered frames from the first frame of the oldest track seen in
        frame ``k`` on, then ``k`` (the poses that observe what frame ``k`` sees)."""
        seen = track[track >= 0]
        first = min((self.tracks[int(t)].obs[0][0] for t in seen), default=k)
        return self.frames[bisect.bisect_left(self.frames, first):] + [k]

    def _declare_lost(self, f: FrameFeatures, reason: str, res: FrameResult) -> FrameResult:
        self.lost = True
        self.lost_reason = reason
        self.lost_frame = f.index
        res.ok = False
        res.lost_reason = reason
        return res

    def _new_track(self) -> int:
        t = self._next_track
        self._next_track += 1
        self.tracks[t] = _Track()
        return t

    def _admission_budget(self, kp: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """Which of the candidate keypoints ``cand`` (indices into ``kp``) may admit a new landmark
        this frame: all, or ``max_new_landmarks`` spread over a 16 x 12 image grid (round robin over
        the cells, so the graph keeps seeds from every part of the view)."""
        cap = self.cfg.backend.max_new_landmarks
        ok = np.zeros(len(kp), bool)
        if cap is None or len(cand) <= cap:
            ok[cand] = True
            return ok
        gx = np.clip((kp[cand, 0] / self.calib.width * 16).astype(int), 0, 15)
        gy = np.clip((kp[cand, 1] / self.calib.height * 12).astype(int), 0, 11)
        cell = gy * 16 + gx
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        rank = np.arange(len(cs)) - np.searchsorted(cs, cs)  # position within its cell
        pick = order[np.lexsort((cs, rank))][:cap]
        ok[cand[pick]] = True
        return ok

    def _add_obs(self, tid: int, k: int, o: np.ndarray, sid: int, T_world_cam: np.ndarray,
                 pt_cam: np.ndarray, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                 may_admit: bool = True) -> None:
        tr = self.tracks[tid]
        tr.obs.append((k, float(o[0]), float(o[1]), float(o[2])))
        tr.seed_ids.append(int(sid))
        if tr.admitted:
            graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(*o), self.stereo_noise, X(k), L(tid), self.K))
        elif may_admit and len(tr.obs) >= self.cfg.backend.min_observations:
            tr.admitted = True
            for kk, ul, ur, v in tr.obs:
                graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(ul, ur, v), self.stereo_noise,
                                                      X(kk), L(tid), self.K))
            pw = T_world_cam[:3, :3] @ pt_cam + T_world_cam[:3, 3]
            values.insert(L(tid), gtsam.Point3(*pw))

    # ------------------------------------------------------------------------------------------
    def register_frame(self, f: FrameFeatures) -> FrameResult:
        """Add one frame; returns its pose estimate or the reason the track was lost."""
        if self.lost:
            raise RuntimeError("SemanticSlam: track already lost; start a new instance")
        tm: dict[str, float] = {}
        ridx, obs, pts = self._stereo_arrays(f)
        has3d = ridx >= 0
        res = FrameResult(f.index, True, None, len(f.kp_left), int(has3d.sum()), 0, 0, 0, None, tm)
        k = f.index
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        track = np.full(len(f.kp_left), -1, np.int64)
        sids = f.seed_ids_left if f.seed_ids_left is not None else np.full(len(f.kp_left), -1)

        if self.prev is None:
            if has3d.sum() < self.cfg.lost.min_inliers:
                return self._declare_lost(f, f"too few stereo seed matches in the first frame "
                                             f"({int(has3d.sum())} < {self.cfg.lost.min_inliers})", res)
            T = self.first_pose
            graph.add(gtsam.PriorFactorPose3(X(k), _pose3(T), self.prior_noise))
            values.insert(X(k), _pose3(T))
            for i in np.flatnonzero(has3d):
                track[i] = tid = self._new_track()
                self._add_obs(tid, k, obs[i], sids[i], T, pts[i], graph, values)
        else:
            t0 = time.perf_counter()
            tmatch: Matches = self.matcher.match_temporal(self.prev, f)
            tm["temporal_match"] = (time.perf_counter() - t0) * 1e3
            res.n_temporal = len(tmatch)
            t0 = time.perf_counter()
            pa, pb = tmatch.idx_a, tmatch.idx_b
            both = (self._prev_stereo_r[pa] >= 0) & has3d[pb]
            pa, pb = pa[both], pb[both]
            est = None
            if len(pa) >= 3:
                fe = self.cfg.frontend
                fit = ransac_translation if fe.motion_model == "translation" else ransac_motion
                est = fit(self.calib, self._prev_pts[pa], pts[pb], obs[pb], self.rng,
                          fe.ransac_iters, self._reproj_px, MOTION_REFINE_ITERS)
            tm["motion"] = (time.perf_counter() - t0) * 1e3
            n_inl = 0 if est is None else int(est.inliers.sum())
            res.n_inliers = n_inl
            if n_inl < self.cfg.lost.min_inliers:
                g = self.cfg.gates
                hint = ""
                if len(tmatch) < self.cfg.lost.min_inliers and (g.travel_sign != 0 or g.temporal_min_shift_px > 0):
                    # the default temporal gates assume a robot driving along a row (one image-u direction, at
                    # least a minimum shift); a hovering or differently moving camera fails them all
                    hint = ("; the temporal gates expect row travel: for other motion set gates.travel_sign=0 "
                            "and gates.temporal_min_shift_px=0")
                return self._declare_lost(f, f"too few verified 3D matches ({n_inl} < "
                                             f"{self.cfg.lost.min_inliers}; {len(tmatch)} temporal matches{hint})", res)
            T_prev = self.online_poses[-1]
            T = T_prev @ est.T_prev_cur
            kp = self.frames[-1]
            graph.add(gtsam.BetweenFactorPose3(X(kp), X(k), _pose3(est.T_prev_cur), self.between_noise))
            values.insert(X(k), _pose3(T))
            inl_a, inl_b = pa[est.inliers], pb[est.inliers]
            track[inl_b] = self._prev_track[inl_a]
            cand = np.flatnonzero(has3d & (track >= 0))
            cand = cand[[not self.tracks[int(track[i])].admitted
                         and len(self.tracks[int(track[i])].obs) + 1 >= self.cfg.backend.min_observations
                         for i in cand]] if len(cand) else cand
            may = self._admission_budget(f.kp_left, cand)
            for i in np.flatnonzero(has3d & (track >= 0)):
                self._add_obs(int(track[i]), k, obs[i], sids[i], T, pts[i], graph, values, may_admit=bool(may[i]))
            # the rest start tracks, numbered in keypoint order (one observation each: no factor yet)
            new = np.flatnonzero(has3d & (track < 0))
            track[new] = np.arange(self._next_track, self._next_track + len(new))
            for tid, o, sid in zip(track[new].tolist(), obs[new].tolist(), sids[new].tolist()):
                tr = self.tracks[tid] = _Track()
                tr.obs.append((k, *o))
                tr.seed_ids.append(int(sid))
            self._next_track += len(new)

        # back-end
        t0 = time.perf_counter()
        try:
            T_opt = self.backend.update(k, graph, values, lambda: self._window(k, track))
        except RuntimeError as e:  # IndeterminantLinearSystemException and friends
            tm["backend"] = (time.perf_counter() - t0) * 1e3
            return self._declare_lost(f, f"optimiser failed ({type(e).__name__}: {str(e).splitlines()[0][:80]})", res)
        tm["backend"] = (time.perf_counter() - t0) * 1e3
        T_pred = values.atPose3(X(k)).matrix()
        if not np.all(np.isfinite(T_opt)) or np.linalg.norm(T_opt[:3, 3] - T_pred[:3, 3]) > MAX_CORRECTION_M:
            return self._declare_lost(f, "optimiser diverged (pose moved away from the motion estimate)", res)
        self.graph.push_back(graph)
        self.initial.insert(values)
        self.frames.append(k)
        self.timestamps.append(f.timestamp)
        self.online_poses.append(T_opt)
        self.prev = f
        self._prev_stereo_r, self._prev_pts, self._prev_track = ridx, pts, track
        res.T_world_cam = T_opt
        res.n_landmarks_seen = int(sum(1 for t in track[track >= 0] if self.tracks[int(t)].admitted))
        return res

    def run(self, frames: Iterable[StereoFrame | FrameFeatures], prefetch: int = 1) -> Iterator[FrameResult]:
        """Streaming API: ``for res in slam.run(frames): ...`` registers each frame as it comes and yields its
        :class:`FrameResult`; it ends after the frame that lost the track. ``frames``: stereo pairs (the matcher
        turns them into features; a matcher with ``detect_frame`` detects frame t+1 in a background thread,
        ``prefetch`` frames ahead, while frame t is associated) or ready :class:`FrameFeatures`. The map so far
        is :meth:`landmarks`, the final trajectory :meth:`finalize`."""
        from seedmap.slam.stream import Prefetch

        detect = getattr(self.matcher, "detect_frame", None)

        def work(f):  # noqa: ANN001, ANN202 - a frame or features
            return f, (detect(f) if detect is not None and isinstance(f, StereoFrame) else None)

        stream = Prefetch(work, frames, prefetch if detect is not None else 0)
        for f, det in stream:
            if isinstance(f, FrameFeatures):
                feats = f
            else:
                feats = self.matcher.features(f, det) if det is not None else self.matcher.features(f)
            res = self.register_frame(feats)
            yield res
            if not res.ok:
                stream.close()
                return

    # ------------------------------------------------------------------------------------------
    def online_trajectory(self) -> Trajectory:
        return Trajectory(np.asarray(self.timestamps), np.asarray(self.online_poses).reshape(-1, 4, 4))

    @property
    def estimate(self) -> gtsam.Values:
        """The online back-end's current estimate of the variables of :attr:`graph` (the initial values without
        one), computed on demand: a copy of the whole map, so it is not taken per frame."""
        return self.backend.estimate(self.initial)

    def _current_values(self) -> gtsam.Values:
        """Best current values of every variable in :attr:`graph` (online estimate, else initial)."""
        return self.estimate

    def finalize(self) -> tuple[Trajectory, gtsam.Values, str]:
        """Final trajectory: batch LM/Dogleg over the whole graph (if configured), else online.

        Returns ``(trajectory, values, backend_name)``; a failing batch falls back to the online
        estimate (and says so in ``backend_name``).
        """
        values = self._current_values()
        name = self.backend.name
        mode = self.cfg.backend.final_batch
        if mode != "none" and len(self.frames) > 1:
            try:
                if mode == "lm":
                    p = gtsam.LevenbergMarquardtParams()
                    p.setMaxIterations(50)
                    values = gtsam.LevenbergMarquardtOptimizer(self.graph, values, p).optimize()
                else:
                    p = gtsam.DoglegParams()
                    p.setMaxIterations(50)
                    values = gtsam.DoglegOptimizer(self.graph, values, p).optimize()
                name = f"{name}+{mode}"
            except RuntimeError:
                name = f"{name} (batch {mode} failed)"
        poses = np.asarray([values.atPose3(X(k)).matrix() for k in self.frames]).reshape(-1, 4, 4)
        return Trajectory(np.asarray(self.timestamps), poses), values, name

    def landmarks(self, values: gtsam.Values | None = None) -> Landmarks:
        """The seed map with positions from ``values`` (default: current estimate): the graph's
        landmarks, plus every track of >= ``min_observations`` frames that the per-frame budget
        (``backend.max_new_landmarks``) kept out of the graph, placed at the mean of its stereo
        points transformed with the optimised poses (vectorised over all such observations)."""
        values = values if values is not None else self._current_values()
        frames = np.asarray([k for k in self.frames if values.exists(X(k))], np.int64)
        poses = np.asarray([values.atPose3(X(int(k))).matrix() for k in frames]).reshape(-1, 4, 4)
        have = set(frames.tolist())
        min_obs = self.cfg.backend.min_observations
        ids, xyz, nobs, sids, ing = [], [], [], [], []
        out_row: list[int] = []
        out_obs: list[tuple] = []
        for tid, tr in self.tracks.items():
            if tr.admitted:
                if not values.exists(L(tid)):
                    continue
                p = np.asarray(values.atPoint3(L(tid)))
            else:
                o = [ob for ob in tr.obs if ob[0] in have]
                if len(o) < min_obs:
                    continue
                out_row += [len(ids)] * len(o)
                out_obs += o
                p = np.full(3, np.nan)
            ids.append(tid)
            xyz.append(p)
            nobs.append(len(tr.obs))
            known = [s for s in tr.seed_ids if s >= 0]
            sids.append(Counter(known).most_common(1)[0][0] if known else -1)
            ing.append(tr.admitted)
        xyz_a = np.asarray(xyz, float).reshape(-1, 3)
        if out_obs:
            o = np.asarray(out_obs, float)  # (frame, u_left, u_right, v)
            row = np.asarray(out_row, np.int64)
            pc = self.calib.triangulate(o[:, [1, 3]], o[:, 2])
            T = poses[np.searchsorted(frames, o[:, 0].astype(np.int64))]
            pw = np.einsum("mij,mj->mi", T[:, :3, :3], pc) + T[:, :3, 3]
            cnt = np.bincount(row, minlength=len(ids))
            sel = cnt > 0
            for d in range(3):
                xyz_a[sel, d] = np.bincount(row, pw[:, d], len(ids))[sel] / cnt[sel]
        return Landmarks(np.asarray(ids, np.int64), xyz_a, np.asarray(nobs, np.int64), np.asarray(sids, np.int64),
                         np.asarray(ing, bool))
