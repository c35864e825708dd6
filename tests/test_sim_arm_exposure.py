"""Arm-scan exposure: the default ``exposure="auto"`` exposes seeds facing the camera at the
scan's stand-off as the field camera exposes them at 0.7 m; ``exposure=1.0`` keeps the field gain (flash-saturated
close-ups)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml

from seedmap.config import load_config
from seedmap.errors import ConfigError
from seedmap.io.seedmap_dataset import SeedmapDataset
from seedmap.sim.arm import ArmConfig
from seedmap.sim.config import CameraConfig, PanicleConfig, SimConfig, WindConfig
from seedmap.sim.panicle_scan import PanicleScanConfig, exposure_factor, scan_distance, simulate_panicle
from seedmap.sim.render import REF_DISTANCE
from seedmap.sim.world import build_panicle_world


def _small(exposure) -> PanicleScanConfig:
    sim = SimConfig(camera=CameraConfig(scale=0.1), wind=WindConfig(enabled=False),
                    panicle=PanicleConfig(seeds_min=300, seeds_max=400))
    return PanicleScanConfig(seed=140, arm=ArmConfig(views=3), sim=sim, exposure=exposure)


def _saturated_seed_fraction(root) -> tuple[float, float]:
    """(fraction of seed pixels at 255 in all channels, median grey of the seed pixels) over all left images."""
    ds = SeedmapDataset(root)
    sat, grey = [], []
    for i in range(len(ds)):
        img = ds[i].left
        lab = ds.gt_label_image(i, "left")
        px = img[lab > 0]
        sat.append(np.all(px == 255, axis=1))
        grey.append(px.mean(axis=1))
    return float(np.concatenate(sat).mean()), float(np.median(np.concatenate(grey)))


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    base = tmp_path_factory.mktemp("arm_exposure")
    return {e: simulate_panicle(_small(e), base / f"e_{e}", progress=False) for e in ("auto", 1.0)}


def test_auto_exposure_removes_flash_saturation(scans):
    sat_auto, grey_auto = _saturated_seed_fraction(scans["auto"])
    sat_old, grey_old = _saturated_seed_fraction(scans[1.0])
    assert sat_auto < 0.03, sat_auto
    assert sat_old > 0.3, sat_old  # (a white panicle) the field gain at the 0.3 m stand-off: a large part of the seeds clip
    assert 60 < grey_auto < 200, grey_auto  # well exposed, not dark
    assert grey_old > grey_auto + 40


def test_resolved_gain_is_recorded_and_scan_yaml_reloads(scans):
    cfg = _small("auto")
    sim = cfg.sim.model_copy(update={"seed": cfg.seed})
    world = build_panicle_world(sim, np.random.default_rng(np.random.SeedSequence(cfg.seed).spawn(4)[0]))
    d = scan_distance(world, cfg.arm.radius)
    # the camera circles at 0.3 m from the rachis; the seeds it faces are a few cm closer
    assert 0.2 < d < 0.29
    assert exposure_factor(cfg, world) == pytest.approx((d / REF_DISTANCE) ** 2)
    written = yaml.safe_load((scans["auto"] / "gt" / "config.yaml").read_text())
    assert written["imaging"]["exposure"] == pytest.approx((d / REF_DISTANCE) ** 2)
    assert yaml.safe_load((scans[1.0] / "gt" / "config.yaml").read_text())["imaging"]["exposure"] == 1.0
    again = load_config(PanicleScanConfig, scans["auto"] / "gt" / "scan.yaml", [])
    assert again.exposure == "auto" and again.seed == cfg.seed


def test_numeric_exposure_and_bad_values():
    cfg = load_config(PanicleScanConfig, None, ["exposure=0.5"])
    assert cfg.exposure == 0.5
    assert load_config(PanicleScanConfig, None, []).exposure == "auto"
    with pytest.raises(ConfigError):
        load_config(PanicleScanConfig, None, ["exposure=bright"])
    with pytest.raises(ConfigError):
        load_config(PanicleScanConfig, None, ["exposure=-1"])


def test_cli_bad_exposure_fails_with_one_line(tmp_path):
    out = tmp_path / "scan"
    r = subprocess.run([sys.executable, "-m", "seedmap.cli", "simulate", "panicle", "--out", str(out),
                        "--exposure", "0", "--quiet"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "exposure" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_partial_sim_override_keeps_arm_scan_defaults(tmp_path):
    """`--set sim.panicle.X=...` (or a YAML with a partial sim: section) once rebuilt SimConfig from its field
    defaults: full-resolution field camera and simulator wind on an arm scan. The scan defaults now stay."""
    from seedmap.config import config_to_yaml, load_config

    default = PanicleScanConfig()
    cfg = load_config(PanicleScanConfig, None, ["sim.panicle.seeds_min=300", "sim.panicle.seeds_max=400"])
    assert cfg.sim.panicle.seeds_min == 300
    assert cfg.sim.camera.scale == default.sim.camera.scale == 0.25
    assert cfg.sim.wind.enabled is False
    assert cfg.sim.camera == default.sim.camera and cfg.sim.wind == default.sim.wind
    # an explicit value still wins, and a dumped config reloads to itself
    cfg2 = load_config(PanicleScanConfig, None, ["sim.camera.scale=0.5", "sim.wind.enabled=true"])
    assert cfg2.sim.camera.scale == 0.5 and cfg2.sim.wind.enabled is True
    p = tmp_path / "scan.yaml"
    p.write_text(config_to_yaml(cfg2))
    assert load_config(PanicleScanConfig, p) == cfg2
    part = tmp_path / "part.yaml"
    part.write_text("sim:\n  panicle:\n    seeds_min: 300\n")
    assert load_config(PanicleScanConfig, part).sim.camera.scale == 0.25
