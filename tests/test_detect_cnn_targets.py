"""Training targets and losses of the fast CNN (seedmap.detect.train_cnn) on exact synthetic geometry,
and the inference options of seedmap.detect.cnn that do not need a trained network to check."""

import numpy as np
import pytest

from seedmap.detect.cnn import decode, peak_kernel
from seedmap.detect.train_cnn import CropSpec, TrainImage, crop_batch
from seedmap.errors import ConfigError


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


def test_peak_window_five_keeps_one_of_two_close_peaks():
    """Two heat maxima 2 px apart: the 3x3 test keeps both, the 5x5 disk only the stronger one."""
    out = np.full((1, 7, 20, 20), -9.0, np.float32)
    out[0, 0, 8, 8] = 3.0
    out[0, 0, 8, 10] = 2.0
    out[0, 1:5] = 2.0
    d3 = decode(out, 0.5, (0, 20, 0, 20), 0.0, peak_kernel(3))
    d5 = decode(out, 0.5, (0, 20, 0, 20), 0.0, peak_kernel(5))
    assert len(d3[0]) == 2 and len(d5[0]) == 1 and (d5[1][0], d5[2][0]) == (8, 8)
    with pytest.raises(ConfigError, match="peak_window"):
        peak_kernel(4)


def test_center_weight_makes_errors_at_the_peak_cost_more_than_at_the_rim():
    """box_center_weight: the same 1 px edge error costs more at the heat peak than at a rim pixel."""
    torch = pytest.importorskip("torch")
    from seedmap.detect.train_cnn import losses

    im = _one_seed_image(sliver_area=1.0)
    X, H, R, M, IG = (torch.from_numpy(np.ascontiguousarray(a)) for a in
                      crop_batch([im], 1, 96, np.random.default_rng(1), seed_fraction=1.0, augment=False))
    py, px = np.unravel_index(int(torch.argmax(H[0])), H[0].shape)
    ys, xs = np.nonzero(M[0].numpy() * (H[0].numpy() < 0.01))  # a mask pixel outside the Gaussian
    ry, rx = ys[0], xs[0]

    def box_l1(y: int, x: int, cw: float) -> float:
        out = torch.zeros(1, 7, 96, 96)
        out[:, 1:7] = R
        out[0, 3, y, x] += 1.0
        return float(losses(out, H, R, M, IG, iou_weight=1.0, center_weight=cw)[2])

    assert box_l1(py, px, 0.0) == pytest.approx(box_l1(ry, rx, 0.0))  # uniform: every pixel alike
    assert box_l1(py, px, 4.0) > 2.0 * box_l1(ry, rx, 4.0)


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


def _sliver_crop(spec: CropSpec):
    """A crop holding the whole 2x3 sliver (area 6: ignored by the heatmap, box-trained) and not the seed."""
    im = _one_seed_image()
    im2 = TrainImage(im.rgb, im.inst, im.boxes, im.kp, im.centers[1:], im.area)
    for seed in range(20):
        X, H, R, M, IG = crop_batch([im2], 1, 96, np.random.default_rng(seed), seed_fraction=1.0, augment=False,
                                    spec=CropSpec(scale_prob=0.0))
        if (M[0] > 0).sum() == 6:
            return crop_batch([im2], 1, 96, np.random.default_rng(seed), seed_fraction=1.0, augment=False, spec=spec)
    raise AssertionError("no crop with the whole sliver")


def test_peak_box_radius_trains_the_sliver_box_around_its_peak():
    """peak_box_radius=1: the 3x3 window around the sliver's peak pixel, which inference reads, gets the sliver's
    box (3 x 2 px) and keypoint as targets also outside its 6-px mask; radius 0 trains the mask pixels only."""
    _, _, R0, M0, _ = _sliver_crop(CropSpec(scale_prob=0.0))
    _, _, R1, M1, _ = _sliver_crop(CropSpec(scale_prob=0.0, peak_box_radius=1))
    m0, m1 = M0[0] > 0, M1[0] > 0
    assert m0.sum() == 6 and m1.sum() == 9 and (m1 & m0).sum() == 6  # 3x3 window over a 3x2 sliver: 3 more px
    ys, xs = np.nonzero(m1 & ~m0)
    assert np.allclose(R1[0, 0, ys, xs] + R1[0, 2, ys, xs], 3.0) and np.allclose(R1[0, 1, ys, xs] + R1[0, 3, ys, xs], 2.0)
    ky, kx = ys + R1[0, 5, ys, xs], xs + R1[0, 4, ys, xs]
    y0, x0 = np.nonzero(m0)
    assert np.allclose(kx, x0[0] + R0[0, 4, y0[0], x0[0]]) and np.allclose(ky, y0[0] + R0[0, 5, y0[0], x0[0]])
    assert np.array_equal(R1[0][:, m0], R0[0][:, m0])  # the mask pixels' own targets are unchanged


