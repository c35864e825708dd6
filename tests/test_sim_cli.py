"""`seedmap simulate range|stats`: bad input fails with one line and writes nothing; good input works."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from seedmap.config import load_config
from seedmap.errors import ConfigError
from seedmap.sim.config import PAPER_LENGTHS, PRESETS, SimConfig, preset_dict

TINY = ["--set", "camera.scale=0.06", "--set", "panicle.seeds_min=200", "--set", "panicle.seeds_max=300",
        "--set", "motion.speed=0.6", "--quiet"]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "seedmap.cli", "simulate", *args], capture_output=True, text=True,
                          timeout=300)


def _entries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "paper9"], "unknown preset"),
        (["--length", "0"], "--length must be positive"),
        (["--length", "-1.5"], "--length must be positive"),
        (["--set", "world.length=-2"], "world.length"),
        (["--set", "imaging.supersample=0"], "imaging.supersample"),
        (["--set", "no_such_section.x=1"], "no_such_section"),
    ],
)
def test_bad_arguments_fail_cleanly(tmp_path, args, message):
    out = tmp_path / "ds"
    r = run("range", "--out", str(out), *args, *TINY)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1  # one line, no traceback
    assert not out.exists()
    assert _entries(tmp_path) == []  # no partial folder left behind


def test_unwritable_output_and_existing_dataset(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    r = run("range", "--out", str(blocker / "ds"), "--length", "0.12", *TINY)
    assert r.returncode == 2 and "not a folder" in r.stderr
    assert _entries(tmp_path) == ["a_file"]

    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "keep.txt").write_text("user data")
    r = run("range", "--out", str(existing), "--length", "0.12", *TINY)
    assert r.returncode == 2 and "--overwrite" in r.stderr
    assert _entries(existing) == ["keep.txt"]
    assert _entries(tmp_path) == ["a_file", "existing"]

    bad_cfg = tmp_path / "bad.yaml"
    bad_cfg.write_text("world: [1, 2\n")
    r = run("range", "--out", str(tmp_path / "x"), "--config", str(bad_cfg), *TINY)
    assert r.returncode == 2 and "bad.yaml" in r.stderr
    assert not (tmp_path / "x").exists()


def test_range_preview_stats_overwrite_and_stats_command(tmp_path):
    out = tmp_path / "ds"
    r = run("range", "--out", str(out), "--length", "0.12", "--seed", "3", "--preview", "--stats", *TINY)
    assert r.returncode == 0, r.stderr
    assert {"calib.yaml", "times.txt", "left", "right", "gt", "preview.png", "stats.json"} <= set(_entries(out))
    st = json.loads((out / "stats.json").read_text())
    assert st["frames"] == 2 and st["range_length_m"] == pytest.approx(0.12)
    assert st["seeds_per_panicle_min"] >= 200 and st["seeds_per_panicle_max"] <= 300
    assert st["dataset"] == str(out)
    cfg = yaml.safe_load((out / "gt" / "config.yaml").read_text())
    assert cfg["seed"] == 3 and cfg["world"]["length"] == pytest.approx(0.12)
    assert cfg["camera"]["scale"] == pytest.approx(0.06)
    # overwrite replaces the dataset (different seed -> different seeds table)
    before = (out / "gt" / "seeds.csv").read_bytes()
    r = run("range", "--out", str(out), "--length", "0.12", "--seed", "4", "--overwrite", *TINY)
    assert r.returncode == 0, r.stderr
    assert (out / "gt" / "seeds.csv").read_bytes() != before
    assert not (out / "preview.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    r = run("stats", str(out))
    assert r.returncode == 0 and "seeds_per_panicle_mean" in r.stdout
    r = run("stats", str(tmp_path / "missing"))
    assert r.returncode == 2 and "not found" in r.stderr


def test_presets_match_the_paper():
    assert list(PRESETS) == [f"paper{k}" for k in range(1, 9)]
    lengths = [load_config(SimConfig, base=preset_dict(name)).world.length for name in PRESETS]
    assert lengths == list(PAPER_LENGTHS) == [3.56, 5.00, 4.42, 4.10, 4.78, 3.94, 5.03, 4.43]
    seeds = [load_config(SimConfig, base=preset_dict(name)).seed for name in PRESETS]
    assert len(set(seeds)) == 8
    # overrides on top of a preset win
    cfg = load_config(SimConfig, overrides=["world.length=2.5"], base=preset_dict("paper3"))
    assert cfg.world.length == 2.5 and cfg.preset == "paper3"
    with pytest.raises(ConfigError):
        preset_dict("paper0")
