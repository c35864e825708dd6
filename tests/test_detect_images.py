"""``seedmap detect`` on plain images: one file, or a folder of photos (no stereo, no calibration).

The photos are crops of a simulated frame written as PNG, JPEG, grayscale, 16-bit TIFF and RGBA; the results keep
the user's file names, one COCO image per photo, and the seed size the user gives sets the network's scale.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from seedmap.detect import make_detector
from seedmap.detect.cnn import auto_scale
from seedmap.errors import ConfigError, InputError
from seedmap.io.photos import PhotoSet, is_photo_input, read_photo

from helpers.cli import run_cli
from helpers.networks import PHOTO_SEED_PX


def _errors(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.replace("\r", "\n").splitlines()
            if ln.startswith("error: ") or "Traceback" in ln]


@pytest.fixture(scope="module")
def crop(cnn_range) -> np.ndarray:
    """A simulated frame with many seeds (420 x 315 px) as a photo."""
    return np.ascontiguousarray(cnn_range[2].left)


@pytest.fixture()
def photos(crop, tmp_path):
    """A folder of the crop in five encodings, a subfolder and a text file (neither is an image of the folder)."""
    d = tmp_path / "photos"
    (d / "sub").mkdir(parents=True)
    bgr = cv2.cvtColor(crop, cv2.COLOR_RGB2BGR)
    cv2.imwrite(str(d / "IMG_10.png"), bgr)
    cv2.imwrite(str(d / "IMG_2.jpg"), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    cv2.imwrite(str(d / "gray.png"), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    cv2.imwrite(str(d / "scan16.tif"), bgr.astype(np.uint16) * 257)
    cv2.imwrite(str(d / "alpha.png"), np.dstack([bgr, np.full(bgr.shape[:2], 128, np.uint8)]))
    cv2.imwrite(str(d / "sub" / "other.png"), bgr)
    (d / "notes.txt").write_text("not an image")
    return d


def test_photos_are_converted_to_8_bit_rgb(photos, crop):
    assert np.array_equal(read_photo(photos / "IMG_10.png"), crop)
    assert np.array_equal(read_photo(photos / "scan16.tif"), crop)  # 16-bit scaled back to 8 bits
    assert np.array_equal(read_photo(photos / "alpha.png"), crop)  # alpha dropped
    g = read_photo(photos / "gray.png")
    assert g.shape == crop.shape and g.dtype == np.uint8 and (g[..., 0] == g[..., 2]).all()
    twelve = photos / "twelve.png"  # 12-bit camera data in a 16-bit file keeps its brightness
    cv2.imwrite(str(twelve), cv2.cvtColor(crop, cv2.COLOR_RGB2BGR).astype(np.uint16) * 16)
    assert np.array_equal(read_photo(twelve), crop)
    bad = photos / "float.tif"
    cv2.imwrite(str(bad), np.zeros((8, 8, 3), np.float32))
    with pytest.raises(InputError, match="float.tif"):
        read_photo(bad)


def test_a_folder_of_photos_lists_its_images_by_name_not_its_subfolders(photos, crop):
    ps = PhotoSet(photos)
    assert ps.names == ["IMG_2.jpg", "IMG_10.png", "alpha.png", "gray.png", "scan16.tif"]
    assert is_photo_input(photos) and is_photo_input(photos / "gray.png")
    assert PhotoSet(photos / "gray.png").names == ["gray.png"]


def test_detect_on_a_folder_keeps_the_file_names_one_coco_image_per_photo(photos, crop, tmp_path, monkeypatch):
    out = tmp_path / "det"
    assert run_cli(["detect", photos, "--detector", "fast", "--out", out, "--overlay"], monkeypatch) == 0
    coco = json.loads((out / "detections_coco.json").read_text())
    names = ["IMG_2.jpg", "IMG_10.png", "alpha.png", "gray.png", "scan16.tif"]
    assert [im["file_name"] for im in coco["images"]] == names
    assert all((im["width"], im["height"]) == (420, 315) for im in coco["images"])
    recs = [json.loads(ln) for ln in (out / "detections.jsonl").read_text().splitlines()]
    assert [r["image"] for r in recs] == names and all(r["camera"] == "mono" for r in recs)
    n = {r["image"]: r["n"] for r in recs}
    assert n["IMG_10.png"] > 50  # the simulated seeds are found in the photo ...
    assert n["alpha.png"] == n["scan16.tif"] == n["IMG_10.png"]  # ... whatever the lossless encoding
    assert abs(n["IMG_2.jpg"] - n["IMG_10.png"]) < 0.2 * n["IMG_10.png"]
    assert len(coco["annotations"]) == sum(n.values())
    assert sorted(p.name for p in (out / "overlay").iterdir()) == ["IMG_10.png", "IMG_2.png", "alpha.png",
                                                                    "gray.png", "scan16.png"]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["images"] == 5 and meta["trained_seed_px"] == PHOTO_SEED_PX  # the photo network's size
    for im in coco["images"]:  # each photo at its own scale: where the network scores highest, near its seed size
        if im["cnn_scale"] != 1.0:
            assert PHOTO_SEED_PX / im["cnn_scale"] == pytest.approx(im["seed_px"], rel=0.3)
    one = tmp_path / "one"
    assert run_cli(["detect", photos / "IMG_10.png", "--detector", "fast", "--out", one], monkeypatch) == 0
    assert [im["file_name"] for im in json.loads((one / "detections_coco.json").read_text())["images"]] == \
        ["IMG_10.png"]
    (rec,) = [json.loads(ln) for ln in (one / "detections.jsonl").read_text().splitlines()]
    assert rec["boxes"] == recs[1]["boxes"] and rec["image"] == "IMG_10.png"


def test_photos_run_the_photo_network_on_the_whole_image_unless_told_otherwise(photos, tmp_path, monkeypatch):
    import yaml

    out = tmp_path / "det"
    assert run_cli(["detect", photos / "IMG_10.png", "--out", out], monkeypatch) == 0
    cnn = yaml.safe_load((out / "config.yaml").read_text())["cnn"]
    assert cnn["domain"] == "photo" and cnn["tile"] == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta["scale_source"] == "auto" and meta["seed_px_estimate"] > 0
    field = tmp_path / "field"
    assert run_cli(["detect", photos / "IMG_10.png", "--out", field, "--set", "cnn.domain=field"], monkeypatch) == 0
    cnn = yaml.safe_load((field / "config.yaml").read_text())["cnn"]
    assert cnn["domain"] == "field" and cnn["tile"] == 0
    n_photo = len(json.loads((out / "detections_coco.json").read_text())["annotations"])
    assert n_photo > 50  # the photo network finds the simulated range's seeds too


@pytest.mark.parametrize("case", ["gt", "corrupt", "empty-folder", "text-file"])
def test_bad_photo_inputs_are_one_line_and_write_nothing(case, photos, tmp_path, monkeypatch, capsys):
    path, det, needle = photos, "fast", None
    if case == "gt":
        det, needle = "gt", "oracle"
    elif case == "corrupt":
        (photos / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"x" * 40)
        needle = "broken.png"
    elif case == "empty-folder":
        path = tmp_path / "empty"
        path.mkdir()
        needle = str(path)
    else:
        path, needle = photos / "notes.txt", "notes.txt"
    out = tmp_path / "out"
    assert run_cli(["detect", path, "--detector", det, "--out", out], monkeypatch) == 2
    err = _errors(capsys)
    assert len(err) == 1 and needle in err[0], err
    assert not out.exists()


def test_seed_px_scales_large_seeds_to_the_training_size(crop, tmp_path, monkeypatch):
    """The crop enlarged 2x: with its seed size given (10 px) the network finds the seeds of the original at
    twice the coordinates; without it the count is far off."""
    base = make_detector("fast").detect(crop)
    big = cv2.resize(crop, (840, 630), interpolation=cv2.INTER_CUBIC)
    det = make_detector("fast", overrides=["cnn.seed_px=10"])
    assert det.scale == pytest.approx(0.5)
    d = det.detect(big)
    assert abs(len(d) - len(base)) < 0.15 * len(base)
    k_big, k = d.keypoints, base.keypoints
    dist = np.sqrt(((k_big[:, None] - (2 * k[None] + 0.5)) ** 2).sum(-1)).min(1)
    assert np.median(dist) < 2.0
    plain = make_detector("fast", overrides=["cnn.scale=1"]).detect(big)
    assert abs(len(plain) - len(base)) > 0.3 * len(base)
    photo = tmp_path / "big.png"
    cv2.imwrite(str(photo), cv2.cvtColor(big, cv2.COLOR_RGB2BGR))
    out = tmp_path / "det"
    assert run_cli(["detect", photo, "--detector", "fast", "--out", out, "--set", "cnn.seed_px=10"],
                   monkeypatch) == 0
    meta = json.loads((out / "meta.json").read_text())
    op = PHOTO_SEED_PX  # a photo runs the photo network
    assert meta["cnn_scale"] == pytest.approx(op / 10.0) and meta["seed_px"] == pytest.approx(10.0)
    assert meta["trained_seed_px"] == op


def test_seed_px_and_scale_together_or_too_small_seeds_are_config_errors():
    with pytest.raises(ConfigError, match="not both"):
        make_detector("fast", overrides=["cnn.seed_px=10", "cnn.scale=0.5"])
    with pytest.raises(ConfigError, match="too small"):
        make_detector("fast", overrides=["cnn.seed_px=1"])
    assert make_detector("fast", overrides=["cnn.seed_px=7", "cnn.domain=arm"]).scale == pytest.approx(1.0)


def _rig(d, sizes, seed=0, empty=()):
    """A folder of simulated training photos (480 x 480) with seeds of ``sizes`` px (one photo each); the photos at
    the indices ``empty`` have none."""
    from seedmap.sim.photos.compose import render_photo

    d.mkdir()
    for k, px in enumerate(sizes):
        ph = render_photo(np.random.default_rng(seed + k), "train", (480, 480), (px, px * 1.05),
                          1.0 if k in empty else 0.0)
        cv2.imwrite(str(d / f"tray_{k}.png"), cv2.cvtColor(ph.image, cv2.COLOR_RGB2BGR))
    return d


def test_one_seed_size_per_folder_is_the_median_of_the_photos_estimates(tmp_path, monkeypatch, capsys):
    """``cnn.scale=folder``: every photo runs at one seed size, the median of what each photo alone gives
    (a fixed camera), near the true size; four photos are too few for the default to look for a folder's size."""
    d = _rig(tmp_path / "rig", [18.0] * 4)
    own, folder = tmp_path / "own", tmp_path / "folder"
    assert run_cli(["detect", d, "--out", own], monkeypatch) == 0
    capsys.readouterr()
    assert run_cli(["detect", d, "--out", folder, "--set", "cnn.scale=folder"], monkeypatch) == 0
    assert "seed size (estimated, all 4 images)" in capsys.readouterr().out
    ims = json.loads((own / "detections_coco.json").read_text())["images"]
    assert {im["seed_px_from"] for im in ims} == {"photo"}
    est = [im["seed_px"] for im in ims]
    assert sum(e is not None for e in est) >= 3
    want = float(np.median([e for e in est if e is not None]))
    run = float(np.median([PHOTO_SEED_PX / im["cnn_scale"] for im in ims if im["seed_px"] is not None]))
    got = json.loads((folder / "detections_coco.json").read_text())["images"]
    assert [im["seed_px"] for im in got] == [pytest.approx(want, abs=1e-3)] * 4
    assert {im["seed_px_from"] for im in got} == {"folder"}
    assert abs(want / 18.5 - 1) < 0.2
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["scale_source"] == "auto" and meta["seed_px_estimate"] == pytest.approx(want, abs=1e-3)
    assert meta["cnn_scale"] == pytest.approx(auto_scale(run, PHOTO_SEED_PX, band=False), rel=1e-4)


