"""A user's own arm scan (images + calib.yaml + times.txt + joints.csv + arm.yaml, no gt/) through
`seedmap reconstruct` and `seedmap count`: the recount of an unchanged reconstruction gives its count (the
stored detections keep full precision), bad scans are one line, other image layouts read alike.
"""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
import yaml

from helpers.cli import run_cli as _run, run_cli_ok


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.replace("\r", "\n")
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ") or "Traceback" in ln]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture(scope="module")
def user_scan(tmp_path_factory):
    """A 6-view simulated scan with gt/ removed: what a user's own arm writes."""
    from seedmap.config import load_config
    from seedmap.sim.panicle_scan import PanicleScanConfig, simulate_panicle

    root = tmp_path_factory.mktemp("arm")
    cfg = load_config(PanicleScanConfig, None, ["seed=7", "arm.views=6"])
    sim = simulate_panicle(cfg, root / "sim", overwrite=False, progress=False)
    user = root / "user"
    shutil.copytree(sim, user, ignore=shutil.ignore_patterns("gt"))
    return user


@pytest.fixture(scope="module")
def user_result(user_scan, tmp_path_factory):
    out = tmp_path_factory.mktemp("arm_res") / "rec"
    run_cli_ok(["reconstruct", user_scan, "--detector", "fast", "-q", "--out", out])
    return out


def test_user_scan_without_gt_gives_cloud_count_and_quality(user_result):
    import open3d as o3d
    from evo.tools import file_interface

    m = json.loads((user_result / "metrics.json").read_text())
    assert "gt" not in m and m["oracle_detector"] is False and m["skipped_views"] == []
    assert m["registered_views"] == 5 and m["seed_count"] > 100
    assert 0 < m["quality"]["cross_view_seed_mm"] < 3.0
    head = (user_result / "cloud.ply").read_bytes().split(b"end_header")[0].decode()
    assert "property int seed_label" in head and "property uchar red" in head
    pc = o3d.t.io.read_point_cloud(str(user_result / "cloud.ply"))
    assert len(pc.point.positions) == m["cloud_points"]
    lab = pc.point.seed_label.numpy().ravel()
    assert lab.min() >= -1 and 0 < lab.max() < m["seed_count"]
    seeds = np.loadtxt(user_result / "seeds.csv", delimiter=",", skiprows=1, ndmin=2)
    assert (user_result / "seeds.csv").read_text().splitlines()[0] == "seed,x,y,z,diameter_m,n_views,spread_m"
    assert len(seeds) == m["seed_count"] and np.array_equal(seeds[:, 0], np.arange(len(seeds)))
    # seeds are 3-5 mm grains on a panicle within ~0.1 m of its axis
    assert 0.002 < np.median(seeds[:, 4]) < 0.006 and np.all(seeds[:, 5] >= 2)
    traj = file_interface.read_tum_trajectory_file(str(user_result / "poses_tum.txt"))
    assert traj.num_poses == 6


def test_count_repeats_the_reconstructions_count_and_config_repeats_it(user_scan, user_result, tmp_path,
                                                                       monkeypatch):
    m = json.loads((user_result / "metrics.json").read_text())
    cnt = tmp_path / "cnt"
    assert _run(["count", user_result, "--out", cnt], monkeypatch) == 0
    c = json.loads((cnt / "count.json").read_text())
    assert c["seed_count"] == m["seed_count"]  # detections.csv keeps full precision
    # the same seeds (their order may differ where the stored poses' 1e-9 rounding breaks a tie)
    from scipy.spatial import cKDTree

    a = np.loadtxt(user_result / "seeds.csv", delimiter=",", skiprows=1, ndmin=2)
    b = np.loadtxt(cnt / "seeds.csv", delimiter=",", skiprows=1, ndmin=2)
    dist, nn = cKDTree(a[:, 1:4]).query(b[:, 1:4])
    assert dist.max() < 1e-6 and len(np.unique(nn)) == len(a)
    assert np.array_equal(a[nn, 5], b[:, 5])  # views per seed
    again = tmp_path / "again"
    assert _run(["reconstruct", user_scan, "--config", user_result / "config.yaml", "-q", "--out", again],
                monkeypatch) == 0
    for f in ("poses_tum.txt", "seeds.csv", "detections.csv", "cloud.ply", "config.yaml"):
        assert (again / f).read_bytes() == (user_result / f).read_bytes(), f
    assert yaml.safe_load((user_result / "config.yaml").read_text())["detector"] == "fast"


def test_all_black_views_are_recorded_skips(user_scan, tmp_path, monkeypatch, capsys):
    scan = tmp_path / "black"
    shutil.copytree(user_scan, scan)
    h, w = cv2.imread(str(scan / "left" / "000000.png")).shape[:2]
    for cam in ("left", "right"):
        for i in (1, 3):
            cv2.imwrite(str(scan / cam / f"{i:06d}.png"), np.zeros((h, w, 3), np.uint8))
    out = tmp_path / "rec"
    assert _run(["reconstruct", scan, "--detector", "fast", "-q", "--out", out], monkeypatch) == 0
    capsys.readouterr()
    m = json.loads((out / "metrics.json").read_text())
    assert [s["view"] for s in m["skipped_views"]] == [1, 3]
    assert all("valid 3D points" in s["reason"] for s in m["skipped_views"])
    assert m["registered_views"] == 3 and m["seed_count"] > 50
    for cam in ("left", "right"):
        for i in range(6):
            cv2.imwrite(str(scan / cam / f"{i:06d}.png"), np.zeros((h, w, 3), np.uint8))
    assert _run(["reconstruct", scan, "--detector", "fast", "-q", "--out", tmp_path / "none"], monkeypatch) == 2
    assert "no view has valid disparity" in _error_line(capsys)


