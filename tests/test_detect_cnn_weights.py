"""Which ONNX file ``cnn.weights`` selects (seedmap.detect.cnn.cnn_weights_path): opt-in shipped networks by name."""

from pathlib import Path

import numpy as np
import pytest

from seedmap.detect import make_detector
from seedmap.detect.cnn import CnnDetector, cnn_weights_path, default_cnn_path
from seedmap.detect.config import CnnConfig
from seedmap.errors import InputError


def test_bare_name_selects_a_shipped_network(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no such file here: the name means the one in seedmap/detect/weights/
    arm = default_cnn_path("arm")
    assert cnn_weights_path(CnnConfig(weights="fast_cnn_arm.onnx")) == arm
    assert make_detector("fast", overrides=["cnn.weights=fast_cnn_arm.onnx"]).path == arm
    # the default is still the field network, and a path with a folder is taken as written
    assert cnn_weights_path(CnnConfig()) == default_cnn_path("field")
    assert cnn_weights_path(CnnConfig(weights="sub/fast_cnn_arm.onnx")) == Path("sub/fast_cnn_arm.onnx")
    # a file of that name in the working directory wins over the shipped one (it is what the user means)
    (tmp_path / "fast_cnn_arm.onnx").write_bytes(default_cnn_path("field").read_bytes())
    det = make_detector("fast", overrides=["cnn.weights=fast_cnn_arm.onnx"])
    assert det.path.resolve() == (tmp_path / "fast_cnn_arm.onnx").resolve()
    # an unknown name is a one-line error naming it
    with pytest.raises(InputError, match="nonexistent_net.onnx"):
        CnnDetector(CnnConfig(weights="nonexistent_net.onnx"))


def test_selected_network_is_the_one_that_runs(tmp_path, monkeypatch):
    """The arm network selected by name gives the same detections as selected by its full path (and other ones
    than the field network) on a synthetic image of bright blobs."""
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(0)
    img = np.full((192, 256, 3), (60, 90, 40), np.uint8)
    yy, xx = np.mgrid[:192, :256]
    for x, y in rng.uniform((20, 20), (236, 172), (40, 2)):
        img[(xx - x) ** 2 + (yy - y) ** 2 <= 6] = (235, 225, 200)
    by_name = make_detector("fast", overrides=["cnn.weights=fast_cnn_arm.onnx", "cnn.tile=0"]).detect(img)
    by_path = make_detector("fast", overrides=[f"cnn.weights={default_cnn_path('arm')}", "cnn.tile=0"]).detect(img)
    field = make_detector("fast", overrides=["cnn.tile=0"]).detect(img)
    assert len(by_name) > 10
    assert np.array_equal(by_name.boxes, by_path.boxes) and np.array_equal(by_name.scores, by_path.scores)
    assert len(field) != len(by_name) or not np.allclose(field.scores, by_name.scores)
