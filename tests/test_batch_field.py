"""`seedmap batch` on a tiny simulated field: discovery, both executors, a failing range, resume."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from seedmap.batch import find_ranges, run_batch
from seedmap.config import load_config
from seedmap.slam.config import SlamConfig

from helpers.datasets import tiny_stereo_dataset

TINY = ["world.length=0.3", "world.gap=0.3", "camera.scale=0.15", "imaging.supersample=1"]
SLAM = ["max_frames=3"]


@pytest.fixture(scope="module")
def sim_ranges(tmp_path_factory) -> list[Path]:
    """Two tiny simulated ranges (different seeds), rendered once for this module."""
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig

    root = tmp_path_factory.mktemp("sim")
    paths = []
    for seed in (3, 4):
        cfg = load_config(SimConfig, None, [*TINY, f"seed={seed}"])
        paths.append(simulate_range(cfg, root / f"s{seed}", overwrite=True, progress=False))
    return paths


def _field(tmp_path: Path, sims: list[Path], bad: bool = True) -> Path:
    """field/row1/a, field/row2/b (+ field/row2/bad with a corrupt image), plus distractors."""
    field = tmp_path / "field"
    shutil.copytree(sims[0], field / "row1" / "a")
    shutil.copytree(sims[1], field / "row2" / "b")
    if bad:
        shutil.copytree(sims[0], field / "row2" / "bad")
        (field / "row2" / "bad" / "left" / "000001.png").write_bytes(b"not a png")
    (field / "notes").mkdir()
    (field / "notes" / "readme.txt").write_text("not a dataset")
    shutil.copytree(sims[0], field / ".hidden" / "c")
    return field


def _summary(out: Path) -> dict[str, dict]:
    with (out / "summary.csv").open(newline="") as f:
        return {r["range"]: r for r in csv.DictReader(f)}


def _tiny_dataset(root: Path) -> Path:
    """A 2-frame seedmap-layout dataset with 16x12 images (enough for the loaders to recognise it)."""
    return tiny_stereo_dataset(root, 2, 16, 12)


def test_find_ranges_skips_hidden_nonsense_and_output(tmp_path):
    field = tmp_path / "field"
    for rel in ("row1/a", "row2/b", "row2/bad", ".hidden/c", "out/x", "row3/deep/er/d"):
        _tiny_dataset(field / rel)
    (field / "notes").mkdir()
    (field / "notes" / "readme.txt").write_text("not a dataset")
    found = [p.relative_to(field).as_posix() for p in find_ranges(field, exclude=[field / "out"])]
    assert found == ["row1/a", "row2/b", "row2/bad", "row3/deep/er/d"]
    assert find_ranges(field / "row1" / "a") == [field / "row1" / "a"]  # a range is its own field


@pytest.mark.slow
def test_processes_failure_recorded_and_resume(tmp_path, sim_ranges):
    field = _field(tmp_path, sim_ranges)
    out = tmp_path / "res"
    cfg = load_config(SlamConfig, None, SLAM)
    s = run_batch(field, out, detector="gt", config=cfg, workers=2, progress=False)
    assert [r.range for r in s.ranges] == ["row1/a", "row2/b", "row2/bad"]
    assert (s.n_ok, s.n_failed) == (2, 1)
    rows = _summary(out)
    assert rows["row2/bad"]["status"] == "failed"
    assert "000001.png" in rows["row2/bad"]["error"] and "\n" not in rows["row2/bad"]["error"]
    for rel in ("row1/a", "row2/b"):
        m = json.loads((out / rel / "metrics.json").read_text())
        r = rows[rel]
        assert r["status"] == "ok" and float(r["mdm_m"]) == pytest.approx(m["mdm_m"], abs=1e-4)
        assert int(r["landmarks"]) == m["landmarks"] > 0
        assert 0 < int(r["seeds_mapped"]) <= m["landmarks"]
        assert int(r["panicles_mapped"]) >= 1 and float(r["wall_s"]) > 0
        assert m["frames"] == 3
    assert not (out / "row2" / "bad").exists()  # no half-written result of the failed range
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_ok"] == 2 and summary["workers"] == 2 and summary["executor"] == "processes"
    md = (out / "summary.md").read_text()
    assert "row2/bad" in md and "failed" in md and "2 ok, 1 failed" in md
    assert (out / "config.yaml").is_file()

    # resume: finished ranges are not re-run (their folders are untouched); the failure is retried
    stamp = (out / "row1" / "a" / "metrics.json").stat().st_mtime_ns
    shutil.copy(sim_ranges[0] / "left" / "000001.png", field / "row2" / "bad" / "left" / "000001.png")
    s2 = run_batch(field, out, detector="gt", config=cfg, workers=1, progress=False)
    assert (s2.n_ok, s2.n_failed) == (3, 0)
    by = {r.range: r for r in s2.ranges}
    assert by["row1/a"].resumed and by["row2/b"].resumed and not by["row2/bad"].resumed
    assert (out / "row1" / "a" / "metrics.json").stat().st_mtime_ns == stamp
    # the repaired range is a copy of row1/a: same numbers (every random choice flows from the seed)
    assert by["row2/bad"].mdm_m == pytest.approx(by["row1/a"].mdm_m, abs=1e-9)
    assert by["row2/bad"].landmarks == by["row1/a"].landmarks


@pytest.mark.slow
def test_ray_local_matches_processes(tmp_path, sim_ranges):
    ray = pytest.importorskip("ray")
    field = _field(tmp_path, sim_ranges, bad=False)
    cfg = load_config(SlamConfig, None, SLAM)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        s = run_batch(field, tmp_path / "ray", detector="gt", config=cfg, workers=2, ray="local", progress=False)
    finally:
        ray.shutdown()
    assert s.executor == "ray" and (s.n_ok, s.n_failed) == (2, 0)
    seq = run_batch(field, tmp_path / "seq", detector="gt", config=cfg, workers=1, progress=False)
    for a, b in zip(s.ranges, seq.ranges):
        assert a.range == b.range and a.mdm_m == pytest.approx(b.mdm_m, abs=1e-9) and a.landmarks == b.landmarks


def test_cli_errors(tmp_path):
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    cmd = [sys.executable, "-m", "seedmap.cli", "batch"]
    r = subprocess.run([*cmd, str(tmp_path / "nope"), "--out", str(tmp_path / "o")], capture_output=True,
                       text=True, env=env, timeout=120)
    assert r.returncode == 2 and "field folder not found" in r.stderr and "Traceback" not in r.stderr
    (tmp_path / "empty" / "sub").mkdir(parents=True)
    r = subprocess.run([*cmd, str(tmp_path / "empty"), "--out", str(tmp_path / "o")], capture_output=True,
                       text=True, env=env, timeout=120)
    assert r.returncode == 2 and "no dataset found" in r.stderr
    r = subprocess.run([*cmd, str(tmp_path / "empty"), "--out", str(tmp_path / "o"), "--workers", "0"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and "--workers" in r.stderr
