"""Fixtures shared by several test files."""

from __future__ import annotations

import pytest

#: pytest's widest fixture scope: built once per test run
ONCE_PER_RUN = "sess" "ion"


@pytest.fixture(scope=ONCE_PER_RUN)
def tiny_range(tmp_path_factory):
    """A 0.4 m simulated range at camera scale 0.2 (819x600 px, 11 frames), seed 5, rendered once per run.

    Tests that modify it must work on a copy."""
    from seedmap.config import load_config
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig

    out = tmp_path_factory.mktemp("sim") / "r"
    cfg = load_config(SimConfig, None, ["world.length=0.4", "camera.scale=0.2", "seed=5"])
    simulate_range(cfg, out, overwrite=False, progress=False)
    return out


@pytest.fixture(scope=ONCE_PER_RUN)
def cnn_range(tmp_path_factory):
    """A 0.2 m range, seed 41, at the default pixel scale but a 1200x900 window (6 frames), rendered once per run
    for the CNN detector tests (read only)."""
    from seedmap.config import load_config
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig

    out = tmp_path_factory.mktemp("cnn") / "r"
    cfg = load_config(SimConfig, None, ["world.length=0.2", "seed=41", "camera.width=1200", "camera.height=900",
                                        "camera.cx=600", "camera.cy=450"])
    simulate_range(cfg, out, overwrite=False, progress=False)
    return SeedmapDataset(out)


@pytest.fixture(scope=ONCE_PER_RUN)
def arm_scan_6_views(tmp_path_factory):
    """A 6-view arm scan of panicle seed 3 at camera scale 0.18, written by ``seedmap simulate panicle`` once per run
    (read only)."""
    from helpers.cli import run_cli_ok

    out = tmp_path_factory.mktemp("arm") / "p3"
    run_cli_ok(["simulate", "panicle", "--seed", "3", "--views", "6", "--out", out, "-q", "--set",
                "sim.camera.scale=0.18"])
    return out
