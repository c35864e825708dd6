"""The robustness sweep: its grid, where a method fails first, its report, bad arguments, and a tiny real sweep."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from seedmap.errors import ConfigError
from seedmap.eval.benchmark.sweep import LADDER_NAME, SweepConfig, run_sweep, sweep_grid, unique_ranges
from seedmap.eval.benchmark.sweep_report import NEVER, fails_first, point_stats, sweep_summary, write_sweep_reports

SEEDMAP = [sys.executable, "-m", "seedmap.cli"]
TINY = ["world.gap=0.3", "camera.scale=0.12", "panicle.seeds_min=300", "panicle.seeds_max=600",
        "imaging.supersample=1"]


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    return subprocess.run([*SEEDMAP, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120)


def test_grid_expands_every_point_and_shares_identical_renders(tmp_path):
    cfg = SweepConfig(conditions=["wind", "blur"], strengths=[2, 0, 1, 1], seeds=[3, 4], ladder=True, length=0.4)
    cfg.benchmark.data_dir = str(tmp_path)
    pts = sweep_grid(cfg)
    assert cfg.strengths == [0.0, 1.0, 2.0]
    assert len(pts) == 2 * 3 * 2 + 4 * 2
    assert [(p.condition, p.level, p.seed) for p in pts[:6]] == [
        ("wind", "0", 3), ("wind", "0", 4), ("wind", "1", 3), ("wind", "1", 4), ("wind", "2", 3), ("wind", "2", 4)]
    ladder = [p for p in pts if p.condition == LADDER_NAME]
    assert [p.level for p in ladder] == ["calm", "calm", "breeze", "breeze", "windy", "windy", "rough", "rough"]
    assert [p.strength for p in ladder[::2]] == [0.0, 1.0, 2.0, 3.0]
    ranges = unique_ranges(pts)
    # per seed: strength 0 of both conditions and the calm rung render one range; 2 conditions x 2 strengths; 3 rungs
    assert len(ranges) == 2 * (1 + 4 + 3)
    assert len({r.dataset for r in ranges}) == len(ranges)
    by = {(p.condition, p.level, p.seed): p.range for p in pts}
    assert by[("wind", "0", 3)] is by[("blur", "0", 3)] is by[(LADDER_NAME, "calm", 3)]
    assert by[("wind", "0", 3)] is not by[("wind", "0", 4)]
    assert by[("wind", "0", 3)].sim_overrides == ("world.length=0.4",)
    assert by[("wind", "1", 4)].sim_overrides == ("world.length=0.4", "conditions.wind=1")
    assert by[(LADDER_NAME, "rough", 3)].sim_overrides == ("world.length=0.4", "conditions.preset=rough")
    assert all(r.seed in (3, 4) and r.length_m == 0.4 and r.scenario == "sweep" for r in ranges)


@pytest.mark.parametrize("field, value, words", [
    ("conditions", ["wind", "fog"], "unknown condition 'fog'"),
    ("strengths", [0, -1], "outside 0..3"),
    ("strengths", [4], "outside 0..3"),
    ("strengths", [], "at least one strength"),
    ("seeds", [], "at least one world seed"),
])
def test_config_refuses_bad_values(field, value, words):
    from seedmap.config import load_config

    with pytest.raises(ConfigError, match=words):
        load_config(SweepConfig, overrides=[f"{field}={json.dumps(value)}"])


def _row(cond: str, level: str, s: float, seed: int, method: str, gt: float | None, status: str = "ok") -> dict:
    return {"condition": cond, "level": level, "strength": s, "seed": seed, "method": method, "status": status,
            "gt_mdm_fraction": gt, "mdm_fraction": gt, "ate_rmse_m": None if gt is None else 0.01, "note": ""}


def _synthetic() -> list[dict]:
    rows = []
    for s, (a, b) in {0.0: (1.0, 1.0), 0.5: (0.9, 0.3), 1.0: (0.2, 0.5), 2.0: (0.0, 0.0)}.items():
        rows += [_row("wind", f"{s:g}", s, 1, "seeds+fast", a), _row("wind", f"{s:g}", s, 2, "seeds+fast", b)]
        rows += [_row("wind", f"{s:g}", s, k, "orbslam3", 0.9) for k in (1, 2)]
        rows += [_row("wind", f"{s:g}", s, k, "sift", None, "n/a") for k in (1, 2)]
    # orb: an error at 0 (skipped), holds at 0.5, fails at 1 on one seed only (mean 0.45)
    for s, g in {0.5: (0.8, 0.8), 1.0: (0.9, 0.0), 2.0: (1.0, 1.0)}.items():
        rows += [_row("wind", f"{s:g}", s, k + 1, "orb", g[k]) for k in (0, 1)]
    rows += [_row("wind", "0", 0.0, k, "orb", None, "error") for k in (1, 2)]
    return rows


def test_fails_first_is_the_smallest_strength_whose_mean_is_below_half():
    stats = point_stats(_synthetic())["wind"]
    # seeds: mean 1.0, 0.6 (min 0.3), 0.35, 0.0 -> fails first at 1 although one seed fell below at 0.5
    assert [p["gt"] for p in stats["seeds+fast"]] == pytest.approx([1.0, 0.6, 0.35, 0.0])
    assert stats["seeds+fast"][1]["gt_min"] == 0.3 and stats["seeds+fast"][1]["gt_max"] == 0.9
    assert fails_first(stats["seeds+fast"]) == "1"
    assert fails_first(stats["orbslam3"]) == NEVER
    assert fails_first(stats["sift"]) == "n/a"
    assert stats["orb"][0]["errors"] == 2 and stats["orb"][0]["gt"] is None
    assert fails_first(stats["orb"]) == "1"  # mean 0.45 < 0.5; the errored strength 0 is no measurement
    assert fails_first(stats["orb"], threshold=0.4) == NEVER
    assert fails_first([{"level": "rough", "strength": 3.0, "gt": 0.1}, {"level": "calm", "strength": 0.0,
                                                                        "gt": 0.2}]) == "calm"


def test_report_files_from_records(tmp_path):
    rows = _synthetic()
    written = write_sweep_reports(rows, tmp_path, {"conditions": ["wind"]}, "conditions: [wind]\n")
    assert set(written) == {"results.csv", "sweep.json", "report.md", "plots/wind.png"}
    assert (tmp_path / "plots" / "wind.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    csv_rows = list(csv.DictReader(io.StringIO((tmp_path / "results.csv").read_text())))
    assert len(csv_rows) == len(rows)
    assert list(csv_rows[0])[:4] == ["condition", "level", "strength", "seed"]
    doc = json.loads((tmp_path / "sweep.json").read_text())
    assert doc["summary"] == json.loads(json.dumps(sweep_summary(rows)))
    assert doc["summary"]["conditions"]["wind"]["methods"]["seeds+fast"]["fails_first"] == "1"
    md = (tmp_path / "report.md").read_text()
    assert "| method | wind |" in md and "| seeds+fast | 1 |" in md and f"| orbslam3 | {NEVER} |" in md
    assert "| seeds+fast | 100% | 60% (30–90) | **35% (20–50)** | **0%** |" in md
    assert "| sift | n/a | n/a | n/a | n/a |" in md and "[2 error]" not in md and "error" in md


def test_default_methods_are_seeds_with_each_shipped_detector_then_every_baseline():
    from seedmap.eval.benchmark.spec import BenchmarkConfig, default_methods

    chosen = SweepConfig().benchmark.methods
    shipped = [m.name for m in default_methods(BenchmarkConfig(), with_gt=True) if m.matcher == "seeds"]
    # gt (the ORACLE) and fast; the paper's detector at reduced width costs 26x fast per image: --methods adds it
    assert "seeds+frcnn-pix2pix-lite" in shipped and "seeds+frcnn-pix2pix-lite" not in chosen
    assert set(shipped) - {"seeds+frcnn-pix2pix-lite"} <= set(chosen)
    assert {"orbslam3", "sift", "orb", "akaze"} <= set(chosen)


ROOT = Path(__file__).resolve().parents[1]


def _docs_pages():
    """scripts/docs_pages.py, the results pages' functions (loaded as make_docs loads it)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_docs", ROOT / "scripts" / "make_docs.py")
    spec.loader.exec_module(importlib.util.module_from_spec(spec))
    return sys.modules["docs_pages"]


