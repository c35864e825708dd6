"""CLI of the reconstruction: seedmap simulate panicle / reconstruct / count."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from helpers.arm_scan_files import write_arm_scan
from seedmap import cli


def _run(args: list[str], monkeypatch) -> int:
    monkeypatch.setattr(sys, "argv", ["seedmap", *args])
    with pytest.raises(SystemExit) as e:
        cli.main()
    return int(e.value.code or 0)


def test_reconstruct_without_joints_file_exits_2_and_writes_nothing(tmp_path, monkeypatch, capsys):
    write_arm_scan(tmp_path / "scan", 3, joints=False)
    code = _run(["reconstruct", str(tmp_path / "scan"), "--out", str(tmp_path / "res")], monkeypatch)
    assert code == 2
    assert "joints.csv" in capsys.readouterr().err
    assert not (tmp_path / "res").exists()


def test_bad_register_mode_and_missing_results(tmp_path, monkeypatch, capsys):
    write_arm_scan(tmp_path / "scan", 3)
    assert _run(["reconstruct", str(tmp_path / "scan"), "--out", str(tmp_path / "r"), "--register", "icp"],
                monkeypatch) == 2
    assert "--register" in capsys.readouterr().err
    assert _run(["count", str(tmp_path / "nothing")], monkeypatch) == 2


@pytest.mark.slow
def test_simulate_reconstruct_count_end_to_end(arm_scan_6_views, tmp_path, monkeypatch):
    data, res = arm_scan_6_views, tmp_path / "r3"
    for f in ("joints.csv", "arm.yaml", "gt/poses_tum.txt", "gt/poses_fk_tum.txt", "gt/surface_points.npy"):
        assert (data / f).is_file(), f
    assert _run(["reconstruct", str(data), "--register", "seeds", "--detector", "gt", "--out", str(res), "-q",
                 "--set", "detector_overrides=[gt.min_area_px=6]"], monkeypatch) == 0
    for f in ("config.yaml", "metrics.json", "cloud.ply", "seeds.csv", "poses_tum.txt", "report.md",
              "detections.csv", "calib.yaml"):  # the last two: `seedmap count` with the multiview method
        assert (res / f).is_file(), f
    m = json.loads((res / "metrics.json").read_text())
    assert m["seed_count"] > 50 and m["oracle_detector"]
    assert m["gt"]["cloud_dist_mm_median"] < 3.0
    seeds = np.loadtxt(res / "seeds.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(seeds) == m["seed_count"]
    assert _run(["count", str(res), "--set", "count.min_observations=1", "--out", str(tmp_path / "c")],
                monkeypatch) == 0
    assert json.loads((tmp_path / "c" / "count.json").read_text())["seed_count"] >= m["seed_count"]
    # the paper's 3D de-duplication counts from the same folder
    assert _run(["count", str(res), "--set", "count.method=density", "--out", str(tmp_path / "c2")], monkeypatch) == 0
    assert json.loads((tmp_path / "c2" / "count.json").read_text())["seed_count"] > 0
