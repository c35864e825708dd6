"""Association precision / recall against ground-truth seed ids (``seedmap eval associate``).

For every frame the matcher's stereo matches and the temporal matches to the previous frame are
compared with the GT seed ids the detector attached to its keypoints (the ``gt`` oracle carries
them; detectors without ids cannot be scored).

* precision = correct matches / matches with known ids on both sides;
* recall = correct matches / GT-possible pairs, i.e. seeds detected in *both* images
  (``recall``), and the stricter-to-interpret ``recall_gated``, which counts only possible pairs
  that also pass the horizontal-travel gates and border margins (pairs no gated matcher may
  return are excluded).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from seedmap.associate.base import GateConfig
from seedmap.progress import Progress
from seedmap.records import Matches


@dataclass
class MatchCounts:
    matches: int = 0
    known: int = 0
    correct: int = 0
    possible: int = 0
    possible_gated: int = 0

    def add(self, o: MatchCounts) -> None:
        for k in ("matches", "known", "correct", "possible", "possible_gated"):
            setattr(self, k, getattr(self, k) + getattr(o, k))

    @property
    def precision(self) -> float | None:
        return self.correct / self.known if self.known else None

    @property
    def recall(self) -> float | None:
        return self.correct / self.possible if self.possible else None

    @property
    def recall_gated(self) -> float | None:
        return min(1.0, self.correct / self.possible_gated) if self.possible_gated else None

    def summary(self) -> dict:
        return {**asdict(self), "precision": self.precision, "recall": self.recall, "recall_gated": self.recall_gated}


def score_matches(m: Matches, ids_a: np.ndarray, ids_b: np.ndarray, kp_a: np.ndarray, kp_b: np.ndarray,
                  gate) -> MatchCounts:
    """Counts for one image pair; ``gate(kp_a (K,2), kp_b (K,2)) -> bool (K,)`` says which GT pairs
    are matchable under the gates."""
    ids_a = np.asarray(ids_a)
    ids_b = np.asarray(ids_b)
    a, b = ids_a[m.idx_a], ids_b[m.idx_b]
    known = (a >= 0) & (b >= 0)
    correct = known & (a == b)
    common, ia, ib = np.intersect1d(ids_a[ids_a >= 0], ids_b[ids_b >= 0], return_indices=True)
    ia = np.flatnonzero(ids_a >= 0)[ia]
    ib = np.flatnonzero(ids_b >= 0)[ib]
    g = gate(kp_a[ia], kp_b[ib]) if len(common) else np.zeros(0, bool)
    return MatchCounts(len(m), int(known.sum()), int(correct.sum()), len(common), int(np.sum(g)))


def stereo_gate(width: int, gates: GateConfig):
    g = gates.scaled(width)

    def f(kl: np.ndarray, kr: np.ndarray) -> np.ndarray:
        inside = lambda u: (u >= g.stereo_border_px) & (u <= width - 1 - g.stereo_border_px)  # noqa: E731
        return (inside(kl[:, 0]) & inside(kr[:, 0]) & (np.abs(kl[:, 1] - kr[:, 1]) <= g.stereo_max_dy_px)
                & (kl[:, 0] - kr[:, 0] >= g.stereo_min_disparity_px))
    return f


def temporal_gate(width: int, gates: GateConfig):
    g = gates.scaled(width)

    def f(ka: np.ndarray, kb: np.ndarray) -> np.ndarray:
        inside = lambda u: (u >= g.temporal_border_px) & (u <= width - 1 - g.temporal_border_px)  # noqa: E731
        dv = np.abs(kb[:, 1] - ka[:, 1])
        return (inside(ka[:, 0]) & inside(kb[:, 0]) & (dv <= min(g.temporal_max_dy_px, g.temporal_post_max_dy_px))
                & (g.travel_sign * (kb[:, 0] - ka[:, 0]) >= g.temporal_min_shift_px))
    return f


@dataclass
class AssociationReport:
    dataset: str
    detector: str
    matcher: str
    frames: int
    stereo: dict
    temporal: dict
    per_frame: list[dict] = field(default_factory=list)
    #: mean CPU ms per frame of the association (detection excluded): ``stereo`` = the matcher's
    #: stereo step, ``temporal`` = the ``match_temporal`` call
    cpu_ms_per_frame: dict = field(default_factory=dict)


def evaluate_association(dataset: str | Path, detector: str = "gt", matcher: str = "seeds", config=None,
                         max_frames: int | None = None, progress: bool = True) -> AssociationReport:
    """Run the matcher over ``dataset`` and score stereo and temporal matches per frame."""
    from seedmap.associate import make_matcher
    from seedmap.io import open_dataset
    from seedmap.io.stereo_order import check_stereo_order
    from seedmap.slam.config import SlamConfig
    from seedmap.slam.pipeline import _detector_for

    cfg = config or SlamConfig()
    ds = open_dataset(dataset)
    n = len(ds) if max_frames is None else min(len(ds), max_frames)
    det = _detector_for(detector, Path(dataset), cfg.detect) if matcher == "seeds" else None
    m = make_matcher(matcher, ds.calib, detector=det, cfg=cfg)
    sg, tg = stereo_gate(ds.calib.width, cfg.gates), temporal_gate(ds.calib.width, cfg.gates)
    st_tot, tm_tot = MatchCounts(), MatchCounts()
    rows = []
    cpu: dict[str, list[float]] = {}
    prev = None
    with Progress(n, f"associate {matcher}", "frame", progress) as bar:
        for i in range(n):
            frame = ds[i]
            if i == 0:
                check_stereo_order(frame.left, frame.right, dataset)
            f = m.features(frame)
            cpu.setdefault("stereo", []).append(f.timings_ms.get("stereo_match_cpu", np.nan))
            s = score_matches(f.stereo, f.seed_ids_left, f.seed_ids_right, f.kp_left, f.kp_right, sg)
            st_tot.add(s)
            row = {"frame": i, "stereo": s.summary()}
            if prev is not None:
                c0 = time.process_time()
                tmatch = m.match_temporal(prev, f)
                cpu.setdefault("temporal", []).append((time.process_time() - c0) * 1e3)
                t = score_matches(tmatch, prev.seed_ids_left, f.seed_ids_left, prev.kp_left, f.kp_left, tg)
                tm_tot.add(t)
                row["temporal"] = t.summary()
            rows.append(row)
            prev = f
            bar.advance()
    return AssociationReport(str(dataset), detector if det is not None else "", matcher, n,
                             st_tot.summary(), tm_tot.summary(), rows, _cpu_summary(cpu, n))


def _cpu_summary(cpu: dict[str, list[float]], frames: int) -> dict:
    """Mean CPU ms per frame of each step, and ``total`` = stereo + temporal per frame."""
    out = {k: float(np.nansum(v)) / max(frames, 1) for k, v in cpu.items()}
    out["total"] = out.get("stereo", 0.0) + out.get("temporal", 0.0)
    return out


def write_report(rep: AssociationReport, path: Path) -> None:
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(Path(path), json.dumps(asdict(rep), indent=2) + "\n")