@pytest.mark.parametrize("case, needle", [
    ("no_arm_yaml", "arm description not found"),
    ("short_joints", "joints file has 5 rows"),
    ("unordered_joints", "line 3 has view 2 (expected 1)"),
    ("gt_oracle", "no ground-truth instances"),
])
def test_bad_user_scan_is_one_line(user_scan, tmp_path, monkeypatch, capsys, case, needle):
    scan = tmp_path / "scan"
    shutil.copytree(user_scan, scan)
    jp = scan / "joints.csv"
    lines = jp.read_text().splitlines()
    det = ["--detector", "fast"]
    if case == "no_arm_yaml":
        (scan / "arm.yaml").unlink()
    elif case == "short_joints":
        jp.write_text("\n".join(lines[:-1]) + "\n")
    elif case == "unordered_joints":
        lines[2], lines[3] = lines[3], lines[2]
        jp.write_text("\n".join(lines) + "\n")
    elif case == "gt_oracle":
        det = ["--detector", "gt"]
    out = tmp_path / "out"
    assert _run(["reconstruct", scan, *det, "-q", "--out", out], monkeypatch) == 2
    line = _error_line(capsys)
    assert needle in line, line
    assert not out.exists()


def test_jpeg_user_scan_reconstructs(user_scan, user_result, tmp_path, monkeypatch):
    """JPEG images (not seedmap's NNNNNN.png layout) are read by the image-folder loader."""
    scan = tmp_path / "scan"
    shutil.copytree(user_scan, scan)
    for f in sorted(scan.glob("*/*.png")):
        cv2.imwrite(str(f.with_suffix(".jpg")), cv2.imread(str(f)), [cv2.IMWRITE_JPEG_QUALITY, 95])
        f.unlink()
    out = tmp_path / "out"
    assert _run(["reconstruct", scan, "--detector", "fast", "-q", "--out", out], monkeypatch) == 0
    m = json.loads((out / "metrics.json").read_text())
    png = json.loads((user_result / "metrics.json").read_text())
    assert m["views"] == 6 and not m["skipped_views"] and m["registered_views"] == png["registered_views"]
    assert abs(m["seed_count"] - png["seed_count"]) <= 0.05 * png["seed_count"], (m["seed_count"], png["seed_count"])


def test_simulate_panicle_repeats_from_scan_yaml_and_names_it_for_config_yaml(tmp_path, monkeypatch, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _run(["simulate", "panicle", "--seed", "8", "--views", "3", "-q", "--out", a], monkeypatch) == 0
    assert _run(["simulate", "panicle", "-q", "--config", a / "gt" / "scan.yaml", "--out", b], monkeypatch) == 0
    for rel in ("joints.csv", "arm.yaml", "left/000002.png", "right/000001.png", "gt/seeds.csv"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    capsys.readouterr()
    # gt/config.yaml is the scene's config: the error names the scan.yaml beside it
    assert _run(["simulate", "panicle", "-q", "--config", a / "gt" / "config.yaml", "--out", tmp_path / "c"],
                monkeypatch) == 2
    line = _error_line(capsys)
    assert str(a / "gt" / "scan.yaml") in line and str(a / "gt" / "config.yaml") in line


def test_reconstruct_reads_a_plain_image_folder_with_joints_elsewhere(tmp_path, monkeypatch, capsys):
    """A user's arm scan as a generic stereo folder (images not named NNNNNN.png, joints and arm files kept
    elsewhere) reconstructs to the same result as the same scan in seedmap's layout."""
    data = tmp_path / "p3"
    assert _run(["simulate", "panicle", "--seed", "3", "--views", "4", "--out", data, "-q",
                 "--set", "sim.camera.scale=0.18"], monkeypatch) == 0
    user, arm_dir = tmp_path / "user_scan", tmp_path / "robot"
    for cam in ("left", "right"):
        (user / cam).mkdir(parents=True)
        for k, f in enumerate(sorted((data / cam).glob("*.png"))):
            shutil.copy(f, user / cam / f"view_{k:02d}.png")
    shutil.copy(data / "calib.yaml", user / "calib.yaml")
    shutil.copy(data / "times.txt", user / "times.txt")
    arm_dir.mkdir()
    shutil.copy(data / "joints.csv", arm_dir / "joints_rad.csv")
    shutil.copy(data / "arm.yaml", arm_dir / "ur5.yaml")
    before = sorted(p.name for p in user.rglob("*"))

    common = ["--register", "seeds", "--detector", "fast", "-q"]
    assert _run(["reconstruct", data, "--out", tmp_path / "a", *common], monkeypatch) == 0
    # without the joints file: one line naming the missing file, nothing written
    capsys.readouterr()
    assert _run(["reconstruct", user, "--out", tmp_path / "b", *common], monkeypatch) == 2
    assert "joints.csv" in capsys.readouterr().err and not (tmp_path / "b").exists()
    assert _run(["reconstruct", user, "--out", tmp_path / "b", *common, "--set", f"joints={arm_dir / 'joints_rad.csv'}",
                 "--set", f"arm={arm_dir / 'ur5.yaml'}"], monkeypatch) == 0
    a = json.loads((tmp_path / "a" / "metrics.json").read_text())
    b = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert a["seed_count"] > 20 and b["seed_count"] == a["seed_count"]
    assert "gt" in a and "gt" not in b  # a user's folder has no ground truth
    assert (tmp_path / "a" / "seeds.csv").read_bytes() == (tmp_path / "b" / "seeds.csv").read_bytes()
    assert sorted(p.name for p in user.rglob("*")) == before  # the input is untouched
