"""Input validation at the boundary: text files decoded with a one-line error, numbers finite and in range,
timestamps matching the images, GT that does not overlap the timestamps, swapped stereo folders."""

from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest
import yaml

from seedmap.errors import InputError, SeedmapError
from seedmap.io.timestamps import read_times_txt
from seedmap.io.options import DatasetOptions
from seedmap.io.seedmap_dataset import DatasetWriter, SeedmapDataset, read_calib_yaml
from seedmap.io.stereo_order import check_stereo_order, negative_disparity_fraction
from seedmap.io.text import read_table, read_text
from seedmap.io.trajectory import gt_overlapping
from seedmap.records import StereoCalib, Trajectory

CALIB = StereoCalib(200.0, 200.0, 79.5, 59.5, 0.1, 160, 120)


def _textured_pair(disparity: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair of a random texture at one depth (constant positive disparity)."""
    rng = np.random.default_rng(0)
    base = (rng.random((30, 44)) * 255).astype(np.uint8)
    big = np.kron(base, np.ones((4, 4), np.uint8))[:, : 160 + disparity]
    left = np.repeat(big[:, :160, None], 3, axis=2)  # a point at u in the left image is at u - disparity right
    right = np.repeat(big[:, disparity:160 + disparity, None], 3, axis=2)
    return np.ascontiguousarray(left[:120]), np.ascontiguousarray(right[:120])


def _dataset(root, n=4, n_times=None):
    w = DatasetWriter(root)
    w.write_calib(CALIB)
    left, right = _textured_pair()
    for i in range(n):
        w.write_frame(i, left, right)
    w.write_times(np.arange(n if n_times is None else n_times) * 0.1)
    return root


# ---- text files ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("data", [bytes(range(256)) * 4, "fx: 1\n".encode("utf-16")])
def test_binary_or_utf16_text_is_one_line_input_error(tmp_path, data):
    p = tmp_path / "calib.yaml"
    p.write_bytes(data)
    for call in (lambda: read_text(p, "calibration file"), lambda: read_calib_yaml(p)):
        with pytest.raises(InputError, match="not UTF-8 text") as e:
            call()
        assert str(p) in str(e.value) and "\n" not in str(e.value)


def test_read_table_names_non_numbers_and_nan(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("a,b\n1,2\n3,x\n")
    with pytest.raises(InputError, match="numbers only"):
        read_table(p, "t.csv")
    p.write_text("a,b\n1,2\n3,nan\n")
    with pytest.raises(InputError, match="NaN or inf .data row 2"):
        read_table(p, "t.csv")
    assert np.isnan(read_table(p, "t.csv", finite=False)[1, 1])


# ---- numbers ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key,value,msg", [("fx", float("inf"), "finite"), ("cx", -5000.0, "principal point"),
                                           ("cy", float("nan"), "finite")])
def test_calibration_values_finite_and_principal_point_near_the_image(tmp_path, key, value, msg):
    p = tmp_path / "calib.yaml"
    d = {"seedmap_dataset": 1, **CALIB.to_dict(), key: value}
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=msg):
        read_calib_yaml(p)


def test_joints_and_arm_values_must_be_finite(tmp_path):
    from seedmap.sim.arm import fk_camera_poses, read_joints_csv

    p = tmp_path / "joints.csv"
    head = "view,t," + ",".join(f"cmd_{i}" for i in range(6)) + "," + ",".join(f"meas_{i}" for i in range(6))
    p.write_text(head + "\n0,0.0," + ",".join(["0.1"] * 12) + "\n")
    assert read_joints_csv(p)[1].shape == (1, 6)
    p.write_text(head + "\n0,0.0,nan," + ",".join(["0.1"] * 11) + "\n")  # a commanded angle: read, unused
    with pytest.raises(InputError, match="line 2: NaN or inf"):
        read_joints_csv(p)
    arm = {"dh": {"d": [float("nan")] + [0.1] * 5, "a": [0.0] * 6, "alpha": [0.0] * 6},
           "T_world_base": np.eye(4).tolist(), "T_flange_cam": np.eye(4).tolist()}
    with pytest.raises(InputError, match="dh.d has NaN or inf"):
        fk_camera_poses(np.zeros((1, 6)), arm)


@pytest.mark.parametrize("row,msg", [("r1,inf", "finite number > 0"), ("r1,-3", "finite number > 0"),
                                     ("r1,abc", "not a number")])
def test_counts_csv_counts_finite_and_positive(tmp_path, row, msg):
    from seedmap.recon.calibrate import read_true_counts

    p = tmp_path / "counts.csv"
    p.write_text(f"result,count\nr0,100\n{row}\n")
    with pytest.raises(InputError, match=msg):
        read_true_counts(p)
    p.write_bytes(b"\xff\xfe" + "result,count\n".encode("utf-16-le"))
    with pytest.raises(InputError, match="not UTF-8"):
        read_true_counts(p)


# ---- timestamps ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text,msg", [("", "empty"), ("0.0\nnan\n", "NaN or inf"), ("0.0\ninf\n", "NaN or inf"),
                                      ("0.2\n0.1\n", "strictly increasing"), ("0.1\n0.1\n", "strictly increasing")])
def test_times_txt_finite_increasing_non_empty(tmp_path, text, msg):
    p = tmp_path / "times.txt"
    p.write_text(text)
    with pytest.raises(InputError, match=msg):
        read_times_txt(p)


def test_times_txt_must_match_the_image_count(tmp_path):
    short = _dataset(tmp_path / "short", n=4, n_times=3)
    with pytest.raises(InputError, match="3 timestamps but left/ has 4 images") as e:
        SeedmapDataset(short)
    assert "times.txt" in str(e.value) and "allow_fewer_times" in str(e.value)
    assert len(DatasetOptions(allow_fewer_times=True).open(short)) == 3  # the explicit opt-in
    long = _dataset(tmp_path / "long", n=3, n_times=4)
    with pytest.raises(InputError, match="4 timestamps but left/ has only 3 images"):
        DatasetOptions(allow_fewer_times=True).open(long)  # more timestamps than images is never allowed
    assert len(SeedmapDataset(_dataset(tmp_path / "ok", n=3))) == 3


def test_gt_not_overlapping_the_timestamps_is_a_warning(caplog):
    gt = Trajectory(np.arange(5) * 0.1, np.tile(np.eye(4), (5, 1, 1)))
    assert gt_overlapping(np.arange(5) * 0.1 + 0.05, gt, "ds") is gt
    with caplog.at_level(logging.WARNING, logger="seedmap.io"):
        assert gt_overlapping(np.arange(5) * 0.1 + 100.0, gt, "ds") is None
    assert len(caplog.records) == 1 and "do not overlap the ground-truth" in caplog.records[0].getMessage()


# ---- swapped stereo folders ------------------------------------------------------------------------------------


def test_swapped_stereo_pair_is_explained():
    left, right = _textured_pair()
    frac, n = negative_disparity_fraction(left, right)
    assert n >= 15 and frac < 0.2
    check_stereo_order(left, right, "ds")  # a good pair passes
    with pytest.raises(InputError, match="look swapped") as e:
        check_stereo_order(right, left, "ds")
    assert "left/" in str(e.value) and "right/" in str(e.value)


def test_swapped_folders_stop_slam_with_one_line(tmp_path):
    from seedmap.slam.pipeline import run_slam

    ds = _dataset(tmp_path / "ds")
    (ds / "left").rename(ds / "tmp")
    (ds / "right").rename(ds / "left")
    (ds / "tmp").rename(ds / "right")
    with pytest.raises(SeedmapError, match="swapped"):
        run_slam(ds, None, matcher="orb", progress=False, html_report=False)
    shutil.rmtree(ds)


# ---- command-line option ranges ----------------------------------------------------------------------------------


@pytest.mark.parametrize("argv,option", [
    (["eval", "associate", "DS", "--max-frames", "0"], "--max-frames"),
    (["eval", "detect", "DS", "DET", "--min-gt-area", "-5"], "--min-gt-area"),
    (["train", "fast-cnn", "DS", "--out", "OUT", "--steps", "0"], "--steps"),
    (["train", "fast-cnn", "DS", "--out", "OUT", "--batch", "0"], "--batch"),
    (["train", "fast-cnn", "DS", "--out", "OUT", "--crop", "0"], "--crop"),
    (["train", "fast-cnn", "DS", "--out", "OUT", "--lr", "nan"], "--lr"),
    (["train", "cnn-refiner", "DS", "--out", "OUT", "--steps", "0"], "--steps"),
    (["train", "cnn-refiner", "DS", "--out", "OUT", "--candidates", "2"], "--candidates"),
])
def test_option_out_of_range_is_one_line_error(tmp_path, monkeypatch, capsys, argv, option):
    import sys

    from seedmap import cli

    if argv[0] == "train":
        pytest.importorskip("torch")
    argv = [str(tmp_path / a) if a in ("DS", "DET", "OUT") else a for a in argv]
    monkeypatch.setattr(sys, "argv", ["seedmap", *argv])
    with pytest.raises(SystemExit) as e:
        cli.main()
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert e.value.code == 2 and len(err) == 1 and err[0].startswith("error: ") and option in err[0]
    assert not (tmp_path / "OUT").exists()
