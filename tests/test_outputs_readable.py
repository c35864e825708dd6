"""Result files are what the README's "Outputs" promises, readable by the tools users have (evo, Open3D,
COCO consumers), and a result's config.yaml passed back with --config repeats the run byte for byte (it
records the matcher and the detector too, so the run is not silently repeated with the gt oracle).
"""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
import yaml

from helpers.cli import run_cli as _run, run_cli_ok


@pytest.fixture(scope="module")
def slam_result(tiny_range, tmp_path_factory):
    out = tmp_path_factory.mktemp("slam") / "r"
    run_cli_ok(["slam", tiny_range, "--detector", "fast", "-q", "--out", out])
    return out


def test_slam_trajectories_read_by_evo_and_agree(slam_result):
    from evo.tools import file_interface

    tum = file_interface.read_tum_trajectory_file(str(slam_result / "trajectory.tum"))
    kitti = file_interface.read_kitti_poses_file(str(slam_result / "trajectory.kitti"))
    m = json.loads((slam_result / "metrics.json").read_text())
    assert tum.num_poses == kitti.num_poses == m["frames_tracked"] >= 3
    assert np.all(np.diff(tum.timestamps) > 0)
    for a, b in zip(tum.poses_se3, kitti.poses_se3):
        assert np.allclose(a, b, atol=1e-6)
        assert np.allclose(a[:3, :3] @ a[:3, :3].T, np.eye(3), atol=1e-6)
    # the camera travels along the row (world x) at ~0.2 m/s x 0.2 s per frame
    step = np.linalg.norm(np.diff(tum.positions_xyz, axis=0), axis=1)
    assert np.all((step > 0.02) & (step < 0.06)), step


def test_slam_landmarks_ply_has_the_per_point_labels_of_the_csv(slam_result):
    import open3d as o3d

    rows = list(csv.DictReader((slam_result / "landmarks.csv").open()))
    assert rows and {"landmark_id", "seed_id", "cluster_id", "x", "y", "z"} <= set(rows[0])
    head = (slam_result / "landmarks.ply").read_bytes().split(b"end_header")[0].decode()
    for f in ("seed_id", "landmark_id", "cluster_id"):
        assert f"property int {f}" in head
    pc = o3d.t.io.read_point_cloud(str(slam_result / "landmarks.ply"))
    xyz = pc.point.positions.numpy()
    assert len(xyz) == len(rows)
    ref = np.array([[float(r[k]) for k in ("x", "y", "z")] for r in rows])
    assert np.allclose(xyz, ref, atol=1e-5)
    for f in ("seed_id", "landmark_id", "cluster_id"):
        got = getattr(pc.point, f).numpy().ravel()
        assert np.array_equal(got, [int(r[f]) for r in rows]), f
    assert len(np.unique(pc.point.landmark_id.numpy())) == len(rows)


def test_slam_config_yaml_repeats_the_run(slam_result, tiny_range, tmp_path, monkeypatch):
    cfg = yaml.safe_load((slam_result / "config.yaml").read_text())
    assert cfg["detector"] == "fast" and cfg["matcher"] == "seeds"
    again = tmp_path / "again"
    assert _run(["slam", tiny_range, "--config", slam_result / "config.yaml", "-q", "--out", again],
                monkeypatch) == 0
    for f in ("trajectory.tum", "trajectory.kitti", "landmarks.csv", "config.yaml"):
        assert (again / f).read_bytes() == (slam_result / f).read_bytes(), f
    assert json.loads((again / "metrics.json").read_text())["detector"] == "fast"
    # an option still overrides the config's choice, and the written config says what ran
    orb = tmp_path / "orb"
    assert _run(["slam", tiny_range, "--config", slam_result / "config.yaml", "--matcher", "orb", "-q",
                 "--set", "max_frames=3", "--out", orb], monkeypatch) == 0
    assert yaml.safe_load((orb / "config.yaml").read_text())["matcher"] == "orb"
    assert json.loads((orb / "metrics.json").read_text())["matcher"] == "orb"


def test_slam_config_without_matcher_or_detector_still_reads(tiny_range, tmp_path, monkeypatch):
    # configs of seedmap 0.1.0 before these keys existed: they mean the defaults (seeds, the best real detector)
    from seedmap.detect import default_detector_name
    from seedmap.slam.config import SlamConfig

    old = SlamConfig().model_dump(mode="json")
    old.pop("matcher"), old.pop("detector")
    p = tmp_path / "old.yaml"
    p.write_text(yaml.safe_dump(old))
    out = tmp_path / "o"
    assert _run(["slam", tiny_range, "--config", p, "-q", "--set", "max_frames=3", "--out", out], monkeypatch) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["detector"] == default_detector_name() and m["matcher"] == "seeds" and not m["oracle_detector"]


