"""The robustness sweep's report: statistics per point, where each method fails first, tables, plots, files.

Every function works on the rows of the sweep's ``results.csv`` (plain dicts: ``condition``, ``level``,
``strength``, ``seed``, then a benchmark record's columns), so a report can be rebuilt from that file.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from seedmap.eval.benchmark.report import md_table, method_label
from seedmap.eval.benchmark.spec import CSV_FIELDS, safe_name
from seedmap.io.atomic import atomic_write_bytes, atomic_write_text
from seedmap.viz.plotting import figure_text

#: a method has failed at a point when its mean GT-validated fraction mapped (over the world seeds) is below this
FAIL_BELOW = 0.5
#: what :func:`fails_first` says of a method that holds at every strength of the sweep
NEVER = "never in range"


def _num(v: Any) -> float | None:
    if v is None or v == "":
        return None
    f = float(v)
    return f if np.isfinite(f) else None


def _ordered(rows: Sequence[dict], key: str) -> list:
    return list(dict.fromkeys(r[key] for r in rows))


def point_stats(rows: Sequence[dict]) -> dict[str, dict[str, list[dict]]]:
    """``{condition: {method: [point, ...]}}`` in order of strength; a point holds ``level``, ``strength``, the
    mean/min/max over seeds of the GT-validated fraction mapped (``gt``), the mean fraction mapped
    (``mapped``) and ATE (``ate_m``), and the number of seeds ``ok``, ``na`` and ``errors``."""
    out: dict[str, dict[str, list[dict]]] = {}
    for c in _ordered(rows, "condition"):
        rc = [r for r in rows if r["condition"] == c]
        levels = sorted({(float(r["strength"]), str(r["level"])) for r in rc})
        out[c] = {}
        for m in _ordered(rc, "method"):
            pts = []
            for s, lev in levels:
                rs = [r for r in rc if r["method"] == m and str(r["level"]) == lev]
                ok = [r for r in rs if r["status"] == "ok"]
                gt = [g for g in (_num(r["gt_mdm_fraction"]) for r in ok) if g is not None]
                mapped = [g for g in (_num(r["mdm_fraction"]) for r in ok) if g is not None]
                ate = [g for g in (_num(r["ate_rmse_m"]) for r in ok) if g is not None]
                pts.append({
                    "level": lev, "strength": s,
                    "gt": float(np.mean(gt)) if gt else None,
                    "gt_min": min(gt) if gt else None, "gt_max": max(gt) if gt else None,
                    "mapped": float(np.mean(mapped)) if mapped else None,
                    "ate_m": float(np.mean(ate)) if ate else None,
                    "ok": len(ok), "na": sum(r["status"] == "n/a" for r in rs),
                    "errors": sum(r["status"] == "error" for r in rs),
                })
            out[c][m] = pts
    return out


def fails_first(points: Sequence[dict], threshold: float = FAIL_BELOW) -> str:
    """The level of the smallest strength whose mean GT-validated fraction is below ``threshold``; :data:`NEVER`
    when every measured point holds; ``"n/a"`` when no point was measured (the method unavailable or failing to
    run). Points without a measurement (every seed n/a or an error) are skipped."""
    measured = [p for p in sorted(points, key=lambda p: p["strength"]) if p["gt"] is not None]
    if not measured:
        return "n/a"
    for p in measured:
        if p["gt"] < threshold:
            return str(p["level"])
    return NEVER


def sweep_summary(rows: Sequence[dict]) -> dict:
    """``{"fail_below", "conditions": {c: {"methods": {m: {"fails_first", "points"}}}}}`` (JSON-ready)."""
    stats = point_stats(rows)
    return {"fail_below": FAIL_BELOW, "conditions": {
        c: {"methods": {m: {"fails_first": fails_first(pts), "points": pts} for m, pts in per.items()}}
        for c, per in stats.items()}}


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.0f}%"


def _cell(p: dict) -> str:
    """A point's mean (min–max) GT-validated fraction, in bold where the method fails (one decimal where the
    rounded mean would hide which side of :data:`FAIL_BELOW` it lies on)."""
    if p["gt"] is None:
        return "n/a" if p["na"] else ("error" if p["errors"] else "–")
    lo, hi = f"{100 * p['gt_min']:.0f}", f"{100 * p['gt_max']:.0f}"
    band = "" if lo == hi else f" ({lo}–{hi})"
    mean = f"{100 * p['gt']:.1f}%" if round(100 * p["gt"]) == round(100 * FAIL_BELOW) else _pct(p["gt"])
    text = mean + band + (f" [{p['errors']} error]" if p["errors"] else "")
    return f"**{text}**" if p["gt"] < FAIL_BELOW else text


def failure_table(summary: dict) -> str:
    """Markdown: method × condition, the level at which each method fails first."""
    conds = list(summary["conditions"])
    methods = list(dict.fromkeys(m for c in conds for m in summary["conditions"][c]["methods"]))
    rows = [[method_label(m)] + [summary["conditions"][c]["methods"].get(m, {}).get("fails_first", "–")
                                 for c in conds] for m in methods]
    return md_table(["method"] + conds, rows)


def condition_table(summary: dict, condition: str) -> str:
    """Markdown: method × strength, mean GT-validated fraction mapped (min–max over seeds) and mean ATE (mm)."""
    per = summary["conditions"][condition]["methods"]
    levels = [p["level"] for p in next(iter(per.values()))["points"]]
    rows = []
    for m, v in per.items():
        rows.append([method_label(m)] + [_cell(p) for p in v["points"]])
    for m, v in per.items():
        if any(p["ate_m"] is not None for p in v["points"]):
            rows.append([f"{method_label(m)} ATE (mm)"] + [
                "–" if p["ate_m"] is None else f"{1000 * p['ate_m']:.1f}" for p in v["points"]])
    return md_table([f"{condition} strength"] + levels, rows)


@figure_text()
def condition_plot_png(summary: dict, condition: str) -> bytes:
    """Fraction mapped (GT-validated) vs strength, one line per method: mean over seeds, min–max band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per = summary["conditions"][condition]["methods"]
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    cmap = plt.get_cmap("tab10")
    ticks: dict[float, str] = {}
    for j, (m, v) in enumerate(per.items()):
        pts = [p for p in v["points"] if p["gt"] is not None]
        for p in v["points"]:
            ticks[p["strength"]] = p["level"]
        if not pts:
            continue
        x = [p["strength"] for p in pts]
        c = cmap(j % 10)
        style = ("-", "--", "-.", ":")[j % 4]
        ax.plot(x, [p["gt"] for p in pts], style, marker="os^vD"[j % 5], color=c, lw=1.5, ms=4,
                label=f"{method_label(m)} (fails: {v['fails_first']})")
        ax.fill_between(x, [p["gt_min"] for p in pts], [p["gt_max"] for p in pts], color=c, alpha=0.15, lw=0)
    ax.axhline(FAIL_BELOW, color="0.5", lw=0.8, ls=":")
    xs = sorted(ticks)
    ax.set_xticks(xs, [ticks[x] for x in xs])
    top = max([1.0] + [p["gt_max"] for v in per.values() for p in v["points"] if p["gt_max"] is not None])
    ax.set_ylim(-0.03, top + 0.05)  # above 1: a vibrating rig travels further than the range is long
    ax.set_xlabel("ladder rung" if condition == "ladder" else f"{condition} strength (1 = typical field)")
    ax.set_ylabel("GT-validated fraction mapped")
    ax.set_title(f"{condition}: mean over world seeds, band = min–max", fontsize=10)
    if any(p["gt"] is not None for v in per.values() for p in v["points"]):
        ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def rows_csv(rows: Sequence[dict]) -> str:
    """The sweep's ``results.csv``: one row per (condition, strength, seed, method)."""
    fields = ["condition", "level", "strength", "seed", *CSV_FIELDS]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r[k]) for k in fields})
    return buf.getvalue()


