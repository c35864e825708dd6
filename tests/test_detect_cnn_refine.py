"""The fast CNN's learned second stage (seedmap.detect.cnn_refine): targets, features, training, shipped weights."""

import numpy as np
import pytest

from seedmap.detect import make_detector
from seedmap.detect.cnn import CnnDetector, default_cnn_path
from seedmap.detect.cnn_refine import CnnRefiner, default_cnn_refiner_path, file_sha256, peak_features
from seedmap.detect.train_refiner import CnnRefinerTrainConfig, peak_targets, train_cnn_refiner
from seedmap.errors import ConfigError, InputError
from seedmap.eval.detect_metrics import frame_metrics
from seedmap.io.seedmap_dataset import Instances


def _two_instances():
    """A 30 x 30 label image: instance 1 a 4 x 5 seed (20 px) at x 10-13, y 10-14; instance 2 a 2 x 3 sliver (6 px)."""
    lab = np.zeros((30, 30), np.uint16)
    lab[10:15, 10:14] = 1
    lab[20:23, 20:22] = 2
    inst = Instances(label=np.array([1, 2], np.uint16), seed_id=np.array([7, 8]), panicle_id=np.array([0, 0]),
                     boxes=np.array([[10, 10, 14, 15], [20, 20, 22, 23]], float),
                     center_uv=np.array([[11.5, 12.0], [20.5, 21.0]]), area=np.array([20, 6]),
                     center_visible=np.array([True, True]))
    return lab, inst


def test_peak_targets_one_seed_per_instance_boxes_for_all():
    lab, inst = _two_instances()
    # peaks: two on the seed (the second stronger), one on the sliver, one on background whose keypoint
    # offset lands on the seed, one on background
    x = np.array([11.0, 12.0, 21.0, 9.0, 2.0])
    y = np.array([12.0, 13.0, 21.0, 12.0, 2.0])
    raw = np.zeros((5, 7))
    raw[:, 0] = [1.0, 2.0, 3.0, 0.5, 0.5]
    raw[3, 5] = 2.0  # keypoint 9 + 2 = 11: on the seed
    seed, box, has = peak_targets(x, y, raw, lab, inst, min_gt_area=10)
    assert seed.tolist() == [False, True, False, False, False]  # the strongest peak on the seed only
    assert has.tolist() == [True, True, True, True, False]
    # edges (left, top, right, bottom) / 5 px from the peak pixel, x1 / y1 exclusive
    np.testing.assert_allclose(box[1] * 5, [2, 3, 2, 2])
    np.testing.assert_allclose(box[2] * 5, [1, 1, 1, 2])
    np.testing.assert_allclose(box[3] * 5, [-1, 2, 5, 3])
    assert np.isnan(box[4]).all()


def test_peak_features_patch_raw_and_strongest_neighbour():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    x = np.array([20.0, 23.0, 20.0, 45.0])
    y = np.array([20.0, 20.0, 22.0, 5.0])
    raw = np.zeros((4, 7))
    raw[:, 0] = [1.0, 3.0, 2.0, 0.0]
    raw[:, 1:5] = 5.0
    f = peak_features(img, x, y, raw, r=2)
    n_patch = 3 * 25
    assert f.shape == (4, n_patch + 15)
    np.testing.assert_allclose(f[0, :n_patch].reshape(5, 5, 3), img[18:23, 18:23] / 255.0, atol=1e-6)
    np.testing.assert_allclose(f[:, n_patch + 1:n_patch + 5], 1.0)  # edges / 5 px
    nb = f[:, n_patch + 7:]
    # peak 0: the strongest higher neighbour is peak 1 (logit 3), 3 px to the right
    np.testing.assert_allclose(nb[0, :6], [1, 3 / 5, 0, 2.0, 2.0, 2.0])
    assert nb[1, 0] == 0 and nb[3, 0] == 0  # the strongest and the isolated peak have none
    assert nb[0, 6] == 2 and nb[0, 7] == 2  # two peaks within 4 px and within 8 px of peak 0
    assert nb[3, 6] == 0 and nb[3, 7] == 0
    # the patch of a peak at the image border is zero-padded
    g = peak_features(img, np.array([0.0]), np.array([0.0]), np.zeros((1, 7)), r=2)
    assert (g[0, :n_patch].reshape(5, 5, 3)[:2] == 0).all()


