"""The semantic seed matcher: detector keypoints associated by the paper's cost or the field matcher."""

from __future__ import annotations

import time

import numpy as np

from seedmap.associate.base import FrameFeatures, GateConfig
from seedmap.associate.config import SemanticConfig
from seedmap.associate.cost import full_res_scale, full_res_sums, neighbour_sums
from seedmap.associate.methods import METHODS
from seedmap.errors import SeedmapError
from seedmap.records import Matches, StereoCalib, StereoDetections, StereoFrame


class SeedMatcher:
    """Seeds as semantic features: a detector gives keypoints, the semantic cost associates them.

    ``detector`` needs ``detect_stereo(frame: StereoFrame) -> StereoDetections`` (every seedmap
    detector has it); :meth:`features_from_detections` works without a detector. The method
    (``cfg.refine``) is picked once here. With ``cfg.temporal_prediction`` :meth:`match_temporal`
    predicts the image shift of the next pair of frames as the median shift of its last matches.
    """

    name = "seeds"

    def __init__(self, calib: StereoCalib, detector=None, cfg: SemanticConfig | None = None,
                 gates: GateConfig | None = None) -> None:
        self.calib = calib
        self.detector = detector
        self.cfg = cfg or SemanticConfig()
        self.gates = gates or GateConfig()
        self._method = METHODS[self.cfg.refine]
        self._scaled_gates = self.gates.scaled(calib.width)
        self._last_shift: float | None = None
        self._last_shift_v: float | None = None
        #: neighbour sums of the last two frames' left keypoints (reused by match_temporal)
        self._sums: list[tuple[np.ndarray, np.ndarray]] = []

    def _cached_sums(self, kp: np.ndarray) -> np.ndarray:
        for arr, sums in self._sums:
            if arr is kp:
                return sums
        sums = neighbour_sums(kp * full_res_scale(self.calib.width), self.cfg.delta_px, self.cfg.eps_px)
        self._remember(kp, sums)
        return sums

    def _remember(self, kp: np.ndarray, sums: np.ndarray) -> None:
        self._sums = [*self._sums[-1:], (kp, sums)]

    def features_from_detections(self, det: StereoDetections) -> FrameFeatures:
        """Stereo matches of one frame's detections."""
        t0, c0 = time.perf_counter(), time.process_time()
        kl = np.asarray(det.left.keypoints, np.float64).reshape(-1, 2)
        kr = np.asarray(det.right.keypoints, np.float64).reshape(-1, 2)
        sums = full_res_sums(kl, kr, full_res_scale(self.calib.width), self.cfg)
        if len(kl) == 0 or len(kr) == 0:
            m = Matches()
        else:
            m = self._method.stereo(kl, kr, self.calib.width, self._scaled_gates, self.cfg, sums)
        timings = {"stereo_match": (time.perf_counter() - t0) * 1e3,
                   "stereo_match_cpu": (time.process_time() - c0) * 1e3}
        f = FrameFeatures(
            index=det.index, timestamp=det.timestamp, kp_left=kl, kp_right=kr, stereo=m,
            seed_ids_left=det.left.seed_ids, seed_ids_right=det.right.seed_ids, timings_ms=timings,
        )
        self._remember(f.kp_left, sums[0])
        return f

    def detect_frame(self, frame: StereoFrame) -> StereoDetections:
        """The detector's seeds of both images (depends on this frame alone: it may run ahead, in another
        thread, while the previous frame is associated)."""
        if self.detector is None:
            raise SeedmapError("the seeds matcher needs a detector to turn images into keypoints")
        return self.detector.detect_stereo(frame)

    def features(self, frame: StereoFrame, det: StereoDetections | None = None) -> FrameFeatures:
        """Detect the seeds of both images (unless ``det``, :meth:`detect_frame`'s result, is given) and match
        them left<->right."""
        if det is not None:
            return self.features_from_detections(det)
        t0 = time.perf_counter()
        det = self.detect_frame(frame)
        t_det = (time.perf_counter() - t0) * 1e3
        f = self.features_from_detections(det)
        f.timings_ms["detect"] = t_det
        return f

    def match_temporal(self, prev: FrameFeatures, cur: FrameFeatures) -> Matches:
        """Previous-left <-> current-left matches; updates the constant-velocity prediction."""
        ka, kb = prev.kp_left, cur.kp_left
        sums = (self._cached_sums(ka), self._cached_sums(kb))
        if len(ka) == 0 or len(kb) == 0:
            m = Matches()
        else:
            shift, shift_v = (self._last_shift, self._last_shift_v) if self.cfg.temporal_prediction else (None, None)
            m = self._method.temporal(ka, kb, self.calib.width, self._scaled_gates, self.cfg, sums, shift, shift_v)
        if len(m) >= 5:
            d = kb[m.idx_b] - ka[m.idx_a]
            self._last_shift = float(np.median(d[:, 0]))
            self._last_shift_v = float(np.median(d[:, 1]))
        return m

    def reset(self) -> None:
        """Forget the prediction and the cached neighbour sums (a new sequence)."""
        self._last_shift = None
        self._last_shift_v = None
        self._sums = []