def write_sweep_reports(rows: Sequence[dict], out: str | Path, config: dict | None = None,
                        config_yaml: str | None = None) -> dict[str, Path]:
    """Write results.csv, sweep.json (the config, summary and rows), report.md and plots/<condition>.png into
    ``out``."""
    out = Path(out)
    written: dict[str, Path] = {}
    summary = sweep_summary(rows)
    atomic_write_text(out / "results.csv", rows_csv(rows))
    written["results.csv"] = out / "results.csv"
    doc = {"config": config, "summary": summary, "records": list(rows)}
    atomic_write_text(out / "sweep.json", json.dumps(doc, indent=1) + "\n")
    written["sweep.json"] = out / "sweep.json"
    md = ["# seedmap robustness sweep\n",
          f"A method fails at a strength when its mean GT-validated fraction of the range mapped (over the world "
          f"seeds) drops below {FAIL_BELOW:.0%}.\n", "## Where each method fails first\n", failure_table(summary)]
    for c in summary["conditions"]:
        png = out / "plots" / f"{safe_name(c)}.png"
        atomic_write_bytes(png, condition_plot_png(summary, c))
        written[f"plots/{png.name}"] = png
        md += [f"## {c}\n", f"![{c}](plots/{png.name})\n",
               "GT-validated fraction mapped, mean (min–max) over world seeds, in bold where the method fails; ATE "
               "over the tracked part.\n",
               condition_table(summary, c)]
    if config_yaml is not None:
        md.append("## Configuration\n\n```yaml\n" + config_yaml + "```\n")
    md.append("Per-run tables, logs and result folders: `bench/` (`bench/report.md`).\n")
    atomic_write_text(out / "report.md", "\n".join(md))
    written["report.md"] = out / "report.md"
    return written
