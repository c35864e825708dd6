"""Benchmark reports: summaries, Markdown tables, CSV files and plots of the run records."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from seedmap.config import config_to_yaml
from seedmap.detect.base import detector_label
from seedmap.eval.benchmark.spec import CSV_FIELDS, BenchmarkConfig, RunRecord, safe_name
from seedmap.eval.published import (
    PAPER_RANGE_LENGTHS,
    PUBLISHED_MDM,
    PUBLISHED_TITLES,
    published_fraction,
    published_key,
    published_mean_fraction,
)
from seedmap.io.atomic import atomic_write_bytes, atomic_write_text
from seedmap.viz.plotting import figure_text


def fmt_cell(rec: RunRecord | None, attr: str = "mdm_m", digits: int = 2) -> str:
    """Table cell of ``rec.<attr>``: the number, or fail / n/a / error / – (see docs/method/benchmark.md)."""
    if rec is None:
        return ""
    if rec.status == "n/a":
        return "n/a"
    if rec.status != "ok":
        return "error"
    v = getattr(rec, attr)
    if v is None:
        return "–"
    if attr in ("mdm_m", "gt_mdm_m") and v <= 0.0:
        return "fail"
    return f"{v:.{digits}f}"


def _mean(vals: Iterable[float | None]) -> float | None:
    v = [x for x in vals if x is not None]
    return float(np.mean(v)) if v else None


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.0f}%"


def _methods_in(records: Sequence[RunRecord]) -> list[str]:
    seen: list[str] = []
    for r in records:
        if r.method not in seen:
            seen.append(r.method)
    return seen


def _ranges_in(records: Sequence[RunRecord]) -> list[str]:
    seen: list[str] = []
    for r in records:
        if r.range_name not in seen:
            seen.append(r.range_name)
    return seen


def summarize(records: Sequence[RunRecord]) -> dict[str, dict[str, dict[str, float | None]]]:
    """``{scenario: {method: {mean_fraction, mean_gt_fraction, mean_ate_m, ms_per_frame, ranges}}}``."""
    out: dict[str, dict[str, dict[str, float | None]]] = {}
    for sc in dict.fromkeys(r.scenario for r in records):
        rs = [r for r in records if r.scenario == sc]
        out[sc] = {}
        for m in _methods_in(rs):
            mr = [r for r in rs if r.method == m and r.status == "ok"]
            out[sc][m] = {
                "mean_fraction": _mean(r.mdm_fraction for r in mr),
                "mean_gt_fraction": _mean(r.gt_mdm_fraction for r in mr),
                "mean_ate_m": _mean(r.ate_rmse_m for r in mr),
                "ms_per_frame": _mean(r.ms_per_frame for r in mr),
                "ranges": float(len(mr)),
                "available": float(any(r.status != "n/a" for r in rs if r.method == m)),
            }
    return out


def method_label(m: str) -> str:
    """A method as reports show it: ``seeds+<detector>`` with the detector labelled ORACLE where it is one."""
    matcher, plus, detector = m.partition("+")
    return f"{matcher}+{detector_label(detector)}" if plus else m


def md_table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _range_label(recs: Sequence[RunRecord], name: str) -> str:
    L = next((r.range_length_m for r in recs if r.range_name == name and r.range_length_m), None)
    return f"{name} ({L:.2f})" if L else name


def scenario_tables(records: Sequence[RunRecord], scenario: str) -> str:
    """Markdown: Table-1-like MDM table, GT-validated MDM, ATE and timing for one scenario."""
    rs = [r for r in records if r.scenario == scenario]
    if not rs:
        return ""
    methods = _methods_in(rs)
    names = _ranges_in(rs)
    by = {(r.range_name, r.method): r for r in rs}
    summ = summarize(rs)[scenario]
    header = ["range (m)"] + [method_label(m) for m in methods]
    parts = []

    def block(title: str, attr: str, frac_attr: str | None, digits: int = 2) -> str:
        rows = [[_range_label(rs, n)] + [fmt_cell(by.get((n, m)), attr, digits) for m in methods] for n in names]
        if frac_attr is not None:
            rows.append(["**mean fraction**"] + [
                "n/a" if all(by[(n, m)].status == "n/a" for n in names if (n, m) in by)
                else _pct(summ[m][frac_attr]) for m in methods])
        return f"**{title}**\n\n" + md_table(header, rows)

    parts.append(block("Maximum distance mapped (m), this run", "mdm_m", "mean_fraction"))
    parts.append(block("GT-validated maximum distance mapped (m): position error within max(5 % of distance, "
                       "5 cm)", "gt_mdm_m", "mean_gt_fraction"))
    parts.append(block("ATE RMSE (m) over the tracked part", "ate_rmse_m", None, 3))
    timing = [["ms / frame (mean over ranges)"] + [
        "n/a" if summ[m]["ms_per_frame"] is None else f"{summ[m]['ms_per_frame']:.0f}" for m in methods]]
    parts.append("**Timing**\n\n" + md_table(["method"] + methods, timing))
    notes = sorted({f"{r.method}: {r.note}" for r in rs if r.status != "ok" and r.note})
    if notes:
        parts.append("Notes: " + "; ".join(notes) + "\n")
    peer_notes = [f"{r.range_name} {r.method}: {r.note}" for r in rs if r.status == "ok" and r.note]
    if peer_notes:  # a peer's finished run says which vocabulary it used and its longest tracked segment
        parts.append("Runs: " + "; ".join(peer_notes) + "\n")
    return "\n".join(parts)


def published_table() -> str:
    """The paper's Tables 1 and 2 (real field data), with their mean-fraction row."""
    keys = list(PUBLISHED_MDM)
    header = ["range (m)"] + [PUBLISHED_TITLES[k] for k in keys]
    rows = []
    for i, L in enumerate(PAPER_RANGE_LENGTHS):
        rows.append([f"paper{i + 1} ({L:.2f})"] + [
            "fail" if PUBLISHED_MDM[k][i] is None else f"{PUBLISHED_MDM[k][i]:.2f}" for k in keys])
    rows.append(["**mean fraction**"] + [_pct(published_mean_fraction(k)) for k in keys])
    return "**Published (real field data)** — the paper's Tables 1 and 2, not re-measured here\n\n" + md_table(
        header, rows)


