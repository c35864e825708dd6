"""Detection files, their evaluation, COCO labels and bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest

from seedmap.detect import make_detector
from seedmap.detect.io import read_detections
from seedmap.detect.labels import CocoSource, rle_counts_to_string, rle_string_to_counts, segmentation_mask
from seedmap.detect.run import run_detect, run_eval_detect
from seedmap.detect.synth import write_synthetic_dataset
from seedmap.errors import InputError
from seedmap.io.seedmap_dataset import SeedmapDataset


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return SeedmapDataset(write_synthetic_dataset(tmp_path_factory.mktemp("fast") / "d", n_frames=2))


def test_fast_rejects_bad_images():
    det = make_detector("fast")
    with pytest.raises(InputError, match="H x W x 3"):
        det.detect(np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError, match="uint16"):
        det.detect(np.zeros((10, 10, 3), np.uint16))
    with pytest.raises(InputError, match="empty"):
        det.detect(np.zeros((0, 10, 3), np.uint8))
    assert len(det.detect(np.zeros((40, 50, 3), np.uint8))) == 0


def test_detect_files_and_eval_roundtrip(ds, tmp_path):
    out = run_detect(ds.root, tmp_path / "det", "gt", overlay=True, progress=False)
    dets = read_detections(out)
    assert set(dets) == {(0, "left"), (0, "right"), (1, "left"), (1, "right")}
    assert (out / "overlay" / "left" / "000001.png").is_file()
    meta = json.loads((out / "meta.json").read_text())
    assert meta["oracle"] is True and meta["detector"] == "gt"
    m, p = run_eval_detect(ds.root, out, progress=False)
    assert m.precision == 1.0 and m.recall > 0.98 and m.kp_err_median_px < 0.3
    assert json.loads(p.read_text())["per_frame"][0]["n_gt"] > 0
    # the COCO file reads back as labels: boxes equal the detections'
    coco = CocoSource(out / "detections_coco.json", images_root=ds.root)
    li = coco[0]
    np.testing.assert_allclose(li.boxes, dets[(0, "left")].boxes, atol=0.01)
    assert li.labels.max() > 0


def test_eval_detect_refuses_detections_of_other_sized_images(ds, tmp_path):
    """Scoring a detections folder against a dataset of another image size is a one-line error naming the folder
    (it used to score everything as a miss, or fail with 'frame N but the dataset has N frames')."""
    other = write_synthetic_dataset(tmp_path / "big", n_frames=2, width=400, height=300)
    out = run_detect(other, tmp_path / "det_big", "gt", progress=False)
    with pytest.raises(InputError, match="made on 400x300 images but the dataset's are 320x240") as e:
        run_eval_detect(ds.root, out, progress=False)
    assert str(out) in str(e.value)
    assert not (out / "detect_metrics.json").exists()


def test_rle_and_polygons():
    rng = np.random.default_rng(0)
    m = (rng.random((7, 9)) > 0.6).astype(np.uint8)
    flat = m.T.reshape(-1)
    counts, v, run = [], 0, 0
    for x in flat:
        if x != v:
            counts.append(run)
            run, v = 0, x
        run += 1
    counts.append(run)
    np.testing.assert_array_equal(segmentation_mask({"counts": counts, "size": [7, 9]}, 7, 9), m)
    s = rle_counts_to_string(counts)
    assert rle_string_to_counts(s) == counts
    np.testing.assert_array_equal(segmentation_mask({"counts": s, "size": [7, 9]}, 7, 9), m)
    sq = segmentation_mask([[2, 3, 6, 3, 6, 7, 2, 7]], 10, 10)  # pixel-edge square 4x4
    assert sq.sum() == 16 and sq[3:7, 2:6].all()


def test_cli_bad_input_exits_2(ds, tmp_path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(ds.root, bad)
    (bad / "left" / "000001.png").write_bytes(b"garbage")
    r = subprocess.run([sys.executable, "-m", "seedmap.cli", "detect", str(bad), "--out", str(tmp_path / "o"),
                        "-d", "fast"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "000001.png" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()
    r = subprocess.run([sys.executable, "-m", "seedmap.cli", "eval", "detect", str(ds.root), str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "detections.jsonl" in r.stderr