def test_shipped_refiner_raises_f1_on_an_unseen_frame(cnn_range):
    """The shipped refiner (trained on other seeds) on an unseen simulated frame: higher box F1 than the plain
    network at its own threshold, keypoints unchanged (the refiner moves boxes and scores, not keypoints)."""
    assert default_cnn_refiner_path().is_file() and default_cnn_refiner_path().stat().st_size < 2e6
    img, inst = cnn_range[2].left, cnn_range.gt_instances(2, "left")
    plain = make_detector("fast", overrides=["cnn.refiner=none"]).detect(img)
    det = make_detector("fast", overrides=["cnn.refiner=auto"])
    assert det.refiner is not None and det.threshold == det.cfg.refine_threshold
    ref = det.detect(img)
    mp, _ = frame_metrics(plain, inst, min_gt_area=10)
    mr, err = frame_metrics(ref, inst, min_gt_area=10)
    assert mr.f1 > mp.f1 + 0.02 and mr.precision > mp.precision, (mp, mr)
    assert np.median(err) < 0.5 and ref.scores.min() >= det.threshold - 1e-6
    # the refiner belongs to the shipped field network: auto leaves other networks alone ...
    assert make_detector("fast", overrides=["cnn.refiner=auto", "cnn.domain=arm"]).refiner is None
    # ... and an explicit refiner on another network is refused, naming the file
    with pytest.raises(ConfigError, match="fast_cnn_refiner.onnx"):
        make_detector("fast", overrides=["cnn.domain=arm", f"cnn.refiner={default_cnn_refiner_path()}"])


def test_bad_refiner_files_are_named(tmp_path):
    bad = tmp_path / "r.onnx"
    bad.write_bytes(b"no onnx")
    with pytest.raises(InputError, match="r.onnx"):
        make_detector("fast", overrides=[f"cnn.refiner={bad}"])
    with pytest.raises(InputError, match="expected cnn_refiner"):  # a fast_cnn network is no refiner
        CnnRefiner.load(default_cnn_path())
    with pytest.raises(InputError, match="not found"):
        make_detector("fast", overrides=[f"cnn.refiner={tmp_path / 'none.safetensors'}"])


def test_training_a_refiner_on_a_small_range_learns(cnn_range, tmp_path):
    """A few hundred steps on one small range: the loss falls, both files compute the same MLP, the network's
    hash is recorded, and the refined detections on another frame of the range beat the untrained refiner."""
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    out = tmp_path / "ref.safetensors"
    cfg = CnnRefinerTrainConfig(steps=400, hidden=(32,), patch_r=3)
    onnx_path = train_cnn_refiner([cnn_range.root], out, cfg, progress=False)
    assert onnx_path == tmp_path / "ref.onnx" and out.is_file()
    a, b = CnnRefiner.load(onnx_path), CnnRefiner.load(out)
    info = a.mlp.info
    assert info["cnn_sha256"] == file_sha256(default_cnn_path()) and info["loss_last_100"] < info["loss_first_100"]
    x = np.random.default_rng(1).random((50, 3 * 49 + 15)).astype(np.float32)
    np.testing.assert_allclose(a.forward(x), b.forward(x), atol=1e-4)
    det = make_detector("fast", overrides=[f"cnn.refiner={onnx_path}"])
    assert isinstance(det, CnnDetector) and det.refiner is not None
    img, inst = cnn_range[4].right, cnn_range.gt_instances(4, "right")
    m, _ = frame_metrics(det.detect(img), inst, min_gt_area=10)
    assert m.f1 > 0.7, m


