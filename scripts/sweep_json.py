#!/usr/bin/env python3
"""Turn a ``seedmap benchmark sweep`` result folder into ``benchmarks/results/sweep.json``: the folder's
``sweep.json`` (its config, the summary per condition and method, one record per condition, strength, seed and
method) plus the command, commit, date and machine; and its plots (``plots/<condition>.png``, drawn by the sweep
from that summary) into ``docs/results/sweep/``, where the generated page ``docs/results/sweep.md`` shows them.

    python scripts/sweep_json.py results/sweep --command "seedmap benchmark sweep --out results/sweep ..."
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from provenance import stamp

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", type=Path, help="folder written by `seedmap benchmark sweep`")
    ap.add_argument("--command", required=True, help="the exact command that wrote the folder")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sweep.json")
    ap.add_argument("--plots", type=Path, default=ROOT / "docs" / "results" / "sweep",
                    help="folder the sweep's plots are copied into (its old plots are replaced)")
    a = ap.parse_args()
    src = a.result / "sweep.json"
    if not src.is_file():
        raise SystemExit(f"{src}: not found (is {a.result} a finished `seedmap benchmark sweep` folder?)")
    body = json.loads(src.read_text())
    pngs = sorted((a.result / "plots").glob("*.png"))
    if len(pngs) != len(body["summary"]["conditions"]):
        raise SystemExit(f"{a.result / 'plots'}: {len(pngs)} plots for {len(body['summary']['conditions'])} "
                         "conditions (re-run the sweep to redraw them)")
    doc = {**stamp(a.command), **body}
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    a.plots.mkdir(parents=True, exist_ok=True)
    for old in a.plots.glob("*.png"):
        old.unlink()
    for png in pngs:
        shutil.copyfile(png, a.plots / png.name)
    print(a.out, a.plots)


if __name__ == "__main__":
    main()