def side_by_side_table(records: Sequence[RunRecord]) -> str:
    """Mean fraction mapped per method: this run (paper ranges) next to the published value."""
    rs = [r for r in records if r.scenario == "paper"]
    if not rs:
        return ""
    summ = summarize(rs)["paper"]
    rows = []
    for m in _methods_in(rs):
        key = published_key(m)
        pub = _pct(published_mean_fraction(key)) if key else "–"
        if key and key != m.split("+", 1)[0].lower():  # a counterpart (orbslam3 beside ORB-SLAM2)
            pub += f" ({PUBLISHED_TITLES[key]})"
        s = summ[m]
        na = all(r.status == "n/a" for r in rs if r.method == m)
        rows.append([method_label(m), "n/a" if na else _pct(s["mean_fraction"]),
                     "n/a" if na else _pct(s["mean_gt_fraction"]),
                     pub])
    if not any(published_key(m) == "orb-slam2" for m in _methods_in(rs)):
        rows.append(["orb-slam2 (not run here)", "–", "–", _pct(published_mean_fraction("orb-slam2"))])
    return "**Mean fraction of range mapped: simulated paper ranges vs published (real field data)**\n\n" + \
        md_table(["method", "this run", "this run, GT-validated", "published (real field data)"], rows)


def records_csv(records: Sequence[RunRecord]) -> str:
    """``results.csv``: one row per record (columns :data:`CSV_FIELDS`)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in records:
        d = asdict(r)
        w.writerow({k: ("" if d[k] is None else d[k]) for k in CSV_FIELDS})
    return buf.getvalue()


def table1_csv(records: Sequence[RunRecord]) -> str:
    """Wide table: one row per (scenario, range); per method MDM, GT-MDM, ATE; published columns."""
    methods = _methods_in(records)
    pub_keys = list(PUBLISHED_MDM)
    header = ["scenario", "range", "length_m"]
    for m in methods:
        header += [f"{m} mdm_m", f"{m} gt_mdm_m", f"{m} ate_m", f"{m} ms_per_frame"]
    header += [f"published {PUBLISHED_TITLES[k]} mdm_m" for k in pub_keys]
    by = {(r.scenario, r.range_name, r.method): r for r in records}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for sc in dict.fromkeys(r.scenario for r in records):
        rs = [r for r in records if r.scenario == sc]
        for n in _ranges_in(rs):
            L = next((r.range_length_m for r in rs if r.range_name == n and r.range_length_m), None)
            row: list[Any] = [sc, n, "" if L is None else f"{L:.3f}"]
            for m in methods:
                r = by.get((sc, n, m))
                row += [fmt_cell(r, "mdm_m", 3), fmt_cell(r, "gt_mdm_m", 3), fmt_cell(r, "ate_rmse_m", 4),
                        "" if r is None or r.ms_per_frame is None else f"{r.ms_per_frame:.1f}"]
            pidx = next((r.paper_index for r in rs if r.range_name == n), None) if sc == "paper" else None
            for k in pub_keys:
                if pidx is None:
                    row.append("")
                else:
                    v = PUBLISHED_MDM[k][pidx]
                    row.append("fail" if v is None else f"{v:.2f}")
            w.writerow(row)
    return buf.getvalue()


def _png_bytes(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


@figure_text()
def bar_chart_png(records: Sequence[RunRecord]) -> bytes:
    """Grouped bars of the fraction of each range mapped per method (+ GT-validated dots, published)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(r.scenario for r in records))
    show_pub = "paper" in scenarios
    n_panels = len(scenarios) + (1 if show_pub else 0)
    fig, axes = plt.subplots(n_panels, 1, figsize=(11, 3.4 * n_panels), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for ax, sc in zip(axes[:, 0], scenarios, strict=False):
        rs = [r for r in records if r.scenario == sc]
        methods = [m for m in _methods_in(rs) if any(r.status == "ok" for r in rs if r.method == m)]
        names = _ranges_in(rs)
        by = {(r.range_name, r.method): r for r in rs}
        width = 0.8 / max(1, len(methods))
        summ = summarize(rs)[sc]
        x = np.arange(len(names))
        for j, m in enumerate(methods):
            vals = [by[(n, m)].mdm_fraction if (n, m) in by and by[(n, m)].mdm_fraction is not None else 0.0
                    for n in names]
            gts = [by[(n, m)].gt_mdm_fraction if (n, m) in by else None for n in names]
            mf = summ[m]["mean_fraction"]
            ax.bar(x + (j - (len(methods) - 1) / 2) * width, vals, width, color=cmap(j % 10),
                   label=f"{m} (mean {_pct(mf)})")
            gx = [x[i] + (j - (len(methods) - 1) / 2) * width for i, g in enumerate(gts) if g is not None]
            ax.plot(gx, [g for g in gts if g is not None], "k.", ms=5)
        ax.set_xticks(x, [_range_label(rs, n) for n in names], fontsize=8)
        ax.set_ylim(0, 1.08)
        ax.set_ylabel("fraction mapped")
        ax.set_title(f"{sc}: maximum distance mapped / range length (dots: GT-validated)", fontsize=10)
        if methods:  # every run failed: no bars, and matplotlib warns about an empty legend
            ax.legend(fontsize=7, ncol=4, loc="upper left")
    if show_pub:
        ax = axes[-1, 0]
        keys = list(PUBLISHED_MDM)
        width = 0.8 / len(keys)
        x = np.arange(len(PAPER_RANGE_LENGTHS))
        for j, k in enumerate(keys):
            ax.bar(x + (j - (len(keys) - 1) / 2) * width, published_fraction(k), width, color=cmap((j + 3) % 10),
                   hatch="//", alpha=0.8, label=f"{PUBLISHED_TITLES[k]} (mean {_pct(published_mean_fraction(k))})")
        ax.set_xticks(x, [f"paper{i + 1} ({L:.2f})" for i, L in enumerate(PAPER_RANGE_LENGTHS)], fontsize=8)
        ax.set_ylim(0, 1.08)
        ax.set_ylabel("fraction mapped")
        ax.set_title("published (real field data), the paper's Tables 1 and 2", fontsize=10)
        ax.legend(fontsize=7, ncol=3, loc="upper left")
    fig.tight_layout()
    data = _png_bytes(fig)
    plt.close(fig)
    return data


@figure_text()
def matches_plot_png(records: Sequence[RunRecord], scenario: str, range_name: str) -> bytes | None:
    """Per-frame surviving matches of every method on one range: stereo (top), temporal and
    RANSAC-verified temporal inliers (bottom); a dotted vertical line marks where a method got lost."""
    rs = [r for r in records if r.scenario == scenario and r.range_name == range_name and r.status == "ok"
          and (r.stereo_matches or r.temporal_matches)]
    if not rs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.6), sharex=True)
    cmap = plt.get_cmap("tab10")
    for j, r in enumerate(rs):
        c = cmap(j % 10)
        if r.stereo_matches:
            ax1.plot(np.arange(len(r.stereo_matches)), r.stereo_matches, "-", color=c, lw=1.2, label=r.method)
        if r.temporal_matches:
            ax2.plot(np.arange(len(r.temporal_matches)), r.temporal_matches, "-", color=c, lw=1.2,
                     label=f"{r.method} temporal")
        if r.inlier_matches:
            ax2.plot(np.arange(len(r.inlier_matches)), r.inlier_matches, "--", color=c, lw=1.0,
                     label=f"{r.method} inliers")
        if r.lost_frame is not None:
            for ax in (ax1, ax2):
                ax.axvline(int(r.lost_frame), color=c, lw=0.8, ls=":")
    for ax, what in ((ax1, "stereo matches"), (ax2, "temporal matches")):
        ax.set_yscale("symlog", linthresh=10)
        ax.set_ylim(bottom=0)
        ax.set_ylabel(what)
        ax.legend(fontsize=7, ncol=2)
    ax2.set_xlabel("frame")
    ax1.set_title(f"{scenario} / {range_name}: surviving matches per frame (dotted: lost)", fontsize=10)
    fig.tight_layout()
    data = _png_bytes(fig)
    plt.close(fig)
    return data


