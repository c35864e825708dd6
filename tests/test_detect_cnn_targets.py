"""Training targets and losses of the fast CNN (seedmap.detect.train_cnn) on exact synthetic geometry,
and the inference options of seedmap.detect.cnn that do not need a trained network to check."""

import numpy as np
import pytest

from seedmap.detect.train_cnn import CropSpec, TrainImage, crop_batch


def _one_seed_image(w: int = 9, h: int = 7, x0: int = 60, y0: int = 50, sliver_area: float = 6.0) -> TrainImage:
    """A 200x160 image with one w x h rectangular seed (instance 0) and a 2x3 sliver (instance 1)."""
    inst = np.full((160, 200), -1, np.int16)
    inst[y0:y0 + h, x0:x0 + w] = 0
    inst[20:22, 150:153] = 1
    boxes = np.array([[x0, y0, x0 + w, y0 + h], [150, 20, 153, 22]], np.float32)
    kp = np.array([[x0 + (w - 1) / 2, y0 + (h - 1) / 2], [151.0, 20.5]], np.float32)
    rgb = np.zeros((160, 200, 3), np.uint8)
    rgb[inst >= 0] = 200
    return TrainImage(rgb, inst, boxes, kp, np.round(kp).astype(np.int64), np.array([w * h, sliver_area], np.float32))


def _targets_at_seed(spec: CropSpec, seed: int = 0):
    im = _one_seed_image(sliver_area=1.0)  # below min_area even x 1.5: background, the seed is the only target
    X, H, R, M, IG = crop_batch([im], 1, 96, np.random.default_rng(seed), seed_fraction=1.0, augment=True,
                                spec=spec)
    return X[0], H[0], R[0], M[0], IG[0]


@pytest.mark.parametrize("scale", [1.0, 1.5, 0.8])
def test_box_targets_scale_with_the_crop(scale):
    """Every mask pixel's l + r / t + b is the GT box size times the crop scale; the heat peak sits at the
    scaled keypoint, and the keypoint offset points there from every mask pixel."""
    for seed in range(6):  # random crop origin and flips
        x, heat, reg, mask, _ = _targets_at_seed(CropSpec(scale_prob=1.0, scale_range=(scale, scale)), seed)
        m = mask > 0
        if not m.any():
            continue
        assert np.allclose(reg[0][m] + reg[2][m], 9 * scale, atol=1e-4)
        assert np.allclose(reg[1][m] + reg[3][m], 7 * scale, atol=1e-4)
        ys, xs = np.nonzero(m)
        kx, ky = xs + reg[4][m], ys + reg[5][m]
        assert np.ptp(kx) < 1e-4 and np.ptp(ky) < 1e-4  # one keypoint for the whole seed
        py, px = np.unravel_index(np.argmax(heat), heat.shape)
        assert heat[py, px] == pytest.approx(1.0) and abs(px - kx[0]) <= 0.5 + 1e-6 and abs(py - ky[0]) <= 0.5 + 1e-6
        # a seed inside the crop: its rescaled mask covers about scale^2 times its pixels (nearest
        # neighbour) and the mask's pixel bounds agree with the box targets within a pixel
        if xs.min() > 0 and ys.min() > 0 and xs.max() < 95 and ys.max() < 95:
            assert abs(m.sum() - 63 * scale**2) <= (9 + 7) * scale
            k = np.argmin(xs)
            assert abs(reg[0][ys[k], xs[k]] - 0.5 * scale + 0.5) <= 0.5 + 1e-6
        # the image pixels under the mask are the seed's colour
        assert x[:, m].mean() > 0.6


def test_slivers_are_ignored_not_background():
    """A GT instance below the detectable size gets no peak but is excluded from the heat loss."""
    im = _one_seed_image()
    X, H, R, M, IG = crop_batch([im], 1, 96, np.random.default_rng(0), seed_fraction=0.0, augment=False,
                                spec=CropSpec(scale_prob=0.0))
    # find a crop that holds the sliver: place one by hand through seed_fraction=1 on the sliver only
    im2 = TrainImage(im.rgb, im.inst, im.boxes, im.kp, im.centers[1:], im.area)
    for seed in range(10):
        X, H, R, M, IG = crop_batch([im2], 1, 96, np.random.default_rng(seed), seed_fraction=1.0, augment=False,
                                    spec=CropSpec(scale_prob=0.0))
        if M[0].sum() == 6:  # the whole sliver (and not the seed) is in the crop
            break
    assert M[0].sum() == 6 and H[0].max() < 0.999 and IG[0].sum() >= 6
    # as a seed (heat_min_area below its area) it is a peak and not ignored
    X, H, R, M, IG = crop_batch([im2], 1, 96, np.random.default_rng(seed), seed_fraction=1.0, augment=False,
                                spec=CropSpec(scale_prob=0.0, heat_min_area=5))
    assert H[0].max() == pytest.approx(1.0) and IG[0].sum() == 0


