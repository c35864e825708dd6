"""Descriptor baselines (SIFT, SURF, ORB, AKAZE + brute force) behind the same Matcher interface.

The paper compares its semantic seed association against classical descriptors matched by brute
force (its Table 1). To make that comparison fair and reproducible, :class:`FeatureMatcher`:

* detects and describes keypoints with OpenCV (SIFT; SURF with Hessian threshold 400; ORB with
  1,000 features; AKAZE), optionally after CLAHE contrast equalisation of the grey image;
* matches descriptors with ``cv2.BFMatcher`` kNN (k = 2) and Lowe's ratio test (0.8);
* then applies **the same horizontal-travel gates** as the semantic matcher
  (:class:`seedmap.associate.base.GateConfig`, scaled to the image width): stereo ``|dv|`` limit,
  minimum disparity, border margins; temporal ``|dv|`` limit (pre- and post-filter), minimum shift
  in the direction of travel, border margins;
* keeps matches one-to-one (for every train keypoint only the query with the smallest descriptor
  distance survives; kNN already gives each query at most one match).

``gate_first=True`` is an optional, stronger variant: the gates are given to ``knnMatch`` as a mask,
so the ratio test compares only geometrically possible candidates (a descriptor that is ambiguous
only with a far-away look-alike is then kept). It is off by default (facts.md order: ratio test,
then gates); the benchmark's tuning decides whether it helps.

Availability depends on the OpenCV build: SIFT and ORB are in the main module of every version.
SURF is patented and lives only in builds with the non-free contrib module
(``cv2.xfeatures2d.SURF_create``), which no PyPI wheel ships. AKAZE is in the main module of
OpenCV 4.x; OpenCV 5 moved it (with KAZE, BRISK, AGAST) to ``opencv_contrib/xfeatures2d``
(opencv/opencv#25292), where it is looked up as a fallback. When a detector is missing,
``FeatureMatcher`` raises a :class:`SeedmapError` whose message starts with ``"n/a"``; the
benchmark turns that into an "n/a" row instead of failing or substituting another descriptor.

Tuning record. :class:`FeatureMatcherConfig` defaults are the facts.md parameters. The benchmark
applies the per-kind overrides in :data:`TUNED`, found with ``seedmap benchmark tune`` on ONE
training range that is not evaluated (preset paper1 world, seed 900, 2.0 m, default 1434x1050;
first 15 frames, ``max_frames=15``; SIFT capped at 4000 features per image for the compute budget —
uncapped SIFT finds ~10,000 per image and costs ~7 CPU-s per frame, and uncapped gave the same result
on the first frames). One factor at a time around the defaults (ratio 0.7-0.9, CLAHE, gate-first,
SIFT contrast threshold 0.01/0.02 and 3000 features, ORB 2000/5000 features and FAST threshold 5/10,
AKAZE threshold 0.0005), then the combination of the improvements; ranked by GT-validated distance,
distance, then RANSAC-verified matches per frame pair. Measured (MDM of at most 0.56 m in 15 frames;
"lost at 1" = lost at the first frame pair):

* SIFT: defaults lost at 1 (7 verified matches, 12 needed); gate_first lost at 2 (11 verified);
  ratio 0.85 + gate_first lost at 2 (16). Chosen: gate_first (+ the 4000 cap).
* ORB: defaults lost at 1 (3 verified); ratio 0.9 lost at 2; ratio 0.9 + gate_first + 5000 features
  tracked all 15 frames (0.55 m, 44 verified matches per pair, ATE 3 mm). Chosen: that combination.
* AKAZE: defaults already tracked all 15 frames (0.55 m, ATE 5 mm); no variation did better
  (ratio 0.7/0.75 and CLAHE were worse). Chosen: defaults.
* SURF: not available in this OpenCV build (n/a), not tuned.

The paper reports SIFT as the best baseline on its real field data; on our simulated training range
AKAZE and tuned ORB map further than SIFT. Every benchmark result folder records the parameters used.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Literal

import cv2
import numpy as np

from seedmap.associate.base import FrameFeatures, GateConfig
from seedmap.config import ConfigModel
from seedmap.errors import ConfigError, SeedmapError
from seedmap.records import Matches, StereoCalib, StereoFrame

#: Descriptor kinds the baseline matcher knows.
KINDS = ("sift", "surf", "orb", "akaze")
#: CLAHE clip limit and tile grid (OpenCV's usual values), with ``clahe=True``
CLAHE_CLIP = 2.0
CLAHE_TILES = 8


class FeatureMatcherConfig(ConfigModel):
    """Parameters of the descriptor baselines (facts.md defaults; pixel gates at 4096 px width)."""

    #: Lowe's ratio: keep the best match when ``d1 < ratio * d2``
    ratio: float = 0.8
    #: SIFT: keep the best N features (0 = all)
    sift_nfeatures: int = 0
    #: SIFT: DoG contrast threshold (OpenCV default 0.04; lower finds more, weaker features)
    sift_contrast_threshold: float = 0.04
    #: SURF: Hessian threshold (facts.md 400)
    surf_hessian: float = 400.0
    #: ORB: maximum number of features (facts.md 1000)
    orb_nfeatures: int = 1000
    #: ORB: FAST threshold (OpenCV default 20)
    orb_fast_threshold: int = 20
    #: AKAZE: detector response threshold (OpenCV default 0.001)
    akaze_threshold: float = 0.001
    #: equalise the grey image with CLAHE before detection (helps dark flash images)
    clahe: bool = False
    #: apply the geometric gates as a kNN mask before the ratio test (else after, as facts.md)
    gate_first: bool = False
    gates: GateConfig = GateConfig()

    def check(self) -> None:
        if not 0.0 < self.ratio <= 1.0:
            raise ConfigError(f"feature matcher ratio must be in (0, 1], got {self.ratio}")
        if self.orb_nfeatures < 1:
            raise ConfigError(f"orb_nfeatures must be >= 1, got {self.orb_nfeatures}")


#: Per-kind overrides of the facts.md defaults that the benchmark uses, from the tuning run recorded
#: in the module docstring (an empty dict = the defaults were best).
TUNED: dict[str, dict[str, Any]] = {
    "sift": {"gate_first": True, "sift_nfeatures": 4000},
    "orb": {"ratio": 0.9, "gate_first": True, "orb_nfeatures": 5000},
    "akaze": {},
}


def _contrib_missing(kind: str, what: str) -> SeedmapError:
    return SeedmapError(f"n/a — OpenCV {cv2.__version__} without {what}: {kind.upper()} is not available")


def _make_detector(kind: str, cfg: FeatureMatcherConfig) -> tuple[Any, int]:
    """OpenCV Feature2D object and the BFMatcher norm for ``kind``."""
    if kind == "sift":
        det = cv2.SIFT_create(nfeatures=cfg.sift_nfeatures, contrastThreshold=cfg.sift_contrast_threshold)
        return det, cv2.NORM_L2
    if kind == "orb":
        det = cv2.ORB_create(nfeatures=cfg.orb_nfeatures, fastThreshold=cfg.orb_fast_threshold)
        return det, cv2.NORM_HAMMING
    if kind == "surf":
        xf = getattr(cv2, "xfeatures2d", None)
        if xf is None or not hasattr(xf, "SURF_create"):
            raise _contrib_missing(kind, "non-free")
        try:
            det = xf.SURF_create(hessianThreshold=cfg.surf_hessian)
        except cv2.error:  # contrib present but built without OPENCV_ENABLE_NONFREE
            raise _contrib_missing(kind, "non-free") from None
        return det, cv2.NORM_L2
    if kind == "akaze":
        create: Callable | None = getattr(cv2, "AKAZE_create", None)
        if create is None:
            create = getattr(getattr(cv2, "xfeatures2d", None), "AKAZE_create", None)
        if create is None:
            raise _contrib_missing(kind, "contrib (OpenCV 5 moved AKAZE to opencv_contrib xfeatures2d)")
        return create(threshold=cfg.akaze_threshold), cv2.NORM_HAMMING
    raise ConfigError(f"unknown feature matcher {kind!r} (known: {', '.join(KINDS)})")


def available_kinds() -> dict[str, str | None]:
    """``{kind: None if usable else the one-line reason}`` for every descriptor kind."""
    out: dict[str, str | None] = {}
    for k in KINDS:
        try:
            _make_detector(k, FeatureMatcherConfig())
            out[k] = None
        except SeedmapError as e:
            out[k] = str(e)
    return out


def _one_to_one(qi: np.ndarray, ti: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Indices of the matches to keep so every train index is used once (smallest distance wins)."""
    if len(qi) == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((dist, ti))  # by train index, then distance
    first = np.ones(len(order), bool)
    first[1:] = ti[order][1:] != ti[order][:-1]
    keep = order[first]
    return np.sort(keep)