def test_a_one_setup_folder_runs_every_photo_at_the_size_its_photos_agree_on(tmp_path, monkeypatch, capsys):
    """The default on a folder of one setup (seeds of one size; two photos without seeds): the photos agree on a
    size and all run at it, the seedless ones included; on a folder of two setups (seeds 3x apart) each photo keeps
    its own size."""
    one = _rig(tmp_path / "one", [18.0] * 7, empty=(2, 5))
    capsys.readouterr()
    assert run_cli(["detect", one, "--out", tmp_path / "r1"], monkeypatch) == 0
    meta = json.loads((tmp_path / "r1" / "meta.json").read_text())
    assert abs(meta["folder_seed_px"] / 18.5 - 1) < 0.2 and 2 <= meta["photos_rerun"] <= 7
    assert "photos ran again at it" in capsys.readouterr().out
    ims = json.loads((tmp_path / "r1" / "detections_coco.json").read_text())["images"]
    scales = np.array([im["cnn_scale"] for im in ims])
    assert scales.max() / scales.min() < 1.05 ** 2  # one size: every photo within the tolerance of the median
    assert ims[2]["seed_px_from"] == ims[5]["seed_px_from"] == "folder"
    assert all(abs(im["seed_px"] / 18.5 - 1) < 0.2 for im in ims)
    two = _rig(tmp_path / "two", [12.0, 36.0] * 3, seed=10)
    assert run_cli(["detect", two, "--out", tmp_path / "r2"], monkeypatch) == 0
    ims = json.loads((tmp_path / "r2" / "detections_coco.json").read_text())["images"]
    assert {im["seed_px_from"] for im in ims} == {"photo"}
    meta = json.loads((tmp_path / "r2" / "meta.json").read_text())
    assert meta["folder_seed_px"] is None and meta["photos_rerun"] == 0
    small, large = [np.median([im["seed_px"] for im in ims[k::2]]) for k in (0, 1)]
    assert 2.0 < large / small < 4.5


def test_folder_agreement_needs_most_photos_within_the_band():
    """One setup: the photos off the median run again (and those without an estimate); sizes split between two
    ladder levels still agree on the seed size; mixed sizes or too few photos: None."""
    from seedmap.detect.autoscale import folder_agreement

    est = [(12.0, 11.0)] * 6 + [(12.5, 24.0), (None, None), (36.0, 33.0)]
    seed, run, redo = folder_agreement(est)
    assert seed == pytest.approx(12.0) and run == pytest.approx(11.0)
    assert redo.tolist() == [False] * 6 + [True] * 3
    split = [(12.0, 11.0), (12.5, 15.5), (12.2, 11.2), (12.4, 15.7), (11.9, 11.1), (12.1, 15.2)]
    seed, run, redo = folder_agreement(split)
    assert 11.9 <= seed <= 12.5 and 11.0 <= run <= 15.7 and redo.sum() >= 3
    assert folder_agreement([(10.0 * 1.3 ** k, 10.0 * 1.3 ** k) for k in range(8)]) is None
    assert folder_agreement([(12.0, 11.0)] * 4) is None
