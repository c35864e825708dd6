"""Opt-in exposure normalisation before detection (DetectConfig.exposure), on a simulated frame."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from seedmap.detect import make_detector
from seedmap.detect.base import ExposureNormalised, apply_gain, exposure_gain
from seedmap.io.seedmap_dataset import SeedmapDataset


def _grey_image(p99: float) -> np.ndarray:
    """RGB image whose grey 99th percentile is ``p99`` (2 % of the pixels at that level)."""
    a = np.full((100, 100, 3), 20, np.uint8)
    a[:2] = int(p99)
    return a


def test_gain_band_and_clipping():
    assert exposure_gain(_grey_image(165), 165, 1.3, 2.0) == 1.0
    assert exposure_gain(_grey_image(140), 165, 1.3, 2.0) == 1.0  # inside the band: untouched
    assert exposure_gain(_grey_image(100), 165, 1.3, 2.0) == pytest.approx(1.65)
    assert exposure_gain(_grey_image(40), 165, 1.3, 2.0) == 2.0  # clipped
    assert exposure_gain(_grey_image(250), 165, 1.3, 2.0) == pytest.approx(0.66)
    img = _grey_image(100)
    assert apply_gain(img, 1.0) is img
    assert apply_gain(img, 2.0)[0, 0, 0] == 200 and apply_gain(img, 3.0)[0, 0, 0] == 255


def test_oracle_is_not_wrapped_and_names_forward(tmp_path):
    from seedmap.detect.synth import write_synthetic_dataset

    ds = write_synthetic_dataset(tmp_path / "d", n_frames=1)
    gt = make_detector("gt", dataset=ds, overrides=["exposure.enabled=true"])
    assert not isinstance(gt, ExposureNormalised)
    fc = make_detector("fast-classic", overrides=["exposure.enabled=true"])
    assert isinstance(fc, ExposureNormalised)
    assert fc.name == make_detector("fast-classic").name and not fc.is_oracle


def test_slam_config_reaches_the_detector(tmp_path):
    from seedmap.config import load_config
    from seedmap.detect.synth import write_synthetic_dataset
    from seedmap.slam.config import SlamConfig
    from seedmap.slam.pipeline import _detector_for

    ds = write_synthetic_dataset(tmp_path / "d", n_frames=1)
    cfg = load_config(SlamConfig, None, ["detect.exposure.enabled=true", "detect.exposure.ref_p99=150"])
    det = _detector_for("fast-classic", ds, cfg.detect)
    assert isinstance(det, ExposureNormalised) and det.cfg.ref_p99 == 150
    assert not isinstance(_detector_for("fast-classic", ds, SlamConfig().detect), ExposureNormalised)


def test_dark_frame_recovered_on_simulated_range(tmp_path):
    sim = pytest.importorskip("seedmap.sim.range")
    from seedmap.sim.config import SimConfig

    cfg = SimConfig.model_validate({"seed": 5, "world": {"length": 0.12, "gap": 0.05}})
    d = SeedmapDataset(sim.simulate_range(cfg, tmp_path / "sim", progress=False))
    i = int(np.argmax([len(d.gt_instances(k, "left")) for k in range(len(d))]))
    img = d[i].left
    # the reference is the camera's typical level; this short range holds little panicle, so its
    # 99th grey percentile is far below the paper ranges' (the statistic depends on the content)
    p99 = float(np.percentile(np.asarray(img.mean(axis=2))[::2, ::2], 99))
    plain = make_detector("fast-classic")
    norm = make_detector("fast-classic", overrides=["exposure.enabled=true", f"exposure.ref_p99={p99:.1f}"])
    ref = plain.detect(img)
    # a normally exposed frame is passed on untouched: identical detections
    assert exposure_gain(img, p99, 1.3, 2.0) == 1.0
    np.testing.assert_array_equal(norm.detect(img).keypoints, ref.keypoints)
    # the same frame at 55 % exposure: the plain detector loses most seeds, the normalised one keeps them
    dark = apply_gain(img, 0.55)

    def kept(d) -> float:  # share of the normal-exposure keypoints found again within 1.5 px
        return float((cKDTree(d.keypoints).query(ref.keypoints)[0] < 1.5).mean()) if len(d) else 0.0

    k_plain, k_norm = kept(plain.detect(dark)), kept(norm.detect(dark))
    assert k_plain < 0.3  # measured 0.0: every seed below fast.min_brightness
    assert k_norm > 0.6  # measured 0.68 (the gain also amplifies the dark image's quantisation)
