"""`seedmap slam/reconstruct --rerun FILE.rrd` and the report.html of every result folder (end to end)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from seedmap import cli
from seedmap.viz.rerun_log import rrd_entity_paths

from helpers.rerun_read import rrd_column

TINY_RANGE = ["world.length=0.3", "world.gap=0.3", "camera.scale=0.15", "imaging.supersample=1"]


def _run(args: list[str], monkeypatch) -> int:
    monkeypatch.setattr(sys, "argv", ["seedmap", *args])
    with pytest.raises(SystemExit) as e:
        cli.main()
    return int(e.value.code or 0)


def _html_checks(report, *must: str) -> str:
    text = report.read_text()
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert "<h2>Metrics</h2>" in text and "<h2>3D view</h2>" in text and "<h2>Images</h2>" in text
    assert text.count("data:image/png;base64,") >= 3  # trajectory, per-frame plot, overlay thumbnail
    assert "https://cdn" not in text.split("<body>")[0]  # self-contained
    for m in must:
        assert m in text, m
    return text


@pytest.mark.slow
def test_slam_rerun_and_report(tmp_path, monkeypatch):
    from seedmap.config import load_config
    from seedmap.io.trajectory import read_tum
    from seedmap.sim import simulate_range
    from seedmap.sim.config import SimConfig

    ds = simulate_range(load_config(SimConfig, None, [*TINY_RANGE, "seed=5"]), tmp_path / "range", progress=False)
    out, rrd = tmp_path / "res", tmp_path / "logs" / "slam.rrd"
    assert _run(["slam", str(ds), "--detector", "gt", "--out", str(out), "--rerun", str(rrd), "--set",
                 "max_frames=3", "-q"], monkeypatch) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames_tracked"] == 3 and m["landmarks"] > 0
    _html_checks(out / "report.html", f"{m['landmarks']} landmarks", "ground truth")

    ents = rrd_entity_paths(rrd)
    assert ents["/cam/left"] == ents["/cam/right"] == ents["/cam/left/stereo_matches"] == 3
    assert ents["/cam/left/temporal_matches"] == 2  # none for the first frame
    assert ents["/world/landmarks"] == 3 and ents["/world/landmarks_final"] == 1
    assert "/world/trajectory/ground_truth" in ents
    # the recorded final trajectory is the one written to trajectory.tum
    final = np.asarray(rrd_column(rrd, "/world/trajectory/final", "LineStrips3D:strips")[0][0], float)
    np.testing.assert_allclose(final, read_tum(out / "trajectory.tum").positions, atol=1e-5)
    lm = np.loadtxt(out / "landmarks.csv", delimiter=",", skiprows=1).reshape(-1, 8)
    rec_lm = np.asarray(rrd_column(rrd, "/world/landmarks_final", "Points3D:positions")[0], float)
    np.testing.assert_allclose(rec_lm, lm[:, 3:6], atol=1e-5)
    # the stereo match lines of frame 0 are horizontal (rectified pair): same row at both ends
    strips = rrd_column(rrd, "/cam/left/stereo_matches", "LineStrips2D:strips")[0]
    assert len(strips) > 10 and all(abs(s[0][1] - s[1][1]) < 1e-6 and s[0][0] > s[1][0] for s in strips)


@pytest.mark.slow
def test_reconstruct_rerun_and_report(tmp_path, monkeypatch):
    scan = tmp_path / "scan"
    assert _run(["simulate", "panicle", "--out", str(scan), "--views", "4", "--seed", "2",
                 "--set", "sim.camera.scale=0.12", "-q"], monkeypatch) == 0
    out, rrd = tmp_path / "res", tmp_path / "recon.rrd"
    assert _run(["reconstruct", str(scan), "--out", str(out), "--detector", "gt", "--rerun", str(rrd), "-q"],
                monkeypatch) == 0
    m = json.loads((out / "metrics.json").read_text())
    _html_checks(out / "report.html", f"{m['seed_count']} seeds counted", "forward kinematics")
    ents = rrd_entity_paths(rrd)
    assert {"/recon/cloud", "/recon/seeds", "/world/trajectory/forward_kinematics"} <= set(ents)
    assert sum(e.startswith("/recon/views/") and e.endswith("/pose") for e in ents) == 4
    seeds = np.asarray(rrd_column(rrd, "/recon/seeds", "Points3D:positions")[0], float)
    assert len(seeds) == m["seed_count"]
    csv_seeds = np.loadtxt(out / "seeds.csv", delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_allclose(seeds, csv_seeds[:, 1:4], atol=1e-4)
