#!/usr/bin/env python3
"""Turn a ``seedmap benchmark paper`` result folder into ``benchmarks/results/paper.json`` (schema in
``benchmarks/README.md``): its ``results.csv`` rows as records, plus the command, commit, date and machine.

    python scripts/paper_json.py results/paper --command "seedmap benchmark paper --out results/paper --workers 2"

``--merge`` adds the methods of a run of some methods only (``--methods``) to the existing file: its records replace
those of the same range and method, the others stay, and the command is kept under ``added``.
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
    ap.add_argument("--merge", action="store_true", help="add these records to the existing --out file")
    a = ap.parse_args()
    with open(a.result / "results.csv", newline="") as fh:
        records = [{k: _value(k, v) for k, v in row.items()} for row in csv.DictReader(fh)]
    doc = {**stamp(a.command), "records": records}
    if a.merge:
        old = json.loads(a.out.read_text())
        key = (lambda r: (r["scenario"], r["range_name"], r["method"]))
        new = {key(r) for r in records}
        methods = list(dict.fromkeys(r["method"] for r in old["records"] + records))
        kept = [r for r in old["records"] if key(r) not in new] + records
        kept.sort(key=lambda r: (r.get("paper_index") if r.get("paper_index") is not None else 99, r["range_name"],
                                 methods.index(r["method"])))
        doc = {**{k: v for k, v in old.items() if k != "records"},
               "added": [*old.get("added", []), stamp(a.command)], "records": kept}
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(a.out)


if __name__ == "__main__":
    main()
