"""The seedmap dataset layout: what the writer writes, the reader reads back."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.errors import InputError
from seedmap.io import open_dataset
from seedmap.io.images import read_rgb, write_png
from seedmap.io.seedmap_dataset import DatasetWriter, Instances, SeedmapDataset, SeedTable
from seedmap.records import StereoCalib, Trajectory


def _tiny(tmp_path, n=3):
    calib = StereoCalib(100.0, 100.0, 31.5, 23.5, 0.11, 64, 48)
    w = DatasetWriter(tmp_path)
    w.write_calib(calib)
    w.write_times(np.arange(n) * 0.2)
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(2 * n)]
    for i in range(n):
        w.write_frame(i, imgs[2 * i], imgs[2 * i + 1])
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.arange(n) * 0.04
    w.write_gt_poses(Trajectory(np.arange(n) * 0.2, T))
    w.write_gt_seeds(SeedTable(np.array([0, 1]), np.array([0, 0]), np.array([[0.0, 0.7, 1.2], [0.01, 0.7, 1.2]]),
                               np.full((2, 3), 0.002)))
    labels = np.zeros((48, 64), np.uint16)
    labels[10:14, 20:25] = 1
    inst = Instances(np.array([1], np.uint16), np.array([1]), np.array([0]), np.array([[20, 10, 25, 14]]),
                     np.array([[22.0, 11.5]]), np.array([20]), np.array([True]))
    for i in range(n):
        for cam in ("left", "right"):
            w.write_gt_instances(i, cam, labels, inst)
    return calib, imgs


def test_writer_reader_round_trip(tmp_path):
    calib, imgs = _tiny(tmp_path)
    ds = open_dataset(tmp_path)
    assert isinstance(ds, SeedmapDataset) and len(ds) == 3 and ds.has_gt
    assert ds.calib == calib
    f = ds[1]
    np.testing.assert_array_equal(f.left, imgs[2])
    np.testing.assert_array_equal(f.right, imgs[3])
    assert f.timestamp == pytest.approx(0.2)
    assert ds.gt_trajectory().poses[2, 0, 3] == pytest.approx(0.08)
    assert len(ds.gt_seeds()) == 2
    ids = ds.gt_seed_id_image(0, "left")
    assert ids[11, 22] == 1 and ids[0, 0] == -1
    inst = ds.gt_instances(0, "right")
    assert inst.seed_id.tolist() == [1] and inst.center_visible.all()


def test_reader_errors_name_the_file(tmp_path):
    _tiny(tmp_path)
    (tmp_path / "right" / "000001.png").unlink()
    ds = SeedmapDataset(tmp_path)
    with pytest.raises(InputError, match="000001.png"):
        ds[1]
    (tmp_path / "times.txt").write_text("0.0\n0.4\n0.2\n")
    with pytest.raises(InputError, match="not strictly increasing"):
        SeedmapDataset(tmp_path)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p.write_bytes(b""), "empty"),
        (lambda p: p.write_bytes(b"\x89PNG garbage"), "not a readable image"),
        (lambda p: write_png(p, np.zeros((8, 8), np.uint8)), "grayscale"),
        (lambda p: write_png(p, np.zeros((8, 8, 3), np.uint16)), "uint16"),
    ],
)
def test_bad_images_are_refused_with_the_file_name(tmp_path, make, message):
    p = tmp_path / "img.png"
    make(p)
    with pytest.raises(InputError, match=message) as e:
        read_rgb(p)
    assert "img.png" in str(e.value)


def test_calibration_with_zero_baseline_is_refused(tmp_path):
    _tiny(tmp_path)
    text = (tmp_path / "calib.yaml").read_text().replace("baseline_m: 0.11", "baseline_m: 0.0")
    (tmp_path / "calib.yaml").write_text(text)
    with pytest.raises(InputError, match="baseline"):
        SeedmapDataset(tmp_path)


def test_instance_table_round_trip_empty_and_malformed(tmp_path):
    """Many instances survive write -> read exactly (3-decimal centres); a frame without seeds reads as
    empty; a damaged table is refused naming the file."""
    _tiny(tmp_path)
    rng = np.random.default_rng(3)
    n = 500
    boxes = np.sort(rng.integers(0, 60, (n, 2, 2)), axis=1).reshape(n, 4)[:, [0, 2, 1, 3]]
    inst = Instances(np.arange(1, n + 1).astype(np.uint16), rng.integers(0, 10**6, n), rng.integers(0, 40, n),
                     boxes, np.round(rng.uniform(-5, 70, (n, 2)), 3), rng.integers(1, 400, n), rng.random(n) < 0.5)
    labels = np.zeros((48, 64), np.uint16)
    w = DatasetWriter(tmp_path)
    w.write_gt_instances(2, "left", labels, inst)
    w.write_gt_instances(2, "right", labels, Instances.empty())
    ds = SeedmapDataset(tmp_path)
    got = ds.gt_instances(2, "left")
    for name in ("label", "seed_id", "panicle_id", "boxes", "area", "center_visible"):
        np.testing.assert_array_equal(getattr(got, name), getattr(inst, name))
    np.testing.assert_allclose(got.center_uv, inst.center_uv, atol=5e-4)
    assert len(ds.gt_instances(2, "right")) == 0
    bad = tmp_path / "gt" / "instances" / "left" / "000001.csv"
    bad.write_text("label,seed_id\n1,2\n")
    with pytest.raises(InputError, match="000001.csv"):
        ds.gt_instances(1, "left")
    bad.write_text("label,seed_id,panicle_id,x0,y0,x1,y1,u,v,area,center_visible\n1,2,3,4,5,6,7,x,9,10,1\n")
    with pytest.raises(InputError, match="000001.csv: malformed"):
        ds.gt_instances(1, "left")
