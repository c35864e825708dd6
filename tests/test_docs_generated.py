"""The results pages under docs/results/ are exactly what scripts/make_docs.py writes from benchmarks/results/."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_results_pages_match_the_benchmark_json(tmp_path: Path) -> None:
    subprocess.run([sys.executable, str(ROOT / "scripts" / "make_docs.py"), "--out", str(tmp_path)],
                   check=True, capture_output=True)
    committed = {p.name: p.read_text() for p in (ROOT / "docs" / "results").glob("*.md")}
    generated = {p.name: p.read_text() for p in tmp_path.glob("*.md")}
    assert sorted(committed) == sorted(generated), "run `make docs`: the set of pages differs"
    stale = [name for name in generated if committed[name] != generated[name]]
    assert not stale, f"run `make docs`: {stale} differ from the benchmark JSON files"
