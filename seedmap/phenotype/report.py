"""``phenotype.html``: the phenotype table of a row pass as one self-contained page.

A row profile (panicles along the row: height, length, seed estimate with its uncertainty, plot bands, flagged
panicles hollow), histograms of the panicle traits, the table itself (and the per-plot summaries) and the
per-panicle thumbnails ``thumbs/panicle_NNN.png`` found next to it. Images are embedded (base64 PNG) with the
helpers of :mod:`seedmap.viz.html_report`, so the file opens offline.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from seedmap.io.atomic import atomic_write_text
from seedmap.phenotype.table import COLUMNS, PLOT_COLUMNS
from seedmap.phenotype.views import THUMB_PATTERN
from seedmap.viz.html_report import (figure_html, format_value, html_page, metrics_table_html, png_data_uri,
                                     png_file_data_uri, written_line)
from seedmap.viz.plotting import figure_text

#: file name of the report in the phenotype output folder
REPORT_NAME = "phenotype.html"
#: histogram panels: (column, axis label, scale applied to the value)
HISTOGRAMS = (("length_m", "length (cm)", 100.0), ("width_m", "width (cm)", 100.0),
              ("height_m", "height above ground (m)", 1.0), ("tilt_deg", "tilt from vertical (°)", 1.0),
              ("seeds_est", "estimated seeds", 1.0))
#: largest marker diameter (points) of the row profile: the longest panicle
MAX_MARKER_PT = 26.0
#: the row profile spans at least this far (m) either side of its panicles
MIN_HALF_SPAN_M = 0.25

_CSS = """
table.panicles { border-collapse: collapse; font-size: 0.85em; } table.panicles th, table.panicles td {
  padding: 2px 7px; border-bottom: 1px solid #eee; text-align: right; font-variant-numeric: tabular-nums; }
table.panicles th { position: sticky; top: 0; background: #fafafa; }
table.panicles tr.flagged td { background: #fff6e0; }
table.panicles td.text { text-align: left; } .tablewrap { max-height: 32em; overflow: auto; }
.thumbs { display: flex; flex-wrap: wrap; gap: 10px; } .thumbs figure { margin: 0; width: 150px; }
.thumbs figure img { width: 150px; } .thumbs figcaption { font-size: 0.8em; }
"""


def _num(v: Any) -> float:
    """``v`` as a float (NaN when missing or not a number)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _col(rows: Sequence[dict], key: str) -> np.ndarray:
    return np.array([_num(r.get(key)) for r in rows], dtype=float)


def _cell(v: Any) -> tuple[str, bool]:
    """Table cell text (``–`` for a missing or non-finite number) and whether it is numeric."""
    if v is None or (isinstance(v, (float, np.floating)) and not math.isfinite(float(v))):
        return "–", True
    if isinstance(v, (float, np.floating)) and abs(float(v)) >= 100:
        return f"{float(v):.0f}", True
    return format_value(v)


def table_html(rows: Sequence[dict], columns: Sequence[str], cls: str = "panicles") -> str:
    """An HTML table of ``rows`` with ``columns`` (rows whose ``quality`` is not ``ok`` marked ``flagged``)."""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = []
    for r in rows:
        flagged = "quality" in r and r["quality"] != "ok"
        cells = []
        for c in columns:
            text, num = _cell(r.get(c))
            cells.append(("<td>" if num else '<td class="text">') + html.escape(text) + "</td>")
        body.append(('<tr class="flagged">' if flagged else "<tr>") + "".join(cells) + "</tr>")
    return (f'<div class="tablewrap"><table class="{cls}"><thead><tr>{head}</tr></thead><tbody>\n'
            + "\n".join(body) + "\n</tbody></table></div>")


def _plot_bands(axes, plot_rows: Sequence[dict] | None) -> None:
    """Alternating shaded spans for the plots, their names along the top of the first axis."""
    if not plot_rows:
        return
    for k, p in enumerate(plot_rows):
        a, b = _num(p.get("start_m")), _num(p.get("end_m"))
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        for ax in axes:
            ax.axvspan(a, b, color="0.5" if k % 2 else "0.75", alpha=0.15, lw=0, zorder=0)
        axes[0].text((a + b) / 2, 1.01, str(p.get("plot", "")), transform=axes[0].get_xaxis_transform(),
                     ha="center", va="bottom", fontsize=8, color="0.3")


def row_profile_figure(rows: Sequence[dict], plot_rows: Sequence[dict] | None = None):
    """Panicles along the row: height vs position (marker diameter ∝ length, colour = estimated seeds, flagged
    panicles hollow) above the estimated seeds per panicle as bars with their ±1 sd."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    x, h, length = _col(rows, "x_m"), _col(rows, "height_m"), _col(rows, "length_m")
    seeds, sd = _col(rows, "seeds_est"), _col(rows, "seeds_sd")
    ok = np.array([r.get("quality") == "ok" for r in rows])
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(11, 6), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    finite_len = length[np.isfinite(length)]
    longest = float(finite_len.max()) if finite_len.size and finite_len.max() > 0 else 1.0
    size = np.where(np.isfinite(length), (MAX_MARKER_PT * np.clip(length, 0, None) / longest) ** 2, 20.0)
    size = np.maximum(size, 9.0)
    finite_seeds = seeds[np.isfinite(seeds)]
    lo, hi = (float(finite_seeds.min()), float(finite_seeds.max())) if finite_seeds.size else (0.0, 1.0)
    norm = plt.Normalize(lo, hi if hi > lo else lo + 1.0)
    cmap = plt.get_cmap("viridis")
    colours = np.array([cmap(norm(s)) if math.isfinite(s) else (0.6, 0.6, 0.6, 1.0) for s in seeds])
    at = np.isfinite(x) & np.isfinite(h)
    for sel, filled in ((at & ok, True), (at & ~ok, False)):
        if sel.any():
            ax0.scatter(x[sel], h[sel], s=size[sel], c=colours[sel] if filled else "none",
                        edgecolors=colours[sel] if not filled else "k", linewidths=0.5 if filled else 1.6, zorder=3)
    for i in np.flatnonzero(at):
        ax0.annotate(str(rows[i].get("panicle_id", i)), (x[i], h[i]), xytext=(0, np.sqrt(size[i]) / 2 + 2),
                     textcoords="offset points", ha="center", fontsize=7, color="0.25")
    # the colour bar beside the top axis, an empty slot of the same width beside the bottom one: x stays aligned
    cax = make_axes_locatable(ax0).append_axes("right", size="2%", pad=0.1)
    make_axes_locatable(ax1).append_axes("right", size="2%", pad=0.1).axis("off")
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax).set_label("estimated seeds")
    ax0.set_ylabel("height above ground (m)")
    ax0.legend(handles=[Line2D([], [], ls="", marker="o", mfc="0.6", mec="k", label="ok"),
                        Line2D([], [], ls="", marker="o", mfc="none", mec="0.3", mew=1.6, label="flagged")],
               fontsize=8, loc="best", framealpha=0.7, title=f"diameter ∝ length ({100 * longest:.0f} cm max)",
               title_fontsize=8)
    xs = np.sort(x[np.isfinite(x)])
    width = 0.6 * float(np.median(np.diff(xs))) if xs.size > 1 and np.median(np.diff(xs)) > 0 else 0.03
    bars = np.isfinite(x) & np.isfinite(seeds)
    err = np.where(np.isfinite(sd), sd, 0.0)
    for sel, filled in ((bars & ok, True), (bars & ~ok, False)):
        if sel.any():
            ax1.bar(x[sel], seeds[sel], width=width, yerr=err[sel], capsize=2, color="tab:green" if filled else "none",
                    edgecolor="tab:green", hatch=None if filled else "///", error_kw={"lw": 0.8}, zorder=3)
    ax1.set_ylabel("estimated seeds (±1 sd)")
    ax1.set_xlabel("position along the row x (m)")
    ax1.set_ylim(bottom=0)
    ax0.grid(alpha=0.3)
    ax1.grid(alpha=0.3, axis="y")
    _plot_bands([ax0, ax1], plot_rows)
    if xs.size and xs[-1] - xs[0] < 2 * MIN_HALF_SPAN_M:  # one panicle, or a few close together
        mid = (xs[0] + xs[-1]) / 2
        ax1.set_xlim(min(ax1.get_xlim()[0], mid - MIN_HALF_SPAN_M), max(ax1.get_xlim()[1], mid + MIN_HALF_SPAN_M))
    fig.tight_layout()
    return fig


def histograms_figure(rows: Sequence[dict]):
    """One histogram per trait of :data:`HISTOGRAMS` (flagged panicles stacked on the ok ones)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(HISTOGRAMS), figsize=(14, 2.8))
    ok = np.array([r.get("quality") == "ok" for r in rows])
    for ax, (key, label, scale) in zip(axes, HISTOGRAMS):
        v = _col(rows, key) * scale
        fin = np.isfinite(v)
        if not fin.any():
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes, color="0.4")
        else:
            edges = np.histogram_bin_edges(v[fin], bins=min(15, max(3, int(fin.sum()) // 2)))
            ax.hist([v[fin & ok], v[fin & ~ok]], bins=edges, stacked=True, color=["tab:blue", "tab:orange"],
                    label=["ok", "flagged"])
        ax.set_xlabel(label)
        ax.grid(alpha=0.3, axis="y")
    axes[0].set_ylabel("panicles")
    if (~ok).any() and ok.any():
        axes[-1].legend(fontsize=8)
    fig.tight_layout()
    return fig


def summary(rows: Sequence[dict]) -> dict:
    """Counts and medians shown above the figures."""
    flags: dict[str, int] = {}
    for r in rows:
        if r.get("quality", "ok") != "ok":
            for f in str(r["quality"]).split("+"):
                flags[f] = flags.get(f, 0) + 1
    seeds = _col(rows, "seeds_est")
    out: dict[str, Any] = {"panicles": len(rows), "panicles ok": sum(r.get("quality") == "ok" for r in rows)}
    out.update({f"flagged {k}": v for k, v in sorted(flags.items())})
    out["estimated seeds, total"] = float(np.nansum(seeds)) if np.isfinite(seeds).any() else math.nan
    for key, label, scale in HISTOGRAMS:
        v = _col(rows, key) * scale
        out[f"median {label}"] = float(np.nanmedian(v)) if np.isfinite(v).any() else math.nan
    return out


def thumbnails_html(folder: Path, rows: Sequence[dict]) -> str:
    """A grid of the ``thumbs/panicle_NNN.png`` that exist, captioned id, seed estimate and quality ("" if none)."""
    figs = []
    for r in rows:
        try:
            pid = int(r.get("panicle_id"))
        except (TypeError, ValueError):
            continue
        uri = png_file_data_uri(folder / THUMB_PATTERN.format(pid))
        if uri is None:
            continue
        s, sd = _num(r.get("seeds_est")), _num(r.get("seeds_sd"))
        est = "seeds n/a" if not math.isfinite(s) else (f"~{s:.0f}" + (f" ± {sd:.0f}" if math.isfinite(sd) else "")
                                                           + " seeds")
        figs.append(figure_html(f"#{pid} · {est} · {r.get('quality', '?')}", uri))
    return '<div class="thumbs">\n' + "\n".join(figs) + "\n</div>" if figs else ""


def write_phenotype_report(folder: str | Path, rows: Sequence[dict], plot_rows: Sequence[dict] | None = None,
                           title: str = "seedmap phenotype") -> Path:
    """Write ``folder/phenotype.html`` (atomically) from the panicle ``rows`` (the columns of panicles.csv) and
    the optional per-plot summaries; return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    rows = list(rows)
    parts = [f"<h1>{html.escape(title)}</h1>", written_line()]
    if not rows:
        parts.append("<p><strong>No panicles were found</strong>: no cluster of seed landmarks in this result was "
                     "large enough to be a panicle.</p>")
    else:
        parts += ["<h2>Summary</h2>", metrics_table_html(summary(rows))]
        with figure_text():
            fig = row_profile_figure(rows, plot_rows)
            profile = png_data_uri(fig)
            plt.close(fig)
            fig = histograms_figure(rows)
            hists = png_data_uri(fig)
            plt.close(fig)
        parts += ["<h2>Row profile</h2>",
                  figure_html("panicles along the row: height (marker diameter ∝ length, colour = estimated seeds, "
                              "hollow = flagged) and estimated seeds per panicle (±1 sd, hatched = flagged)"
                              + ("; shaded: plots" if plot_rows else ""), profile),
                  "<h2>Distributions</h2>", figure_html("panicle traits (orange: flagged panicles)", hists)]
    if plot_rows is not None:
        parts += ["<h2>Plots</h2>", table_html(list(plot_rows), PLOT_COLUMNS)]
    if rows:
        parts += ["<h2>Panicles</h2>", "<p>The columns of <code>panicles.csv</code>; flagged rows shaded "
                  "(<code>cut</code> at the end of the mapped stretch, <code>merged</code> with a neighbour, "
                  "<code>few</code> landmarks).</p>", table_html(rows, COLUMNS)]
        thumbs = thumbnails_html(folder, rows)
        if thumbs:
            parts += ["<h2>Thumbnails</h2>", thumbs]
    path = folder / REPORT_NAME
    atomic_write_text(path, html_page(title, parts, _CSS))
    return path
