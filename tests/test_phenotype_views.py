"""Each panicle's best view (seeds counted inside its projected outline), thumbnails, the count calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seedmap.io.trajectory import read_tum
from seedmap.phenotype.config import PhenotypeConfig
from seedmap.phenotype.run import FrameSeeds, Images, phenotype_result, write_phenotype
from seedmap.phenotype.table import COLUMNS
from seedmap.phenotype.views import frames_of_poses, outline_of, seeds_inside
from seedmap.records import StereoCalib
from tests.helpers.cli import run_cli
from tests.test_phenotype import PANICLES, write_result

CALIB = StereoCalib(fx=800.0, fy=800.0, cx=600.0, cy=450.0, baseline=0.06, width=1200, height=900)


def _seeds_in_frames(result, hide_even=0):
    """The landmarks themselves as the detector's seeds of every frame (ellipses of 6 px), plus distractors far
    from every panicle; with ``hide_even``, only half of panicle ``hide_even``'s seeds are found in even frames."""
    import pandas as pd

    lm = pd.read_csv(result / "landmarks.csv")
    xyz = lm[["x", "y", "z"]].to_numpy()
    cluster = lm["cluster_id"].to_numpy()
    traj = read_tum(result / "trajectory.tum")
    rec = FrameSeeds()
    rng = np.random.default_rng(1)
    for f, (t, T) in enumerate(zip(traj.timestamps, traj.poses)):
        Ti = np.linalg.inv(T)
        uv, _ = CALIB.project(xyz @ Ti[:3, :3].T + Ti[:3, 3])
        keep = np.isfinite(uv).all(1) & (uv[:, 0] >= 0) & (uv[:, 0] < 1200) & (uv[:, 1] >= 0) & (uv[:, 1] < 900)
        if f % 2 == 0 and hide_even is not None:
            first = np.flatnonzero(cluster == hide_even)
            keep[first[: len(first) // 2]] = False
        far = np.c_[rng.uniform(0, 1200, 40), rng.uniform(0, 60, 40)]  # a strip at the top, far above the panicles
        pts = np.vstack([uv[keep], far])
        rec.add(f, t, np.c_[pts, np.full(len(pts), 6.0), np.full(len(pts), 6.0), np.zeros(len(pts))])
    return rec


def test_each_panicle_is_counted_in_its_least_hidden_whole_view(tmp_path):
    res = write_result(tmp_path / "r", stray=False)
    rec = _seeds_in_frames(res, hide_even=0)
    idx, ts = rec.timestamps()
    images = Images(CALIB, idx, ts, rec, lambda f: np.zeros((900, 1200, 3), np.uint8))
    ph = phenotype_result(res, PhenotypeConfig(), images)
    assert ph.calibration == "fast" and len(ph.views) == 4
    rows = ph.rows
    # panicles 0 and 1 stand alone: every one of their 500 seeds, none of the distractors, in an odd frame for 0
    assert [r["seeds_in_view"] for r in rows[:2]] == [500, 500]
    assert rows[0]["view_frame"] % 2 == 1
    assert all(v.whole for v in ph.views)
    # the touching pair: each view holds its own 500 and at most what of the neighbour overlaps its outline
    assert all(500 <= r["seeds_in_view"] < 1000 for r in rows[2:])
    # the count follows the calibration: log N = a + b log(seeds_in_view)
    cal = ph.cal
    n = np.exp(cal["intercept"] + cal["coef"]["seeds_in_view"] * np.log(500))
    assert rows[0]["seeds_est"] == pytest.approx(n)
    # a stride of 2 frames only looks at every other whole view
    assert phenotype_result(res, PhenotypeConfig(view_stride=2), images).rows[0]["seeds_in_view"] in (250, 500)


def test_write_phenotype_writes_the_table_summary_and_thumbnails(tmp_path):
    res = write_result(tmp_path / "r", stray=False)
    rec = _seeds_in_frames(res, hide_even=None)
    idx, ts = rec.timestamps()
    img = np.full((900, 1200, 3), 40, np.uint8)
    images = Images(CALIB, idx, ts, rec, lambda f: img)
    ph = phenotype_result(res, PhenotypeConfig(), images)
    out = tmp_path / "o"
    out.mkdir()
    write_phenotype(out, ph, images, [("A", 0.0, 1.0)], dataset="d")
    assert (out / "panicles.csv").read_text().splitlines()[0] == ",".join(COLUMNS)
    s = json.loads((out / "panicles.json").read_text())
    assert s["panicles"] == 4 and s["count_from"] == "seeds_in_view" and s["dataset"] == "d"
    import cv2

    for i in range(4):
        t = cv2.imread(str(out / "thumbs" / f"panicle_{i:03d}.png"))
        assert t is not None and max(t.shape[:2]) <= 320 and t.mean() > 40  # outline and seeds drawn on it
    assert (out / "plots.csv").is_file()


def test_outline_margin_and_frame_lookup():
    square = outline_of(np.array([[0, 0], [100, 0], [100, 100], [0, 100], [50, 50]], float))
    assert len(square) == 4
    e = np.array([[50, 50, 8, 8], [107, 50, 8, 8], [110, 50, 8, 8], [-5, -5, 8, 8]], np.float32)
    # inside, or within two median seed radii (8 px) of the outline
    assert seeds_inside(e, square).tolist() == [[50, 50], [107, 50], [-5, -5]]
    from seedmap.records import Trajectory

    traj = Trajectory(np.array([0.19, 0.41, 1.0]), np.tile(np.eye(4), (3, 1, 1)))
    assert frames_of_poses(traj, np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])).tolist() == [1, 2, 5]