def test_giou_loss_is_zero_for_exact_boxes_and_grows_with_error():
    torch = pytest.importorskip("torch")
    from seedmap.detect.train_cnn import losses

    im = _one_seed_image(sliver_area=1.0)
    X, H, R, M, IG = (torch.from_numpy(np.ascontiguousarray(a)) for a in
                      crop_batch([im], 2, 96, np.random.default_rng(1), seed_fraction=1.0, augment=False))
    out = torch.zeros(2, 7, 96, 96)
    out[:, 1:7] = R
    iou0 = float(losses(out, H, R, M, IG, iou_weight=1.0)[4])
    assert iou0 == pytest.approx(0.0, abs=1e-5)
    # one edge 1 px too far on a 9 x 7 box: IoU 63/70 (GIoU the same: the union is the enclosing box)
    out[:, 3] += 1.0
    assert float(losses(out, H, R, M, IG, iou_weight=1.0)[4]) == pytest.approx(1 - 63 / 70, abs=1e-4)


def test_arm_fraction_sets_the_share_of_arm_scan_crops():
    """``image_weights``: with 1 arm-scan image among 4 field images, arm_fraction 0.5 draws half the crops
    from it (uniform sampling would draw a fifth); one kind only or None: uniform (None)."""
    from seedmap.detect.train_cnn import image_weights

    ims = [_one_seed_image() for _ in range(5)]
    ims[3].arm = True
    ims[3].rgb = ims[3].rgb.copy()
    ims[3].rgb[ims[3].inst >= 0] = 100  # tell its crops apart by the seed's brightness
    w = image_weights(ims, 0.5)
    assert np.isclose(w.sum(), 1.0) and np.isclose(w[3], 0.5) and np.allclose(w[[0, 1, 2, 4]], 0.125)
    assert image_weights(ims, None) is None and image_weights(ims[:3], 0.5) is None
    X, *_ = crop_batch(ims, 400, 48, np.random.default_rng(0), seed_fraction=1.0, augment=False, weights=w)
    arm = np.isclose(X.max(axis=(1, 2, 3)), 100 / 255)
    assert 0.42 < arm.mean() < 0.58
    X, *_ = crop_batch(ims, 400, 48, np.random.default_rng(0), seed_fraction=1.0, augment=False)
    assert np.isclose(X.max(axis=(1, 2, 3)), 100 / 255).mean() < 0.3


def test_replay_fraction_sets_the_share_of_rehearsal_crops_beside_arm_scans():
    """``image_weights`` with rehearsal images: they get ``replay_fraction`` of the crops, the user's images the
    rest (split by ``arm_fraction`` among themselves when both kinds are there)."""
    from seedmap.detect.train_cnn import image_weights

    ims = [_one_seed_image() for _ in range(6)]
    ims[4].replay = ims[5].replay = True
    w = image_weights(ims, None, 0.5)
    assert np.isclose(w.sum(), 1.0) and np.allclose(w[4:], 0.25) and np.allclose(w[:4], 0.125)
    ims[0].arm = True
    w = image_weights(ims, 0.5, 0.4)
    assert np.isclose(w.sum(), 1.0) and np.isclose(w[0], 0.3) and np.allclose(w[1:4], 0.1) and np.allclose(w[4:], 0.2)
    assert image_weights(ims[:4], None, 0.5) is None  # nothing to rehearse: uniform
    ims[0].arm = False
    assert image_weights(ims, None, 0.0) is None



def test_off_scale_crops_show_seeds_as_background():
    """An off-scale crop (seeds far smaller or larger than the network's size) has no peak, no box target and no
    ignored pixel, although the seed is in it; an ordinary crop of the same seed has its peak."""
    im = _one_seed_image(w=12, h=10)
    off = CropSpec(off_scale_prob=1.0, off_scale_range=((0.45, 0.45), (2.5, 2.5)))
    for seed in range(6):
        X, H, R, M, IG = crop_batch([im], 1, 96, np.random.default_rng(seed), seed_fraction=1.0, spec=off)
        assert X[0].max() > 0.4  # the seed is in the crop ...
        assert H.max() == 0 and R.max() == 0 and M.max() == 0 and IG.max() == 0  # ... and is background
    assert max(crop_batch([im], 1, 96, np.random.default_rng(s), seed_fraction=1.0, spec=CropSpec())[1].max()
               for s in range(6)) == pytest.approx(1.0)


def test_context_stage_keeps_the_output_grid_and_round_trips_through_onnx(tmp_path):
    """With the quarter-resolution context stage the network still gives 7 channels per input pixel (odd sizes too),
    its exported ONNX gives torch's output, and its channels are read back from the weights."""
    torch = pytest.importorskip("torch")
    from seedmap.detect.cnn_net import build_net, net_channels
    from seedmap.detect.runtime import load_session
    from seedmap.detect.train_cnn import export_onnx, onnx_weights

    torch.manual_seed(0)
    net = build_net(6, 10, 12).eval()
    x = torch.rand(2, 3, 37, 50)
    with torch.no_grad():
        y = net(x).numpy()
    assert y.shape == (2, 7, 37, 50)
    p = export_onnx(net, tmp_path / "n.onnx", {"seed_px": 8.0})
    got = load_session(p, 1).run(None, {"image": x.numpy()})[0]
    assert np.allclose(got, y, atol=1e-4)
    assert net_channels(onnx_weights(p)) == (6, 10, 12)
    assert net_channels(onnx_weights(tmp_path / "n.onnx")) != (6, 10, 0)
