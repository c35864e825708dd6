"""Count calibration: from the multiview counter's seed count to an estimate of the true count.

Why: with the ``fast`` detector the counter's error on a panicle is the balance of seeds the detector never
reaches (partly hidden seeds, mostly on dense, large-seeded panicles) and ghost tracks (mostly on red varieties).
Over 112 simulated panicles that balance ranges from -19 % to +19 %, and the detector's reach explains it almost
alone (docs/method/counting.md). Two numbers the counter sees without ground truth follow it:

* ``obs_fraction`` = left detections over all views / (count x views): how many of the views each counted seed is
  detected in, on average. An open panicle whose seeds are seen from most directions scores high; its seeds are
  reached and its ghosts add to the count. A dense panicle whose seeds hide each other scores low and is
  under-counted.
* ``seed_diam_mm``: the median diameter of the counted seeds (mm), from their stereo depth. At equal
  ``obs_fraction``, larger seeds hide more of their neighbours.

The calibration is a log-linear model fitted to reconstructions whose true count is known (simulated scans, or
panicles counted by hand)::

    log(count / true) = intercept + sum_k coef_k * feature_k      estimate = count * exp(-(...))

It is only valid for the detector, detector settings and counter settings it was fitted with: the file records
their SHA-256 (:class:`CountDomain`) and a calibration is applied only where they match (``count.calibration=auto``
picks the shipped one for the ``fast`` detector's default settings; a mismatch leaves the count uncalibrated and
says why). ``seedmap train count-calibration`` fits one from ``seedmap reconstruct`` results; the file also keeps
the fit's own error and its leave-one-out error, so a user sees how good it is before trusting it.

When the counter's or the detector's settings change shape (a field added or removed, same behaviour), the shipped
files are re-stamped with the new hashes, coefficients untouched: :func:`restamp_shipped_calibrations`, or
``python -m seedmap.recon.calibrate --restamp``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from seedmap.errors import ConfigError, InputError
from seedmap.io.text import read_text

if TYPE_CHECKING:
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.count import SeedCount, StereoKeypoints

FEATURES: tuple[str, ...] = ("obs_fraction", "seed_diam_mm")
KIND = "seedmap-count-calibration"


def shipped_calibration_dir() -> Path:
    return Path(__file__).with_name("calibrations")


@dataclass(frozen=True)
class CountFeatures:
    """What the calibration reads from one count: the raw ``count``, the ``views`` that have detections, the
    left ``detections`` over those views and the median counted-seed diameter (mm)."""

    count: int
    views: int
    detections: int
    seed_diam_mm: float

    @property
    def obs_fraction(self) -> float:
        return self.detections / max(self.count * self.views, 1)

    def value(self, name: str) -> float:
        if name == "obs_fraction":
            return self.obs_fraction
        if name == "seed_diam_mm":
            return self.seed_diam_mm
        raise ConfigError(f"unknown count-calibration feature {name!r} (known: {', '.join(FEATURES)})")

    def as_dict(self) -> dict:
        return {"count": self.count, "views": self.views, "detections": self.detections,
                "seed_diam_mm": self.seed_diam_mm, "obs_fraction": self.obs_fraction}


def count_features(views: list[StereoKeypoints | None], cnt: SeedCount) -> CountFeatures:
    """The calibration features of the multiview count ``cnt`` made from the per-view keypoints ``views``."""
    used = [v for v in views if v is not None]
    diam = float(np.median(cnt.diameter) * 1000.0) if cnt.count else float("nan")
    return CountFeatures(count=int(cnt.count), views=len(used), detections=int(sum(len(v.left) for v in used)),
                         seed_diam_mm=diam)


class CountDomain(BaseModel):
    """What a calibration is valid for: the detector name, the SHA-256 of its weights file (None for detectors
    without one), of its resolved settings and of the counter's resolved settings (``calibration`` excluded)."""

    model_config = ConfigDict(extra="forbid")
    detector: str
    weights_sha256: str | None
    detector_config_sha256: str
    count_config_sha256: str

    def mismatch(self, other: CountDomain) -> str | None:
        """How ``other`` differs from this domain (None: it is inside)."""
        if self.detector != other.detector:
            return f"detector {self.detector!r}, not {other.detector!r}"
        if self.weights_sha256 != other.weights_sha256:
            return "other detector weights"
        if self.detector_config_sha256 != other.detector_config_sha256:
            return "other detector settings"
        if self.count_config_sha256 != other.count_config_sha256:
            return "other counter settings"
        return None


