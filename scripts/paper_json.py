#!/usr/bin/env python3
"""Turn a ``seedmap benchmark paper`` result folder into ``benchmarks/results/paper.json`` (schema in
``benchmarks/README.md``): its ``results.csv`` rows as records, plus the command, commit, date and machine.

    python scripts/paper_json.py results/paper --command "seedmap benchmark paper --out results/paper --workers 2"
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from provenance import stamp

ROOT = Path(__file__).resolve().parents[1]
TEXT = {"scenario", "range_name", "method", "status", "note", "lost_reason"}


def _value(key: str, v: str) -> object:
    if key in TEXT:
        return v if v != "" or key in {"note", "status"} else None
    if v == "":
        return None
    if v in {"True", "False"}:
        return v == "True"
    f = float(v)
    return int(f) if key in {"frames", "frames_tracked", "lost_frame", "paper_index"} else f


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", type=Path, help="folder written by `seedmap benchmark paper`")
    ap.add_argument("--command", required=True, help="the exact command that wrote the folder")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "paper.json")
    a = ap.parse_args()
    with open(a.result / "results.csv", newline="") as fh:
        records = [{k: _value(k, v) for k, v in row.items()} for row in csv.DictReader(fh)]
    doc = {**stamp(a.command), "records": records}
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(a.out)


if __name__ == "__main__":
    main()
