"""Ellipse fitting recovers synthetic ellipses (centre, axes, angle) on rasterised masks."""

import cv2
import numpy as np
import pytest

from seedmap.detect.ellipse import ellipse_boxes, fit_ellipse_mask, fit_ellipses_labels


def _raster(cx, cy, major, minor, angle, h=80, w=100, ss=8):
    """Exact-coverage mask: a pixel is inside when its centre is inside the ellipse."""
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    t = np.radians(angle)
    u, v = xx - cx, yy - cy
    x = (u * np.cos(t) + v * np.sin(t)) / (major / 2)
    y = (-u * np.sin(t) + v * np.cos(t)) / (minor / 2)
    return (x * x + y * y <= 1).astype(np.uint8)


def _angle_diff(a, b):
    d = abs(a - b) % 180
    return min(d, 180 - d)


@pytest.mark.parametrize("method", ["contour", "moments"])
@pytest.mark.parametrize("angle", [0.0, 30.0, 75.0, 120.0, 165.0])
def test_fit_recovers_large_ellipse(method, angle):
    cx, cy, ma, mi = 47.3, 38.6, 40.0, 22.0
    e = fit_ellipse_mask(_raster(cx, cy, ma, mi, angle), method)
    assert abs(e[0] - cx) < 0.15 and abs(e[1] - cy) < 0.15
    assert abs(e[2] - ma) < 1.6 and abs(e[3] - mi) < 1.6
    assert e[2] >= e[3]
    assert _angle_diff(e[4], angle) < 2.0


def test_small_seed_centre_subpixel():
    rng = np.random.default_rng(1)
    errs = []
    for _ in range(50):
        cx, cy = rng.uniform(20, 30, 2)
        e = fit_ellipse_mask(_raster(cx, cy, rng.uniform(5, 7), rng.uniform(4, 5), rng.uniform(0, 180), 50, 50),
                             "moments")
        errs.append(np.hypot(e[0] - cx, e[1] - cy))
    assert np.median(errs) < 0.2


def test_angle_convention_matches_cv2_drawing():
    # draw with cv2.ellipse using (major/2, minor/2, angle) and fit back
    img = np.zeros((100, 100), np.uint8)
    cv2.ellipse(img, (50, 50), (30, 12), 40.0, 0, 360, 255, -1)
    e = fit_ellipse_mask(img, "contour")
    assert _angle_diff(e[4], 40.0) < 2.0 and abs(e[2] - 60) < 3 and abs(e[3] - 24) < 3


def test_labels_vectorised_equals_single():
    lab = np.zeros((80, 100), np.uint16)
    truth = [(20.2, 20.7, 14, 8, 10), (60.5, 30.1, 10, 6, 100), (70.0, 60.0, 18, 12, 45)]
    for k, t in enumerate(truth, 1):
        lab[_raster(*t) > 0] = k
    for method in ("moments", "contour"):
        e = fit_ellipses_labels(lab, np.array([1, 2, 3, 9]), method)
        assert np.isnan(e[3]).all()
        for k in range(3):
            single = fit_ellipse_mask(lab == k + 1, method)
            np.testing.assert_allclose(e[k], single, atol=1e-6)
            assert np.hypot(e[k, 0] - truth[k][0], e[k, 1] - truth[k][1]) < 0.3


def test_largest_component_and_empty():
    m = _raster(30, 30, 12, 8, 0, 60, 60)
    m[5, 5] = 1  # a speck
    e = fit_ellipse_mask(m, "contour")
    assert abs(e[0] - 30) < 0.2 and abs(e[1] - 30) < 0.2
    assert fit_ellipse_mask(np.zeros((5, 5)), "moments") is None
    tiny = np.zeros((5, 5), np.uint8)
    tiny[2, 2] = 1
    e = fit_ellipse_mask(tiny, "contour")  # < 5 contour points: moments fallback
    assert e[0] == 2 and e[1] == 2 and e[2] > 0


def test_ellipse_boxes_contain_axes():
    b = ellipse_boxes(np.array([[10.0, 20.0, 8.0, 4.0, 0.0], [10.0, 20.0, 8.0, 4.0, 90.0]]))
    np.testing.assert_allclose(b[0], [6, 18, 14, 22], atol=1e-9)
    np.testing.assert_allclose(b[1], [8, 16, 12, 24], atol=1e-9)
