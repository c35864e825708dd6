"""The results pages under docs/results/ and the README's results table are exactly what scripts/make_docs.py
writes from benchmarks/results/, so no published number can drift from the runs."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_results_pages_match_the_benchmark_json(tmp_path: Path) -> None:
    subprocess.run([sys.executable, str(ROOT / "scripts" / "make_docs.py"), "--out", str(tmp_path), "--no-readme"],
                   check=True, capture_output=True)
    committed = {p.name: p.read_text() for p in (ROOT / "docs" / "results").glob("*.md")}
    generated = {p.name: p.read_text() for p in tmp_path.glob("*.md")}
    assert sorted(committed) == sorted(generated), "run `make docs`: the set of pages differs"
    stale = [name for name in generated if committed[name] != generated[name]]
    assert not stale, f"run `make docs`: {stale} differ from the benchmark JSON files"


def test_readme_results_table_matches_the_benchmark_json() -> None:
    spec = importlib.util.spec_from_file_location("make_docs", ROOT / "scripts" / "make_docs.py")
    make_docs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_docs)
    readme = (ROOT / "README.md").read_text()
    assert make_docs.readme_with_glance(readme) == readme, "run `make docs`: README's results table is stale"


def test_sweep_page_shows_a_committed_plot_per_condition() -> None:
    import json

    doc = ROOT / "benchmarks" / "results" / "sweep.json"
    if not doc.is_file():
        pytest.skip("no sweep.json: the sweep page is not generated")
    conds = list(json.loads(doc.read_text())["summary"]["conditions"])
    page = (ROOT / "docs" / "results" / "sweep.md").read_text()
    pngs = sorted(p.name for p in (ROOT / "docs" / "results" / "sweep").glob("*.png"))
    assert pngs == sorted(f"{c}.png" for c in conds), "run scripts/sweep_json.py: the sweep's plots differ"
    assert all(f"](sweep/{c}.png)" in page for c in conds)