def _sha(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def count_domain(cfg: ReconConfig) -> CountDomain:
    """The domain of a reconstruction run with config ``cfg`` (its detector, weights and resolved settings)."""
    from seedmap.detect.config import resolve_config

    dcfg = resolve_config(None, list(cfg.detector_overrides))
    weights = None
    if cfg.detector == "fast":
        from seedmap.detect.cnn import cnn_weights_path

        w = cnn_weights_path(dcfg.cnn)
        weights = hashlib.sha256(w.read_bytes()).hexdigest() if w.is_file() else None
    d = dcfg.model_dump()
    if isinstance(d.get("cnn"), dict):
        d["cnn"].pop("weights", None)  # the file's hash stands for it (a path differs between machines)
    if isinstance(d.get("dataset"), dict):
        d["dataset"].pop("allow_fewer_times", None)  # which frames are read, not how seeds are detected
    return CountDomain(detector=cfg.detector, weights_sha256=weights, detector_config_sha256=_sha(d),
                       count_config_sha256=_sha(counter_settings(cfg)))


def counter_settings(cfg: ReconConfig) -> dict:
    """The counter's resolved settings that a calibration depends on: the count config with the detector's
    profile applied (``calibration`` and ``detector_profile`` excluded) and the depth range seeds are looked
    for in (m)."""
    c = cfg.count.for_detector(cfg.detector).model_dump()
    for k in ("calibration", "detector_profile"):  # (the profile is applied in c already)
        c.pop(k, None)
    c["depth_range"] = [cfg.cloud.min_depth, cfg.cloud.max_depth]
    return c


def restamp_shipped_calibrations(directory: str | Path | None = None) -> list[Path]:
    """Re-stamp every calibration file in ``directory`` (default: the shipped ones) with the domain of the
    DEFAULT reconstruction config of its detector, keeping its coefficients, fit and samples. Run it after a
    change that renames or removes settings without changing results (the hashes change, the counts do not);
    returns the files rewritten."""
    from seedmap.recon.config import ReconConfig

    d = Path(directory) if directory is not None else shipped_calibration_dir()
    out = []
    for p in sorted(d.glob("*.json")):
        cal = load_count_calibration(p)
        dom = count_domain(ReconConfig(detector=cal.domain.detector))
        if dom.weights_sha256 != cal.domain.weights_sha256:
            raise ConfigError("the detector's weights differ from the ones it was fitted with: refit it "
                              "(`seedmap train count-calibration`), a re-stamp would hide that", p)
        if dom != cal.domain:
            save_count_calibration(cal.model_copy(update={"domain": dom}), p)
            out.append(p)
    return out


class CountCalibration(BaseModel):
    """A fitted count calibration (module docstring); JSON on disk."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["seedmap-count-calibration"] = KIND
    version: Literal[1] = 1
    intercept: float
    coef: dict[str, float] = Field(description="feature name -> coefficient of log(count / true)")
    domain: CountDomain
    views_range: tuple[int, int] = Field(description="fewest and most views of the fitted scans")
    samples: list[str] = Field(description="the reconstructions it was fitted on")
    truth: str = Field("", description="what the true counts were (e.g. GT countable seeds, hand counts)")
    fit: dict[str, float] = Field(default_factory=dict, description="raw and calibrated MAPE (%) on the fitted "
                                                                    "samples, leave-one-out MAPE and signed mean (%)")

    def log_ratio(self, f: CountFeatures) -> float:
        return self.intercept + sum(c * f.value(k) for k, c in self.coef.items())

    def describe(self) -> str:
        """What it was fitted on and how well, in one line (reports)."""
        loo = self.fit.get("loo_mape_pct")
        return (f"fitted on {len(self.samples)} panicles with {self.views_range[0]}-{self.views_range[1]} views"
                + (f" against {self.truth}" if self.truth else "")
                + (f", leave-one-out MAPE {loo:.1f} %" if loo is not None else ""))

    def estimate(self, f: CountFeatures) -> float:
        """The calibrated count of a reconstruction with features ``f``."""
        if f.count == 0:
            return 0.0
        return float(f.count * np.exp(-self.log_ratio(f)))


def _design(feats: list[CountFeatures], names: tuple[str, ...]) -> np.ndarray:
    return np.column_stack([np.ones(len(feats))] + [[f.value(k) for f in feats] for k in names])


def fit_count_calibration(feats: list[CountFeatures], truth: list[float], domain: CountDomain, samples: list[str],
                          features: tuple[str, ...] = FEATURES, truth_name: str = "") -> CountCalibration:
    """Least-squares fit of ``log(count / truth)`` on ``features`` (module docstring); needs at least two samples
    more than parameters (the leave-one-out error is computed and stored)."""
    for k in features:
        if k not in FEATURES:
            raise ConfigError(f"unknown count-calibration feature {k!r} (known: {', '.join(FEATURES)})")
    features = tuple(dict.fromkeys(features))
    n_par = 1 + len(features)
    if len(feats) != len(truth) or len(feats) != len(samples):
        raise ValueError("feats, truth and samples differ in length")
    if len(feats) < n_par + 2:
        raise InputError(f"{len(feats)} reconstructions cannot fit a calibration with {n_par} parameters "
                         f"(give at least {n_par + 2})")
    C = np.array([f.count for f in feats], float)
    G = np.asarray(truth, float)
    for s, c, g, f in zip(samples, C, G, feats):
        if c <= 0 or g <= 0:
            raise InputError("a reconstruction with no counted seeds or a true count of 0 cannot calibrate", s)
        if not all(np.isfinite(f.value(k)) for k in features):
            raise InputError("its count features are not finite", s)
    X = _design(feats, features)
    y = np.log(C / G)
    b, *_ = np.linalg.lstsq(X, y, rcond=None)
    est = C * np.exp(-(X @ b))
    loo = np.zeros(len(C))
    for i in range(len(C)):
        m = np.arange(len(C)) != i
        bi, *_ = np.linalg.lstsq(X[m], y[m], rcond=None)
        loo[i] = (C[i] * np.exp(-(X[i] @ bi)) - G[i]) / G[i] * 100.0
    raw = (C - G) / G * 100.0
    cal = (est - G) / G * 100.0
    views = [f.views for f in feats]
    return CountCalibration(
        intercept=float(b[0]), coef={k: float(c) for k, c in zip(features, b[1:])}, domain=domain,
        views_range=(int(min(views)), int(max(views))), samples=list(samples), truth=truth_name,
        fit={"raw_mape_pct": float(np.mean(np.abs(raw))), "raw_signed_pct": float(np.mean(raw)),
             "calibrated_mape_pct": float(np.mean(np.abs(cal))), "loo_mape_pct": float(np.mean(np.abs(loo))),
             "loo_signed_pct": float(np.mean(loo)), "loo_std_pct": float(np.std(loo))})


def read_true_counts(path: str | Path) -> dict[str, float]:
    """A counts CSV: ``result,count`` rows (a header row is skipped) -> {result: count}; counts finite and > 0."""
    path = Path(path)
    if not path.is_file():
        raise InputError("counts file not found", path)
    out: dict[str, float] = {}
    for i, row in enumerate(csv.reader(io.StringIO(read_text(path, "counts file"), newline=""))):
        if not row or not "".join(row).strip():
            continue
        if len(row) != 2:
            raise InputError(f"line {i + 1}: expected `result,count`, got {len(row)} fields", path)
        try:
            v = float(row[1])
        except ValueError:
            if i == 0:
                continue  # header
            raise InputError(f"line {i + 1}: count {row[1]!r} is not a number", path) from None
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"line {i + 1}: count must be a finite number > 0, got {row[1].strip()}", path)
        out[row[0].strip().rstrip("/")] = v
    if not out:
        raise InputError("no `result,count` rows", path)
    return out


def load_count_calibration(path: str | Path) -> CountCalibration:
    """A calibration file (JSON), or a one-line InputError naming it."""
    p = Path(path)
    if not p.is_file():
        raise InputError("count calibration file not found", p)
    try:
        return CountCalibration.model_validate_json(read_text(p, "count calibration file"))
    except (ValidationError, ValueError, UnicodeDecodeError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"not a seedmap count calibration ({first})", p) from None


def save_count_calibration(cal: CountCalibration, path: str | Path) -> None:
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(Path(path), cal.model_dump_json(indent=2) + "\n")


@dataclass
class CalibratedCount:
    """The count of a run and, where a calibration applies, its calibrated estimate."""

    count: int  # raw: the counted seeds (seeds.csv)
    estimate: float | None  # calibrated count, None = no calibration applied
    source: str | None  # the calibration file applied
    reason: str  # why none was applied ("" when one was)
    features: CountFeatures
    fitted: str = ""  # what the applied calibration was fitted on (CountCalibration.describe)

    def as_dict(self) -> dict:
        return {"seed_count": self.count,
                "seed_count_calibrated": None if self.estimate is None else round(self.estimate, 1),
                "count_calibration": self.source, "count_calibration_fit": self.fitted or None,
                "count_calibration_note": self.reason,
                "count_features": self.features.as_dict()}


def shipped_calibrations(detector: str) -> list[Path]:
    """The shipped calibration files of ``detector``: ``DETECTOR.json`` and ``DETECTOR_*.json`` (e.g. one per
    number of views)."""
    d = shipped_calibration_dir()
    return sorted(p for p in d.glob(f"{detector}*.json") if p.stem == detector or p.stem.startswith(f"{detector}_"))


def _views_note(cal: CountCalibration, p: Path, views: int) -> str | None:
    lo, hi = cal.views_range
    if lo <= views <= hi:
        return None
    return f"{p.name} was fitted on scans with {lo}-{hi} views"


def calibrate_count(cfg: ReconConfig, feats: CountFeatures) -> CalibratedCount:
    """Apply ``cfg.count.calibration`` to ``feats``: ``auto`` = the shipped calibration of the run's detector whose
    domain the run is in and whose fitted numbers of views include the scan's (:func:`shipped_calibrations`);
    ``none``; or a file, which must match the run's domain. Never outside the fitted numbers of views:
    ``obs_fraction`` depends on the spacing of the views (the 24-view calibration "corrects" the count of a 6-view
    scan by -49 %)."""
    choice = cfg.count.calibration
    if choice == "none":
        return CalibratedCount(feats.count, None, None, "count.calibration=none", feats)
    if cfg.count.method != "multiview":
        return CalibratedCount(feats.count, None, None, "calibrations are for the multiview counter", feats)
    dom = count_domain(cfg)
    hint = " (fit one for your scans with `seedmap train count-calibration`)"
    if choice == "auto":
        files = shipped_calibrations(cfg.detector)
        if not files:
            return CalibratedCount(feats.count, None, None, f"no shipped calibration for detector {cfg.detector!r}",
                                   feats)
        reasons = []
        for p in files:
            cal = load_count_calibration(p)
            why = cal.domain.mismatch(dom)
            why = f"{p.name} was fitted with {why}" if why is not None else _views_note(cal, p, feats.views)
            if why is None:
                return CalibratedCount(feats.count, cal.estimate(feats), str(p), "", feats, cal.describe())
            reasons.append(why)
        return CalibratedCount(feats.count, None, None, f"not applied: the scan has {feats.views} views with "
                               f"detections; shipped calibrations: {'; '.join(reasons)}{hint}", feats)
    p = Path(choice)
    cal = load_count_calibration(p)
    why = cal.domain.mismatch(dom)
    if why is not None:
        raise ConfigError(f"count calibration does not fit this run: it was fitted with {why}", p)
    why = _views_note(cal, p, feats.views)
    if why is not None:
        return CalibratedCount(feats.count, None, None, f"not applied: the scan has {feats.views} views with "
                               f"detections, {why}{hint}", feats)
    return CalibratedCount(feats.count, cal.estimate(feats), str(p), "", feats, cal.describe())


def main(argv: list[str] | None = None) -> None:
    """``python -m seedmap.recon.calibrate --restamp [DIR]``: :func:`restamp_shipped_calibrations`."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m seedmap.recon.calibrate", description=main.__doc__)
    ap.add_argument("--restamp", action="store_true", help="re-stamp the calibration files with the current "
                                                           "default settings' hashes (coefficients unchanged)")
    ap.add_argument("dir", nargs="?", default=None, help="folder of calibration files (default: the shipped ones)")
    a = ap.parse_args(argv)
    if not a.restamp:
        ap.error("nothing to do (pass --restamp)")
    done = restamp_shipped_calibrations(a.dir)
    print("\n".join(f"re-stamped {p}" for p in done) or "every calibration file already matches")


if __name__ == "__main__":
    main()
