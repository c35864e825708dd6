"""phenotype.html: the report of a synthetic phenotype table, its thumbnails and empty cases, the command writing
it, and the phenotype benchmark's pooled scores."""

from __future__ import annotations

import base64
import importlib.util
import math
import re
from pathlib import Path

import numpy as np
import pytest

from seedmap.io.images import encode_png
from seedmap.phenotype.report import write_phenotype_report
from seedmap.phenotype.table import COLUMNS, PLOT_COLUMNS
from tests.helpers.cli import run_cli
from tests.test_phenotype import write_result

ROOT = Path(__file__).resolve().parents[1]
URI = re.compile(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"')


def _rows(n: int = 6) -> list[dict]:
    """``n`` panicles 0.3 m apart with distinct, known values; 0 is cut, 3 merged+few."""
    quality = {0: "cut", 3: "merged+few"}
    return [{"panicle_id": 10 + i, "x_m": 0.2 + 0.3 * i, "y_m": 0.01 * i, "height_m": 1.0 + 0.03 * i,
             "length_m": 0.15 + 0.02 * i, "width_m": 0.05 + 0.005 * i, "hull_volume_cm3": 100.0 + i,
             "ellipsoid_volume_cm3": 200.0 + i, "tilt_deg": 3.0 + i, "landmarks": 300 + i, "frames": 9 + i,
             "seeds_est": 1111.0 + 100 * i, "seeds_sd": 150.0, "quality": quality.get(i, "ok")} for i in range(n)]


def _cells(page: str) -> list[list[str]]:
    """Text of the cells of the panicle table, row by row."""
    body = page.split('<table class="panicles">')[-1].split("</tbody>")[0]
    return [re.findall(r"<td[^>]*>([^<]*)</td>", tr) for tr in body.split("<tr")[1:] if "<td" in tr]


def _thumb(folder: Path, pid: int, colour: int) -> bytes:
    img = np.zeros((40, 30, 3), np.uint8)
    img[..., colour] = 200
    data = encode_png(img)
    (folder / "thumbs").mkdir(exist_ok=True)
    (folder / "thumbs" / f"panicle_{pid:03d}.png").write_bytes(data)
    return data


def test_report_shows_every_panicle_figures_and_the_table(tmp_path):
    rows = _rows()
    path = write_phenotype_report(tmp_path, rows)
    assert path == tmp_path / "phenotype.html"
    page = path.read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>")
    assert all(src.startswith("data:image/png;base64,") for src in re.findall(r'src="([^"]*)"', page))  # offline
    header = re.findall(r"<th>([^<]*)</th>", page.split('<table class="panicles">')[-1].split("</thead>")[0])
    assert header == list(COLUMNS)
    cells = _cells(page)
    assert [c[0] for c in cells] == [str(r["panicle_id"]) for r in rows]
    assert [c[-1] for c in cells] == [r["quality"] for r in rows]
    assert [c[COLUMNS.index("seeds_est")] for c in cells] == [f"{r['seeds_est']:.0f}" for r in rows]
    assert page.count('<tr class="flagged">') == 2
    assert 'alt="panicles along the row' in page and 'alt="panicle traits' in page
    uris = URI.findall(page)
    assert len(uris) == 2 and all(base64.b64decode(u).startswith(b"\x89PNG") for u in uris)
    assert "Thumbnails" not in page and "Plots" not in page


def test_thumbnails_are_embedded_when_present(tmp_path):
    rows = _rows()
    want = {11: _thumb(tmp_path, 11, 0), 14: _thumb(tmp_path, 14, 1)}
    (tmp_path / "thumbs" / "panicle_012.png").write_text("not a png")  # skipped
    _thumb(tmp_path, 99, 2)  # no such panicle
    page = write_phenotype_report(tmp_path, rows).read_text(encoding="utf-8")
    thumbs = page.split('<div class="thumbs">')[1]
    got = {int(m.group(1)): base64.b64decode(m.group(2)) for m in
           re.finditer(r'<img alt="#(\d+) [^"]*" src="data:image/png;base64,([A-Za-z0-9+/=]+)"', thumbs)}
    assert got == want
    assert "#14 · ~1511 ± 150 seeds · ok" in thumbs
    assert "#12" not in thumbs and "#99" not in thumbs


def test_plot_summaries_and_bands(tmp_path):
    plots = [{"plot": "north-A", "start_m": 0.0, "end_m": 1.0, "panicles": 3, "panicles_ok": 2, "height_m": 1.03,
              "length_m": 0.17, "width_m": 0.055, "seeds_est": 3633.0, "seeds_per_panicle": 1211.0},
             {"plot": "north-B", "start_m": 1.0, "end_m": 2.0, "panicles": 0, "panicles_ok": 0,
              "height_m": math.nan, "length_m": math.nan, "width_m": math.nan, "seeds_est": 0.0,
              "seeds_per_panicle": math.nan}]
    page = write_phenotype_report(tmp_path, _rows(3), plots).read_text(encoding="utf-8")
    plot_table = page.split("<h2>Plots</h2>")[1].split("</table>")[0]
    assert re.findall(r"<th>([^<]*)</th>", plot_table) == list(PLOT_COLUMNS)
    assert "north-A" in plot_table and "north-B" in plot_table and "–" in plot_table  # NaN means
    assert "shaded: plots" in page


def test_no_panicles_one_panicle_and_missing_values(tmp_path):
    (tmp_path / "none").mkdir()
    page = write_phenotype_report(tmp_path / "none", []).read_text(encoding="utf-8")
    assert "No panicles were found" in page and "<img" not in page and "<table" not in page
    (tmp_path / "one").mkdir()
    page = write_phenotype_report(tmp_path / "one", _rows(1)).read_text(encoding="utf-8")
    assert len(URI.findall(page)) == 2 and [c[0] for c in _cells(page)] == ["10"]
    rows = _rows(4)
    rows[1]["seeds_est"] = rows[1]["seeds_sd"] = math.nan
    rows[2]["length_m"] = math.nan
    rows[3]["height_m"] = float("inf")
    for r in rows:
        r["tilt_deg"] = math.nan  # a histogram with no values
    (tmp_path / "nan").mkdir()
    page = write_phenotype_report(tmp_path / "nan", rows).read_text(encoding="utf-8")
    cells = _cells(page)
    assert cells[1][COLUMNS.index("seeds_est")] == "–" and cells[3][COLUMNS.index("height_m")] == "–"
    assert len(URI.findall(page)) == 2


def test_command_writes_the_report(tmp_path, monkeypatch, capsys):
    res = write_result(tmp_path / "r")
    plots = tmp_path / "plots.csv"
    plots.write_text("plot,start,end\nwest,0,1\neast,1,2\n")
    assert run_cli(["phenotype", res, "--out", tmp_path / "o", "--plots", plots], monkeypatch) == 0
    assert "phenotype.html" in capsys.readouterr().out
    page = (tmp_path / "o" / "phenotype.html").read_text(encoding="utf-8")
    ids = [ln.split(",")[0] for ln in (tmp_path / "o" / "panicles.csv").read_text().splitlines()[1:]]
    assert len(ids) == 4 and [c[0] for c in _cells(page)] == ids
    assert "west" in page and "east" in page and len(URI.findall(page)) == 2


def _bench():
    spec = importlib.util.spec_from_file_location("bench_phenotype", ROOT / "benchmarks" / "bench_phenotype.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_benchmark_pools_the_held_out_ranges():
    bench = _bench()

    def rec(name, est, expected, recall, errs):
        per = [{"height_err_m": h, "length_rel_err": le, "width_rel_err": w, "seeds_rel_err": s,
                "landmarks_rel_err_visible": 0.5, "seeds": 1000, "seeds_visible": 500} for h, le, w, s in errs]
        return {"name": name, "panicles_est": est, "panicles_gt_expected": expected, "recall": recall,
                "per_panicle": per, "phenotype_s": 1.0}

    s = bench.pooled([rec("a", 3, 4, 0.75, [(0.01, 0.02, -0.1, 0.1), (-0.03, 0.0, 0.05, -0.3)]),
                      rec("b", 1, 1, 1.0, [(0.005, -0.05, 0.0, 0.2)])])
    assert s["matched"] == 3 and s["precision"] == pytest.approx(3 / 4) and s["recall"] == pytest.approx(4 / 5)
    assert s["height_err_median_m"] == pytest.approx(0.01) and s["length_rel_err_median"] == pytest.approx(0.02)
    assert s["width_rel_err_median"] == pytest.approx(0.05) and s["seeds_mape"] == pytest.approx(0.2)
    assert s["visible_fraction"] == pytest.approx(0.5)
    t = s["targets"]
    assert not t["precision"]["met"] and not t["recall"]["met"] and t["height_err_median_m"]["met"]
    assert t["seeds_mape"]["met"] is False and t["length_rel_err_median"]["met"]


def test_benchmark_rejects_an_unknown_range(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        _bench().main(["--ranges", "paper99", "--data-dir", str(tmp_path), "--out", str(tmp_path / "x.json")])
    assert "paper99" in str(e.value) and not (tmp_path / "x.json").exists()
