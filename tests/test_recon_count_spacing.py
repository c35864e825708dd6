"""The multiview counter's view-spacing rule (seedmap.recon.count.support_shift)."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.recon.config import CountConfig
from seedmap.recon.count import StereoKeypoints, count_multiview, support_shift, view_spacing_deg


def _circle(n: int, radius: float = 0.3) -> np.ndarray:
    """T_world_cam of n cameras on a horizontal circle, optical axis (z) at the centre, y down."""
    out = []
    for a in np.linspace(0, 2 * np.pi, n, endpoint=False):
        c = np.array([radius * np.cos(a), 0.0, radius * np.sin(a)])
        z = -c / np.linalg.norm(c)
        y = np.array([0.0, 1.0, 0.0])
        x = np.cross(y, z)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, y, z])
        T[:3, 3] = c
        out.append(T)
    return np.array(out)


def test_view_spacing_and_support_shift():
    assert view_spacing_deg(_circle(24)) == pytest.approx(15.0)
    assert view_spacing_deg(_circle(36)) == pytest.approx(10.0)
    assert np.isnan(view_spacing_deg(_circle(1)))
    assert support_shift(_circle(24)) == 0.0  # the reference: unchanged
    assert support_shift(_circle(25)) == 0.0  # < 5 % denser: unchanged
    assert support_shift(_circle(36)) == pytest.approx(3.0 * 0.5)
    assert support_shift(_circle(48)) == pytest.approx(3.0 * 1.0)
    assert support_shift(_circle(12)) == 0.0  # sparser scans are not shifted


def test_sparse_scans_warn(caplog):
    views = [StereoKeypoints(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))] * 12
    from seedmap.records import StereoCalib

    calib = StereoCalib(fx=1000.0, fy=1000.0, cx=500.0, cy=400.0, baseline=0.06, width=1000, height=800)
    with caplog.at_level("WARNING", logger="seedmap"):  # a seedmap warning (one `warning: ` line in the CLI)
        assert count_multiview(views, _circle(12), calib, CountConfig()).count == 0
    assert [r.name for r in caplog.records if "30.0 deg apart" in r.getMessage()] == ["seedmap"]
