"""seedmap phenotype: the panicle table of a synthetic seed map, eval's matching, the command's errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from seedmap.io.trajectory import write_tum
from seedmap.phenotype.config import PhenotypeConfig
from seedmap.phenotype.evaluate import match_panicles, score
from seedmap.phenotype.run import phenotype_result
from seedmap.phenotype.table import COLUMNS, PLOT_COLUMNS
from seedmap.records import Trajectory
from tests.helpers.cli import run_cli

#: camera looking along +y of a z-up world (x right = +x, y down = -z), as the simulator's
R_SIM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: (x, y, height, length, width, cluster id): the last two touch and share one DBSCAN cluster
PANICLES = [(0.3, 0.0, 1.10, 0.20, 0.06, 0), (0.8, 0.02, 1.20, 0.25, 0.05, 1),
            (1.30, 0.0, 1.15, 0.18, 0.06, 2), (1.39, 0.0, 1.12, 0.18, 0.06, 2)]


def _front_half(rng, c, length, width, n=500):
    """Points on the camera-facing half of a vertical spheroid (the seeds a side view sees)."""
    th = np.arccos(rng.uniform(-1, 1, n))
    ph = rng.uniform(np.pi, 2 * np.pi, n)
    return np.c_[c[0] + width / 2 * np.sin(th) * np.cos(ph), c[1] + width / 2 * np.sin(th) * np.sin(ph),
                 c[2] + length / 2 * np.cos(th)]


def write_result(folder, world=np.eye(4), stray=True):
    """A slam-like result folder: landmarks.csv (cluster ids given) and a straight trajectory along x."""
    rng = np.random.default_rng(0)
    xyz, cl = [], []
    for x, y, h, length, width, c in PANICLES:
        p = _front_half(rng, (x, y, h), length, width)
        xyz.append(p)
        cl += [c] * len(p)
    if stray:  # a small leaf cluster and noise
        xyz.append(rng.normal((0.55, -0.1, 0.9), 0.005, (10, 3)))
        cl += [3] * 10
    xyz = np.vstack(xyz)
    xyz = xyz @ world[:3, :3].T + world[:3, 3]
    folder.mkdir()
    lines = ["landmark_id,seed_id,cluster_id,x,y,z,n_obs,in_graph"]
    lines += [f"{i},-1,{c},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},{3 + i % 5},1" for i, (p, c) in enumerate(zip(xyz, cl))]
    (folder / "landmarks.csv").write_text("\n".join(lines) + "\n")
    poses = np.tile(np.eye(4), (20, 1, 1))
    poses[:, :3, :3] = R_SIM
    poses[:, :3, 3] = np.c_[np.linspace(0, 1.7, 20), np.full(20, -0.7), np.full(20, 1.15)]
    write_tum(folder / "trajectory.tum", Trajectory(np.arange(20) * 0.2, world[None] @ poses))
    return folder


def _check_table(rows, tol_xy=0.01):
    assert len(rows) == 4  # the stray cluster dropped, the touching pair split
    for r, (x, y, h, length, width, _) in zip(rows, PANICLES):
        assert set(r) == set(COLUMNS)
        assert r["x_m"] == pytest.approx(x, abs=tol_xy)
        assert r["y_m"] == pytest.approx(y, abs=tol_xy)
        assert r["height_m"] == pytest.approx(h, abs=0.01)
        assert r["length_m"] == pytest.approx(length, rel=0.1)
        assert r["width_m"] == pytest.approx(width, rel=0.15)
        assert r["tilt_deg"] < 10
        assert r["ellipsoid_volume_cm3"] == pytest.approx(math.pi * length * width ** 2 / 6 * 1e6, rel=0.35)
        assert 0 < r["hull_volume_cm3"] < r["ellipsoid_volume_cm3"]
        assert r["landmarks"] == 500 and r["frames"] == 7 and r["seeds_est"] > 0 and r["seeds_sd"] > 0
        assert r["quality"] == "ok"


def test_table_of_a_synthetic_seed_map(tmp_path):
    ph = phenotype_result(write_result(tmp_path / "r"), PhenotypeConfig())
    assert ph.frame.height_source == "world"
    assert ph.calibration == "fast-shape" and ph.views is None  # no images: the count from the map's shape
    _check_table(ph.rows)
    assert all(r["seeds_in_view"] == "" for r in ph.rows)


def test_a_camera_anchored_world_takes_the_height_from_the_mount(tmp_path):
    # the world is the first camera's frame: the same map, moved; the row frame starts at the first camera
    first = np.eye(4)
    first[:3, :3] = R_SIM
    first[:3, 3] = (0.0, -0.7, 1.15)
    ph = phenotype_result(write_result(tmp_path / "r", np.linalg.inv(first)), PhenotypeConfig())
    rows = ph.rows
    assert ph.frame.height_source == "camera_mount"
    for r in rows:
        r["y_m"] -= 0.7  # y = 0 is the camera path here
    _check_table(rows)


def test_eval_matches_one_to_one_within_the_gate():
    est = [{"x_m": x, "y_m": 0.0, "height_m": 1.1} for x in (0.0, 0.2, 0.21, 1.0)]
    gt = [{"x_m": x, "y_m": 0.0, "height_m": 1.1} for x in (0.01, 0.205, 0.5)]
    assert sorted(match_panicles(est, gt)) == [(0, 0), (1, 1)] or sorted(match_panicles(est, gt)) == [(0, 0), (2, 1)]
    for i, e in enumerate(est):
        e.update(panicle_id=i, quality="ok", landmarks=100, length_m=0.2, width_m=0.05, seeds_in_view=300,
                 seeds_est=1000.0)
    for j, g in enumerate(gt):
        g.update(panicle_id=j, length_m=0.2, width_m=0.05, seeds=2000, seeds_visible=1000 if j < 2 else 5)
    m = score(est, gt)
    assert m["precision"] == 0.5 and m["recall"] == 1.0  # the third GT panicle is not visible: not expected
    assert m["seeds_mape"] == pytest.approx(0.5) and m["landmarks_mape_visible"] == pytest.approx(0.9)
    assert m["visible_fraction"] == pytest.approx(0.5)


def test_command_writes_the_table_and_plot_summaries(tmp_path, monkeypatch):
    res = write_result(tmp_path / "r")
    plots = tmp_path / "plots.csv"
    plots.write_text("plot,start,end\nA,0,1\nB,1,2\n")
    assert run_cli(["phenotype", res, "--out", tmp_path / "o", "--plots", plots], monkeypatch) == 0
    header = (tmp_path / "o" / "panicles.csv").read_text().splitlines()[0]
    assert header == ",".join(COLUMNS)
    lines = (tmp_path / "o" / "plots.csv").read_text().splitlines()
    assert lines[0] == ",".join(PLOT_COLUMNS)
    assert [ln.split(",")[3] for ln in lines[1:]] == ["2", "2"]
    assert json.loads((tmp_path / "o" / "panicles.json").read_text())["panicles"] == 4


@pytest.mark.parametrize("case", ["no_result", "bad_landmarks", "bad_plots", "out_exists", "bad_set",
                                  "bad_calibration", "needs_images", "eval_no_dataset", "eval_json_is_input"])
def test_command_errors_are_one_line(tmp_path, monkeypatch, capsys, case):
    res = write_result(tmp_path / "r")
    args = ["phenotype", res, "--out", tmp_path / "o"]
    if case == "no_result":
        args[1] = tmp_path / "missing"
    elif case == "bad_landmarks":
        (res / "landmarks.csv").write_text("a,b\n1,2\n")
    elif case == "bad_plots":
        (tmp_path / "p.csv").write_text("plot,start,end\nA,x,1\n")
        args += ["--plots", tmp_path / "p.csv"]
    elif case == "out_exists":
        (tmp_path / "o").mkdir()
        (tmp_path / "o" / "f").write_text("x")
    elif case == "bad_set":
        args += ["--set", "min_landmarks=0"]
    elif case == "bad_calibration":
        (tmp_path / "c.json").write_text('{"intercept": 1, "coef": {"leaves": 1}, "sigma_log": 0.1}')
        args += ["--set", f"calibration={tmp_path / 'c.json'}"]
    elif case == "needs_images":  # counting in the best views needs the dataset
        args += ["--set", "calibration=fast"]
    elif case == "eval_no_dataset":
        args = ["eval", "phenotype", res, tmp_path / "missing"]
    else:
        args = ["eval", "phenotype", res, tmp_path / "missing", "--json", res / "landmarks.csv"]
    assert run_cli(args, monkeypatch) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
