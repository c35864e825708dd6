"""A user fine-tunes the fast detector on COCO labels and scores detections against COCO ground truth.

Labels are exported from a tiny simulated range (boxes only on enlarged copies of its images; polygons + RLE masks
at its own size): ``seedmap train fast-cnn`` resizes the images so that the labelled seeds have the network's seed
size, records that size and the labels' size in the ONNX file, holds out a seeded fraction of the labelled images and
reports their box F1 before and after; ``seedmap eval detect LABELS.json DET`` scores a detect output by image name.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from seedmap.detect.cnn_targets import TrainImage, rescale_targets
from seedmap.detect.io import coco_from_records
from seedmap.detect.train_validate import split_coco

from helpers.cli import run_cli
from helpers.coco import export_coco
from helpers.networks import PHOTO_SEED_PX

FAST = ["--steps", "3", "--batch", "2", "--crop", "48", "--threads", "1"]


def _enlarged_boxes_only(src, dst, factor: int = 2, frames=(0, 1, 2)) -> dict:
    """``dst/images``: the left images of ``frames`` enlarged ``factor`` x (PNG), labelled with boxes only."""
    coco, _ = export_coco(src, frames=frames)
    (dst / "images").mkdir(parents=True)
    for im in coco["images"]:
        img = cv2.imread(str(src / im["file_name"]))
        big = cv2.resize(img, None, fx=factor, fy=factor, interpolation=cv2.INTER_LINEAR)
        im["file_name"] = im["file_name"].replace("left/", "")
        cv2.imwrite(str(dst / "images" / im["file_name"]), big)
        im["width"], im["height"] = big.shape[1], big.shape[0]
    for a in coco["annotations"]:
        a.pop("segmentation")
        a["bbox"] = [v * factor for v in a["bbox"]]
        a["area"] *= factor * factor
    return coco


def _sides(coco: dict, image_ids) -> np.ndarray:
    b = np.array([a["bbox"] for a in coco["annotations"] if a["image_id"] in image_ids], float)
    return np.sqrt(b[:, 2] * b[:, 3])


def test_rescaled_targets_keep_boxes_keypoints_and_masks_together():
    inst = np.full((20, 30), -1, np.int16)
    inst[4:8, 10:16] = 0
    ti = TrainImage(np.zeros((20, 30, 3), np.uint8), inst, np.array([[10, 4, 16, 8]], np.float32),
                    np.array([[12.5, 5.5]], np.float32), np.array([[12, 6]]), np.array([24.0], np.float32))
    r = rescale_targets(ti, 0.5)
    assert r.rgb.shape == (10, 15, 3) and r.inst.shape == (10, 15)
    assert np.allclose(r.boxes, [[5, 2, 8, 4]])
    assert np.allclose(r.kp, [[6.0, 2.5]])  # pixel centres: (12.5 + 0.5) / 2 - 0.5
    ys, xs = np.nonzero(r.inst == 0)
    assert xs.min() == 5 and xs.max() == 7 and ys.min() == 2 and ys.max() == 3
    assert r.area[0] == pytest.approx(6.0)


def test_split_holds_out_a_seeded_fraction_and_refuses_one_labelled_image(tmp_path):
    tr, va = split_coco(list(range(10)), [10, 11], 0.2, 0, tmp_path / "l.json")
    assert len(va) == 2 and not set(tr) & set(va) and {10, 11} <= set(tr) and len(tr) == 10
    assert split_coco(list(range(10)), [], 0.2, 0, tmp_path / "l.json") == ([k for k in tr if k < 10], va)
    assert len(split_coco([0, 1], [], 0.9, 0, tmp_path / "l.json")[0]) == 1  # one image always trains
    with pytest.raises(Exception, match="1 labelled image"):
        split_coco([3], [0, 1], 0.2, 0, tmp_path / "l.json")


def test_boxes_only_fine_tune_learns_at_the_network_seed_size_and_reports_heldout_f1(tiny_range, tmp_path,
                                                                                     monkeypatch):
    pytest.importorskip("torch")
    coco = _enlarged_boxes_only(tiny_range, tmp_path / "set")
    labels = tmp_path / "set" / "labels.json"
    labels.write_text(json.dumps(coco))
    out = tmp_path / "ft"
    assert run_cli(["train", "fast-cnn", labels, "--images-root", tmp_path / "set" / "images", "--out", out,
                    *FAST], monkeypatch) == 0
    m = json.loads((out / "train_metrics.json").read_text())
    lab = [k for k, im in enumerate(coco["images"]) if any(a["image_id"] == im["id"] for a in coco["annotations"])]
    tr, va = split_coco(lab, [], 0.2, 0, labels)
    assert m["train_images"] == len(tr) == 2 and m["val_images"] == len(va) == 1
    from seedmap.detect.replay import REPLAY_PHOTOS

    assert m["replay_images"] == REPLAY_PHOTOS and m["config"]["replay"] == 0.5  # rehearsal crops by default
    want = float(np.median(_sides(coco, {coco["images"][k]["id"] for k in tr})))
    assert m["images_seed_px"] == pytest.approx(want)
    op = PHOTO_SEED_PX  # the seed size of the shipped photo network it starts from
    assert m["seed_px"] == op and m["labels_scale"] == pytest.approx(op / want)
    # held-out F1 of the network before (the shipped one) and after, on the held-out image's labelled seeds
    n_val = len(_sides(coco, {coco["images"][va[0]]["id"]}))
    assert m["val_counts"]["n_gt"] == n_val and m["val_counts_before"]["n_gt"] == n_val
    for k in ("val_f1", "val_f1_before", "val_precision", "val_recall"):
        assert 0.0 <= m[k] <= 1.0
    assert m["val_f1_before"] > 0.3  # the shipped network finds these seeds at the stored scale
    import onnx

    info = json.loads({p.key: p.value for p in onnx.load(str(out / "fast_cnn.onnx")).metadata_props}["info"])
    assert info["seed_px"] == op and info["images_seed_px"] == pytest.approx(want)
    assert info["scale_cue"] == "score"  # read off the ladder as the shipped photo network it started from is
    from seedmap.detect.autoscale import SCORE_SIZE

    assert info["score_size"] == SCORE_SIZE  # ... with its multiple, whatever later networks ship with
    # a refiner for the resized network is not trained from the labels at their own size: one line, nothing written
    ref = tmp_path / "ref"
    assert run_cli(["train", "cnn-refiner", labels, "--images-root", tmp_path / "set" / "images", "--weights",
                    out / "fast_cnn.onnx", "--out", ref, "--steps", "1"], monkeypatch) == 2
    assert not ref.exists()


def test_polygon_and_rle_labels_train_from_scratch_and_without_a_held_out_f1_before(tiny_range, tmp_path,
                                                                                    monkeypatch):
    pytest.importorskip("torch")
    coco, _ = export_coco(tiny_range, frames=(0, 1))
    assert any(isinstance(a["segmentation"], dict) for a in coco["annotations"])
    assert any(isinstance(a["segmentation"], list) for a in coco["annotations"])
    for a in coco["annotations"]:
        a.pop("bbox")  # boxes from the masks
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps(coco))
    out = tmp_path / "scratch"
    assert run_cli(["train", "fast-cnn", labels, "--images-root", tiny_range, "--out", out, "--init", "none",
                    "--replay", "0", *FAST], monkeypatch) == 0
    m = json.loads((out / "train_metrics.json").read_text())
    assert m["config"]["init_weights"] is None and "val_f1" in m and "val_f1_before" not in m
    assert m["replay_images"] == 0
    assert m["train_images"] == 1 and m["val_images"] == 1
    assert 1.0 < m["images_seed_px"] < 12.0 and m["labels_scale"] == pytest.approx(5.0 / m["images_seed_px"])


def _detect_records(coco: dict, boxes_of) -> list[dict]:  # noqa: ANN001
    recs = []
    for k, im in enumerate(coco["images"]):
        b = np.array(boxes_of(im["id"]), float).reshape(-1, 4)
        c = (b[:, :2] + b[:, 2:]) / 2 - 0.5
        ell = np.c_[c, b[:, 2] - b[:, 0], b[:, 3] - b[:, 1], np.zeros(len(b))]
        recs.append({"frame": k, "camera": "mono", "timestamp": 0.0, "image": im["file_name"],
                     "width": im["width"], "height": im["height"], "n": len(b), "boxes": b.tolist(),
                     "scores": [0.9] * len(b), "ellipses": ell.tolist(), "seed_ids": [-1] * len(b)})
    return recs


def test_eval_detect_scores_a_detect_output_against_coco_labels(tiny_range, tmp_path, monkeypatch, capsys):
    coco, _ = export_coco(tiny_range, frames=(0, 1))
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps(coco))

    def gt_boxes(i):
        return [[a["bbox"][0], a["bbox"][1], a["bbox"][0] + a["bbox"][2], a["bbox"][1] + a["bbox"][3]]
                for a in coco["annotations"] if a["image_id"] == i]

    exact = tmp_path / "exact"
    exact.mkdir()
    (exact / "detections_coco.json").write_text(json.dumps(coco_from_records(_detect_records(coco, gt_boxes))))
    assert run_cli(["eval", "detect", labels, exact], monkeypatch) == 0
    m = json.loads((exact / "detect_metrics.json").read_text())
    n = len(coco["annotations"])
    assert m["f1"] == 1.0 and m["n_gt"] == n and m["tp"] == n and m["min_gt_area_px"] == 0.0
    assert m["kp_err_median_px"] == pytest.approx(0.0, abs=1e-6)

    rng = np.random.default_rng(0)

    def perturbed(i):  # every third seed missed, every fifth box moved away, one false positive
        out = []
        for k, b in enumerate(gt_boxes(i)):
            if k % 3 == 0:
                continue
            out.append([b[0] + 5000, b[1], b[2] + 5000, b[3]] if k % 5 == 0 else b)
        return out + [[1.0, 1.0, 4.0, 4.0 + rng.random()]]

    pert = tmp_path / "pert.json"  # DETECTIONS may also be the COCO file itself
    pert.write_text(json.dumps(coco_from_records(_detect_records(coco, perturbed))))
    out = tmp_path / "pert_metrics.json"
    assert run_cli(["eval", "detect", labels, pert, "--out", out], monkeypatch) == 0
    p = json.loads(out.read_text())
    kept = sum(1 for i in (1, 2) for k in range(len(gt_boxes(i))) if k % 3 and k % 5)
    assert p["tp"] == kept and p["n_gt"] == n and 0.3 < p["f1"] < 0.9

    coco["images"][1]["file_name"] = "left/000099.png"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(coco))
    capsys.readouterr()
    assert run_cli(["eval", "detect", bad, exact, "--out", tmp_path / "bad_metrics.json"], monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "000099.png" in err[0] and str(bad) in err[0]
    assert not (tmp_path / "bad_metrics.json").exists()


def test_each_photo_is_resized_by_its_own_seed_size(tmp_path):
    from seedmap.detect.train_validate import plan_training

    images, anns = [], []
    for i, side in enumerate((10, 20, 40)):
        cv2.imwrite(str(tmp_path / f"p{i}.png"), np.zeros((200, 300, 3), np.uint8))
        images.append({"id": i + 1, "file_name": f"p{i}.png", "width": 300, "height": 200})
        n = 5 if i < 2 else 2  # the third photo has too few labels for a size of its own
        anns += [{"id": len(anns) + 1, "image_id": i + 1, "category_id": 1, "bbox": [5 + 50 * k, 5, side, side]}
                 for k in range(n)]
    p = tmp_path / "labels.json"
    p.write_text(json.dumps({"images": images, "annotations": anns, "categories": [{"id": 1, "name": "seed"}]}))
    plan = plan_training([p], None, None, 0.2, 0, 5.0)
    val = plan.val[str(p)]
    assert len(val) == 1 and plan.heldout[0].indices == tuple(val)
    sides = np.concatenate([[(10, 20, 40)[k]] * (5 if k < 2 else 2) for k in plan.train[str(p)]])
    assert plan.images_seed_px == np.median(sides) and plan.scale == pytest.approx(5.0 / np.median(sides))
    assert plan.image_scales == {(str(p), 0): 0.5, (str(p), 1): 0.25}


def _sized_labels(tmp_path, sizes: list[float]) -> "Path":
    """A COCO file of one 120 x 120 image per size in ``sizes``, each with six square seeds of that side."""
    coco = {"images": [], "annotations": [], "categories": [{"id": 1, "name": "seed"}]}
    for i, side in enumerate(sizes, 1):
        cv2.imwrite(str(tmp_path / f"im{i}.png"), np.zeros((120, 120, 3), np.uint8))
        coco["images"].append({"id": i, "file_name": f"im{i}.png", "width": 120, "height": 120})
        for k in range(6):
            coco["annotations"].append({"id": len(coco["annotations"]) + 1, "image_id": i, "category_id": 1,
                                        "bbox": [2 + k * 19, 2 + (k % 2) * 40, side, side]})
    p = tmp_path / "labels.json"
    p.write_text(json.dumps(coco))
    return p


@pytest.mark.parametrize("sizes,fixed", [([10, 11, 10], True), ([8, 16, 12], False)])
def test_labels_of_one_seed_size_fix_the_scale_several_sizes_leave_it_to_the_estimate(tmp_path, sizes, fixed):
    from seedmap.detect.train_validate import plan_training

    plan = plan_training([_sized_labels(tmp_path, sizes)], None, None, 0.34, 0, 5.0)
    assert plan.fixed_scale is fixed
    # every photo with enough labels trains at the network's seed size, whatever the run records
    assert sorted(plan.image_scales.values()) == pytest.approx(sorted(5.0 / s for s in sizes))


def test_rehearsal_photos_are_seeded_and_at_the_network_seed_size():
    from seedmap.detect.replay import replay_images

    a = replay_images(3, 5.0, count=3)
    b = replay_images(3, 5.0, count=3)
    assert all(t.replay for t in a) and sum(len(t.boxes) for t in a) > 20
    assert all(np.array_equal(x.rgb, y.rgb) for x, y in zip(a, b))
    for t in a:
        if len(t.boxes):
            side = np.median(np.sqrt((t.boxes[:, 2] - t.boxes[:, 0]) * (t.boxes[:, 3] - t.boxes[:, 1])))
            assert side == pytest.approx(5.0, rel=0.1)
