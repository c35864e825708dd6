"""Online back-ends of the SLAM core, picked once by ``backend.online`` (:func:`make_online_backend`).

Each back-end takes the frame's new factors and initial values, returns the new pose's estimate, and gives the
current estimate of every accepted variable on demand:

* ``isam2``: iSAM2 over the whole graph, with the active window's poses ordered last (docs/method/slam_live.md).
* ``fixed_lag``: GTSAM's ``IncrementalFixedLagSmoother``: a pose or landmark leaves the smoother (is
  marginalised) ``lag_frames`` frames after the last frame that involved it; what left keeps its last estimate.
  Per-frame time and memory stay bounded along the row (docs/method/slam_live.md, "Bounded back-end").
* ``none``: no optimisation per frame; the pose is the motion estimate.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

#: iSAM2 relinearisation threshold and number of updates between relinearisation checks
ISAM_RELINEARIZE_THRESHOLD = 0.01
ISAM_RELINEARIZE_SKIP = 1


def _isam2_params() -> gtsam.ISAM2Params:
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(ISAM_RELINEARIZE_THRESHOLD)
    params.relinearizeSkip = ISAM_RELINEARIZE_SKIP
    return params


def _is_pose(key: int) -> bool:
    return gtsam.Symbol(key).chr() == ord("x")


def _restricted(est: gtsam.Values, keys: gtsam.Values) -> gtsam.Values:
    """The variables of ``keys`` with their values from ``est`` (a rejected last frame left extra ones)."""
    if est.size() == keys.size():
        return est
    v = gtsam.Values()
    for key in keys.keys():
        v.insert(key, est.atPose3(key) if _is_pose(key) else est.atPoint3(key))
    return v


class OnlineBackend(Protocol):
    """What the SLAM core asks of an online back-end."""

    #: name in ``finalize``'s back-end string
    name: str

    def update(self, k: int, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               window: Callable[[], list[int]]) -> np.ndarray:
        """Add frame ``k``'s factors and new variables; return ``T_world_cam`` of ``X(k)``. ``window()``: the
        frames (ascending, ending with ``k``) whose poses observe a track seen in frame ``k``. Raises
        RuntimeError when the optimiser fails."""
        ...

    def estimate(self, initial: gtsam.Values) -> gtsam.Values:
        """Current estimate of the variables of ``initial`` (every accepted variable of the graph)."""
        ...


class MotionOnly:
    """No online optimisation: the pose is the motion estimate; the final batch (if any) optimises."""

    name = "motion-only"

    def update(self, k: int, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               window: Callable[[], list[int]]) -> np.ndarray:
        return values.atPose3(X(k)).matrix()

    def estimate(self, initial: gtsam.Values) -> gtsam.Values:
        return gtsam.Values(initial)


class Isam2:
    """iSAM2 over the whole graph, one update per frame, the active window's poses eliminated last."""

    name = "isam2"

    def __init__(self, lag_frames: int) -> None:
        self.isam = gtsam.ISAM2(_isam2_params())

    def update(self, k: int, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               window: Callable[[], list[int]]) -> np.ndarray:
        # iSAM2's default ordering puts every variable of the new factors, all landmarks of the frame, into a root
        # clique whose dense factors grow with the map; the window's poses last keep the root to poses
        last = gtsam.KeyGroupMap()
        for j in window():
            last.insert2(X(j), 1)
        self.isam.update(graph, values, [], last)
        # the new pose only: the whole estimate is a copy of every variable, O(map) per frame
        return self.isam.calculateEstimatePose3(X(k)).matrix()

    def estimate(self, initial: gtsam.Values) -> gtsam.Values:
        if initial.size() == 0:
            return gtsam.Values()
        try:
            est = self.isam.calculateEstimate()
        except RuntimeError:  # an update that threw (the frame that lost the track) can leave no usable estimate
            return gtsam.Values(initial)
        return _restricted(est, initial)


class FixedLag:
    """``gtsam.IncrementalFixedLagSmoother`` over the recent part of the graph.

    The smoother's clock counts registered frames. A variable's timestamp is the last frame that involved it: a
    landmark's, the last frame that observed it; a pose's, the last frame that saw a track the pose saw (the
    window), so a pose leaves only after all its landmarks and its marginal stays a factor on poses. Variables
    older than ``lag_frames`` are marginalised; their last estimate is kept (:attr:`left`)."""

    name = "fixed-lag"

    def __init__(self, lag_frames: int) -> None:
        params = _isam2_params()
        params.findUnusedFactorSlots = True  # marginalised factors' slots are reused: the factor list stays bounded
        self.lag = int(lag_frames)
        self.smoother = gtsam.IncrementalFixedLagSmoother(float(self.lag), params)
        self.left = gtsam.Values()  # last estimate of every marginalised variable
        self._stamp: dict[int, int] = {}  # key -> timestamp (frames) of the variables in the smoother
        self._clock = -1

    def update(self, k: int, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               window: Callable[[], list[int]]) -> np.ndarray:
        self._clock += 1
        t = self._clock
        new = {key: t for key in graph.keyVector()}
        for key in values.keys():
            new[key] = t
        for j in window():
            new[X(j)] = t
        # the smoother marginalises the keys stamped before t - lag: keep their estimate (as of the last frame)
        going = [key for key, s in self._stamp.items() if s < t - self.lag and key not in new]
        for key in going:
            self.left.insert(key, self.smoother.calculateEstimatePose3(key) if _is_pose(key)
                             else self.smoother.calculateEstimatePoint3(key))
            del self._stamp[key]
        self._stamp.update(new)
        self.smoother.update(graph, values, {key: float(s) for key, s in new.items()})
        return self.smoother.calculateEstimatePose3(X(k)).matrix()

    def size(self) -> int:
        """Variables in the smoother now."""
        return len(self._stamp)

    def estimate(self, initial: gtsam.Values) -> gtsam.Values:
        if initial.size() == 0:
            return gtsam.Values()
        try:
            est = gtsam.Values(self.left)
            est.insert(self.smoother.calculateEstimate())
        except RuntimeError:  # an update that threw can leave no usable estimate
            return gtsam.Values(initial)
        return _restricted(est, initial)


#: ``backend.online`` -> back-end class (constructed with ``backend.lag_frames``)
ONLINE_BACKENDS: dict[str, Callable[[int], OnlineBackend]] = {
    "isam2": Isam2,
    "fixed_lag": FixedLag,
    "none": lambda lag_frames: MotionOnly(),
}


def make_online_backend(name: str, lag_frames: int) -> OnlineBackend:
    """The online back-end registered as ``name``."""
    return ONLINE_BACKENDS[name](lag_frames)