def test_calibration_is_fitted_from_hand_counts(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(0)
    lines = ["panicle_id,seeds_in_view,landmarks,quality,seeds_counted"]
    for i in range(30):
        v = int(rng.integers(300, 1500))
        counted = "" if i % 3 == 0 else f"{3.0 * v ** 0.9:.1f}"  # a third not counted
        lines.append(f"{i},{v},{v},{'ok' if i != 1 else 'cut'},{counted}")
    table = tmp_path / "panicles.csv"
    table.write_text("\n".join(lines) + "\n")
    out = tmp_path / "cal.json"
    assert run_cli(["train", "phenotype-calibration", table, "--out", out], monkeypatch) == 0
    cal = json.loads(out.read_text())
    assert cal["panicles"] == 19  # 20 counted, one of them cut
    assert cal["coef"]["seeds_in_view"] == pytest.approx(0.9, abs=1e-3)
    assert cal["intercept"] == pytest.approx(np.log(3.0), abs=1e-2) and cal["loo_mape"] < 1e-3
    # used by the table
    res = write_result(tmp_path / "r", stray=False)
    rec = _seeds_in_frames(res, hide_even=None)
    idx, ts = rec.timestamps()
    images = Images(CALIB, idx, ts, rec, lambda f: np.zeros((900, 1200, 3), np.uint8))
    ph = phenotype_result(res, PhenotypeConfig(calibration=str(out)), images)
    assert ph.rows[0]["seeds_est"] == pytest.approx(3.0 * 500 ** 0.9, rel=1e-3)
    # errors: one line, exit 2, nothing written
    capsys.readouterr()
    (tmp_path / "bad.csv").write_text("panicle_id,quality\n0,ok\n")
    for args in (["train", "phenotype-calibration", tmp_path / "bad.csv", "--out", tmp_path / "c2.json"],
                 ["train", "phenotype-calibration", table, "--out", tmp_path / "c3.json", "--features", "leaves"],
                 ["train", "phenotype-calibration", table, "--out", table.with_suffix(".json"), "--features",
                  "seeds_in_view,landmarks,length_m,width_m"]):
        assert run_cli(args, monkeypatch) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "c2.json").exists() and not (tmp_path / "c3.json").exists()
    assert len(PANICLES) == 4
