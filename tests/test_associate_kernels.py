"""The compiled kernels (seedmap.associate.kernels, seedmap.detect.kernels) give exactly what the numpy / scipy code
they replaced gave, on the fast detector's real detections of a rendered range: same pairs in the same order, same
sums and histograms bit for bit, same k-NN sets, same network input and refiner patches."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter
from scipy.spatial import cKDTree

from seedmap.associate.cost import full_res_scale, neighbour_sums
from seedmap.associate.base import GateConfig
from seedmap.associate.field import box_pairs, field_candidates, loo_local_median, nearest_points
from seedmap.associate.assignment import mutual_best, ratio_test
from seedmap.associate.kernels import box3_filter, sure_pairs, vote_histogram


@pytest.fixture(scope="module")
def dets(cnn_range):
    """The fast detector's stereo detections of frames 0 and 1 (image px) and the image width."""
    from seedmap.detect import make_detector

    det = make_detector("fast", dataset=cnn_range.root)
    out = [det.detect_stereo(cnn_range[i]) for i in (0, 1)]
    kp = [np.asarray(getattr(d, s).keypoints, np.float64).reshape(-1, 2) for d in out for s in ("left", "right")]
    assert min(len(k) for k in kp) > 500
    return kp, cnn_range.calib.width


def _numpy_neighbour_sums(kp, delta, eps, valid=None):
    """The numpy implementation the kernel replaced (band pairs by sort + searchsorted, sums by bincount)."""
    n = len(kp)
    out = np.zeros((n, 4))
    ok = np.ones(n, bool) if valid is None else valid
    for along, band, col in ((0, 1, 0), (1, 0, 2)):
        order = np.argsort(kp[:, band], kind="stable")
        sb, sa = kp[order, band], kp[order, along]
        hi = np.searchsorted(sb, sb + eps, side="left")
        cnt = np.maximum(hi - np.arange(n) - 1, 0)
        i = np.repeat(np.arange(n), cnt)
        j = np.arange(1, cnt.sum() + 1) - np.repeat(np.cumsum(cnt) - cnt - np.arange(n), cnt)
        d = sa[j] - sa[i]
        keep = (d != 0) & (np.abs(d) < delta)
        i, j, d = i[keep], j[keep], d[keep]
        dist = np.hypot(d, sb[j] - sb[i])
        first, second = np.where(d > 0, i, j), np.where(d > 0, j, i)
        oks = ok[order]
        sel = oks[first]
        out[order, col] = np.bincount(second[sel], dist[sel], minlength=n)
        sel = oks[second]
        out[order, col + 1] = np.bincount(first[sel], dist[sel], minlength=n)
    return out


def _numpy_box_pairs(pa, pb, half):
    """The numpy implementation the kernel replaced (runs by searchsorted, candidates by repeat + offsets)."""
    h = np.maximum(np.asarray(half, np.float64), 1e-9)
    sa, sb = pa / h, pb / h
    rb, ra = np.floor(sb[:, 1]), np.floor(sa[:, 1])
    y0 = min(rb.min(), ra.min()) - 1.0
    x0 = min(sb[:, 0].min(), sa[:, 0].min()) - 2.0
    w = max(sb[:, 0].max(), sa[:, 0].max()) - x0 + 4.0
    m = 1.0 + 1e-9 + 8.0 * np.finfo(np.float64).eps * (max(rb.max(), ra.max()) - y0 + 2.0) * w
    keyb = (rb - y0) * w + (sb[:, 0] - x0)
    order = np.argsort(keyb, kind="stable")
    ks = keyb[order]
    qa = (ra - y0) * w + (sa[:, 0] - x0)
    lo = np.stack([np.searchsorted(ks, qa + dr * w - m, side="left") for dr in (-1.0, 0.0, 1.0)], 1).reshape(-1)
    hi = np.stack([np.searchsorted(ks, qa + dr * w + m, side="right") for dr in (-1.0, 0.0, 1.0)], 1).reshape(-1)
    cnt = hi - lo
    q = np.repeat(np.arange(len(lo)), cnt)
    j = order[lo[q] + np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)]
    i = q // 3
    ok = (np.abs(sb[j, 0] - sa[i, 0]) <= 1.0) & (np.abs(sb[j, 1] - sa[i, 1]) <= 1.0)
    return i[ok], j[ok]


def test_neighbour_sums_equal_the_numpy_version_bit_for_bit(dets):
    kp, width = dets
    s = full_res_scale(width)
    rng = np.random.default_rng(0)
    for k in kp:
        f = k * s
        assert np.array_equal(neighbour_sums(f, 1000.0, 15.0), _numpy_neighbour_sums(f, 1000.0, 15.0))
        valid = rng.random(len(f)) > 0.2
        assert np.array_equal(neighbour_sums(f, 300.0, 15.0, valid), _numpy_neighbour_sums(f, 300.0, 15.0, valid))


