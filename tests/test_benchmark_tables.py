"""Formatting of the benchmark tables on constructed run records (formatting only, no SLAM)."""

from __future__ import annotations

import csv
import io
import json

import pytest

from seedmap.eval.benchmark import (
    BenchmarkConfig,
    RunRecord,
    published_table,
    records_csv,
    scenario_tables,
    side_by_side_table,
    summarize,
    table1_csv,
    write_reports,
)
from seedmap.eval.published import PUBLISHED_MDM, published_mean_fraction


def _rec(rng: str, method: str, L: float, mdm: float, gt: float | None, ate: float | None, status: str = "ok",
         note: str = "", scenario: str = "paper") -> RunRecord:
    r = RunRecord(scenario, rng, method, status, note, range_length_m=L)
    if scenario == "paper":
        r.paper_index = int(rng[5:]) - 1
    if status == "ok":
        r.mdm_m, r.mdm_fraction = mdm, mdm / L
        r.gt_mdm_m, r.gt_mdm_fraction = gt, (None if gt is None else gt / L)
        r.ate_rmse_m, r.ms_per_frame = ate, 40.0 if method.startswith("seeds") else 300.0
        r.frames, r.frames_tracked = 20, 20
        r.stereo_matches = [100, 90, 80, 5]
        r.temporal_matches = [0, 70, 60, 2]
        r.lost_frame = 3 if mdm < L else None
    return r


@pytest.fixture()
def records() -> list[RunRecord]:
    return [
        _rec("paper1", "seeds+gt", 3.56, 3.56, 3.56, 0.004),
        _rec("paper1", "sift", 3.56, 1.0, 0.5, 0.05),
        _rec("paper1", "surf", 3.56, 0, None, None, status="n/a", note="n/a — OpenCV without non-free"),
        _rec("paper1", "orb", 3.56, 0.0, 0.0, None),
        _rec("paper2", "seeds+gt", 5.00, 2.5, 2.0, 0.01),
        _rec("paper2", "sift", 5.00, 0.5, 0.5, 0.02),
        _rec("paper2", "surf", 5.00, 0, None, None, status="n/a", note="n/a — OpenCV without non-free"),
        _rec("paper2", "orb", 5.00, 0, None, None, status="error", note="error: boom"),
        _rec("paper1-hard", "seeds+gt", 3.56, 1.78, 1.78, 0.01, scenario="scenes"),
        _rec("paper1-hard", "sift", 3.56, 0.3, 0.3, 0.01, scenario="scenes"),
    ]


def test_scenario_table_has_every_method_range_and_mean(records):
    md = scenario_tables(records, "paper")
    header = md.splitlines()[2]
    for m in ("seeds+gt", "sift", "surf", "orb"):
        assert m in header
    assert "paper1 (3.56)" in md and "paper2 (5.00)" in md
    row1 = next(line for line in md.splitlines() if line.startswith("| paper1 (3.56)"))
    assert row1.split("|")[1:-1] == [" paper1 (3.56) ", " 3.56 ", " 1.00 ", " n/a ", " fail "]
    # mean fraction of seeds+gt: (1.0 + 0.5) / 2 = 75 %, sift: (1/3.56 + 0.1) / 2 = 19 %
    mean_row = next(line for line in md.splitlines() if "mean fraction" in line)
    assert "75%" in mean_row and "19%" in mean_row and "n/a" in mean_row
    assert "error" in md and "boom" in md
    assert "GT-validated" in md and "ATE" in md and "ms / frame" in md


def test_summary_means(records):
    s = summarize(records)
    assert s["paper"]["seeds+gt"]["mean_fraction"] == pytest.approx(0.75)
    assert s["paper"]["seeds+gt"]["mean_gt_fraction"] == pytest.approx((1.0 + 0.4) / 2)
    assert s["paper"]["surf"]["mean_fraction"] is None
    assert s["scenes"]["seeds+gt"]["mean_fraction"] == pytest.approx(0.5)
    assert "scenes" in s and "paper1-hard" not in scenario_tables(records, "paper")


def test_published_table_matches_facts():
    md = published_table()
    assert "published (real field data)".lower() in md.lower()
    assert "ORB-SLAM2" in md
    assert "| paper1 (3.56) | 1.86 | 1.55 | 0.20 | 1.55 | 0.35 | 3.56 |" in md
    assert "| paper2 (5.00) | 0.25 | 0.25 | fail | 0.19 | 0.25 | 5.00 |" in md
    assert published_mean_fraction("sift") == pytest.approx(0.38, abs=0.005)
    assert published_mean_fraction("seeds") == pytest.approx(0.78, abs=0.01)
    assert published_mean_fraction("orb-slam2") == pytest.approx(0.06, abs=0.01)
    assert published_mean_fraction("surf") == pytest.approx(0.15, abs=0.01)
    assert published_mean_fraction("akaze") == pytest.approx(0.18, abs=0.01)
    assert len(PUBLISHED_MDM["orb"]) == 8


def test_side_by_side_and_csvs(records):
    sbs = side_by_side_table(records)
    assert "| sift | 19% |" in sbs and "38%" in sbs and "78%" in sbs
    rows = list(csv.DictReader(io.StringIO(records_csv(records))))
    assert len(rows) == len(records)
    assert {r["status"] for r in rows} == {"ok", "n/a", "error"}
    wide = list(csv.DictReader(io.StringIO(table1_csv(records))))
    assert [w["range"] for w in wide] == ["paper1", "paper2", "paper1-hard"]
    w1 = wide[0]
    assert w1["seeds+gt mdm_m"] == "3.560" and w1["surf mdm_m"] == "n/a" and w1["orb mdm_m"] == "fail"
    assert w1["published SIFT+BF mdm_m"] == "1.86" and w1["published ORB-SLAM2 mdm_m"] == "0.35"
    assert wide[1]["published ORB+BF mdm_m"] == "fail"
    assert wide[2]["published SIFT+BF mdm_m"] == ""  # held-out scenes have no published counterpart


def test_write_reports_files(records, tmp_path):
    written = write_reports(records, tmp_path, BenchmarkConfig(), wall_s=12.0)
    for name in ("results.csv", "table1.csv", "report.md", "summary.json", "mdm_bars.png"):
        assert (tmp_path / name).is_file(), name
    assert (tmp_path / "mdm_bars.png").read_bytes()[:4] == b"\x89PNG"
    pngs = sorted(p.name for p in (tmp_path / "matches").iterdir())
    assert pngs == ["paper-paper1.png", "paper-paper2.png", "scenes-paper1-hard.png"]
    report = (tmp_path / "report.md").read_text()
    assert "Harder held-out" in report and "published (real field data)" in report.lower()
    assert json.loads((tmp_path / "summary.json").read_text())["wall_s"] == 12.0
    assert set(written) >= {"report.md", "mdm_bars.png"}


def test_user_scenario_without_gt_shows_dash(tmp_path):
    r = RunRecord("user", "myrow", "seeds+fast", "ok", range_length_m=None, mdm_m=2.0)
    md = scenario_tables([r], "user")
    row = next(line for line in md.splitlines() if line.startswith("| myrow"))
    assert "2.00" in row
    gt_block = md.split("GT-validated")[1]
    assert "| myrow | – |" in gt_block
    write_reports([r], tmp_path)
    assert "Side by side" not in (tmp_path / "report.md").read_text()