def test_results_page_names_the_first_method_to_fail_per_condition():
    docs = _docs_pages()
    first = docs._first_to_fail
    rows = _synthetic() + [_row("wind", f"{s:g}", s, k, "seeds+gt", g) for s, g in
                           {0.0: 1.0, 0.5: 0.2, 1.0: 0.1, 2.0: 0.0}.items() for k in (1, 2)]
    per = sweep_summary(rows)["conditions"]["wind"]["methods"]
    assert first(per) == "seeds+gt (ORACLE) (0.5)"  # before seeds+fast and orb (both at 1)
    del per["seeds+gt"]
    assert first(per) == "seeds+fast, orb (1)"  # ties listed together; sift (n/a) and orbslam3 (never) are not
    assert first({"orbslam3": per["orbslam3"], "sift": per["sift"]}) == "none"
    said = docs._seeds_first({"wind": {"methods": per}}, list(per))
    assert "seeds+fast is among the first to fail under: wind (1)." in said
    holds = {m: per[m] for m in ("seeds+fast", "orbslam3")}
    holds["orbslam3"] = {**per["orb"], "fails_first": "0.5"}
    assert "under: no condition" in docs._seeds_first({"wind": {"methods": holds}}, list(holds))


def test_sweep_json_script_stamps_the_command_and_copies_the_plots(tmp_path):
    res = tmp_path / "sweep"
    write_sweep_reports(_synthetic(), res, {"conditions": ["wind"]})
    plots = tmp_path / "docs"
    plots.mkdir()
    (plots / "stale.png").write_bytes(b"old")
    script = [sys.executable, str(ROOT / "scripts" / "sweep_json.py"), str(res), "--out", str(tmp_path / "s.json"),
              "--plots", str(plots)]
    subprocess.run([*script, "--command", "seedmap benchmark sweep --out sweep"], check=True, capture_output=True)
    doc = json.loads((tmp_path / "s.json").read_text())
    assert doc["command"] == "seedmap benchmark sweep --out sweep" and doc["commit"] and doc["records"]
    assert sorted(p.name for p in plots.iterdir()) == ["wind.png"]
    assert (plots / "wind.png").read_bytes() == (res / "plots" / "wind.png").read_bytes()
    (res / "plots" / "wind.png").unlink()
    (tmp_path / "s.json").unlink()
    r = subprocess.run([*script, "--command", "x"], capture_output=True, text=True)
    assert r.returncode != 0 and "0 plots for 1 conditions" in r.stderr and not (tmp_path / "s.json").exists()


