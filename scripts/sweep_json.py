#!/usr/bin/env python3
"""Turn a ``seedmap benchmark sweep`` result folder into ``benchmarks/results/sweep.json``: the folder's
``sweep.json`` (its config, the summary per condition and method, one record per condition, strength, seed and
method) plus the command, commit, date and machine.

    python scripts/sweep_json.py results/sweep --command "seedmap benchmark sweep --out results/sweep ..."
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from provenance import stamp

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", type=Path, help="folder written by `seedmap benchmark sweep`")
    ap.add_argument("--command", required=True, help="the exact command that wrote the folder")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sweep.json")
    a = ap.parse_args()
    src = a.result / "sweep.json"
    if not src.is_file():
        raise SystemExit(f"{src}: not found (is {a.result} a finished `seedmap benchmark sweep` folder?)")
    body = json.loads(src.read_text())
    doc = {**stamp(a.command), **body}
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(a.out)


if __name__ == "__main__":
    main()
