"""Bad inputs and real data give one line and exit code 2, never a traceback.

Each test runs a command on an input a user may give and checks the one line it prints.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seedmap.errors import ConfigError, InputError

from helpers.cli import run_cli as _run
from helpers.datasets import tiny_stereo_dataset

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
EUROC = REAL / "euroc_v101_micro_stereo"


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("warning: ")]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    return lines[0]


_tiny_dataset = tiny_stereo_dataset


# ---- output location the file system refuses (os.access() says yes to root) -------------------------------------

@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc (a folder nobody can create in)")
def test_uncreatable_output_folder_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    # not a FileNotFoundError traceback from tempfile.mkdtemp
    from seedmap.io.atomic import atomic_write_text
    from seedmap.outputs import output_dir

    ds = _tiny_dataset(tmp_path / "ds")
    out = Path("/proc/seedmap-out")
    assert _run(["slam", ds, "--matcher", "orb", "-q", "--out", out], monkeypatch) == 2
    assert str(out) in _one_error_line(capsys.readouterr().err)
    with pytest.raises(InputError, match="cannot"):
        with output_dir(out, "slam"):
            pass
    with pytest.raises(InputError, match="cannot write here"):
        atomic_write_text(out / "metrics.json", "{}")
    assert not out.exists()


# ---- config keys ------------------------------------------------------------------------------------------------

def test_unknown_config_key_names_the_closest_key(tmp_path, monkeypatch, capsys):
    # not pydantic's "invalid config value 'gate': Extra inputs are not permitted"
    from seedmap.config import load_config
    from seedmap.slam.config import SlamConfig

    with pytest.raises(ConfigError, match=r"unknown config key 'gate' \(did you mean 'gates'\?\)"):
        load_config(SlamConfig, None, ["gate.stereo_max_dy_px=3"])
    with pytest.raises(ConfigError, match=r"did you mean 'gates.stereo_max_dy_px'\?"):
        load_config(SlamConfig, None, ["gates.stereo_max_dy_pxx=3"])
    with pytest.raises(ConfigError, match=r"unknown config key 'gates.zzz' \(gates has: .*travel_sign\)"):
        load_config(SlamConfig, None, ["gates.zzz=1"])
    with pytest.raises(ConfigError, match="invalid config value 'gates.stereo_max_dy_px'"):  # wrong type: unchanged
        load_config(SlamConfig, None, ["gates.stereo_max_dy_px=abc"])
    yml = tmp_path / "c.yaml"
    yml.write_text("backend:\n  stereo_sigma_pxx: 2\n")
    ds = _tiny_dataset(tmp_path / "ds")
    assert _run(["slam", ds, "--matcher", "orb", "-q", "--out", tmp_path / "r", "--config", yml], monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert str(yml) in line and "backend.stereo_sigma_px" in line
    assert not (tmp_path / "r").exists()


# ---- real data where seedmap's own (simulated, with GT) layout is needed ---------------------------------------

def test_seedmap_reader_names_the_format_it_was_given(tmp_path, monkeypatch, capsys):
    # not "<folder>/calib.yaml: calibration file not found" for a folder that has its calibration
    from seedmap.io import detect_format
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = _tiny_dataset(tmp_path / "ds")
    folder = tmp_path / "folder"
    folder.mkdir()
    (ds / "left").rename(folder / "cam0")
    (ds / "right").rename(folder / "cam1")
    (ds / "calib.yaml").rename(folder / "calibration.yaml")
    assert detect_format(folder) == "folder"
    with pytest.raises(InputError, match="this is a folder dataset"):
        SeedmapDataset(folder)
    assert _run(["eval", "associate", folder], monkeypatch) == 2
    assert "folder dataset" in _one_error_line(capsys.readouterr().err)
    with pytest.raises(InputError, match="dataset folder not found"):
        SeedmapDataset(tmp_path / "missing")


@pytest.mark.skipif(not EUROC.is_dir(), reason="needs ../shared/realdata")
def test_slam_with_the_oracle_on_recorded_data_says_why(tmp_path, monkeypatch, capsys):
    # the gt oracle on recorded data: the error says why, not "calib.yaml not found"
    assert _run(["slam", EUROC, "-q", "--detector", "gt", "--out", tmp_path / "r"], monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "euroc dataset" in line and "--detector fast" in line
    assert not (tmp_path / "r").exists()


# ---- --weights with a detector that does not read it -------------------------------------------------------------

@pytest.mark.parametrize("detector", ["gt"])
def test_weights_for_a_detector_that_ignores_them(tmp_path, monkeypatch, capsys, detector):
    # not exit 0 with the user's weights silently unused (fast runs the shipped CNN)
    ds = _tiny_dataset(tmp_path / "ds")
    w = tmp_path / "mine.onnx"
    w.write_bytes(b"not a network")
    assert _run(["detect", ds, "--detector", detector, "--weights", w, "--out", tmp_path / "d"], monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--weights" in line and str(w) in line
    assert not (tmp_path / "d").exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc (a folder nobody can create in)")
def test_rerun_recording_in_an_uncreatable_folder(tmp_path, monkeypatch, capsys):
    # `seedmap slam DS --rerun /proc/x/run.rrd`: one line before any work, not a traceback after it
    from seedmap.viz.rerun_log import RerunLogger

    with pytest.raises(InputError, match="cannot (create|write) the rerun recording here"):
        RerunLogger(Path("/proc/seedmap-x/run.rrd"))
    ds = _tiny_dataset(tmp_path / "ds")
    assert _run(["slam", ds, "--matcher", "orb", "-q", "--out", tmp_path / "r", "--rerun", "/proc/seedmap-x/r.rrd"],
                monkeypatch) == 2
    assert "/proc/seedmap-x/r.rrd" in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "r").exists()
    # reconstruct records after writing its results: the path is now checked before any work
    assert _run(["reconstruct", ds, "-q", "--out", tmp_path / "rec", "--rerun", "/proc/seedmap-x/r.rrd"],
                monkeypatch) == 2
    assert "rerun recording" in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "rec").exists()


# ---- loader hints name options the commands have ------------------------------------------------------------------

def test_loader_hints_name_real_options_and_the_bag(tmp_path, monkeypatch, capsys):
    # the hints name options `seedmap slam` has; a swapped-camera error names the bag, not only
    # "/stereo/left/camera_info" (Path(bag) / "/topic" drops the bag)
    from helpers.bags import write_bag

    from seedmap.config import load_config
    from seedmap.io.options import DatasetOptions
    from seedmap.io.rosbag import RosbagSequence

    bag = write_bag(tmp_path / "x.bag", "ros1", n=2)
    with pytest.raises(InputError, match=rf"^{tmp_path}/x.bag:/stereo/left/camera_info: .*swapped"):
        RosbagSequence(bag, left_topic="/stereo/right/image_rect", right_topic="/stereo/left/image_rect")
    nocal = write_bag(tmp_path / "n.bag", "ros1", n=2, info=False, topics=("/a/img", "/b/img"))
    with pytest.raises(InputError, match=r"dataset.left_topic=.*dataset.right_topic="):
        RosbagSequence(nocal)
    with pytest.raises(InputError, match=r"--set dataset.calib=FILE"):
        RosbagSequence(nocal, left_topic="/a/img", right_topic="/b/img")
    for bad in ("sync_tol_s=-1", "fps=0"):
        with pytest.raises(ConfigError, match=bad.split("=")[0]):
            load_config(DatasetOptions, None, [bad])
    ds = _tiny_dataset(tmp_path / "ds")
    (ds / "times.txt").unlink()
    (ds / "calib.yaml").unlink()  # a plain left/ + right/ folder without calibration
    assert _run(["slam", ds, "--matcher", "orb", "-q", "--out", tmp_path / "r"], monkeypatch) == 2
    assert "--set dataset.calib=FILE" in _one_error_line(capsys.readouterr().err)
    assert _run(["slam", bag, "--matcher", "orb", "-q", "--out", tmp_path / "r", "--set", "dataset.sync_tol_s=-1"],
                monkeypatch) == 2
    assert "dataset.sync_tol_s" in _one_error_line(capsys.readouterr().err)


# ---- loader warnings reach the user ------------------------------------------------------------------------------

def test_loader_warnings_are_printed_by_the_commands(tmp_path, monkeypatch, capsys):
    # grey images converted, timestamps made up from fps, a millimetre baseline: the loaders record them in
    # seq.warnings, and every command prints them (once each), not only `bag-info --sequence`
    import cv2

    ds = _tiny_dataset(tmp_path / "ds", n=2)
    (ds / "times.txt").unlink()  # now a plain folder dataset (calib.yaml found by the folder loader)
    for p in sorted((ds / "left").glob("*.png")) + sorted((ds / "right").glob("*.png")):
        cv2.imwrite(str(p), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
    assert _run(["detect", ds, "--detector", "fast", "--out", tmp_path / "d"], monkeypatch) == 0
    err = [ln[ln.index("warning: "):] for ln in capsys.readouterr().err.splitlines() if "warning: " in ln]
    assert any("grayscale images converted" in ln and str(ds) in ln for ln in err), err
    assert any("timestamps are frame index / 5 Hz" in ln for ln in err), err
    assert len(err) == 2  # each once, not once per frame
    from seedmap.io import open_dataset

    seq = open_dataset(ds)
    assert any("frame index" in w for w in seq.warnings)  # the list API is unchanged


# ---- messages about real layouts ----------------------------------------------------------------------------------

def _kitti(root: Path, p3_tx: float) -> Path:
    """A KITTI odometry folder (image_2/ + image_3/, calib.txt P0..P3, times.txt) of two textured frames."""
    import cv2

    ds = _tiny_dataset(root.with_name(root.name + "_src"))
    for cam, kd in (("left", "image_2"), ("right", "image_3")):
        (root / kd).mkdir(parents=True)
        for p in sorted((ds / cam).glob("*.png")):
            cv2.imwrite(str(root / kd / p.name), cv2.imread(str(p)))
    P = "120 0 80 {} 0 120 60 0 0 0 1 0"
    rows = ((0, 0), (1, p3_tx), (2, 0), (3, p3_tx))
    (root / "calib.txt").write_text("".join(f"P{k}: {P.format(t)}\n" for k, t in rows))
    (root / "times.txt").write_text("0.0\n0.1\n")
    return root


def test_real_layout_messages(tmp_path, monkeypatch, capfd):
    from seedmap.io import open_dataset
    from seedmap.io.timestamps import check_timestamps

    # KITTI: a right projection with +fx*b said "P2[0,3] = 12" (P2 is KITTI's LEFT colour camera) and a zero
    # baseline is not blamed on swapped cameras
    with pytest.raises(InputError, match=r"-0.1 m \(right camera's projection P\[0,3\] - left's = 12;.*swapped"):
        open_dataset(_kitti(tmp_path / "pos", 12.0))
    with pytest.raises(InputError, match=r"baseline is 0 m .*has no baseline term"):
        open_dataset(_kitti(tmp_path / "zero", 0.0))
    assert open_dataset(_kitti(tmp_path / "ok", -12.0)).calib.baseline == pytest.approx(0.1)
    # near misses said only "no loader recognises this path"
    (tmp_path / "ok" / "calib.txt").unlink()
    with pytest.raises(InputError, match="KITTI image folders but no calib.txt"):
        open_dataset(tmp_path / "ok")
    (tmp_path / "e" / "mav0" / "cam0").mkdir(parents=True)
    with pytest.raises(InputError, match=r"mav0/ \(EuRoC\) but no mav0/cam0/data.csv"):
        open_dataset(tmp_path / "e")
    (tmp_path / "e" / "mav0" / "cam0" / "data.csv").write_text("#timestamp,filename\n")
    with pytest.raises(InputError, match="no mav0/cam1"):
        open_dataset(tmp_path / "e")
    (tmp_path / "f" / "left").mkdir(parents=True)
    with pytest.raises(InputError, match="one camera folder but not the other"):
        open_dataset(tmp_path / "f")
    # numpy 2 printed "entry 2: np.float64(0.1) after np.float64(0.2)"
    with pytest.raises(InputError, match=r"entry 2: 0.1 after 0.2\)"):
        check_timestamps(np.array([0.0, 0.2, 0.1]), "times.txt")
    # a corrupt PNG: OpenCV's own "[ERROR:0@0.4] global grfmt_png.cpp ..." lines came before ours
    ds = _tiny_dataset(tmp_path / "ds")
    (ds / "left" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 100)
    capfd.readouterr()
    assert _run(["slam", ds, "--matcher", "orb", "-q", "--out", tmp_path / "r"], monkeypatch) == 2
    err = capfd.readouterr().err
    assert "not a readable image" in _one_error_line(err) and "grfmt_png" not in err


# ---- evaluation commands given the wrong pair of folders ---------------------------------------------------------

def test_eval_and_count_refuse_mismatched_folders(tmp_path, monkeypatch, capsys):
    from seedmap.io.seedmap_dataset import DatasetWriter
    from seedmap.io.trajectory import write_tum
    from seedmap.records import Trajectory

    ds = _tiny_dataset(tmp_path / "ds", n=3)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 0.04, 0.08]
    DatasetWriter(ds).write_gt_poses(Trajectory(np.arange(3) * 0.2, poses))
    res = tmp_path / "res"
    res.mkdir()
    # a result of another recording (times 100 s on): `seedmap eval slam` paired poses by nearest time, exit 0
    write_tum(res / "trajectory.tum", Trajectory(100.0 + np.arange(3) * 0.2, poses))
    assert _run(["eval", "slam", res, ds], monkeypatch) == 2
    assert "3 of the 3 poses" in _one_error_line(capsys.readouterr().err)
    write_tum(res / "trajectory.tum", Trajectory(np.arange(3) * 0.2, poses))  # the right dataset still evaluates
    assert _run(["eval", "slam", res, ds], monkeypatch) == 0
    capsys.readouterr()
    # `seedmap count` on a SLAM result said "config.yaml: unknown config key 'gates'"
    (res / "config.yaml").write_text("seed: 0\ngates:\n  travel_sign: -1\n")
    assert _run(["count", res], monkeypatch) == 2
    assert "`seedmap slam` result folder" in _one_error_line(capsys.readouterr().err)
    # --iou 2 scored every detection a miss, exit 0
    assert _run(["eval", "detect", ds, res, "--iou", "2"], monkeypatch) == 2
    assert "--iou" in _one_error_line(capsys.readouterr().err)


def test_union_config_value_says_what_each_member_accepts():
    # `seedmap simulate panicle --exposure abc`: the key path without pydantic's union tag
    # ("exposure.literal['auto']") and both alternatives ('auto' or a number) named
    from seedmap.config import load_config
    from seedmap.sim.panicle_scan import PanicleScanConfig

    with pytest.raises(ConfigError, match=r"'exposure' \(got 'abc'\): Input should be 'auto' or .*valid number") as e:
        load_config(PanicleScanConfig, None, ["exposure=abc"])
    assert "literal" not in str(e.value)
    assert load_config(PanicleScanConfig, None, ["exposure=0.5"]).exposure == 0.5


# ---- the demo never replaces a folder that is not its own --------------------------------------------------------

def test_demo_refuses_to_replace_foreign_folders(tmp_path, monkeypatch, capsys):
    # `seedmap demo --data MY_EUROC_FOLDER` must not delete the folder to simulate a range in its place
    # (overwrite=True), nor --out replace any folder with a SLAM result
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "keep.txt").write_text("precious")
    ds = _tiny_dataset(tmp_path / "ds")
    assert _run(["demo", "--data", mine, "--out", tmp_path / "r"], monkeypatch) == 2
    assert "not a seedmap dataset" in _one_error_line(capsys.readouterr().err)
    assert _run(["demo", "--data", ds, "--out", mine], monkeypatch) == 2
    assert "not a seedmap slam result" in _one_error_line(capsys.readouterr().err)
    assert (mine / "keep.txt").read_text() == "precious" and sorted(p.name for p in mine.iterdir()) == ["keep.txt"]
    assert not (tmp_path / "r").exists()


def test_overwrite_never_replaces_recorded_data(tmp_path, monkeypatch, capsys):
    # `seedmap detect DATA --out DATA --overwrite` must not delete the dataset to put the detections in its place
    from seedmap.outputs import MARKER, output_dir

    data = _kitti(tmp_path / "kitti", -12.0)
    files = sorted(p.relative_to(data) for p in data.rglob("*"))
    for args in (["detect", data, "--detector", "fast"], ["slam", data, "--matcher", "orb", "-q"]):
        assert _run([*args, "--out", data, "--overwrite"], monkeypatch) == 2
        assert "is an input of this command" in _one_error_line(capsys.readouterr().err)
    assert sorted(p.relative_to(data) for p in data.rglob("*")) == files
    # `--out PARENT --overwrite` with the input inside PARENT
    assert _run(["slam", data, "--matcher", "orb", "-q", "--out", tmp_path, "--overwrite"], monkeypatch) == 2
    assert "contains the input" in _one_error_line(capsys.readouterr().err)
    assert sorted(p.relative_to(data) for p in data.rglob("*")) == files
    sim = _tiny_dataset(tmp_path / "sim")  # a seedmap layout without gt/config.yaml: someone's own recording
    with pytest.raises(InputError, match="not a folder seedmap wrote"):
        with output_dir(sim, "dataset", overwrite=True):
            pass
    (sim / "gt").mkdir()
    (sim / "gt" / "config.yaml").write_text("seed: 0\n")  # what `seedmap simulate` writes: it may re-render it
    with output_dir(sim, "dataset", overwrite=True) as tmp:
        (tmp / "x.txt").write_text("x")
    assert sorted(p.name for p in sim.iterdir()) == [MARKER, "x.txt"]


@pytest.mark.skipif(not EUROC.is_dir(), reason="needs ../shared/realdata")
def test_millimetre_baseline_warned_for_euroc_too(tmp_path):
    # the "is the calibration in millimetres?" warning came from load_rig only: EuRoC sensor.yaml pairs and bag
    # CameraInfo with a 49.6 m baseline ran silently
    import shutil

    from seedmap.io import open_dataset

    src, dst = EUROC / "mav0", tmp_path / "mav0"
    for cam in ("cam0", "cam1"):
        (dst / cam / "data").mkdir(parents=True)
        rows = (src / cam / "data.csv").read_text().splitlines()[:3]  # header + 2 images
        (dst / cam / "data.csv").write_text("\n".join(rows) + "\n")
        for r in rows[1:]:
            shutil.copy(src / cam / "data" / r.split(",")[1].strip(), dst / cam / "data")
        text = (src / cam / "sensor.yaml").read_text()
        if cam == "cam1":  # the right camera's translation in millimetres
            text = text.replace("-0.0198435579556", "-19.8435579556").replace("0.0453689425024", "45.3689425024")
        (dst / cam / "sensor.yaml").write_text(text)
    assert not any("millimetres" in w for w in open_dataset(EUROC).warnings)
    seq = open_dataset(tmp_path)
    assert seq.rig.baseline > 40
    assert any("baseline is 49.57 m - is the calibration in millimetres" in w for w in seq.warnings)


def test_benchmark_run_says_when_runs_failed(tmp_path, monkeypatch, capsys, recwarn):
    # every run failing printed a table of "–" (like runs without GT), a matplotlib legend warning, and exit 0
    ds = _tiny_dataset(tmp_path / "broken", n=2)
    (ds / "left" / "000001.png").write_bytes(b"not a png")
    code = _run(["benchmark", "run", ds, "--out", tmp_path / "b", "--methods", "orb", "--workers", "1"], monkeypatch)
    assert code == 2
    err = capsys.readouterr().err
    line = _one_error_line(err)
    assert "1 of 1 runs failed" in line and "000001.png" in line
    assert (tmp_path / "b" / "results.csv").is_file()  # the record of what failed is kept
    assert not [w for w in recwarn if "legend" in str(w.message)] and "legend" not in err  # (CLI: a warning line)


def test_batch_where_every_range_failed_exits_2(tmp_path, monkeypatch, capsys):
    # failing ranges are recorded, not fatal - but a field where none ran exited 0
    field = tmp_path / "field"
    ds = _tiny_dataset(field / "r1", n=2)
    (ds / "left" / "000001.png").write_bytes(b"not a png")
    assert _run(["batch", field, "--out", tmp_path / "out", "--matcher", "orb", "-q"], monkeypatch) == 2
    assert "all 1 ranges failed" in _one_error_line(capsys.readouterr().err)
    assert (tmp_path / "out" / "summary.md").is_file()
    _tiny_dataset(field / "r2", n=2)  # one good range: the failure is recorded, exit 0
    assert _run(["batch", field, "--out", tmp_path / "out2", "--matcher", "orb", "-q"], monkeypatch) == 0
