"""``seedmap train fast-cnn LABELS.json``: the fast CNN learns from a user's COCO boxes (masks optional).

A box without a mask trains the seed's inscribed ellipse, with its keypoint at the box centre; a fine-tune of the
shipped network on a tiny COCO export of a simulated range lowers the held-out loss, and the network it writes runs
through ``seedmap detect --weights`` on a folder of the images, at the scale between its labels' and its own seed size.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from seedmap.detect.cnn_targets import box_ellipse_labels, labelled_targets
from seedmap.detect.labels import LabelledImage
from seedmap.detect.train_cnn import CropSpec, crop_batch

from helpers.cli import run_cli
from helpers.coco import export_coco


def test_a_box_without_mask_trains_its_inscribed_ellipse_and_centre():
    img = np.zeros((40, 50, 3), np.uint8)
    boxes = np.array([[10, 20, 17, 25], [30, 5, 33, 8]], np.float64)  # 7 x 5 px, 3 x 3 px (x1, y1 exclusive)
    lab = box_ellipse_labels(boxes, np.zeros((40, 50), np.int32))
    ys, xs = np.nonzero(lab == 1)
    assert xs.min() == 10 and xs.max() == 16 and ys.min() == 20 and ys.max() == 24  # inside its box, touching it
    assert lab[20, 10] == 0 and lab[22, 13] == 1  # no box corners: an ellipse
    assert (lab == 2).sum() >= 5
    ti = labelled_targets(LabelledImage(img, boxes, np.zeros((40, 50), np.int32)))
    assert np.allclose(ti.kp, [[13.0, 22.0], [31.0, 6.0]]) and ti.labelled
    # a tiny labelled seed is still a heatmap peak (the user labelled it): a peak at each box centre
    _, heat, reg, mask, ign = crop_batch([ti], 1, 40, np.random.default_rng(0), seed_fraction=0.0, augment=False,
                                         spec=CropSpec())
    assert ign.sum() == 0
    peaks = np.argwhere(heat[0] >= 0.999)
    assert len(peaks) == 2


def test_fine_tuning_from_boxes_lowers_the_loss_and_detect_runs_the_network(tiny_range, tmp_path, monkeypatch):
    pytest.importorskip("torch")
    coco, _ = export_coco(tiny_range, frames=(0, 1))
    for a in coco["annotations"][::2]:  # half the seeds as boxes only, the others with their masks
        a.pop("segmentation")
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps(coco))
    out = tmp_path / "ft"
    assert run_cli(["train", "fast-cnn", labels, "--images-root", tiny_range, "--out", out, "--init", "fast_cnn.onnx",
                    "--steps", "40", "--batch", "8", "--lr", "1e-3"], monkeypatch) == 0
    m = json.loads((out / "train_metrics.json").read_text())
    assert m["train_images"] == 1 and m["val_images"] == 1  # one of the two labelled images held out
    assert m["final"]["val_loss"] < m["initial_val_loss"]
    tr_id = 2 if m["val_counts"]["n_gt"] == sum(a["image_id"] == 1 for a in coco["annotations"]) else 1
    boxes = np.array([a["bbox"] for a in coco["annotations"] if a["image_id"] == tr_id])
    assert m["images_seed_px"] == pytest.approx(np.median(np.sqrt(boxes[:, 2] * boxes[:, 3])))
    assert m["seed_px"] == 5.0  # the shipped network's seed size: the images were resized to it
    det = tmp_path / "det"
    assert run_cli(["detect", tiny_range / "left", "--weights", out / "fast_cnn.onnx", "--detector", "fast",
                    "--set", f"cnn.seed_px={m['images_seed_px']}", "--out", det], monkeypatch) == 0
    meta = json.loads((det / "meta.json").read_text())
    assert meta["trained_seed_px"] == 5.0 and meta["cnn_scale"] == pytest.approx(m["labels_scale"])
    assert meta["images"] == len(list((tiny_range / "left").glob("*.png"))) and meta["detections"] > 0


def _refused_training(coco: dict, images_root, tmp_path, monkeypatch, capsys) -> tuple:  # noqa: ANN001
    """``seedmap train fast-cnn`` on the labels ``coco``: it must exit 2 with one error line and write no folder.
    Returns the label file and that line."""
    p = tmp_path / "labels.json"
    p.write_text(json.dumps(coco))
    out = tmp_path / "fc"
    assert run_cli(["train", "fast-cnn", p, "--images-root", images_root, "--out", out, "--steps", "1"],
                   monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error: ")]
    assert len(err) == 1, err
    assert not out.exists()
    return p, err[0]


def test_one_labelled_image_and_no_validation_set_is_one_line(tiny_range, tmp_path, monkeypatch, capsys):
    pytest.importorskip("torch")
    coco, _ = export_coco(tiny_range, frames=(0,))
    p, err = _refused_training(coco, tiny_range, tmp_path, monkeypatch, capsys)
    assert str(p) in err and "held-out" in err, err


def test_labels_made_on_a_resized_copy_are_one_line(tiny_range, tmp_path, monkeypatch, capsys):
    pytest.importorskip("torch")
    coco, _ = export_coco(tiny_range, frames=(0, 1))
    coco["images"][0]["width"] *= 2  # the labelling tool saw another size
    coco["images"][0]["height"] *= 2
    p, err = _refused_training(coco, tiny_range, tmp_path, monkeypatch, capsys)
    assert str(p) in err and "000000.png" in err and "labels say" in err, err


def test_held_out_photos_of_another_seed_size_are_resized_by_their_own(tmp_path):
    """``--val`` photos whose seeds differ in size from the training photos are brought to the network's seed size
    each by its own labels, not by the training labels' size."""
    import cv2

    from seedmap.detect.train_validate import plan_training

    def coco(name: str, sides: list[float]) -> str:
        images, anns = [], []
        for i, side in enumerate(sides):
            cv2.imwrite(str(tmp_path / f"{name}{i}.png"), np.zeros((200, 200, 3), np.uint8))
            images.append({"id": i + 1, "file_name": f"{name}{i}.png", "width": 200, "height": 200})
            for k in range(6):
                anns.append({"id": len(anns) + 1, "image_id": i + 1, "category_id": 1, "iscrowd": 0,
                             "bbox": [10 + 30 * k, 20, side, side], "area": side * side})
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps({"images": images, "annotations": anns, "categories": [{"id": 1, "name": "seed"}]}))
        return str(p)

    train, val = coco("train", [10.0, 10.0]), coco("val", [20.0, 5.0])
    plan = plan_training([train], [val], None, 0.2, 0, 8.0)
    assert plan.scale == pytest.approx(0.8)
    assert plan.image_scales[(val, 0)] == pytest.approx(0.4) and plan.image_scales[(val, 1)] == pytest.approx(1.6)
    assert plan.fixed_scale  # the training photos alone decide whether the network runs at one scale
