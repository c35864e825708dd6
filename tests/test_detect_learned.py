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
    train_segmenter(src, out, SegmenterTrainConfig(steps=10, batch_size=16, checkpoint_every=5,
                                                   log_every=1, arch=TINY_SEG), progress=False)
    train_detector(src, out, DetectorTrainConfig(steps=2, batch_size=1, crop=64, checkpoint_every=1,
                                                 log_every=1, arch=TINY_DET), progress=False)
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
    cfg = DetectorTrainConfig(steps=3, batch_size=1, crop=64, checkpoint_every=1, log_every=1, arch=TINY_DET)
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
        "import numpy as np\n"
        "det = d.make_detector('fast')\n"
        "assert det.name == 'fast' and len(det.detect(np.zeros((96, 96, 3), np.uint8))) == 0\n"
        "try:\n    d.make_detector('frcnn-pix2pix')\nexcept SeedmapError as e:\n    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "pip install 'seedmap[learned]'" in r.stdout


def test_detector_onnx_export_matches_torch(tmp_path):
    """The exported Faster R-CNN graph gives torch's boxes and scores, for any image size."""
    import onnxruntime as ort

    from seedmap.detect.learned.export import export_frcnn_onnx, onnx_post_params

    torch.manual_seed(0)
    m = build_frcnn(TINY_DET).eval()
    p = export_frcnn_onnx(m, TINY_DET, tmp_path / "detector.onnx", score_threshold=0.0, max_detections=1000)
    assert onnx_post_params(p)["nms_iou"] == 0.3
    sess = ort.InferenceSession(str(p), providers=["CPUExecutionProvider"])
    m.roi_heads.score_thresh = 0.0
    m.roi_heads.detections_per_img = 1000
    for h, w in ((96, 128), (72, 100)):  # the second size was never traced
        x = torch.rand(3, h, w, generator=torch.Generator().manual_seed(h))
        set_input_scale(m, h, w, TINY_DET.upscale)
        with torch.no_grad():
            ref = m([x])[0]
        b, s = sess.run(None, {"image": x.numpy()})
        tb, ts = ref["boxes"].numpy(), ref["scores"].numpy()
        assert len(b) == len(tb) > 0
        np.testing.assert_allclose(np.sort(s), np.sort(ts), atol=1e-5)
        # boxes as sets: an untrained net's near-equal scores (ties at 1e-7) may swap a few boxes
        # in the RPN's top-k / NMS; a wrong input scale or layout would match none
        d = np.abs(b[:, None, :] - tb[None, :, :]).max(-1).min(1)
        assert (d < 1e-2).mean() > 0.85
        assert d[np.argmax(s)] < 1e-2
        assert (b[:, 2] <= w + 1e-3).all() and (b[:, 3] <= h + 1e-3).all()  # boxes in input pixels


