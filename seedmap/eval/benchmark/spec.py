"""What a benchmark runs: its configuration, the datasets (ranges) and methods, and one run's record."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Sequence

from pydantic import Field

from seedmap.associate.features import KINDS as FEATURE_KINDS
from seedmap.associate.features import TUNED, FeatureMatcherConfig
from seedmap.config import ConfigModel
from seedmap.errors import ConfigError, InputError, SeedmapError
from seedmap.eval.published import PAPER_RANGE_LENGTHS
from seedmap.peers import PEERS
from seedmap.peers.orbslam3 import OrbSlam3Config

#: Simulator overrides of the harder held-out scene variations (``scenes``); defaults in the comments.
SCENE_OVERRIDES: tuple[str, ...] = (
    "wind.panicle_amplitude_deg=5.0",  # stronger wind (default 1.5 deg)
    "wind.leaf_amplitude_deg=9.0",  # (default 3 deg)
    "imaging.exposure_jitter=0.25",  # exposure swings frame to frame (default 0.04)
    "panicle.loose_fraction=0.9",  # mostly loose panicles (default 0.4)
    "world.leaves_min=8",  # more leaf occlusion (default 5..8 leaves per plant)
    "world.leaves_max=12",
)
#: Seed offset of the held-out scene variations (preset seed + this).
SCENE_SEED_OFFSET = 1000


class BenchmarkConfig(ConfigModel):
    """What ``seedmap benchmark`` runs; written as ``config.yaml`` next to the results."""

    data_dir: str = Field("data/benchmark", description="cache of simulated ranges (reused when finished)")
    presets: list[str] = Field(default_factory=lambda: [f"paper{k}" for k in range(1, 9)],
                               description="simulator presets of the ranges (default: the paper's eight)")
    seeds: list[int] | None = Field(None, description="simulator seed per preset (default: the preset's own)")
    sim_overrides: list[str] = Field(default_factory=list, description="simulator key=value for every range")
    scenes: bool = Field(False, description="also run the harder held-out scene variations")
    methods: list[str] | None = Field(
        None, description="methods to run (default: seeds+<every available detector>, sift, surf, orb, akaze, "
                          "orbslam3)")
    slam_overrides: list[str] = Field(default_factory=list, description="SlamConfig key=value for every run")
    features: FeatureMatcherConfig = Field(default_factory=FeatureMatcherConfig)
    feature_tuning: dict[str, dict[str, Any]] = Field(
        default_factory=lambda: {k: dict(v) for k, v in TUNED.items()},
        description="per-kind overrides of `features` (default: the values tuned on the training range)")
    orbslam3: OrbSlam3Config = Field(default_factory=OrbSlam3Config)
    workers: int = Field(2, ge=1, le=64, description="parallel worker processes (each single-threaded)")
    html_reports: bool = Field(False, description="also write each run's report.html (about 2.7 s CPU per run)")

    def features_for(self, kind: str) -> FeatureMatcherConfig:
        """The descriptor-baseline parameters used for ``kind`` (base + its tuned overrides)."""
        upd = self.feature_tuning.get(kind, {})
        return FeatureMatcherConfig.model_validate({**self.features.model_dump(), **upd})


@dataclass
class RangeSpec:
    """One dataset of the benchmark (simulated from a preset, or the user's own)."""

    name: str
    scenario: str  # "paper", "scenes" or "user"
    dataset: Path
    length_m: float | None = None
    preset: str | None = None
    seed: int | None = None
    sim_overrides: tuple[str, ...] = ()
    paper_index: int | None = None  # 0..7: row of the published table


@dataclass
class MethodSpec:
    """A matcher (+ detector for the seeds matcher) or a peer (``matcher`` names a :data:`seedmap.peers.PEERS`
    entry); ``unavailable`` holds the n/a reason."""

    name: str
    matcher: str
    detector: str | None = None
    unavailable: str | None = None


@dataclass
class RunRecord:
    """One (range, method) outcome: the SlamMetrics fields the tables need plus status."""

    scenario: str
    range_name: str
    method: str
    status: str  # "ok", "n/a", "error"
    note: str = ""
    range_length_m: float | None = None
    frames: int | None = None
    frames_tracked: int | None = None
    mdm_m: float | None = None
    mdm_fraction: float | None = None
    gt_mdm_m: float | None = None
    gt_mdm_fraction: float | None = None
    ate_rmse_m: float | None = None
    rpe_trans_rmse_m: float | None = None
    lost_frame: int | None = None
    lost_reason: str | None = None
    ms_per_frame: float | None = None
    published_mdm_m: float | None = None
    published_failed: bool = False
    paper_index: int | None = None  # row of the published table (paper scenario only)
    stereo_matches: list[int] = field(default_factory=list)
    temporal_matches: list[int] = field(default_factory=list)
    inlier_matches: list[int] = field(default_factory=list)


_PER_FRAME = ("stereo_matches", "temporal_matches", "inlier_matches")
#: Columns of ``results.csv`` (every record field but the per-frame match counts).
CSV_FIELDS = [f.name for f in fields(RunRecord) if f.name not in _PER_FRAME]


def safe_name(s: str) -> str:
    """``s`` with every character outside ``[A-Za-z0-9-_.+]`` replaced by ``_`` (a file name)."""
    return "".join(c if c.isalnum() or c in "-_.+" else "_" for c in s)


def sim_cache_name(preset: str, seed: int, overrides: Sequence[str]) -> str:
    """Cache folder name of a simulated range: preset, seed and a hash of the overrides."""
    h = hashlib.sha1("\n".join(overrides).encode()).hexdigest()[:8] if overrides else "default"
    return f"{preset}-s{seed}-{h}"


def paper_ranges(cfg: BenchmarkConfig) -> list[RangeSpec]:
    """The simulated ranges of the paper benchmark (and their harder variations with ``scenes``)."""
    from seedmap.config import load_config
    from seedmap.sim.config import SimConfig, preset_dict

    if cfg.seeds is not None and len(cfg.seeds) != len(cfg.presets):
        raise ConfigError(f"--seeds gives {len(cfg.seeds)} seeds for {len(cfg.presets)} ranges; give one per range")
    out: list[RangeSpec] = []
    data = Path(cfg.data_dir)
    for k, preset in enumerate(cfg.presets):
        base = preset_dict(preset)
        seed = int(cfg.seeds[k]) if cfg.seeds is not None else int(base.get("seed", 0))
        ov = tuple(cfg.sim_overrides)
        length = float(load_config(SimConfig, base=base, overrides=list(ov)).world.length)
        idx = int(preset[5:]) - 1 if preset.startswith("paper") and preset[5:].isdigit() else None
        if idx is not None and not 0 <= idx < len(PAPER_RANGE_LENGTHS):
            idx = None
        out.append(RangeSpec(preset, "paper", data / sim_cache_name(preset, seed, ov), length, preset, seed, ov,
                             idx))
    if cfg.scenes:
        for spec in list(out):
            seed = int(spec.seed or 0) + SCENE_SEED_OFFSET
            ov = tuple(cfg.sim_overrides) + SCENE_OVERRIDES
            load_config(SimConfig, base=preset_dict(spec.preset or ""), overrides=list(ov))  # fail early
            out.append(RangeSpec(f"{spec.name}-hard", "scenes", data / sim_cache_name(spec.preset, seed, ov),
                                 spec.length_m, spec.preset, seed, ov, spec.paper_index))
    return out


def user_ranges(datasets: Sequence[str | Path]) -> list[RangeSpec]:
    """The user's own datasets (any format :func:`seedmap.io.open_dataset` reads)."""
    out: list[RangeSpec] = []
    seen: set[str] = set()
    for d in datasets:
        p = Path(d)
        if not p.exists():
            raise InputError("dataset not found", p)
        name = safe_name(p.resolve().name) or "dataset"
        while name in seen:
            name += "_"
        seen.add(name)
        out.append(RangeSpec(name, "user", p))
    return out


def dataset_has_gt(path: Path) -> bool:
    """True when the dataset at ``path`` opens and has a ground-truth trajectory."""
    try:
        from seedmap.io import open_dataset

        return open_dataset(path).gt_trajectory() is not None
    except SeedmapError:
        return False


def default_methods(cfg: BenchmarkConfig, with_gt: bool = True) -> list[MethodSpec]:
    """``seeds+<detector>`` for each available detector, every descriptor baseline, then every peer SLAM system.

    ``frcnn-pix2pix`` joins only when trained weights (and torch) are present; the ``gt`` oracle
    only where the data has ground truth. ``cfg.methods`` picks from these (any ``seeds+<detector>`` is accepted).
    """
    from seedmap.associate.features import available_kinds
    from seedmap.detect import available_detectors, default_detector_name

    dets = []
    for d in available_detectors():
        if d == "frcnn-pix2pix" and default_detector_name() != "frcnn-pix2pix":
            continue  # no trained weights shipped
        dets.append(d)
    dets.sort(key=lambda d: {"gt": 0, "fast": 1}.get(d, 2))
    avail = available_kinds()
    methods: list[MethodSpec] = []
    for d in dets:
        why = None if (d != "gt" or with_gt) else "n/a — oracle needs ground truth"
        methods.append(MethodSpec(f"seeds+{d}", "seeds", d, why))
    for k in FEATURE_KINDS:
        methods.append(MethodSpec(k, k, None, avail.get(k)))
    for name, peer in PEERS.items():
        methods.append(MethodSpec(name, name, None, peer.unavailable()))
    if cfg.methods is not None:
        by_name = {m.name: m for m in methods}
        chosen = []
        for name in cfg.methods:
            if name in by_name:
                chosen.append(by_name[name])
            elif name.startswith("seeds+"):
                chosen.append(MethodSpec(name, "seeds", name.split("+", 1)[1]))
            else:
                raise ConfigError(f"unknown benchmark method {name!r} (known: {', '.join(by_name)})")
        methods = chosen
    return methods