def test_train_cnn_refiner_bad_inputs_are_one_line(tmp_path, monkeypatch, capsys):
    """Missing datasets, a dataset without GT and bad numbers give one line and exit code 2, and no output."""
    pytest.importorskip("torch")
    from helpers.cli import run_cli

    from seedmap.io.seedmap_dataset import DatasetWriter
    from seedmap.records import StereoCalib

    out = tmp_path / "o"
    assert run_cli(["train", "cnn-refiner", tmp_path / "missing", "--out", out], monkeypatch) == 2
    err = capsys.readouterr().err
    assert "missing: dataset folder or COCO .json file not found" in err and "Traceback" not in err
    nogt = tmp_path / "nogt"  # a real-data layout: images, no gt/
    w = DatasetWriter(nogt)
    w.write_calib(StereoCalib(fx=120.0, fy=120.0, cx=80.0, cy=60.0, baseline=0.1, width=160, height=120))
    w.write_times(np.zeros(1))
    img = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    w.write_frame(0, img, img)
    assert run_cli(["train", "cnn-refiner", nogt, "--out", out], monkeypatch) == 2
    err = capsys.readouterr().err
    assert "no ground truth" in err and "nogt" in err
    assert run_cli(["train", "cnn-refiner", nogt, "--out", out, "--hidden", "64,x"], monkeypatch) == 2
    assert "--hidden" in capsys.readouterr().err
    assert not out.exists()


def test_refiner_training_data_from_coco_masks_matches_the_simulated_gt(cnn_range, tmp_path):
    """A COCO export (RLE and polygon masks) of two left images gives the refiner nearly the same targets as the
    simulated GT itself; annotations with boxes only are refused (the refiner learns from masks)."""
    import json

    from helpers.coco import export_coco

    from seedmap.detect.train_refiner import training_data
    from seedmap.detect.config import CnnConfig, min_visible_seed_px

    coco, _ = export_coco(cnn_range.root, frames=(0, 1), min_area=1)
    p = tmp_path / "labels.json"
    p.write_text(json.dumps(coco))
    det = CnnDetector(CnnConfig(threshold=0.25, refiner="none"))
    x, box, seed, has = training_data([p], det, images_root=cnn_range.root)
    ref = [peak_targets(pk.x, pk.y, pk.raw, cnn_range.gt_label_image(i, "left"), cnn_range.gt_instances(i, "left"),
                        min_visible_seed_px(cnn_range.calib.width))
           for i in (0, 1) for pk in [det.peaks(cnn_range[i].left)]]
    seed_ref, has_ref = np.concatenate([r[0] for r in ref]), np.concatenate([r[2] for r in ref])
    assert len(seed) == len(seed_ref) > 1000 and x.shape == (len(seed), 3 * 13 * 13 + 15)
    # RLE masks are exact, polygons outline the pixels approximately
    assert (seed == seed_ref).mean() > 0.97 and (has == has_ref).mean() > 0.97
    assert seed.mean() > 0.5 and (~seed).sum() > 20  # both classes (second peaks, slivers, background)
    for a in coco["annotations"]:
        del a["segmentation"]
    p.write_text(json.dumps(coco))
    with pytest.raises(InputError, match="without masks"):
        training_data([p], det, images_root=cnn_range.root)


def test_concurrent_stereo_detection_equals_sequential(cnn_range):
    """``cnn.stereo_threads=2`` (the default) runs left and right at once on shared onnxruntime InferenceSessions (network
    and refiner): the same detections as one after the other."""
    fr = cnn_range[3]
    a = make_detector("fast", overrides=["cnn.stereo_threads=1"]).detect_stereo(fr)
    det = make_detector("fast")
    assert det.cfg.stereo_threads == 2 and det.refiner is not None
    for _ in range(3):
        b = det.detect_stereo(fr)
        for x, y in ((a.left, b.left), (a.right, b.right)):
            assert len(x) > 500
            np.testing.assert_array_equal(x.boxes, y.boxes)
            np.testing.assert_array_equal(x.scores, y.scores)
            np.testing.assert_array_equal(x.keypoints, y.keypoints)