def test_detect_coco_is_valid_and_config_repeats_it(tiny_range, tmp_path, monkeypatch):
    det = tmp_path / "det"
    assert _run(["detect", tiny_range, "--detector", "fast", "--out", det], monkeypatch) == 0
    d = json.loads((det / "detections_coco.json").read_text())
    imgs = {im["id"]: im for im in d["images"]}
    assert len(imgs) == len(d["images"]) == 2 * 11
    cats = {c["id"] for c in d["categories"]}
    ids = [a["id"] for a in d["annotations"]]
    assert len(ids) == len(set(ids)) > 100
    for a in d["annotations"]:
        im = imgs[a["image_id"]]
        assert a["category_id"] in cats and a["iscrowd"] == 0
        x, y, w, h = a["bbox"]
        assert w > 0 and h > 0 and a["area"] > 0
        assert x >= 0 and y >= 0 and x + w <= im["width"] and y + h <= im["height"]
        assert a["area"] <= w * h + 1e-6
        for poly in a["segmentation"]:
            assert len(poly) >= 6 and len(poly) % 2 == 0
            q = np.asarray(poly).reshape(-1, 2)
            assert np.all(np.isfinite(q))
        kx, ky, v = a["keypoints"]
        assert v == 2 and x - 1 <= kx <= x + w + 1 and y - 1 <= ky <= y + h + 1
    for im in d["images"]:
        assert (tiny_range / im["file_name"]).is_file()
    # the same command from its config.yaml: identical detections
    again = tmp_path / "again"
    assert _run(["detect", tiny_range, "--detector", "fast", "--config", det / "config.yaml",
                 "--out", again], monkeypatch) == 0
    assert (again / "detections_coco.json").read_bytes() == (det / "detections_coco.json").read_bytes()


def test_simulate_range_seed_determinism_and_config_round_trip(tmp_path, monkeypatch):
    base = ["simulate", "range", "--length", "0.12", "--set", "camera.scale=0.12", "-q"]
    a, b, c, r = tmp_path / "a", tmp_path / "b", tmp_path / "c", tmp_path / "r"
    assert _run([*base, "--seed", "4", "--out", a], monkeypatch) == 0
    assert _run([*base, "--seed", "4", "--out", b], monkeypatch) == 0
    assert _run([*base, "--seed", "5", "--out", c], monkeypatch) == 0
    assert _run(["simulate", "range", "-q", "--config", a / "gt" / "config.yaml", "--out", r], monkeypatch) == 0
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) > 10
    for rel in files:
        assert (b / rel).read_bytes() == (a / rel).read_bytes(), rel
        assert (r / rel).read_bytes() == (a / rel).read_bytes(), rel
    assert (c / "left" / "000000.png").read_bytes() != (a / "left" / "000000.png").read_bytes()
    assert (c / "gt" / "seeds.csv").read_bytes() != (a / "gt" / "seeds.csv").read_bytes()


def test_batch_takes_matcher_and_detector_from_the_config(slam_result, tiny_range, tmp_path, monkeypatch):
    # `seedmap batch FIELD --config RESULT/config.yaml` ran the gt oracle whatever the config's run used
    import shutil

    field = tmp_path / "field"
    shutil.copytree(tiny_range, field / "r1")
    out = tmp_path / "b"
    assert _run(["batch", field, "--config", slam_result / "config.yaml", "--set", "max_frames=3", "-q",
                 "--out", out], monkeypatch) == 0
    assert json.loads((out / "r1" / "metrics.json").read_text())["detector"] == "fast"
    for p in (out / "config.yaml", out / "r1" / "config.yaml"):
        c = yaml.safe_load(p.read_text())
        assert c["detector"] == "fast" and c["matcher"] == "seeds", p


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
    # inside its box: the analytic ellipse area
    assert inside["area"] == round(np.pi * 8 * 4 / 4, 2)
    assert out["ellipse"]["major"] == 16.0  # the ellipse itself is still reported whole


def test_detect_result_config_repeats_the_run(tiny_range, tmp_path, monkeypatch):
    first, again, plain = tmp_path / "first", tmp_path / "again", tmp_path / "plain"
    assert _run(["detect", tiny_range, "--detector", "gt", "--out", first], monkeypatch) == 0
    cfg = yaml.safe_load((first / "config.yaml").read_text())
    assert cfg["detector"] == "gt" and cfg["weights"] is None
    # the result's config alone repeats it (no --detector): same detections, byte for byte
    assert _run(["detect", tiny_range, "--config", first / "config.yaml", "--out", again], monkeypatch) == 0
    assert (again / "detections.jsonl").read_bytes() == (first / "detections.jsonl").read_bytes()
    # --detector overrides the config's
    over = tmp_path / "over"
    assert _run(["detect", tiny_range, "--config", first / "config.yaml", "--detector", "fast", "--out", over],
                monkeypatch) == 0
    assert yaml.safe_load((over / "config.yaml").read_text())["detector"] == "fast"
    assert json.loads((over / "meta.json").read_text())["detector"] == "fast"
    # a config without the detector key (a plain detector config) still loads; it means the default detector
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump({k: v for k, v in cfg.items() if k not in ("detector", "weights")}))
    assert _run(["detect", tiny_range, "--config", old, "--out", plain], monkeypatch) == 0
    assert yaml.safe_load((plain / "config.yaml").read_text())["detector"] == "fast"
