"""Appearance term of the ``multiview`` stereo assignment (session 11, issue #6): context-patch
descriptors of every keypoint (``context_descriptors``), their normalised cross-correlation in the
one-to-one left/right assignment (``mv_appearance_weight``, in the ``fast`` profile), and how they
travel through a results folder (``descriptors.npz``) to ``seedmap count``."""

from __future__ import annotations

import json
import sys

import cv2
import numpy as np
import pytest
from test_recon_count_pairing import _correct_pairs, wide_row_scan  # pytest puts tests/ on sys.path
from test_recon_multiview import CALIB

from seedmap import cli
from seedmap.errors import InputError
from seedmap.recon.config import CountConfig
from seedmap.recon.count import StereoKeypoints, context_descriptors, count_multiview, merge_close_keypoints
from seedmap.recon.pipeline import read_descriptors, read_detections


def _texture(rng: np.random.Generator, h: int = 240, w: int = 320) -> np.ndarray:
    """A colour image of blurred blobs (seed-sized structure, ~8 px)."""
    img = rng.random((h, w, 3)).astype(np.float32) * 255
    return cv2.GaussianBlur(img, (0, 0), 2.5)


def test_context_descriptors_match_a_shifted_image_and_not_a_neighbour():
    rng = np.random.default_rng(0)
    left = _texture(rng)
    d = 37.3  # sub-pixel disparity: the right image is the left one shifted left by d px
    right = cv2.warpAffine(left, np.float32([[1, 0, -d], [0, 1, 0]]), (left.shape[1], left.shape[0]),
                           flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    uv = np.column_stack([rng.uniform(80, 280, 50), rng.uniform(60, 180, 50)])
    dl = context_descriptors(left, uv, 20.0, 11)
    dr = context_descriptors(right, uv - [d, 0], 20.0, 11)
    wrong = context_descriptors(right, uv - [d - 8.0, 0], 20.0, 11)  # one seed width off on the same row
    assert dl.shape == (50, 11 * 11 * 3) and dl.dtype == np.float32
    assert np.allclose(np.linalg.norm(dl, axis=1), 1, atol=1e-4) and np.allclose(dl.mean(axis=1), 0, atol=1e-5)
    true_ncc, wrong_ncc = np.sum(dl * dr, axis=1), np.sum(dl * wrong, axis=1)
    assert np.min(true_ncc) > 0.97, np.min(true_ncc)
    assert np.median(wrong_ncc) < 0.6 and np.all(wrong_ncc < true_ncc), np.median(wrong_ncc)
    # grey images, no keypoints, a flat patch (zero descriptor, never NaN)
    assert context_descriptors(left[:, :, 0], uv, 10.0, 7).shape == (50, 49)
    assert context_descriptors(left, np.zeros((0, 2)), 10.0).shape == (0, 363)
    flat = context_descriptors(np.full((50, 50, 3), 90, np.uint8), [[25.0, 25.0]], 5.0)
    assert np.all(flat == 0)


def _with_seed_descriptors(views, ids_l, ids_r, rng, dim: int = 64, noise: float = 0.6):
    """Gives every seed a random appearance and every keypoint that appearance plus noise (unit norm);
    false detections get random ones."""
    look = rng.normal(size=(100000, dim))

    def desc(ids):
        d = np.where((ids >= 0)[:, None], look[np.maximum(ids, 0)], rng.normal(size=(len(ids), dim)))
        d = d + noise * rng.normal(size=d.shape)
        d -= d.mean(axis=1, keepdims=True)
        return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)

    for v, il, ir in zip(views, ids_l, ids_r):
        v.left_desc, v.right_desc = desc(il), desc(ir)


def test_appearance_term_prefers_the_partner_that_looks_alike():
    # a wide row tolerance (8 px) admits the neighbouring seeds' right keypoints; their appearance
    # differs, so weighting the assignment by the descriptors' correlation picks the true partner
    rng, views, poses, ids_l, ids_r, base, d0 = wide_row_scan()
    _with_seed_descriptors(views, ids_l, ids_r, rng)
    # descriptors alone change nothing while the weight is 0
    _, dz = count_multiview(views, poses, CALIB, base, detail=True)
    assert np.array_equal(dz.left, d0.left) and np.array_equal(dz.right, d0.right)
    _, d1 = count_multiview(views, poses, CALIB, base.model_copy(update={"mv_appearance_weight": 5.0}),
                            detail=True)
    p0, p1 = _correct_pairs(views, ids_l, ids_r, d0), _correct_pairs(views, ids_l, ids_r, d1)
    assert p1 > p0 + 0.1 and p1 > 0.92, (p0, p1)  # measured 0.79 -> 0.95
    # a minimum correlation drops candidates outright
    _, d2 = count_multiview(views, poses, CALIB, base.model_copy(update={"mv_appearance_weight": 5.0,
                                                                         "mv_appearance_min": 0.99}), detail=True)
    assert len(d2.view) < 0.05 * len(d1.view)


