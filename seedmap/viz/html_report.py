"""A self-contained ``report.html``: metrics table, inline PNG plots and images, an interactive 3D view.

Everything is embedded (PNGs as base64, plotly.js inline), so the file opens offline, can be mailed, and
does not change when a CDN does. Inputs are plain records - :class:`~seedmap.records.Trajectory`, arrays,
a metrics dataclass or mapping - so any command (SLAM, reconstruction, benchmark) can call
:func:`write_html_report` on what it already has.
"""

from __future__ import annotations

import base64
import dataclasses
import datetime as _dt
import html
import io
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from seedmap.io.atomic import atomic_write_text
from seedmap.records import Trajectory
from seedmap.viz.plotting import figure_text

MAX_3D_POINTS = 150_000  # above this the 3D view shows every k-th point (the file stays a few MB)

_CSS = """
body { font-family: system-ui, -apple-system, Segoe UI, sans-serif; margin: 2em auto; max-width: 1100px;
       color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.2em; margin-top: 2em; border-bottom: 1px solid #ddd; }
table.metrics { border-collapse: collapse; } table.metrics td, table.metrics th { padding: 3px 12px;
  border-bottom: 1px solid #eee; text-align: left; } table.metrics td.num { text-align: right;
  font-variant-numeric: tabular-nums; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { color: #666; font-size: 0.9em; } .meta { color: #888; font-size: 0.85em; }
"""


def _flatten(obj: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """Rows ``(dotted.name, value)`` of a dataclass / mapping (nested ones flattened)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    if isinstance(obj, Mapping):
        rows: list[tuple[str, Any]] = []
        for k, v in obj.items():
            name = f"{prefix}.{k}" if prefix else str(k)
            if isinstance(v, Mapping) or (dataclasses.is_dataclass(v) and not isinstance(v, type)):
                rows.extend(_flatten(v, name))
            else:
                rows.append((name, v))
        return rows
    return [(prefix or "value", obj)]


def format_value(v: Any) -> tuple[str, bool]:
    """Display text of a metric value and whether it is numeric."""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)), False
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}", True
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if not np.isfinite(f):
            return str(f), True
        return (f"{f:.4g}" if abs(f) >= 1e-3 or f == 0 else f"{f:.3e}"), True
    if isinstance(v, np.ndarray) and v.size <= 8:
        return np.array2string(v, precision=4), False
    text = str(v)
    return (text if len(text) <= 200 else text[:197] + "..."), False


def metrics_table_html(metrics: Any) -> str:
    rows = []
    for name, value in _flatten(metrics):
        text, num = format_value(value)
        cls = ' class="num"' if num else ""
        rows.append(f"<tr><th>{html.escape(name)}</th><td{cls}>{html.escape(text)}</td></tr>")
    return '<table class="metrics">\n' + "\n".join(rows) + "\n</table>"


def png_data_uri(img_or_fig: Any) -> str:
    """``data:image/png;base64,...`` of an RGB/gray uint8 array or a matplotlib figure."""
    if isinstance(img_or_fig, np.ndarray):
        from seedmap.io.images import encode_png

        a = img_or_fig
        if a.dtype != np.uint8:
            a = np.clip(a, 0, 255).astype(np.uint8)
        data = encode_png(a)
    else:
        buf = io.BytesIO()
        img_or_fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
        data = buf.getvalue()
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def png_file_data_uri(path: str | Path) -> str | None:
    """``data:image/png;base64,...`` of a PNG file as it is (no re-encoding); None when it is not a PNG file."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return None
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def figure_html(caption: str, uri: str) -> str:
    """An ``<figure>`` of an embedded image (a data URI) with its caption."""
    return (f'<figure><img alt="{html.escape(caption)}" src="{uri}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def written_line() -> str:
    """The report's "written <UTC time>" line."""
    return f'<p class="meta">written {_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}</p>'


def html_page(title: str, parts: Sequence[str], css: str = "") -> str:
    """A whole self-contained HTML document: the shared style (plus ``css``) and the body ``parts``."""
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_CSS}{css}</style></head><body>\n"
            + "\n".join(parts) + "\n</body></html>\n")