def test_export_cli_and_onnx_detector(data, trained, tmp_path):
    import shutil

    from typer.testing import CliRunner

    from seedmap.cli import app

    for f in ("detector.safetensors", "segmenter.safetensors"):
        shutil.copy(trained / f, tmp_path / f)
    r = CliRunner().invoke(app, ["train", "export", str(tmp_path), "--score-threshold", "0.0"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "detector.onnx").is_file() and (tmp_path / "segmenter.onnx").is_file()
    from seedmap.io.seedmap_dataset import SeedmapDataset

    img = SeedmapDataset(data)[0].left
    det = make_detector("frcnn-pix2pix", weights=tmp_path, overrides=["learned.score_threshold=0.0"])
    assert det.ort_det is not None and det.ort is not None
    b_onnx, s_onnx = det.boxes(img)
    det.ort_det = None
    b_t, s_t = det.boxes(img)
    assert len(b_onnx) == len(b_t) > 0
    # near-tied scores of a barely trained net: a few boxes may swap in NMS, the rest agree exactly
    assert (np.abs(np.sort(s_onnx) - np.sort(s_t)) < 1e-5).mean() > 0.95
    d = np.abs(b_onnx[:, None, :] - b_t[None, :, :]).max(-1).min(1)
    assert (d < 1e-2).mean() > 0.85
    # a config that keeps boxes the graph already dropped falls back to torch
    det2 = make_detector("frcnn-pix2pix", weights=tmp_path, overrides=["learned.nms_iou=0.5"])
    assert det2.ort_det is None
    r = CliRunner().invoke(app, ["train", "export", str(tmp_path / "nothing")])
    assert isinstance(r.exception, InputError) and "weights not found" in str(r.exception)


def _onnx_only(trained, tmp_path, score=0.0):
    """A folder holding only the exported graphs of the tiny trained weights."""
    from seedmap.detect.learned.export import export_weights

    export_weights(trained, tmp_path, score_threshold=score)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["detector.onnx", "segmenter.onnx"]
    return tmp_path


def test_onnx_only_weights_match_the_torch_pipeline(data, trained, tmp_path):
    """A folder of exported graphs gives the torch pipeline's detections (its ONNX path), with onnxruntime only."""
    import shutil

    from seedmap.detect.learned.pipeline import OnnxLearnedDetector
    from seedmap.io.seedmap_dataset import SeedmapDataset

    folder = _onnx_only(trained, tmp_path / "onnx")
    ref_dir = tmp_path / "ref"
    ref_dir.mkdir()
    for f in ("detector.safetensors", "segmenter.safetensors"):
        shutil.copy(trained / f, ref_dir / f)
    for f in ("detector.onnx", "segmenter.onnx"):
        shutil.copy(folder / f, ref_dir / f)
    over = ["learned.score_threshold=0.0"]
    det = make_detector("frcnn-pix2pix", weights=folder, overrides=over)
    ref = make_detector("frcnn-pix2pix", weights=ref_dir, overrides=over)
    assert isinstance(det, OnnxLearnedDetector) and ref.ort_det is not None
    img = SeedmapDataset(data)[0].left
    a, b = det.detect(img), ref.detect(img)
    assert len(a) == len(b) > 0
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-4)
    # both run the same graphs; onnxruntime's options differ (threads, graph optimisation), so a barely trained
    # segmenter's borderline mask pixel may flip: centres agree on nearly every seed
    assert (np.abs(a.keypoints - b.keypoints).max(axis=1) < 1e-3).mean() > 0.9
    # the same folder, torch unimportable: still runs, and names the detector it was built as
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['torchvision'] = None\n"
        "import numpy as np\n"
        "from seedmap.detect import make_detector\n"
        f"det = make_detector('frcnn-pix2pix', weights={str(folder)!r}, overrides=['learned.score_threshold=0.0'])\n"
        "d = det.detect(np.full((96, 128, 3), 90, np.uint8))\n"
        "print(det.name, d.ellipses.shape[1])\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["frcnn-pix2pix", "5"]


def test_onnx_graph_that_cannot_give_the_config_is_refused(trained, tmp_path):
    folder = _onnx_only(trained, tmp_path, score=0.5)
    with pytest.raises(InputError, match="re-export"):
        make_detector("frcnn-pix2pix", weights=folder, overrides=["learned.score_threshold=0.1"])
    with pytest.raises(InputError, match="upscale"):
        make_detector("frcnn-pix2pix", weights=folder, overrides=["learned.upscale=3.0"])
    det = make_detector("frcnn-pix2pix", weights=folder)  # the default threshold 0.5 is what the graph keeps
    assert det.name == "frcnn-pix2pix" and det.cfg.score_threshold == 0.5
    # a threshold recorded beside the weights is their default; the settings still win
    (folder / "recipe.json").write_text(json.dumps({"score_threshold": 0.7}))
    assert make_detector("frcnn-pix2pix", weights=folder).cfg.score_threshold == 0.7
    det = make_detector("frcnn-pix2pix", weights=folder, overrides=["learned.score_threshold=0.6"])
    assert det.cfg.score_threshold == 0.6


def test_train_cli_reads_several_datasets_and_a_preset(data, tmp_path):
    import yaml
    from typer.testing import CliRunner

    from seedmap.cli import app
    from seedmap.detect.labels import ConcatSource, open_labelled_many

    both = open_labelled_many([data, data])
    assert isinstance(both, ConcatSource) and len(both) == 2 * len(SeedmapSource(data))
    assert both[len(both) - 1].name == SeedmapSource(data)[len(SeedmapSource(data)) - 1].name
    with pytest.raises(IndexError):
        both[len(both)]
    out = tmp_path / "w"
    r = CliRunner().invoke(app, ["train", "segmenter", str(data), str(data), "--preset", "lite", "--out", str(out),
                                 "--set", "steps=2", "--set", "batch_size=4", "--set", "checkpoint_every=2"])
    assert r.exit_code == 0, r.output
    cfg = yaml.safe_load((out / "segmenter_train_config.yaml").read_text())
    assert cfg["steps"] == 2 and cfg["arch"]["ngf"] == 16 and cfg["threads"] == 1  # preset, then --set
    r = CliRunner().invoke(app, ["train", "detector", str(data), "--preset", "huge", "--out", str(tmp_path / "x")])
    assert isinstance(r.exception, SeedmapError) and "unknown detector preset 'huge'" in str(r.exception)
    assert not (tmp_path / "x").exists()
