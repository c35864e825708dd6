"""The learned pipeline (Faster R-CNN VGG16 + pix2pix) on tiny synthetic data, on CPU.

Skipped cleanly when torch is not installed (the optional ``seedmap[learned]`` extra).
"""

import json
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchvision")

from seedmap.detect import make_detector  # noqa: E402
from seedmap.detect.labels import SeedmapSource  # noqa: E402
from seedmap.detect.learned.crops import crop_to_full, extract_crops  # noqa: E402
from seedmap.detect.learned.models import DetectorArch, SegmenterArch, build_frcnn, set_input_scale  # noqa: E402
from seedmap.detect.learned.train import (  # noqa: E402
    DetectorTrainConfig,
    SegmenterTrainConfig,
    train_detector,
    train_segmenter,
)
from seedmap.detect.synth import write_synthetic_dataset  # noqa: E402
from seedmap.errors import InputError, SeedmapError  # noqa: E402
from seedmap.records import Detections  # noqa: E402

TINY_DET = DetectorArch(width=0.125, representation=64, anchor_sizes=[8.0, 16.0], rpn_post_nms_test=300,
                        max_detections=200)
TINY_SEG = SegmenterArch(crop_size=16, ngf=8, ndf=8)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_synthetic_dataset(tmp_path_factory.mktemp("ld") / "d", n_frames=2, width=128, height=96,
                                   seeds_per_cluster=12, n_clusters=2, disparity=10)


@pytest.fixture(scope="module")
def trained(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("weights")
    src = SeedmapSource(data)
    train_segmenter(src, out, SegmenterTrainConfig(steps=10, batch_size=16, val_every=5, checkpoint_every=5,
                                                   log_every=1, val_crops=32, arch=TINY_SEG), progress=False)
    train_detector(src, out, DetectorTrainConfig(steps=2, batch_size=1, crop=64, val_every=2, checkpoint_every=1,
                                                 log_every=1, val_crops=1, arch=TINY_DET), progress=False)
    return out


def _log(path, split="train"):
    return [json.loads(x) for x in path.read_text().splitlines() if json.loads(x)["split"] == split]


def test_crop_mapping_is_exact():
    img = np.zeros((60, 80, 3), np.uint8)
    labels = np.zeros((60, 80), np.int32)
    labels[20:27, 30:35] = 1  # centre (32, 23)
    crops, wins, masks = extract_crops(img, np.array([[30.0, 20, 35, 27]]), 32, 0.5, labels, np.array([1]))
    ys, xs = np.nonzero(masks[0])
    c = crop_to_full(np.array([xs.mean(), ys.mean()]), wins[0], 32)
    assert np.hypot(c[0] - 32, c[1] - 23) < 0.25


def test_segmenter_training_reduces_loss(trained):
    rows = _log(trained / "segmenter_metrics.jsonl")
    assert len(rows) == 10
    first = np.mean([r["loss_l1"] for r in rows[:3]])
    last = np.mean([r["loss_l1"] for r in rows[-3:]])
    assert last < first
    val = _log(trained / "segmenter_metrics.jsonl", "val")
    assert len(val) == 2 and val[-1]["val_l1"] < val[0]["val_l1"]
    assert (trained / "segmenter.onnx").is_file()


def test_detector_overfits_one_image():
    torch.manual_seed(0)
    m = build_frcnn(TINY_DET)
    set_input_scale(m, 64, 64, 2.0)
    m.train()
    img = [torch.zeros(3, 64, 64)]
    boxes = torch.tensor([[10.0, 10, 16, 16], [40, 30, 47, 36], [20, 40, 26, 47]])
    for b in boxes:
        x0, y0, x1, y1 = (int(v) for v in b)
        img[0][:, y0:y1, x0:x1] = 0.9
    tgt = [{"boxes": boxes, "labels": torch.ones(3, dtype=torch.int64)}]
    opt = torch.optim.Adam(m.parameters(), lr=1e-3)
    losses = []
    for _ in range(6):
        loss = sum(m(img, tgt).values())
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0]


def test_resume_continues_from_checkpoint(data, trained, tmp_path):
    import shutil

    for f in trained.iterdir():
        shutil.copy(f, tmp_path / f.name)
    cfg = DetectorTrainConfig(steps=3, batch_size=1, crop=64, val_every=100, checkpoint_every=1, log_every=1,
                              val_crops=0, arch=TINY_DET)
    with pytest.raises(InputError, match="--resume"):
        train_detector(SeedmapSource(data), tmp_path, cfg, progress=False)
    train_detector(SeedmapSource(data), tmp_path, cfg, resume=True, progress=False)
    steps = [r["step"] for r in _log(tmp_path / "detector_metrics.jsonl")]
    assert steps == [1, 2, 3]


def test_learned_detector_end_to_end(data, trained):
    from seedmap.io.seedmap_dataset import SeedmapDataset

    det = make_detector("frcnn-pix2pix", weights=trained, overrides=["learned.score_threshold=0.0"])
    assert det.ort is not None  # the exported ONNX segmenter is used
    frame = SeedmapDataset(data)[0]
    sd = det.detect_stereo(frame)
    for d in (sd.left, sd.right):
        assert isinstance(d, Detections)
        assert d.ellipses.shape[1] == 5 and d.boxes.shape == (len(d), 4)
        if len(d):
            assert np.isfinite(d.keypoints).all()
            assert (d.ellipses[:, 2] >= d.ellipses[:, 3]).all()
    # torch and onnxruntime segmenters agree
    crops = (np.random.default_rng(0).random((4, 16, 16, 3)) * 255).astype(np.uint8)
    m_ort = det.masks(crops)
    det.ort = None
    assert (det.masks(crops) == m_ort).mean() > 0.98


def test_bad_weights_are_named(trained, tmp_path):
    bad = tmp_path / "detector.safetensors"
    bad.write_bytes(b"not a safetensors file at all")
    (tmp_path / "segmenter.safetensors").write_bytes((trained / "segmenter.safetensors").read_bytes())
    with pytest.raises(InputError, match="detector.safetensors"):
        make_detector("frcnn-pix2pix", weights=tmp_path)
    # segmenter weights where detector weights belong -> wrong kind
    bad.write_bytes((trained / "segmenter.safetensors").read_bytes())
    with pytest.raises(InputError, match="expected detector"):
        make_detector("frcnn-pix2pix", weights=tmp_path)
    # weights of another architecture
    from seedmap.detect.learned.models import UNetGenerator
    from seedmap.detect.learned.weights import load_into, read_weights

    t, _ = read_weights(trained / "segmenter.safetensors", "segmenter")
    with pytest.raises(InputError, match="do not match the architecture"):
        load_into(UNetGenerator(32, 16), t, trained / "segmenter.safetensors")
    with pytest.raises(SeedmapError, match="not found"):
        make_detector("frcnn-pix2pix", weights=tmp_path / "nope")


def test_without_torch_clear_error():
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['torchvision'] = None\n"
        "import seedmap.detect as d\n"
        "from seedmap.errors import SeedmapError\n"
        "assert d.make_detector('fast').name == 'fast'\n"
        "try:\n    d.make_detector('frcnn-pix2pix')\nexcept SeedmapError as e:\n    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "pip install 'seedmap[learned]'" in r.stdout