def trajectory_figure(trajectories: Mapping[str, Trajectory]):
    """Top view (x, z of the world frame) and position over time of each named trajectory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
    for name, traj in trajectories.items():
        if len(traj) == 0:
            continue
        p = traj.positions
        ax0.plot(p[:, 0], p[:, 2], "-", marker=".", ms=3, label=name)
        t = traj.timestamps - traj.timestamps[0]
        ax1.plot(t, traj.path_length(), label=name)
    ax0.set_xlabel("x (m)")
    ax0.set_ylabel("z (m)")
    ax0.set_title("top view")
    ax0.axis("equal")
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("distance travelled (m)")
    for ax in (ax0, ax1):
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # no trajectory at all (e.g. lost at the first frame)
            ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def series_figure(series: Mapping[str, Sequence[float]], ylabel: str, xlabel: str = "frame"):
    """One line per named per-frame series (matches per frame, timings)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 3.2))
    for name, y in series.items():
        y = np.asarray(y, float).reshape(-1)
        ax.plot(np.arange(len(y)), y, label=name, lw=1.2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if len(series) > 1 or any(series):
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def points_3d_html(points: np.ndarray, colors: np.ndarray | None = None,
                   trajectories: Mapping[str, Trajectory] | None = None, include_plotlyjs: bool = True) -> str:
    """An interactive plotly 3D scatter (``points`` (N, 3) m, optional RGB uint8 ``colors``) with camera paths."""
    import plotly.graph_objects as go
    import plotly.io as pio

    pts = np.asarray(points, float).reshape(-1, 3)
    step = max(1, int(np.ceil(len(pts) / MAX_3D_POINTS)))
    pts = pts[::step]
    marker: dict[str, Any] = {"size": 2}
    if colors is not None:
        c = np.asarray(colors).reshape(-1, 3)[::step]
        marker["color"] = [f"rgb({int(r)},{int(g)},{int(b)})" for r, g, b in c]
    else:
        marker["color"] = pts[:, 2]
        marker["colorscale"] = "Viridis"
    data = [go.Scatter3d(x=pts[:, 0], y=pts[:, 1], z=pts[:, 2], mode="markers", marker=marker,
                         name=f"points ({len(pts):,}{f', every {step}th' if step > 1 else ''})")]
    for name, traj in (trajectories or {}).items():
        if len(traj):
            p = traj.positions
            data.append(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", name=name, line={"width": 4}))
    fig = go.Figure(data=data)
    fig.update_layout(scene={"aspectmode": "data"}, margin={"l": 0, "r": 0, "t": 30, "b": 0}, height=600)
    return pio.to_html(fig, full_html=False, include_plotlyjs=include_plotlyjs, include_mathjax=False)


@figure_text()
def write_html_report(
    path: str | Path,
    title: str = "seedmap report",
    metrics: Any = None,
    trajectories: Mapping[str, Trajectory] | None = None,
    matches_per_frame: Mapping[str, Sequence[float]] | None = None,
    timings: Mapping[str, Sequence[float]] | None = None,
    points: np.ndarray | None = None,
    point_colors: np.ndarray | None = None,
    images: Mapping[str, np.ndarray] | None = None,
    notes: str | None = None,
) -> Path:
    """Write one self-contained HTML file (atomically) and return its path.

    ``metrics``: dataclass or mapping (nested flattened to ``a.b`` rows). ``trajectories``: name ->
    Trajectory (e.g. "estimate", "ground truth"). ``matches_per_frame`` / ``timings``: name -> per-frame
    numbers (timings in seconds). ``points``: (N, 3) metres for the 3D view. ``images``: caption -> RGB array.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = [f"<h1>{html.escape(title)}</h1>", written_line()]
    if notes:
        parts.append(f"<p>{html.escape(notes)}</p>")
    if metrics is not None:
        parts += ["<h2>Metrics</h2>", metrics_table_html(metrics)]
    if trajectories:
        fig = trajectory_figure(trajectories)
        parts += ["<h2>Trajectory</h2>", figure_html("camera positions (left camera)", png_data_uri(fig))]
        plt.close(fig)
    if matches_per_frame:
        fig = series_figure(matches_per_frame, "matches")
        parts += ["<h2>Matches per frame</h2>", figure_html("matches per frame", png_data_uri(fig))]
        plt.close(fig)
    if timings:
        fig = series_figure({k: np.asarray(v, float) * 1e3 for k, v in timings.items()}, "time (ms)")
        parts += ["<h2>Timing</h2>", figure_html("time per frame", png_data_uri(fig))]
        plt.close(fig)
    if points is not None and len(points):
        parts += ["<h2>3D view</h2>", points_3d_html(points, point_colors, trajectories)]
    if images:
        parts.append("<h2>Images</h2>")
        parts += [figure_html(caption, png_data_uri(img)) for caption, img in images.items()]
    path = Path(path)
    atomic_write_text(path, html_page(title, parts))
    return path
