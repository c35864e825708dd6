"""report.html: produced, self-contained (no external script), carrying the numbers and plots it was given."""

from __future__ import annotations

import base64
import re
from dataclasses import dataclass

import cv2
import numpy as np

from seedmap.records import Trajectory
from seedmap.viz.html_report import write_html_report


@dataclass
class _Metrics:
    frames: int
    distance_m: float
    lost: bool


def _traj(n: int, noise: float = 0.0) -> Trajectory:
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = 0.02 * np.arange(n)
    T[:, 2, 3] = noise * np.sin(np.arange(n))
    return Trajectory(np.arange(n) * 0.2, T)


def test_report_is_self_contained(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    out = write_html_report(
        tmp_path / "r" / "report.html", title="range <3> & co",
        metrics={"slam": _Metrics(40, 0.78, False), "ape_rmse_m": 0.0123, "note": "<script>x</script>"},
        trajectories={"estimate": _traj(40, 0.01), "ground truth": _traj(40)},
        matches_per_frame={"seeds": rng.integers(50, 150, 40), "sift": rng.integers(0, 90, 40)},
        timings={"match": rng.uniform(0.01, 0.02, 40)},
        points=rng.normal(size=(500, 3)), images={"left frame 0": img})
    text = out.read_text()
    assert out.is_file() and not list(out.parent.glob("*.tmp"))
    # self-contained: no external script or stylesheet, plotly inlined once
    assert not re.search(r"<script[^>]+src=[\"']https?://", text)
    assert not re.search(r"<link[^>]+href=[\"']https?://", text)
    assert text.count("Plotly") > 10 and '"type":"scatter3d"' in text
    # numbers and text appear, escaped
    assert "0.78" in text and "0.0123" in text and "slam.frames" in text
    assert "&lt;script&gt;x&lt;/script&gt;" in text and "range &lt;3&gt; &amp; co" in text
    # four inline PNGs (trajectory, matches, timing, the image); the image decodes to the same pixels
    uris = re.findall(r'<img alt="[^"]*" src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(uris) == 4
    back = cv2.imdecode(np.frombuffer(base64.b64decode(uris[-1]), np.uint8), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(back[:, :, ::-1], img)


def test_report_with_only_metrics(tmp_path):
    out = write_html_report(tmp_path / "m.html", metrics={"count": 1234, "r2": 0.875})
    text = out.read_text()
    assert "1,234" in text and "0.875" in text
    assert "base64" not in text and "Plotly" not in text  # nothing else was asked for