def write_reports(records: Sequence[RunRecord], out: str | Path, cfg: BenchmarkConfig | None = None,
                  wall_s: float | None = None) -> dict[str, Path]:
    """Write results.csv, table1.csv, report.md, summary.json, mdm_bars.png, matches/*.png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}

    def put_text(name: str, text: str) -> None:
        atomic_write_text(out / name, text)
        written[name] = out / name

    put_text("results.csv", records_csv(records))
    put_text("table1.csv", table1_csv(records))
    summary = {"wall_s": wall_s, "scenarios": summarize(records)}
    put_text("summary.json", json.dumps(summary, indent=2))
    md = ["# seedmap benchmark\n"]
    if wall_s is not None:
        md.append(f"Wall time: {wall_s / 60:.1f} min.\n")
    titles = {"paper": "Simulated paper ranges (presets paper1..paper8)",
              "scenes": "Harder held-out scene variations (not averaged with the paper ranges)",
              "user": "Your datasets"}
    for sc in dict.fromkeys(r.scenario for r in records):
        md.append(f"## {titles.get(sc, sc)}\n")
        md.append(scenario_tables(records, sc))
    if any(r.scenario == "paper" for r in records):
        md.append("## Side by side with the paper\n")
        md.append(side_by_side_table(records))
        md.append(published_table())
    if cfg is not None:
        md.append("## Configuration\n\n```yaml\n" + config_to_yaml(cfg) + "```\n")
    md.append("Cells: fail = mapped nothing, n/a = method unavailable, error = run failed (see results.csv and "
              "logs/), – = needs ground truth or a known range length.\n")
    put_text("report.md", "\n".join(md))
    atomic_write_bytes(out / "mdm_bars.png", bar_chart_png(records))
    written["mdm_bars.png"] = out / "mdm_bars.png"
    for sc in dict.fromkeys(r.scenario for r in records):
        for n in _ranges_in([r for r in records if r.scenario == sc]):
            png = matches_plot_png(records, sc, n)
            if png is not None:
                p = out / "matches" / f"{sc}-{safe_name(n)}.png"
                atomic_write_bytes(p, png)
                written[f"matches/{p.name}"] = p
    return written