def test_box_pairs_equal_the_numpy_version_pair_for_pair(dets):
    kp, _ = dets
    for a, b in ((kp[0], kp[1]), (kp[0], kp[2])):
        for half in ((4.0, 1.5), (1.2, 0.6), (180.0, 4.2), (30.0, 30.0)):
            got = box_pairs(a, b, np.array(half))
            want = _numpy_box_pairs(a, b, np.array(half))
            assert len(want[0]) > 0
            assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_field_candidates_equal_box_then_gate_then_residual(dets):
    from seedmap.associate.methods import stereo_gate_fn

    kp, width = dets
    kl, kr = kp[0], kp[1]
    gate = stereo_gate_fn(kl, kr, GateConfig().scaled(width), width)
    rng = np.random.default_rng(5)
    pred = np.c_[rng.uniform(-90.0, -30.0, len(kl)), np.zeros(len(kl))]
    for sig in (np.array([2.9, 2.9]), np.array([1.6, 0.5])):
        ia, ib = box_pairs(kl + pred, kr, 3.5 * sig)
        ok = gate(ia, ib)
        ia, ib = ia[ok], ib[ok]
        r = (kr[ib] - kl[ia] - pred[ia]) / sig
        res = np.hypot(r[:, 0], r[:, 1])
        ok = res <= 3.5
        got = field_candidates(kl, kr, pred, sig, gate, 3.5)
        assert ok.sum() > 100
        for g, w in zip(got, (ia[ok], ib[ok], res[ok]), strict=True):
            assert np.array_equal(g, w)