def _resolve_cfg(cfg: Any) -> FeatureMatcherConfig:
    """Accept ``None``, a :class:`FeatureMatcherConfig`, a dict, or a pipeline config object.

    A pipeline config (e.g. ``SlamConfig``) shares its ``gates`` with every matcher, so the
    baselines are gated exactly like the seed matcher; its ``features`` section, when it has one,
    holds the baseline parameters.
    """
    if cfg is None:
        return FeatureMatcherConfig()
    if isinstance(cfg, FeatureMatcherConfig):
        return cfg
    if isinstance(cfg, dict):
        return FeatureMatcherConfig.model_validate(cfg)
    feats = getattr(cfg, "features", None)
    out = _resolve_cfg(feats) if feats is not None else FeatureMatcherConfig()
    gates = getattr(cfg, "gates", None)
    if isinstance(gates, GateConfig):
        out = out.model_copy(update={"gates": gates})
    return out


class FeatureMatcher:
    """Descriptor baseline implementing :class:`seedmap.associate.base.Matcher`.

    ``kind`` is one of ``sift``, ``surf``, ``orb``, ``akaze``. Keypoints are in pixels of the given
    calibration's image size; the gates are scaled to ``calib.width``.
    """

    def __init__(self, kind: str, calib: StereoCalib, cfg: FeatureMatcherConfig | dict | None = None) -> None:
        kind = kind.lower()
        if kind not in KINDS:
            raise ConfigError(f"unknown feature matcher {kind!r} (known: {', '.join(KINDS)})")
        cfg = _resolve_cfg(cfg)
        cfg.check()
        self.kind = kind
        self.name = kind
        self.calib = calib
        self.cfg = cfg
        self.gates = cfg.gates.scaled(calib.width)
        self._det, self._norm = _make_detector(kind, cfg)
        self._bf = cv2.BFMatcher(self._norm, crossCheck=False)
        self._clahe = (
            cv2.createCLAHE(clipLimit=CLAHE_CLIP, tileGridSize=(CLAHE_TILES, CLAHE_TILES))
            if cfg.clahe
            else None
        )

    # -------------------------------------------------------------------------------------------
    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Keypoints ``(N, 2)`` (u, v) and descriptors of one RGB (or grey) uint8 image."""
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        if self._clahe is not None:
            gray = self._clahe.apply(gray)
        kps, desc = self._det.detectAndCompute(gray, None)
        uv = np.array([k.pt for k in kps], np.float64).reshape(-1, 2)
        if desc is None or len(kps) == 0:
            return np.zeros((0, 2)), None
        return uv, desc

    def _match(
        self,
        desc_a: np.ndarray | None,
        desc_b: np.ndarray | None,
        gate: Callable[[np.ndarray, np.ndarray], np.ndarray],
        kp_a: np.ndarray,
        kp_b: np.ndarray,
    ) -> Matches:
        """kNN + ratio test + gates + one-to-one. ``gate(ia, ib)`` -> bool mask of allowed pairs."""
        if desc_a is None or desc_b is None or len(desc_a) == 0 or len(desc_b) == 0:
            return Matches()
        if self.cfg.gate_first:
            # the gate predicates broadcast: (na, 1) x (1, nb) indices give the (na, nb) allowed mask
            na, nb = len(kp_a), len(kp_b)
            mask = gate(np.arange(na)[:, None], np.arange(nb)[None, :]).astype(np.uint8)
            if not mask.any():
                return Matches()
            knn = self._bf.knnMatch(desc_a, desc_b, k=2, mask=mask)
        else:
            knn = self._bf.knnMatch(desc_a, desc_b, k=2)
        qi, ti, dist = [], [], []
        for pair in knn:
            if not pair:
                continue
            best = pair[0]
            # With a single candidate (tiny train set, or only one passes the gate mask) the ratio
            # is undefined; the candidate is kept and must still pass the gates.
            if len(pair) > 1 and not best.distance < self.cfg.ratio * pair[1].distance:
                continue
            qi.append(best.queryIdx)
            ti.append(best.trainIdx)
            dist.append(best.distance)
        qi_a = np.asarray(qi, np.int64)
        ti_a = np.asarray(ti, np.int64)
        d_a = np.asarray(dist, np.float64)
        if len(qi_a):
            ok = gate(qi_a, ti_a)
            qi_a, ti_a, d_a = qi_a[ok], ti_a[ok], d_a[ok]
        keep = _one_to_one(qi_a, ti_a, d_a)
        return Matches(qi_a[keep], ti_a[keep], d_a[keep])

    def _inside(self, u: np.ndarray, border: float) -> np.ndarray:
        return (u >= border) & (u <= self.calib.width - 1 - border)

    def stereo_gate(self, kp_l: np.ndarray, kp_r: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """Pair predicate for left<->right: |dv|, minimum disparity, border margins (scaled px).

        Index arrays broadcast (e.g. ``(na, 1)`` and ``(1, nb)`` give an ``(na, nb)`` mask)."""
        g = self.gates

        def gate(il: np.ndarray, ir: np.ndarray) -> np.ndarray:
            a, b = kp_l[il], kp_r[ir]
            return (
                (np.abs(a[..., 1] - b[..., 1]) <= g.stereo_max_dy_px)
                & (a[..., 0] - b[..., 0] >= g.stereo_min_disparity_px)
                & self._inside(a[..., 0], g.stereo_border_px)
                & self._inside(b[..., 0], g.stereo_border_px)
            )

        return gate

    def temporal_gate(
        self, kp_prev: np.ndarray, kp_cur: np.ndarray, post: bool = True
    ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """Pair predicate for previous-left -> current-left: |dv| (pre and post), shift, borders."""
        g = self.gates
        max_dy = min(g.temporal_max_dy_px, g.temporal_post_max_dy_px) if post else g.temporal_max_dy_px

        def gate(ip: np.ndarray, ic: np.ndarray) -> np.ndarray:
            a, b = kp_prev[ip], kp_cur[ic]
            return (
                (np.abs(a[..., 1] - b[..., 1]) <= max_dy)
                & (g.travel_sign * (b[..., 0] - a[..., 0]) >= g.temporal_min_shift_px)
                & self._inside(a[..., 0], g.temporal_border_px)
                & self._inside(b[..., 0], g.temporal_border_px)
            )

        return gate

    # ---- Matcher protocol -----------------------------------------------------------------------
    def features(self, frame: StereoFrame) -> FrameFeatures:
        """Detect + describe both images and match them left<->right under the stereo gates."""
        t0 = time.perf_counter()
        kp_l, d_l = self.detect(frame.left)
        kp_r, d_r = self.detect(frame.right)
        t1 = time.perf_counter()
        stereo = self._match(d_l, d_r, self.stereo_gate(kp_l, kp_r), kp_l, kp_r)
        t2 = time.perf_counter()
        return FrameFeatures(
            index=frame.index,
            timestamp=frame.timestamp,
            kp_left=kp_l,
            kp_right=kp_r,
            stereo=stereo,
            desc_left=d_l,
            desc_right=d_r,
            timings_ms={"detect": (t1 - t0) * 1e3, "stereo_match": (t2 - t1) * 1e3},
        )

    def match_temporal(self, prev: FrameFeatures, cur: FrameFeatures) -> Matches:
        """Previous left descriptors vs current left descriptors under the temporal gates."""
        t0 = time.perf_counter()
        if self.cfg.gate_first:
            # mask with the wide pre-gate, then the tight post-filter on the survivors
            pre = self.temporal_gate(prev.kp_left, cur.kp_left, post=False)
            m = self._match_masked_then_post(prev, cur, pre)
        else:
            m = self._match(prev.desc_left, cur.desc_left, self.temporal_gate(prev.kp_left, cur.kp_left),
                            prev.kp_left, cur.kp_left)
        cur.timings_ms["temporal_match"] = (time.perf_counter() - t0) * 1e3
        return m

    def _match_masked_then_post(self, prev: FrameFeatures, cur: FrameFeatures, pre) -> Matches:
        m = self._match(prev.desc_left, cur.desc_left, pre, prev.kp_left, cur.kp_left)
        if len(m) == 0:
            return m
        post = self.temporal_gate(prev.kp_left, cur.kp_left, post=True)
        ok = post(m.idx_a, m.idx_b)
        return Matches(m.idx_a[ok], m.idx_b[ok], m.cost[ok])


def make_feature_matcher(
    kind: Literal["sift", "surf", "orb", "akaze"] | str,
    calib: StereoCalib,
    cfg: FeatureMatcherConfig | dict | None = None,
) -> FeatureMatcher:
    """Convenience constructor (same as ``FeatureMatcher(kind, calib, cfg)``)."""
    return FeatureMatcher(kind, calib, cfg)
