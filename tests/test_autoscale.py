"""``cnn.scale = auto``: the ``fast`` detector estimates the seeds' size from the images and resizes them to its own.

Truth: the median geometric mean of the GT box sides of the detectable seeds of a simulated frame, times the factor
the frame is rescaled by. The frames are a 420x315 window at the default camera's pixel scale, so a detectable seed is
one of the default 1434-px camera (min_visible_seed_px(1434)).
"""

from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from seedmap.detect import cnn as cnn_mod
from seedmap.detect import make_detector
from seedmap.detect.autoscale import Level, estimate_seed_px, size_from_levels
from seedmap.detect.cnn import network_scale_cue, network_score_size
from seedmap.detect.config import min_visible_seed_px
from seedmap.errors import ConfigError
from seedmap.eval.detect_metrics import frame_metrics

from helpers.cli import run_cli


#: the frame the estimates are tested on (the one with the most seeds of the last three)
FRAME = 5


def _true_seed_px(ds, i: int) -> float:
    gt = ds.gt_instances(i, "left")
    b = gt.boxes[gt.area >= min_visible_seed_px(1434)]
    return float(np.median(np.sqrt((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]))))


def _resize(img: np.ndarray, f: float) -> np.ndarray:
    return cv2.resize(img, None, fx=f, fy=f, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)


@pytest.fixture(scope="module")
def frame(cnn_range):
    return np.ascontiguousarray(cnn_range[FRAME].left), _true_seed_px(cnn_range, FRAME)


def _f1(det, gt, f: float) -> float:  # noqa: ANN001 - Detections, Instances
    """Box F1 (IoU 0.5) of ``det`` against the GT of a frame rescaled by ``f``."""
    b = gt.boxes.astype(np.float64) * f
    g = SimpleNamespace(boxes=b, area=gt.area * f * f, center_visible=gt.center_visible, center_uv=gt.center_uv * f)
    return frame_metrics(det, g, min_gt_area=min_visible_seed_px(1434) * f * f)[0].f1


@pytest.fixture()
def count_estimates(monkeypatch):
    """The number of seed-size estimates the detector runs."""
    calls = []

    def counted(*a, **k):
        calls.append(1)
        return estimate_seed_px(*a, **k)

    monkeypatch.setattr(cnn_mod, "estimate_seed_px", counted)
    return calls


@pytest.mark.parametrize("factor", [0.5, 1.0, 3.0])
def test_estimate_is_within_15_percent_of_the_true_seed_size(frame, factor):
    img, true = frame
    det = make_detector("fast")
    est = estimate_seed_px(det.peaks, _resize(img, factor), det.trained_seed_px).seed_px
    assert est == pytest.approx(true * factor, rel=0.15)


def test_auto_keeps_scale_1_in_band_and_resizes_large_seeds(frame, cnn_range, count_estimates):
    img, true = frame
    gt = cnn_range.gt_instances(FRAME, "left")
    det = make_detector("fast")
    assert det.scale is None and det.scale_source == "auto"
    d1 = det.detect(img)
    assert det.scale == 1.0 and det.seed_px_estimate == pytest.approx(true, rel=0.15)
    assert len(d1) == len(make_detector("fast", overrides=["cnn.scale=1"]).detect(img))  # same as forced scale 1
    big = _resize(img, 3.0)
    det.detect(big)  # a sequence keeps the scale of its first image
    assert det.scale == 1.0 and len(count_estimates) == 1
    det.reset_scale()  # a new photo: estimated again
    d3 = det.detect(big)
    assert len(count_estimates) == 2 and det.scale == pytest.approx(1 / 3, rel=0.15)
    plain = make_detector("fast", overrides=["cnn.scale=1"]).detect(big)
    assert _f1(d3, gt, 3.0) > _f1(d1, gt, 1.0) - 0.1 > _f1(plain, gt, 3.0) + 0.3


def test_forced_scale_or_seed_px_skip_the_estimate(frame, count_estimates):
    img, _ = frame
    for ov, scale, src in (["cnn.scale=0.5"], 0.5, "scale"), (["cnn.seed_px=10"], 0.5, "seed_px"):
        det = make_detector("fast", overrides=ov)
        det.detect(img)
        det.reset_scale()
        det.detect(img)
        s = det.settings()
        assert det.scale == scale and s["scale_source"] == src and s["seed_px_estimate"] is None
    assert count_estimates == []


