"""Count calibration (seedmap.recon.calibrate): fitting, the domain guard, the shipped file, the CLI."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from seedmap.errors import ConfigError, InputError
from seedmap.recon.calibrate import (CountFeatures, calibrate_count, count_domain, count_features,
                                     fit_count_calibration, load_count_calibration, save_count_calibration,
                                     shipped_calibration_dir)
from seedmap.recon.config import ReconConfig
from seedmap.recon.count import SeedCount, StereoKeypoints


def _samples(n: int, rng: np.random.Generator, b=(-0.8, 2.3, -0.06), noise: float = 0.0):
    """Features of ``n`` panicles and true counts made with log(count / true) = b0 + b1 f + b2 d (+ noise)."""
    feats, truth = [], []
    for _ in range(n):
        f, d, c = rng.uniform(0.38, 0.49), rng.uniform(2.5, 4.1), int(rng.integers(1000, 4000))
        feats.append(CountFeatures(c, 24, int(round(f * c * 24)), d))
        lr = b[0] + b[1] * feats[-1].obs_fraction + b[2] * d + rng.normal(0, noise)
        truth.append(c / np.exp(lr))
    return feats, truth


def test_fit_recovers_the_model_and_estimates_invert_it():
    rng = np.random.default_rng(0)
    feats, truth = _samples(40, rng)
    dom = count_domain(ReconConfig(detector="gt"))
    cal = fit_count_calibration(feats, truth, dom, [f"p{i}" for i in range(40)])
    assert cal.intercept == pytest.approx(-0.8, abs=1e-6)
    assert cal.coef["obs_fraction"] == pytest.approx(2.3, abs=1e-6)
    assert cal.coef["seed_diam_mm"] == pytest.approx(-0.06, abs=1e-6)
    assert [cal.estimate(f) for f in feats] == pytest.approx(truth, rel=1e-9)
    assert cal.fit["calibrated_mape_pct"] < 1e-6 and cal.fit["loo_mape_pct"] < 1e-6
    assert cal.fit["raw_mape_pct"] > 1.0
    assert cal.views_range == (24, 24)
    assert cal.estimate(CountFeatures(0, 24, 0, float("nan"))) == 0.0


def test_fit_with_noise_reports_an_honest_leave_one_out_error():
    rng = np.random.default_rng(1)
    feats, truth = _samples(30, rng, noise=0.05)
    cal = fit_count_calibration(feats, truth, count_domain(ReconConfig(detector="gt")), [str(i) for i in range(30)])
    # the in-sample error is optimistic, the leave-one-out one is not, and both are near the 5 % noise
    assert cal.fit["calibrated_mape_pct"] < cal.fit["loo_mape_pct"] < 6.0
    # constant-ratio calibration: intercept = mean log ratio, no coefficients
    c0 = fit_count_calibration(feats, truth, cal.domain, [str(i) for i in range(30)], features=())
    assert c0.coef == {}
    assert c0.intercept == pytest.approx(np.mean(np.log([f.count / t for f, t in zip(feats, truth)])))


def test_fit_refuses_too_few_panicles_and_unknown_features():
    rng = np.random.default_rng(2)
    feats, truth = _samples(3, rng)
    dom = count_domain(ReconConfig(detector="gt"))
    with pytest.raises(InputError, match="at least 5"):
        fit_count_calibration(feats, truth, dom, ["a", "b", "c"], features=("obs_fraction", "seed_diam_mm"))
    with pytest.raises(ConfigError, match="unknown count-calibration feature"):
        fit_count_calibration(feats, truth, dom, ["a", "b", "c"], features=("colour",))
    feats[1] = CountFeatures(0, 24, 0, float("nan"))
    with pytest.raises(InputError, match="b: .*no counted seeds"):
        fit_count_calibration(feats, truth, dom, ["a", "b", "c"], features=())


def test_count_features_of_keypoints_and_a_count():
    views = [StereoKeypoints(np.zeros((10, 2)), np.zeros((9, 2)), np.full(10, 7.0)), None,
             StereoKeypoints(np.zeros((6, 2)), np.zeros((6, 2)), np.full(6, 7.0))]
    cnt = SeedCount(np.zeros((4, 3)), np.array([0.003, 0.004, 0.0035, 0.005]), np.full(4, 2), np.zeros(16, int),
                    np.zeros(4))
    f = count_features(views, cnt)
    assert (f.count, f.views, f.detections) == (4, 2, 16)
    assert f.obs_fraction == pytest.approx(16 / (4 * 2))
    assert f.seed_diam_mm == pytest.approx(3.75)


def test_shipped_fast_calibration_applies_to_the_default_fast_run_only(tmp_path):
    p = shipped_calibration_dir() / "fast.json"
    cal = load_count_calibration(p)
    # the default `seedmap reconstruct --detector fast` run is the calibration's domain ...
    assert cal.domain.mismatch(count_domain(ReconConfig(detector="fast"))) is None
    assert cal.views_range[0] <= 24 <= cal.views_range[1] and len(cal.samples) >= 100
    # ... and the fit's own leave-one-out error beats the raw counts it was fitted on
    assert cal.fit["loo_mape_pct"] < cal.fit["raw_mape_pct"]
    f = CountFeatures(2000, 24, int(0.43 * 2000 * 24), 3.5)
    out = calibrate_count(ReconConfig(detector="fast"), f)
    assert out.estimate == pytest.approx(cal.estimate(f)) and out.source == str(p) and out.reason == ""
    assert out.fitted.startswith(f"fitted on {len(cal.samples)} panicles with 24-24 views against GT countable seeds")
    # any other counter or detector setting leaves the count uncalibrated, saying why
    for ov, why in ((["count.mv_dedupe=0.8"], "counter settings"),  # (mv_link_px: the fast profile sets it)
                    (["cloud.max_depth=0.5"], "counter settings"),  # (the depth range seeds are looked for in)
                    (["detector_overrides=[cnn.domain=arm,cnn.threshold=0.35]"], "detector settings"),
                    (["detector=gt"], "no shipped calibration"),
                    (["count.calibration=none"], "none"),
                    (["count.method=density"], "multiview")):
        cfg = ReconConfig(detector="fast")
        from seedmap.config import apply_overrides

        cfg = ReconConfig.model_validate(apply_overrides(cfg.model_dump(), ov))
        r = calibrate_count(cfg, f)
        assert r.estimate is None and why in r.reason, (ov, r.reason)
    # a 36-view scan gets the 36-view calibration; never one outside the fitted numbers of views
    f36 = CountFeatures(2000, 36, int(0.40 * 2000 * 36), 3.5)
    r = calibrate_count(ReconConfig(detector="fast"), f36)
    c36 = load_count_calibration(shipped_calibration_dir() / "fast_36views.json")
    assert r.source.endswith("fast_36views.json") and r.estimate == pytest.approx(c36.estimate(f36))
    assert c36.views_range == (36, 36) and c36.fit["loo_mape_pct"] < c36.fit["raw_mape_pct"]
    r = calibrate_count(ReconConfig(detector="fast"), CountFeatures(2000, 60, int(0.43 * 2000 * 60), 3.5))
    assert r.estimate is None and "60 views" in r.reason
    assert "fast_36views.json was fitted on scans with 36-36" in r.reason


def test_restamp_rewrites_only_the_settings_hashes(tmp_path):
    import shutil

    from seedmap.recon.calibrate import restamp_shipped_calibrations

    shutil.copy(shipped_calibration_dir() / "fast.json", tmp_path / "fast.json")
    assert restamp_shipped_calibrations(tmp_path) == []  # the shipped files match the default settings
    cal = load_count_calibration(tmp_path / "fast.json")
    stale = cal.model_copy(update={"domain": cal.domain.model_copy(update={"count_config_sha256": "0" * 64,
                                                                           "detector_config_sha256": "1" * 64})})
    save_count_calibration(stale, tmp_path / "fast.json")
    assert restamp_shipped_calibrations(tmp_path) == [tmp_path / "fast.json"]
    assert load_count_calibration(tmp_path / "fast.json") == cal  # coefficients, fit and samples unchanged
    wrong = cal.model_copy(update={"domain": cal.domain.model_copy(update={"weights_sha256": "2" * 64})})
    save_count_calibration(wrong, tmp_path / "fast.json")
    with pytest.raises(ConfigError, match="refit"):
        restamp_shipped_calibrations(tmp_path)


def test_a_calibration_file_must_match_the_run(tmp_path):
    rng = np.random.default_rng(3)
    feats, truth = _samples(8, rng)
    cal = fit_count_calibration(feats, truth, count_domain(ReconConfig(detector="gt")), [str(i) for i in range(8)])
    save_count_calibration(cal, tmp_path / "gt.json")
    assert load_count_calibration(tmp_path / "gt.json") == cal
    cfg = ReconConfig(detector="gt")
    cfg.count.calibration = str(tmp_path / "gt.json")
    assert calibrate_count(cfg, feats[0]).estimate == pytest.approx(truth[0])
    cfg = ReconConfig(detector="fast")
    cfg.count.calibration = str(tmp_path / "gt.json")
    with pytest.raises(ConfigError, match="gt.json: count calibration does not fit this run: it was fitted with "
                                          "detector 'gt', not 'fast'"):
        calibrate_count(cfg, feats[0])
    (tmp_path / "bad.json").write_text('{"kind": "something else"}')
    for bad in ("bad.json", "missing.json"):
        cfg.count.calibration = str(tmp_path / bad)
        with pytest.raises(InputError, match=bad):
            calibrate_count(cfg, feats[0])


@pytest.mark.slow
def test_reconstruct_count_and_train_count_calibration_cli(arm_scan_6_views, tmp_path, monkeypatch, capsys):
    from helpers.cli import run_cli

    data = arm_scan_6_views
    res, res_gt = tmp_path / "fast", tmp_path / "gt"
    assert run_cli(["reconstruct", data, "--detector", "fast", "--out", res, "-q"], monkeypatch) == 0
    assert run_cli(["reconstruct", data, "--detector", "gt", "--out", res_gt, "-q", "--set",
                    "detector_overrides=[gt.min_area_px=6]"], monkeypatch) == 0
    m = json.loads((res / "metrics.json").read_text())
    # the shipped fast calibration was fitted on 24-view scans: a 6-view scan stays uncalibrated, saying why
    f = m["count_features"]
    assert m["seed_count"] == f["count"] > 0 and f["views"] == 6 and f["detections"] > f["count"]
    assert m["seed_count_calibrated"] is None and "6 views" in m["count_calibration_note"]
    assert "count_calibrated" not in m["gt"]
    assert "calibrated count: none (not applied: the scan has 6 views" in (res / "report.md").read_text()
    mg = json.loads((res_gt / "metrics.json").read_text())
    assert mg["seed_count_calibrated"] is None and "no shipped calibration" in mg["count_calibration_note"]
    # fit a constant-ratio calibration from three copies with known "true" counts (hand counts)
    copies = []
    for i, g in enumerate((1.1, 1.2, 1.3)):
        shutil.copytree(res_gt, tmp_path / f"c{i}")
        copies.append(tmp_path / f"c{i}")
    n = mg["seed_count"]
    (tmp_path / "counts.csv").write_text("result,count\n" + "".join(
        f"c{i},{n * g}\n" for i, g in enumerate((1.1, 1.2, 1.3))))
    out = tmp_path / "cal.json"
    assert run_cli(["train", "count-calibration", *copies, "--counts", tmp_path / "counts.csv", "--features", "",
                    "--out", out], monkeypatch) == 0
    c = load_count_calibration(out)
    assert c.coef == {} and c.intercept == pytest.approx(np.mean(np.log([1 / 1.1, 1 / 1.2, 1 / 1.3])), abs=0.01)
    assert run_cli(["count", res_gt, "--set", f"count.calibration={out}", "--out", tmp_path / "cnt"],
                   monkeypatch) == 0
    j = json.loads((tmp_path / "cnt" / "count.json").read_text())
    assert j["seed_count_calibrated"] == pytest.approx(j["seed_count"] * np.exp(-c.intercept), abs=0.06)
    assert abs(j["seed_count"] - n) <= 0.01 * n  # (a recount of the stored detections: CSV rounding)
    assert run_cli(["reconstruct", data, "--detector", "gt", "--out", tmp_path / "gt2", "-q", "--set",
                    "detector_overrides=[gt.min_area_px=6]", "--set", f"count.calibration={out}"], monkeypatch) == 0
    m2 = json.loads((tmp_path / "gt2" / "metrics.json").read_text())
    assert m2["seed_count"] == n and m2["seed_count_calibrated"] == pytest.approx(n * np.exp(-c.intercept), abs=0.06)
    assert m2["count_calibration"] == str(out) and m2["count_calibration_note"] == ""
    assert m2["count_calibration_fit"] == c.describe() and "fitted on 3 panicles with 6-6 views against counts in" \
        in (tmp_path / "gt2" / "report.md").read_text()
    g2 = m2["gt"]
    assert g2["count_calibrated_countable_err_pct"] == pytest.approx(
        (g2["count_calibrated"] - g2["count_gt_countable"]) / g2["count_gt_countable"] * 100)
    # the gt calibration refuses the fast run; the GT-count default needs metrics with GT; no overwrite
    capsys.readouterr()
    assert run_cli(["count", res, "--set", f"count.calibration={out}"], monkeypatch) == 2
    assert "does not fit this run" in capsys.readouterr().err
    assert run_cli(["train", "count-calibration", *copies, "--features", "", "--out", out], monkeypatch) == 2
    assert "exists" in capsys.readouterr().err
    (copies[0] / "metrics.json").write_text("{}")
    assert run_cli(["train", "count-calibration", *copies, "--features", "", "--out", tmp_path / "c2.json"],
                   monkeypatch) == 2
    assert "no ground-truth count" in capsys.readouterr().err and not (tmp_path / "c2.json").exists()
    assert run_cli(["train", "count-calibration", res, res_gt, "--features", "", "--out", tmp_path / "c3.json"],
                   monkeypatch) == 2
    assert "differs from" in (e := capsys.readouterr().err) and "which ran with detector 'fast', not 'gt'" in e