def test_merged_keypoints_keep_unit_descriptors():
    kp = StereoKeypoints([[10.0, 10.0], [11.0, 10.0], [40.0, 10.0]], [[5.0, 10.0], [30.0, 10.0]], [6.0, 6.0, 6.0],
                         left_desc=np.eye(3, 4), right_desc=np.eye(2, 4))
    m, lab = merge_close_keypoints(kp, 2.0)
    assert len(m.left) == 2 and m.left_desc.shape == (2, 4) and m.right_desc.shape == (2, 4)
    assert np.allclose(np.linalg.norm(m.left_desc, axis=1), 1)
    assert np.allclose(m.left_desc[lab[0]], [2 ** -0.5, 2 ** -0.5, 0, 0], atol=1e-6)
    with pytest.raises(ValueError, match="one image only"):
        StereoKeypoints([[1.0, 1.0]], [[0.0, 1.0]], [5.0], left_desc=np.ones((1, 3)))
    with pytest.raises(ValueError, match="right ones"):
        StereoKeypoints([[1.0, 1.0]], [[0.0, 1.0]], [5.0], left_desc=np.ones((1, 3)), right_desc=np.ones((1, 4)))


def _run(args: list[str], monkeypatch) -> int:
    monkeypatch.setattr(sys, "argv", ["seedmap", *args])
    with pytest.raises(SystemExit) as e:
        cli.main()
    return int(e.value.code or 0)


def test_reconstruction_writes_descriptors_and_count_reuses_them(tmp_path, monkeypatch):
    data, res = tmp_path / "p4", tmp_path / "r4"
    assert _run(["simulate", "panicle", "--seed", "4", "--views", "6", "--out", str(data), "-q",
                 "--set", "sim.camera.scale=0.18"], monkeypatch) == 0
    on = ["--set", "count.mv_desc_size=6", "--set", "count.mv_desc_grid=15", "--set", "count.mv_appearance_weight=5"]
    # off by default: no descriptors are computed or written
    assert _run(["reconstruct", str(data), "--register", "seeds", "--detector", "fast", "--out", str(tmp_path / "r0"),
                 "-q"], monkeypatch) == 0
    assert not (tmp_path / "r0" / "descriptors.npz").exists()
    assert _run(["reconstruct", str(data), "--register", "seeds", "--detector", "fast", "--out", str(res), "-q", *on],
                monkeypatch) == 0
    n = json.loads((res / "metrics.json").read_text())["seed_count"]
    assert n > 20
    kps = read_detections(res, 6)
    read_descriptors(res / "descriptors.npz", kps)
    kp = next(k for k in kps if k is not None)
    assert kp.left_desc.shape == (len(kp.left), 15 * 15 * 3) and kp.right_desc.shape[0] == len(kp.right)
    assert np.allclose(np.linalg.norm(kp.left_desc, axis=1), 1, atol=1e-3)
    # `seedmap count` re-runs the same count from the folder (the int8 descriptors round-trip)
    assert _run(["count", str(res), "--out", str(tmp_path / "c")], monkeypatch) == 0
    again = json.loads((tmp_path / "c" / "count.json").read_text())["seed_count"]
    assert abs(again - n) <= max(2, 0.02 * n), (again, n)
    # without the file: a warning, and the count runs without the appearance term
    (res / "descriptors.npz").rename(tmp_path / "d.npz")
    with pytest.warns(UserWarning, match="descriptors.npz"):
        assert _run(["count", str(res), "--out", str(tmp_path / "c2")], monkeypatch) == 0
    # a descriptors file that does not fit detections.csv is an error naming the file
    bad = dict(np.load(tmp_path / "d.npz"))
    k = next(key for key in bad if key.startswith("left_"))
    bad[k] = bad[k][:-1]
    np.savez(res / "descriptors.npz", **bad)
    with pytest.raises(InputError, match="descriptors.npz"):
        read_descriptors(res / "descriptors.npz", read_detections(res, 6))
    (res / "descriptors.npz").write_bytes(b"not an npz")
    assert _run(["count", str(res)], monkeypatch) == 2
