"""The user's own COCO labels for `seedmap train`.

A COCO file with polygon AND RLE masks exported from a tiny simulated range is read back to the GT masks
and trains the segmenter for a few CPU steps; bad COCO files are one line naming the file, exit 2, and
leave no run folder (a bbox outside the image, an unknown category, a missing image are found before the
run folder is written).
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from seedmap.detect.labels import CocoSource
from seedmap.errors import InputError

from helpers.cli import run_cli as _run
from helpers.coco import export_coco


def test_coco_polygon_and_rle_masks_read_back_to_gt_and_train_the_segmenter(tiny_range, tmp_path, monkeypatch):
    pytest.importorskip("torch")
    coco, masks = export_coco(tiny_range)
    assert len(coco["annotations"]) >= 20
    p = tmp_path / "labels.json"
    p.write_text(json.dumps(coco))
    src = CocoSource(p, images_root=tiny_range)
    assert len(src) == 2
    n_rle = n_poly = 0
    ious: list[float] = []
    for k, im in enumerate(coco["images"]):
        li = src[k]
        ids = [a["id"] for a in coco["annotations"] if a["image_id"] == im["id"]]
        assert len(li.boxes) == len(ids)
        for j, aid in enumerate(ids):
            got = li.labels == j + 1
            gt = masks[aid].astype(bool)
            # instances do not overlap in the GT label image, so every mask is decoded alone
            if aid % 2:
                assert np.array_equal(got, gt)  # RLE is exact
                n_rle += 1
            else:
                ious.append((got & gt).sum() / (got | gt).sum())
                n_poly += 1
            a = next(a for a in coco["annotations"] if a["id"] == aid)
            x, y, bw, bh = a["bbox"]
            assert np.allclose(li.boxes[j], [x, y, x + bw, y + bh])
    assert n_rle >= 10 and n_poly >= 10
    # polygons: the outer outline (0.25 px inside the pixel edges) of seeds a few pixels across, some of
    # them split in two by occluders (only the larger part is outlined)
    assert np.median(ious) >= 0.95 and np.percentile(ious, 10) >= 0.6
    out = tmp_path / "seg"
    assert _run(["train", "segmenter", p, "--images-root", tiny_range, "--out", out, "--set", "steps=2",
                 "--set", "batch_size=8", "--set", "threads=1"], monkeypatch) == 0
    assert (out / "segmenter.safetensors").stat().st_size > 0
    rows = [json.loads(ln) for ln in (out / "segmenter_metrics.jsonl").read_text().splitlines() if ln.strip()]
    assert rows and all(np.isfinite(v) for r in rows for k, v in r.items() if isinstance(v, float))


def test_seedmap_detect_coco_output_is_accepted_as_labels(tiny_range, tmp_path, monkeypatch):
    # pseudo-labels: a `seedmap detect` COCO file must pass the same checks as the user's own
    det = tmp_path / "det"
    assert _run(["detect", tiny_range, "--detector", "fast", "--out", det], monkeypatch) == 0
    src = CocoSource(det / "detections_coco.json", images_root=tiny_range)
    li = src[0]
    assert len(li.boxes) > 50 and li.labels.max() > 50


@pytest.mark.parametrize("case, needle", [
    ("missing_image", "image 'left/999999.png' (id 1) not found"),
    ("bbox_outside", "is outside the"),
    ("bbox_negative", "width, height > 0"),
    ("bbox_short", "four numbers"),
    ("unknown_category", "category_id 7 is not in 'categories'"),
    ("unknown_image", "image_id 99 is not in 'images'"),
    ("empty", "no annotations"),
    ("no_images", "'images' is empty"),
])
def test_bad_coco_is_one_line_naming_the_file_and_leaves_no_folder(tiny_range, tmp_path, monkeypatch, capsys,
                                                                     case, needle):
    coco, _ = export_coco(tiny_range, frames=(0,))
    e = copy.deepcopy(coco)
    a0 = e["annotations"][0]
    if case == "missing_image":
        e["images"][0]["file_name"] = "left/999999.png"
    elif case == "bbox_outside":
        a0["bbox"] = [5000.0, 10.0, 5.0, 5.0]
    elif case == "bbox_negative":
        a0["bbox"] = [10.0, 10.0, -5.0, 5.0]
    elif case == "bbox_short":
        a0["bbox"] = [10.0, 10.0]
    elif case == "unknown_category":
        a0["category_id"] = 7
    elif case == "unknown_image":
        a0["image_id"] = 99
    elif case == "empty":
        e["annotations"] = []
    elif case == "no_images":
        e["images"] = []
    p = tmp_path / f"{case}.json"
    p.write_text(json.dumps(e))
    with pytest.raises(InputError) as ei:
        CocoSource(p, images_root=tiny_range)
    assert needle in str(ei.value) and str(p) in str(ei.value)
    out = tmp_path / "run"
    assert _run(["train", "segmenter", p, "--images-root", tiny_range, "--out", out, "--set", "steps=1"],
                monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.replace("\r", "\n").splitlines()
           if ln.startswith("error: ") or "Traceback" in ln]
    assert len(err) == 1 and needle in err[0] and str(p) in err[0], err
    assert not out.exists()


def test_fast_cnn_on_a_coco_file_without_its_images_names_the_image_folder(tiny_range, tmp_path, monkeypatch,
                                                                           capsys):
    pytest.importorskip("torch")
    coco, _ = export_coco(tiny_range, frames=(0,))
    p = tmp_path / "labels.json"
    p.write_text(json.dumps(coco))
    out = tmp_path / "fc"
    assert _run(["train", "fast-cnn", p, "--out", out, "--steps", "1"], monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error: ")]
    assert len(err) == 1 and str(p) in err[0] and "--images-root" in err[0], err
    assert not out.exists()
