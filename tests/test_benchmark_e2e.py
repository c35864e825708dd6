"""The benchmark end to end on two tiny simulated ranges, plus its command-line errors."""

from __future__ import annotations

import csv
import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from seedmap.eval.benchmark import SCENE_OVERRIDES, BenchmarkConfig, paper_ranges, run_benchmark

SEEDMAP = [sys.executable, "-m", "seedmap.cli"]
TINY = ["world.length=0.3", "world.gap=0.3", "camera.scale=0.12", "panicle.seeds_min=300",
        "panicle.seeds_max=600", "imaging.supersample=1"]


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    return subprocess.run([*SEEDMAP, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120)


def test_cli_rejects_missing_dataset(tmp_path):
    r = _cli("benchmark", "run", str(tmp_path / "nope"), "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert r.returncode == 2
    assert "dataset not found" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_cli_rejects_wrong_seed_count(tmp_path):
    r = _cli("benchmark", "paper", "--out", str(tmp_path / "o"), "--seeds", "1,2", cwd=tmp_path)
    assert r.returncode == 2 and "one per range" in r.stderr


def test_cli_rejects_unknown_method(tmp_path):
    r = _cli("benchmark", "paper", "--out", str(tmp_path / "o"), "--methods", "sift,brisk", cwd=tmp_path)
    assert r.returncode == 2 and "brisk" in r.stderr and "Traceback" not in r.stderr


def test_scene_variations_are_held_out():
    cfg = BenchmarkConfig(scenes=True)
    specs = paper_ranges(cfg)
    paper = [s for s in specs if s.scenario == "paper"]
    hard = [s for s in specs if s.scenario == "scenes"]
    assert [s.length_m for s in paper] == [3.56, 5.00, 4.42, 4.10, 4.78, 3.94, 5.03, 4.43]
    assert len(hard) == 8
    assert not {s.seed for s in paper} & {s.seed for s in hard}
    assert all(set(SCENE_OVERRIDES) <= set(s.sim_overrides) for s in hard)
    assert len({s.dataset for s in specs}) == 16


@pytest.mark.slow
def test_two_tiny_ranges_all_columns_and_resume(tmp_path):
    cfg = BenchmarkConfig(data_dir=str(tmp_path / "cache"), presets=["paper1", "paper2"], sim_overrides=TINY,
                          methods=["seeds+gt", "sift", "surf", "orb"], workers=2)
    out = tmp_path / "bench"
    recs = run_benchmark(paper_ranges(cfg), out, cfg, progress=False)
    assert [(r.range_name, r.method) for r in recs] == [
        (p, m) for p in ("paper1", "paper2") for m in ("seeds+gt", "sift", "surf", "orb")]
    by = {(r.range_name, r.method): r for r in recs}
    for p in ("paper1", "paper2"):
        assert by[(p, "surf")].status == "n/a" and "non-free" in by[(p, "surf")].note
        g = by[(p, "seeds+gt")]
        assert g.status == "ok", g.note
        assert g.range_length_m == pytest.approx(0.3)
        assert g.frames and g.frames >= 5
        assert len(g.stereo_matches) >= 1 and g.stereo_matches[0] > 0
        for m in ("sift", "orb"):
            assert by[(p, m)].status == "ok", by[(p, m)].note
            assert by[(p, m)].ms_per_frame and by[(p, m)].ms_per_frame > 0
    report = (out / "report.md").read_text()
    header = next(line for line in report.splitlines() if line.startswith("| range (m)"))
    for m in ("seeds+gt", "sift", "surf", "orb"):
        assert m in header
    assert "paper1 (0.30)" in report and "published (real field data)" in report.lower()
    rows = list(csv.DictReader(io.StringIO((out / "results.csv").read_text())))
    assert len(rows) == 8
    wide = list(csv.DictReader(io.StringIO((out / "table1.csv").read_text())))
    assert [w["range"] for w in wide] == ["paper1", "paper2"]
    assert {"seeds+gt gt_mdm_m", "sift ate_m", "published ORB-SLAM2 mdm_m"} <= set(wide[0])
    assert (out / "mdm_bars.png").is_file() and (out / "matches" / "paper-paper1.png").is_file()
    assert (out / "config.yaml").is_file()
    # resume: finished runs are read back, not recomputed
    stamp = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/*/*/metrics.json")}
    assert len(stamp) == 6
    # each run keeps its report.md; the per-run report.html is opt-in (cfg.html_reports)
    assert all((p.parent / "report.md").is_file() and not (p.parent / "report.html").exists() for p in stamp)
    recs2 = run_benchmark(paper_ranges(cfg), out, cfg, progress=False)
    assert {p: p.stat().st_mtime_ns for p in out.glob("runs/*/*/*/metrics.json")} == stamp
    assert [(r.method, r.mdm_m) for r in recs2] == [(r.method, r.mdm_m) for r in recs]


def test_methods_without_ground_truth_mark_the_oracle_na():
    from seedmap.associate.features import available_kinds
    from seedmap.eval.benchmark import default_methods

    ms = {m.name: m for m in default_methods(BenchmarkConfig(), with_gt=False)}
    assert ms["seeds+gt"].unavailable and "ground truth" in ms["seeds+gt"].unavailable
    assert ms["seeds+fast"].unavailable is None
    for k, why in available_kinds().items():
        assert ms[k].unavailable == why
    with_gt = {m.name: m for m in default_methods(BenchmarkConfig(), with_gt=True)}
    assert with_gt["seeds+gt"].unavailable is None
    assert list(with_gt)[:2] == ["seeds+gt", "seeds+fast"]
    assert set(with_gt) >= {"seeds+gt", "seeds+fast", "sift", "orb"}