def test_sliver_box_weight_and_sliver_neg_weight():
    """sliver_box_weight=4 weighs the sliver's box pixels 5x (a seed's stay 1); sliver_neg_weight=0.25 turns the
    sliver's heat pixels from ignored into 0.25-weighted background, so a high heat there now costs loss."""
    torch = pytest.importorskip("torch")
    from seedmap.detect.train_cnn import losses

    _, _, _, Mw, _ = _sliver_crop(CropSpec(scale_prob=0.0, sliver_box_weight=4.0))
    assert np.allclose(Mw[0][Mw[0] > 0], 5.0) and (Mw[0] > 0).sum() == 6
    im = _one_seed_image(sliver_area=1.0)
    _, _, _, Ms, _ = crop_batch([im], 1, 96, np.random.default_rng(1), seed_fraction=1.0, augment=False,
                                spec=CropSpec(scale_prob=0.0, sliver_box_weight=4.0))
    assert np.allclose(Ms[0][Ms[0] > 0], 1.0)  # a whole seed is no sliver
    X, H, R, M, IG0 = _sliver_crop(CropSpec(scale_prob=0.0))
    _, _, _, _, IGn = _sliver_crop(CropSpec(scale_prob=0.0, sliver_neg_weight=0.25))
    sl = M[0] > 0
    assert np.allclose(IG0[0][sl], 1.0) and np.allclose(IGn[0][sl], 0.75)
    out = torch.zeros(1, 7, 96, 96)
    out[:, 0] = -8.0
    out[0, 0][torch.from_numpy(sl)] = 2.0  # the network fires on the sliver
    f0 = float(losses(out, *(torch.from_numpy(a) for a in (H, R, M, IG0)))[1])
    fn = float(losses(out, *(torch.from_numpy(a) for a in (H, R, M, IGn)))[1])
    assert f0 < 0.01 and fn > 10 * max(f0, 1e-3)


def test_photometric_augmentation_changes_pixels_not_targets():
    """gamma_jitter / noise_max (session 9) change only the crop's pixels: heat, box targets, weights and ignore
    masks stay those of the same crop without them; off (0) the crops are bit-identical to the session-4 ones."""
    im = _one_seed_image()
    rng_args = dict(n=4, size=96, seed_fraction=1.0, augment=True)
    base = crop_batch([im], rng=np.random.default_rng(3), spec=CropSpec(scale_prob=0.0), **rng_args)
    again = crop_batch([im], rng=np.random.default_rng(3), spec=CropSpec(scale_prob=0.0, gamma_jitter=0.0,
                                                                          noise_max=0.0), **rng_args)
    assert all(np.array_equal(a, b) for a, b in zip(base, again))
    for spec in (CropSpec(scale_prob=0.0, gamma_jitter=0.3), CropSpec(scale_prob=0.0, noise_max=8.0)):
        aug = crop_batch([im], rng=np.random.default_rng(3), spec=spec, **rng_args)
        assert not np.array_equal(aug[0], base[0])
        assert aug[0].min() >= 0.0 and aug[0].max() <= 1.0 and aug[0].dtype == np.float32
        # the same crops (the extra draws come after the crop position and flip of each crop are chosen, so the
        # targets of the first crop match; later crops may sit elsewhere) — compare crop 0's targets
        for a, b in zip(aug[1:], base[1:]):
            assert np.array_equal(a[0], b[0])
    # noise: the flat seed interior (grey 200) gets a spread of about the drawn sd; without, it is constant
    noisy = crop_batch([im], rng=np.random.default_rng(5), spec=CropSpec(scale_prob=0.0, noise_max=20.0),
                       **rng_args)
    plain = crop_batch([im], rng=np.random.default_rng(5), spec=CropSpec(scale_prob=0.0), **rng_args)
    inner = plain[3][0] > 0  # seed pixels of the first crop
    assert plain[0][0][:, inner].std() < 1e-6 and 0.5 / 255 < noisy[0][0][:, inner].std() < 20 / 255
