"""The fast detector's learned second stage (seedmap.detect.refine) on synthetic frames."""

import numpy as np
import pytest

from seedmap.detect import make_detector
from seedmap.detect.config import FastConfig
from seedmap.detect.fast import FastDetector
from seedmap.detect.refine import Refiner, default_refiner_path, train_refiner, training_samples
from seedmap.detect.synth import write_synthetic_dataset
from seedmap.errors import InputError
from seedmap.eval.detect_metrics import frame_metrics
from seedmap.io.seedmap_dataset import SeedmapDataset

pytest.importorskip("torch")

CFG = FastConfig(seed_px=5, region_min=-6, refine=False)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_synthetic_dataset(tmp_path_factory.mktemp("refine") / "d", n_frames=3)


def test_refiner_learns_boxes_and_roundtrips(data, tmp_path):
    x, y, s = training_samples(data, [0, 1], CFG)
    assert len(x) == len(y) == len(s) > 100 and 0.3 < s.mean() <= 1.0
    ref = train_refiner(x, y, s, steps=400, hidden=(32,), seed=0)
    assert ref.info["loss_last_100"] < 0.7 * ref.info["loss_first_100"]
    p = ref.save(tmp_path / "r.safetensors")
    back = Refiner.load(p)
    np.testing.assert_allclose(back.forward(x[:50].copy()), ref.forward(x[:50].copy()), rtol=1e-6, atol=1e-6)
    # held-out frame: refined boxes are whole pixels, keypoints are a subset of the candidates'
    ds = SeedmapDataset(data)
    img, gt = ds[2].left, ds.gt_instances(2, "left")
    cand, f = FastDetector(CFG).detect_with_seediness(img)
    out = back.refine(f, cand, 0.5)
    assert len(out) > 0.5 * len(cand)
    assert np.array_equal(out.boxes, np.round(out.boxes))
    assert (out.boxes[:, 2] > out.boxes[:, 0]).all() and (out.boxes[:, 3] > out.boxes[:, 1]).all()
    d = np.linalg.norm(out.keypoints[:, None] - cand.keypoints[None], axis=2).min(1)
    assert d.max() < 1e-9
    # on held-out data the learned boxes are at least as good as the region extents
    m0, _ = frame_metrics(cand, gt, min_gt_area=6)
    m1, _ = frame_metrics(out, gt, min_gt_area=6)
    assert m1.f1 >= m0.f1 - 0.02


def test_shipped_refiner_is_used_and_bad_files_are_named(tmp_path):
    assert default_refiner_path().is_file()
    assert make_detector("fast-classic").refiner is not None
    assert make_detector("fast-classic", overrides=["fast.refine=false"]).refiner is None
    bad = tmp_path / "r.safetensors"
    bad.write_bytes(b"not safetensors")
    with pytest.raises(InputError, match="r.safetensors"):
        make_detector("fast-classic", overrides=[f"fast.refine_weights={bad}"])
    with pytest.raises(InputError, match="not found"):
        make_detector("fast-classic", overrides=[f"fast.refine_weights={tmp_path / 'none.safetensors'}"])