def test_vote_histogram_and_box3_filter_equal_bincount_and_scipy(dets):
    kp, width = dets
    ka, kb = kp[0], kp[1]
    lo, hi, cell = np.array([-520.0, -4.2]), np.array([-17.0, 4.2]), 90.0
    nb = np.maximum(1, np.ceil((hi - lo) / 1.05).astype(int))
    binw = (hi - lo) / nb
    i, j = box_pairs(ka + 0.5 * (lo + hi), kb, 0.5 * (hi - lo))
    ncx, ncy = int(np.ceil(width / cell)) + 1, int(np.ceil(900 / cell)) + 1
    cell_of = (np.clip((ka[:, 0] // cell).astype(int), 0, ncx - 1) * ncy
               + np.clip((ka[:, 1] // cell).astype(int), 0, ncy - 1)).astype(np.int64)
    ub = np.clip(((kb[j] - ka[i] - lo) / binw).astype(int), 0, nb - 1)
    flat = (cell_of[i] * nb[0] + ub[:, 0]) * nb[1] + ub[:, 1]
    want = np.bincount(flat, minlength=ncx * ncy * nb[0] * nb[1]).astype(np.float32)
    got = vote_histogram(i, j, ka, kb, cell_of, lo, binw, nb.astype(np.int64), ncx * ncy)
    assert want.sum() > 1000 and np.array_equal(got, want)
    hist = got.reshape(ncx, ncy, nb[0], nb[1])
    assert np.array_equal(box3_filter(hist), uniform_filter(hist, size=(3, 3, 3, 3), mode="constant"))
    # a denser histogram with non-integer values, and a degenerate axis of length 1
    rng = np.random.default_rng(1)
    x = (rng.integers(0, 5, (6, 1, 30, 9)) * (rng.random((6, 1, 30, 9)) > 0.5) / 7).astype(np.float32)
    assert np.array_equal(box3_filter(x), uniform_filter(x, size=3, mode="constant"))


def test_sure_pairs_equal_mutual_best_then_ratio_test(dets):
    kp, _ = dets
    a, b = kp[0], kp[1]
    rng = np.random.default_rng(4)
    ia, ib = box_pairs(a + [-60.0, 0.0], b, np.array([40.0, 3.0]))
    res = np.hypot(*((b[ib] - a[ia] - [-60.0, 0.0]) / [13.0, 1.0]).T)
    res[rng.random(len(res)) < 0.05] = 0.5  # exact ties between competitors
    n, m = len(a), len(b)
    for ratio in (0.3, 0.7, 1.0):
        want = ratio_test(mutual_best(ia, ib, res, n, m), ia, ib, res, n, m, ratio)
        got = sure_pairs(ia, ib, res, n, m, ratio)
        assert len(want) > 10
        assert np.array_equal(got[0], want.idx_a) and np.array_equal(got[1], want.idx_b)


def _kdtree_loo_median(pos, val, k):
    """The KD-tree implementation the grid search replaced."""
    n = len(pos)
    kk = min(k + 1, n)
    _, nn = cKDTree(pos).query(pos, kk)
    is_self = nn == np.arange(n)[:, None]
    drop = np.where(is_self.any(1), is_self.argmax(1), kk - 1)
    keep = np.ones_like(nn, bool)
    keep[np.arange(n), drop] = False
    others = nn[keep].reshape(n, kk - 1)
    return np.median(val[others], axis=1)


def test_grid_knn_gives_the_kdtree_sets_and_medians(dets):
    kp, _ = dets
    a, b = kp[0], kp[1]
    rng = np.random.default_rng(2)
    seeds = np.sort(rng.choice(len(a), len(a) // 2, replace=False))
    pos = a[seeds]
    val = rng.normal(0, 3, (len(pos), 2)) + [-40.0, 0.0]
    for k in (25, 4, 1):
        assert np.array_equal(loo_local_median(pos, val, k), _kdtree_loo_median(pos, val, k))
    # nearest seed of every keypoint (also far ones: the other image's keypoints shifted away)
    for q in (a, b, b + [900.0, 300.0]):
        assert np.array_equal(nearest_points(pos, q, 1)[:, 0], cKDTree(pos).query(q, 1)[1])
    assert np.array_equal(nearest_points(pos, b, 7), cKDTree(pos).query(b, 7)[1])
    # repeated positions and exact ties at the k-th distance are left to the KD-tree, as before
    grid = np.stack(np.meshgrid(np.arange(12.0), np.arange(9.0)), -1).reshape(-1, 2)
    grid = np.r_[grid, grid[:10]]
    v = rng.normal(size=(len(grid), 2))
    assert np.array_equal(loo_local_median(grid, v, 6), _kdtree_loo_median(grid, v, 6))


def test_detector_gathers_equal_the_numpy_expressions(cnn_range):
    from seedmap.detect.kernels import INPUT_LUT, window_batch
    from seedmap.detect.mlp import patches

    img = np.ascontiguousarray(cnn_range[0].left)
    h, w = img.shape[:2]
    t, sh, sw = 48, 64, 3 * 48 + 16  # runs of three tiles and their margin
    pad = np.pad(img, ((8, 8 + 48), (8, 8 + 3 * 48), (0, 0)))
    org = t * np.array([[0, 0], [3, 5], [h // t, w // t], [1, 0]], np.int64)
    want = np.stack([pad[y0: y0 + sh, x0: x0 + sw] for y0, x0 in org])
    want = np.ascontiguousarray((want.astype(np.float32) * (1.0 / 255.0)).transpose(0, 3, 1, 2))
    assert np.array_equal(window_batch(pad, org, sh, sw, INPUT_LUT), want)
    rng = np.random.default_rng(3)
    x = np.r_[0, 2, w - 1, 100, rng.integers(0, w, 300)]
    y = np.r_[0, h - 1, 5, h - 3, rng.integers(0, h, 300)]
    r = 6
    padp = np.pad(img, ((r, r), (r, r), (0, 0)))
    idx = np.arange(-r, r + 1)
    offs = ((idx[:, None] * padp.shape[1] + idx[None, :])[..., None] * 3 + np.arange(3)).ravel()
    base = ((y + r) * padp.shape[1] + (x + r)) * 3
    want = np.take(padp.ravel(), base[:, None] + offs[None, :]).astype(np.float32) / 255.0
    got = patches(img, x, y, r)
    assert np.array_equal(got, want)
    assert np.array_equal(patches(img[..., 1], x, y, 2), patches(img[..., 1:2], x, y, 2))


def test_refiner_context_equals_the_kdtree_version(cnn_range):
    """The compiled neighbour context of the refiner's features equals the KD-tree + numpy version (which also
    answers the rows the kernel flags), on real peaks and on dense lattices full of equal distances and logits."""
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.cnn_refine import NEAR_PX, NEIGHBOUR_K, NEIGHBOUR_PX, SCALE_PX, _context_kdtree, peak_features
    from seedmap.detect.kernels import peak_context

    def both(xy, raw):
        rw = np.asarray(raw, np.float32).copy()
        rw[:, 1:5] /= SCALE_PX
        k = min(NEIGHBOUR_K + 1, len(xy))
        nb, amb = peak_context(xy, rw, k, NEIGHBOUR_PX, NEAR_PX, SCALE_PX)
        ref = _context_kdtree(xy, rw, np.arange(len(xy)), k)
        return nb, amb, ref

    img = np.ascontiguousarray(cnn_range[0].left)
    pk = CnnDetector().peaks(img)
    xy = np.c_[pk.x, pk.y]
    nb, amb, ref = both(xy, pk.raw)
    assert len(xy) > 500 and amb.mean() < 0.05
    assert np.array_equal(nb[~amb], ref[~amb])
    assert np.array_equal(peak_features(img, pk.x, pk.y, pk.raw)[:, -8:], ref)
    rng = np.random.default_rng(4)
    for trial in range(12):
        n = int(rng.integers(2, 600))
        xy = np.c_[rng.integers(0, 50, n), rng.integers(0, 30, n)].astype(np.float64)
        if trial % 3 == 0:
            xy += rng.random((n, 2)) * 0.5
        if trial % 4 == 1:
            xy[: n // 4] = xy[n // 4: 2 * (n // 4)]  # repeated positions
        raw = rng.normal(size=(n, 7)).astype(np.float32)
        raw[:, 0] = np.round(raw[:, 0] * 2) / 2  # many equal logits
        nb, amb, ref = both(xy, raw)
        assert np.array_equal(nb[~amb], ref[~amb])
        full = peak_features(rng.integers(0, 255, (40, 60, 3), np.uint8), xy[:, 0], xy[:, 1], raw)
        assert np.array_equal(full[:, -8:], ref)
