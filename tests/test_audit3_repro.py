"""Reproducers left by the session-8 audits, fixed in session 9."""

from __future__ import annotations

import json

import cv2
import numpy as np
import yaml

from cli_run import run_cli  # tests/ is on sys.path (pytest rootdir import mode)


def _record(box, ellipse):
    return {"frame": 0, "camera": "left", "image": "left/000000.png", "width": 100, "height": 80,
            "boxes": [box], "scores": [0.9], "ellipses": [ellipse], "seed_ids": [-1]}


def test_coco_segmentation_lies_inside_its_bbox_and_area_fits():
    from seedmap.detect.io import coco_from_records

    # an ellipse (full axes 16 x 6 px) that sticks out of a 10 x 8 box on the right, and one well inside its box
    out, inside = coco_from_records([_record([40.0, 30.0, 50.0, 38.0], [47.0, 34.0, 16.0, 6.0, 0.0]),
                                     _record([10.0, 10.0, 30.0, 30.0], [20.0, 20.0, 8.0, 4.0, 30.0])])["annotations"]
    x, y, w, h = out["bbox"]
    poly = np.asarray(out["segmentation"][0]).reshape(-1, 2)
    assert poly[:, 0].min() >= x - 1e-3 and poly[:, 0].max() <= x + w + 1e-3
    assert poly[:, 1].min() >= y - 1e-3 and poly[:, 1].max() <= y + h + 1e-3
    assert out["area"] <= w * h
    # the clipped area is the part of the ellipse inside the box, measured independently on a 1/8-px raster
    s = 8
    full = np.zeros((80 * s, 100 * s), np.uint8)
    cv2.ellipse(full, ((47.5 * s, 34.5 * s), (16.0 * s, 6.0 * s), 0.0), 1, -1)
    box = np.zeros_like(full)
    box[int(30 * s):int(38 * s), int(40 * s):int(50 * s)] = 1
    raster = float((full & box).sum()) / s**2
    assert abs(out["area"] - raster) / raster < 0.06, (out["area"], raster)
    assert out["area"] < np.pi * 16 * 6 / 4 * 0.8  # clearly less than the whole ellipse
    # inside its box: the analytic ellipse area, as before
    assert inside["area"] == round(np.pi * 8 * 4 / 4, 2)
    assert out["ellipse"]["major"] == 16.0  # the ellipse itself is still reported whole


def test_detect_result_config_repeats_the_run(tiny_range, tmp_path, monkeypatch):
    first, again, plain = tmp_path / "first", tmp_path / "again", tmp_path / "plain"
    assert run_cli(["detect", tiny_range, "--detector", "fast-classic", "--out", first], monkeypatch) == 0
    cfg = yaml.safe_load((first / "config.yaml").read_text())
    assert cfg["detector"] == "fast-classic" and cfg["weights"] is None
    # the result's config alone repeats it (no --detector): same detections, byte for byte
    assert run_cli(["detect", tiny_range, "--config", first / "config.yaml", "--out", again], monkeypatch) == 0
    assert (again / "detections.jsonl").read_bytes() == (first / "detections.jsonl").read_bytes()
    # --detector overrides the config's
    over = tmp_path / "over"
    assert run_cli(["detect", tiny_range, "--config", first / "config.yaml", "--detector", "fast", "--out", over],
                   monkeypatch) == 0
    assert yaml.safe_load((over / "config.yaml").read_text())["detector"] == "fast"
    assert json.loads((over / "meta.json").read_text())["detector"] != "fast"  # fast = the CNN ("fast-cnn")
    # a config written before session 9 (no detector key) still loads; it means the default detector
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump({k: v for k, v in cfg.items() if k not in ("detector", "weights")}))
    assert run_cli(["detect", tiny_range, "--config", old, "--out", plain], monkeypatch) == 0
    assert yaml.safe_load((plain / "config.yaml").read_text())["detector"] == "fast"


def test_reconstruct_reads_a_plain_image_folder_with_joints_elsewhere(tmp_path, monkeypatch, capsys):
    """A user's arm scan as a generic stereo folder (images not named NNNNNN.png, joints and arm files kept
    elsewhere) reconstructs to the same result as the same scan in seedmap's layout."""
    import shutil

    data = tmp_path / "p3"
    assert run_cli(["simulate", "panicle", "--seed", "3", "--views", "4", "--out", data, "-q",
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
    assert run_cli(["reconstruct", data, "--out", tmp_path / "a", *common], monkeypatch) == 0
    # without the joints file: one line naming the missing file, nothing written
    capsys.readouterr()
    assert run_cli(["reconstruct", user, "--out", tmp_path / "b", *common], monkeypatch) == 2
    assert "joints.csv" in capsys.readouterr().err and not (tmp_path / "b").exists()
    assert run_cli(["reconstruct", user, "--out", tmp_path / "b", *common, "--set", f"joints={arm_dir / 'joints_rad.csv'}",
                    "--set", f"arm={arm_dir / 'ur5.yaml'}"], monkeypatch) == 0
    a = json.loads((tmp_path / "a" / "metrics.json").read_text())
    b = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert a["seed_count"] > 20 and b["seed_count"] == a["seed_count"]
    assert "gt" in a and "gt" not in b  # a user's folder has no ground truth
    assert (tmp_path / "a" / "seeds.csv").read_bytes() == (tmp_path / "b" / "seeds.csv").read_bytes()
    assert sorted(p.name for p in user.rglob("*")) == before  # the input is untouched
