"""The gt oracle detector and the detector registry on a small synthetic dataset in seedmap layout."""

import numpy as np
import pytest

from seedmap.detect import GtDetector, available_detectors, make_detector
from seedmap.detect.synth import write_synthetic_dataset
from seedmap.errors import SeedmapError
from seedmap.io.seedmap_dataset import SeedmapDataset
from seedmap.records import Detections, StereoDetections


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return SeedmapDataset(write_synthetic_dataset(tmp_path_factory.mktemp("synth") / "d", n_frames=2))


def test_registry_names():
    names = available_detectors()
    assert {"gt", "fast", "frcnn-pix2pix"} <= set(names)
    with pytest.raises(SeedmapError, match="unknown detector"):
        make_detector("nope")


@pytest.mark.parametrize("method", ["moments", "contour"])
def test_gt_keypoints_match_true_centres(ds, method):
    det = make_detector("gt", dataset=ds, overrides=[f"gt.ellipse={method}"])
    assert det.is_oracle
    sd = det.detect_stereo(ds[1])
    assert isinstance(sd, StereoDetections) and isinstance(sd.left, Detections)
    assert sd.index == 1
    inst = ds.gt_instances(1, "left")
    # every instance of at least the detectable-seed size (scaled to this image) is detected, with
    # its seed id, and no sliver below it
    from seedmap.detect.config import min_visible_seed_px

    a_min = min_visible_seed_px(ds.calib.width)
    assert 0 < a_min < 10
    assert set(sd.left.seed_ids) == set(inst.seed_id[inst.area >= a_min])
    explicit = make_detector("gt", dataset=ds, overrides=["gt.min_area_px=3"]).detect_frame(1, "left")
    assert set(explicit.seed_ids) == set(inst.seed_id[inst.area >= 3])
    pos = {s: k for k, s in enumerate(inst.seed_id)}
    k = np.array([pos[s] for s in sd.left.seed_ids])
    err = np.linalg.norm(sd.left.keypoints - inst.center_uv[k], axis=1)
    whole = inst.center_visible[k] & (inst.area[k] >= 20)
    assert np.median(err[whole]) < 0.3
    # boxes are the GT boxes and contain the keypoints
    np.testing.assert_allclose(sd.left.boxes, inst.boxes[k])
    kp = sd.left.keypoints
    assert np.all((kp[:, 0] >= sd.left.boxes[:, 0] - 0.5) & (kp[:, 0] <= sd.left.boxes[:, 2]))


def test_gt_stereo_disparity(ds):
    sd = GtDetector(ds).detect_stereo(ds[0])
    common, il, ir = np.intersect1d(sd.left.seed_ids, sd.right.seed_ids, return_indices=True)
    assert len(common) > 50
    d = sd.left.keypoints[il, 0] - sd.right.keypoints[ir, 0]
    assert abs(np.median(d) - 30.0) < 0.2


def test_gt_needs_dataset_and_frame(ds, tmp_path):
    with pytest.raises(SeedmapError, match="needs the dataset"):
        make_detector("gt")
    det = make_detector("gt", dataset=ds.root)
    with pytest.raises(SeedmapError, match="detect_frame"):
        det.detect(ds[0].left)
    with pytest.raises(SeedmapError, match="camera"):
        det.detect_frame(0, "middle")
    with pytest.raises(SeedmapError, match="not found"):
        det.detect_frame(99, "left")