def test_a_network_with_images_seed_px_runs_at_its_fixed_scale(frame, tmp_path, count_estimates):
    import onnx

    m = onnx.load(str(cnn_mod.default_cnn_path("field")))
    props = {p.key: p for p in m.metadata_props}
    info = json.loads(props["info"].value) if "info" in props else {}
    info.update(seed_px=6.0, images_seed_px=24.0)
    if "info" in props:
        props["info"].value = json.dumps(info)
    else:
        m.metadata_props.add(key="info", value=json.dumps(info))
    p = tmp_path / "tuned.onnx"
    onnx.save(m, str(p))
    det = make_detector("fast", weights=p)
    assert det.scale == pytest.approx(0.25) and det.scale_source == "network"
    det.detect(frame[0])
    assert count_estimates == []
    assert make_detector("fast", weights=p, overrides=["cnn.scale=1"]).scale == 1.0  # forcing wins
    shutil.copy(cnn_mod.default_cnn_path("field"), tmp_path / "plain.onnx")
    assert make_detector("fast", weights=tmp_path / "plain.onnx").scale_source == "auto"


def test_scale_is_recorded_for_a_dataset_and_per_photo(cnn_range, frame, tmp_path, monkeypatch, capsys):
    from seedmap.detect.run import run_detect

    out = run_detect(cnn_range.root, tmp_path / "seq", "fast", frames=slice(FRAME - 1, FRAME + 1), progress=False)
    meta = json.loads((out / "meta.json").read_text())  # estimated on the first frame run
    assert meta["scale_source"] == "auto" and meta["cnn_scale"] == 1.0
    assert meta["seed_px_estimate"] == pytest.approx(_true_seed_px(cnn_range, FRAME - 1), rel=0.15)
    img, true = frame
    d = tmp_path / "photos"
    d.mkdir()
    cv2.imwrite(str(d / "a.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(d / "b.png"), cv2.cvtColor(_resize(img, 3.0)[:900, :1200], cv2.COLOR_RGB2BGR))
    capsys.readouterr()
    assert run_cli(["detect", d, "--detector", "fast", "--out", tmp_path / "ph"], monkeypatch) == 0
    assert "seed size (estimated, per image)" in capsys.readouterr().out
    ims = json.loads((tmp_path / "ph" / "detections_coco.json").read_text())["images"]
    assert [im["file_name"] for im in ims] == ["a.png", "b.png"]
    op = make_detector("fast", overrides=["cnn.domain=photo"]).trained_seed_px  # the photo network's seed size
    assert ims[0]["seed_px"] == pytest.approx(true, rel=0.15)
    assert ims[1]["seed_px"] == pytest.approx(3 * true, rel=0.15)
    for im in ims:  # the network runs where it scores highest: for seeds within a ladder step of the estimate
        if im["cnn_scale"] != 1.0:
            assert op / im["cnn_scale"] == pytest.approx(im["seed_px"], rel=0.3)
    assert ims[1]["cnn_scale"] < 1.0
    meta = json.loads((tmp_path / "ph" / "meta.json").read_text())
    assert meta["scale_source"] == "auto" and meta["detections"] > 0


@pytest.mark.parametrize("value,scale", [("auto", None), ("AUTO", None), ("0.5", 0.5), ("4", 4.0)])
def test_scale_config_accepts_auto_and_numbers(value, scale):
    assert make_detector("fast", overrides=[f"cnn.scale={value}"]).scale == scale


@pytest.mark.parametrize("value", ["big", "0", "-1", "5", "true"])
def test_bad_scale_values_are_one_line_config_errors(value, tmp_path, monkeypatch, capsys, frame):
    with pytest.raises(ConfigError, match="auto, folder or a number"):
        make_detector("fast", overrides=[f"cnn.scale={value}"])
    p = tmp_path / "a.png"
    cv2.imwrite(str(p), np.zeros((64, 64, 3), np.uint8))
    assert run_cli(["detect", p, "--out", tmp_path / "o", "--set", f"cnn.scale={value}"], monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error:") and "cnn.scale" in err[0]
    assert not (tmp_path / "o").exists()


def test_arm_network_estimates_an_arm_scan(arm_scan_6_views):
    """The arm network on a scan whose seeds are smaller than its own (~4.5 px for 7): the size is found and the
    scan is upscaled to it."""
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(arm_scan_6_views)
    gt = ds.gt_instances(0, "left")
    b = gt.boxes[gt.area >= min_visible_seed_px(ds.calib.width)]
    true = float(np.median(np.sqrt((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]))))
    det = make_detector("fast", overrides=["cnn.domain=arm"])
    scale = det.ensure_scale(ds[0].left)
    assert det.seed_px_estimate == pytest.approx(true, rel=0.15)
    assert scale == pytest.approx(7.0 / det.seed_px_estimate) and scale > 1.2


def test_size_is_read_where_the_boxes_come_closest_when_they_never_reach_the_target():
    """Levels the arm network gave on a 1024x750 arm-scan view (true seed size 8.4 px): its boxes stop at 12.5 px,
    short of the 12.6-px target, so no level pair passes it; the closest level (12.5 px at scale 1.41) reads
    8.8 px, 8.3 px without the blur. With a pass the size is interpolated between the two levels."""
    lv = [Level(2.0, 36, 1.0, 0.6, 10.86), Level(2 ** 0.5, 701, 1.0, 0.7, 12.50), Level(1.0, 708, 1.0, 0.7, 9.37),
          Level(2 ** -0.5, 767, 1.0, 0.7, 7.13), Level(0.5, 893, 1.0, 0.6, 5.59), Level(0.25, 8, 1.0, 0.6, 7.0)]
    assert size_from_levels(lv, 7.0) == pytest.approx(8.26, abs=0.01)
    passing = [Level(2.0, 700, 1.0, 0.7, 10.0), Level(2 ** 0.5, 900, 1.0, 0.7, 8.0)]
    s = np.exp(np.log(2.0) + np.log(10 / 9) / np.log(10 / 8) * np.log(2 ** -0.5))  # boxes of 9 px at scale s
    assert size_from_levels(passing, 5.0) == pytest.approx(np.sqrt((9 / s) ** 2 - 2.25 ** 2))
    assert size_from_levels([Level(1.0, 5, 1.0, 0.7, 9.0)], 5.0) is None  # too few peaks anywhere


def test_the_photo_network_reads_a_grain_photos_seed_size_off_its_scores():
    from seedmap.detect.autoscale import estimate_seed_px
    from seedmap.sim.photos.compose import render_photo

    from seedmap.detect.config import PHOTO_DEFAULTS

    # as `seedmap detect` runs photos: the whole image, no tile gate (its brightness test skips dark seeds on paper)
    det = make_detector("fast", overrides=["cnn.domain=photo", f"cnn.tile={PHOTO_DEFAULTS['cnn']['tile']}"])
    assert network_scale_cue(det.path, det.info) == "score" and det.scale_cue == "score"
    errs = []
    for seed in range(10):  # every photo of the stream, dim and colour-cast ones included; no estimate = error 1
        ph = render_photo(np.random.default_rng(seed), "train", (640, 640), (16.0, 24.0), 0.0)
        sides = [np.sqrt((np.ptp(xs) + 1) * (np.ptp(ys) + 1)) for xs, ys in
                 ((np.nonzero(ph.ids == k)[1], np.nonzero(ph.ids == k)[0]) for k in ph.seeds)]
        true = float(np.median(sides))
        est = estimate_seed_px(det.peaks, ph.image, det.trained_seed_px, "score", det.score_size).seed_px
        errs.append(1.0 if est is None else abs(est / true - 1))
    assert np.median(errs) < 0.15 and np.mean(np.array(errs) < 0.15) >= 0.7, errs
    with pytest.raises(ValueError, match="cue"):
        estimate_seed_px(det.peaks, ph.image, det.trained_seed_px, "colour")


def test_the_score_cues_multiple_belongs_to_the_network(tmp_path):
    """A network file's recorded multiple wins; shipped files use SCORE_SIZE; a trained file without one (older
    fine-tunes) keeps the multiple it was made with; the estimate scales with it."""
    from seedmap.detect.autoscale import SCORE_SIZE, UNRECORDED_SCORE_SIZE, size_from_scores
    from seedmap.detect.cnn import default_cnn_path

    shipped = default_cnn_path("photo")
    assert network_score_size(shipped, {}) == SCORE_SIZE
    assert network_score_size(shipped, {"score_size": 1.3}) == 1.3
    assert network_score_size(tmp_path / "fast_cnn.onnx", {"scale_cue": "score"}) == UNRECORDED_SCORE_SIZE
    levels = [Level(2.0, 30, 1.0, 0.70, 8.0), Level(1.0, 30, 1.0, 0.90, 8.0), Level(0.5, 30, 1.0, 0.70, 8.0)]
    assert size_from_scores(levels, 8.0, 1.0) == pytest.approx(8.0)  # symmetric scores: the peak at scale 1
    assert size_from_scores(levels, 8.0, 1.3) == pytest.approx(1.3 * 8.0)


def test_a_score_network_declares_the_seed_size_at_which_its_estimates_centre_on_labels(tmp_path):
    """calibrate_seed_px (training from scratch, score cue): a copy of the photo network that declares a seed size
    30 % too small reads sizes 30 % too small; calibrated on labelled photos, it declares one at which its
    estimates on other photos centre on their labels again, and close to the shipped network's."""
    onnx = pytest.importorskip("onnx")
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.config import CnnConfig
    from seedmap.detect.labels import CocoSource
    from seedmap.detect.train_validate import HeldOut, calibrate_seed_px
    from seedmap.sim.photos import PhotoSimConfig, simulate_photos

    shipped = CnnDetector(CnnConfig(domain="photo", tile=0))
    m = onnx.load(str(shipped.path))
    wrong = shipped.trained_seed_px * 0.7
    for p in m.metadata_props:
        if p.key == "info":
            p.value = json.dumps({**json.loads(p.value), "seed_px": wrong})
    onnx.save(m, str(tmp_path / "wrong.onnx"))

    def photos(seed: int, n: int) -> CocoSource:
        cfg = PhotoSimConfig(count=n, seed=seed, split="validation", long_side=(320, 400), seed_px=(10.0, 16.0),
                             empty_fraction=0.0)
        return CocoSource(simulate_photos(cfg, tmp_path / f"p{seed}", progress=False) / "labels.json", None)

    fit = photos(1, 8)
    cal = calibrate_seed_px(tmp_path / "wrong.onnx", [HeldOut(coco=fit, indices=tuple(range(len(fit))))])
    assert cal is not None and cal["images"] >= 5
    assert cal["median_ratio_before"] == pytest.approx(0.7, abs=0.12)
    assert cal["seed_px"] == pytest.approx(shipped.trained_seed_px, rel=0.12)
    assert calibrate_seed_px(tmp_path / "wrong.onnx", [HeldOut(coco=fit, indices=(0, 1, 2))]) is None
    det = CnnDetector(CnnConfig(domain="photo", tile=0), tmp_path / "wrong.onnx")
    check = photos(2, 6)
    ratios = []
    for k in range(len(check)):
        li = check[k]
        b = np.asarray(li.boxes, float).reshape(-1, 4)
        true = float(np.median(np.sqrt((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]))))
        est = estimate_seed_px(det.peaks, li.image, cal["seed_px"], det.scale_cue, det.score_size).seed_px
        ratios.append(est / true if est else 0.0)
    assert np.median(ratios) == pytest.approx(1.0, abs=0.12), ratios


def test_the_score_peak_is_read_between_ladder_levels_and_ignores_a_second_bump():
    """The score cue's peak is the score-weighted centre of the curve's upper half around its highest (smoothed)
    level: asymmetric neighbours move it off the level, a lone noisy level elsewhere does not pull it, and the
    ladder's midpoints are measured only around the peak."""
    from seedmap.detect.autoscale import LADDER_STEP, score_midpoints, size_from_scores

    scales = 2.0 / LADDER_STEP ** np.arange(7)  # 2 ... 0.25
    curve = [0.55, 0.56, 0.62, 0.80, 0.76, 0.60, 0.55]  # peak at scale 0.707, leaning towards 0.5
    levels = [Level(float(s), 40, 1.0, y, 8.0) for s, y in zip(scales, curve)]
    s_peak = 8.0 / size_from_scores(levels, 8.0, 1.0)
    assert 0.5 < s_peak < 0.707 * 0.98  # between the best level and its better neighbour, not on a level
    # a far, isolated high level (background texture at another scale) does not move the peak
    bump = [Level(4.0, 40, 1.0, 0.79, 8.0), Level(2.83, 40, 1.0, 0.55, 8.0), *levels]
    assert 8.0 / size_from_scores(bump, 8.0, 1.0) == pytest.approx(s_peak, rel=0.02)
    mids = score_midpoints(levels)
    assert mids and all(0.25 < m < 1.5 for m in mids) and len(mids) <= 4
    assert score_midpoints([Level(1.0, 5, 1.0, 0.9, 8.0)]) == []  # too few peaks: nothing to refine


def test_the_photo_networks_estimate_follows_a_rescale_between_ladder_levels():
    """Estimates of one photo rescaled by a quarter and a half ladder step scale with it (the peak is read between
    levels, not pinned to one)."""
    from seedmap.detect.autoscale import estimate_seed_px
    from seedmap.detect.config import PHOTO_DEFAULTS
    from seedmap.sim.photos.compose import render_photo

    det = make_detector("fast", overrides=["cnn.domain=photo", f"cnn.tile={PHOTO_DEFAULTS['cnn']['tile']}"])
    ph = render_photo(np.random.default_rng(3), "train", (560, 560), (18.0, 18.0), 0.0)
    per_px = []
    for f in (1.0, 2 ** 0.25, 2 ** 0.5):
        img = cv2.resize(ph.image, None, fx=f, fy=f, interpolation=cv2.INTER_LINEAR)
        est = estimate_seed_px(det.peaks, img, det.trained_seed_px, "score", det.score_size).seed_px
        per_px.append(est / f)
    assert max(per_px) / min(per_px) < 1.12, per_px