@pytest.mark.parametrize("args, words", [
    (["--conditions", "wind,fog"], "unknown condition 'fog'"),
    (["--strengths", "0,-1"], "outside 0..3"),
    (["--strengths", "0,x"], "comma-separated numbers"),
    (["--methods", "seeds+fast,brisk"], "brisk"),
    (["--seeds", "4,a"], "comma-separated integers"),
])
def test_cli_bad_arguments_one_line_exit_2(tmp_path, args, words):
    r = _cli("benchmark", "sweep", "--out", str(tmp_path / "o"), *args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert words in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def _mtimes(root: Path) -> dict[str, int]:
    return {str(p): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()
            and (p.name == "metrics.json" or p.name == "calib.yaml")}


@pytest.mark.slow
def test_tiny_sweep_end_to_end_and_resume(tmp_path):
    cfg = SweepConfig(conditions=["wind", "blur"], strengths=[0, 1], seeds=[5], length=0.3)
    cfg.benchmark.data_dir = str(tmp_path / "cache")
    cfg.benchmark.sim_overrides = TINY
    cfg.benchmark.methods = ["seeds+gt", "orb"]
    cfg.benchmark.workers = 2
    out = tmp_path / "sweep"
    rows = run_sweep(cfg, out, progress=False)
    assert [(r["condition"], r["level"], r["method"]) for r in rows] == [
        (c, s, m) for c in ("wind", "blur") for s in ("0", "1") for m in ("seeds+gt", "orb")]
    assert len(list((tmp_path / "cache").iterdir())) == 3  # strength 0 rendered once for both conditions
    oracle = {(r["condition"], r["level"]): r for r in rows if r["method"] == "seeds+gt"}
    assert oracle[("wind", "0")]["status"] == "ok" and oracle[("wind", "0")]["gt_mdm_fraction"] > 0.9
    assert oracle[("wind", "0")]["ate_rmse_m"] == oracle[("blur", "0")]["ate_rmse_m"]  # one shared run
    for f in ("results.csv", "sweep.json", "report.md", "config.yaml", "plots/wind.png", "plots/blur.png",
              "bench/report.md"):
        assert (out / f).is_file(), f
    assert "## Where each method fails first" in (out / "report.md").read_text()
    before = _mtimes(tmp_path)
    assert len(before) == 3 + 3 * 2  # datasets' calib.yaml + a metrics.json per (range, method)
    again = run_sweep(cfg, out, progress=False)
    assert _mtimes(tmp_path) == before  # nothing rendered or run again
    assert again == rows
