"""Lost detection on a *rendered* sequence: frames blanked in a copy of a simulated range.

The synthetic-geometry version lives in test_slam_core.py; here the whole pipeline (dataset reader,
gt detector, seed matcher, front-end, lost rule, metrics) runs on simulator output. A blank frame is
black in both images and has no seed in its ground truth (the scene a camera sees when the flash
fails or the lens is covered), so the oracle detector returns no keypoints for it.
"""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest


def _blank_copy(src, dst, frames: set[int]):
    """Copy the dataset and blank ``frames`` (images black, GT masks empty, no GT instances)."""
    shutil.copytree(src, dst)
    for k in frames:
        name = f"{k:06d}"
        for side in ("left", "right"):
            img = dst / side / f"{name}.png"
            shape = cv2.imread(str(img), cv2.IMREAD_UNCHANGED).shape
            cv2.imwrite(str(img), np.zeros(shape, np.uint8))
            mask = dst / "gt" / "masks" / side / f"{name}.png"
            m = cv2.imread(str(mask), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(mask), np.zeros_like(m))
            inst = dst / "gt" / "instances" / side / f"{name}.csv"
            inst.write_text(inst.read_text().splitlines()[0] + "\n")
    return dst


@pytest.mark.slow
def test_untouched_tiny_range_is_tracked_to_the_end(tiny_range, tmp_path):
    """The reference for the next test: without blanks nothing is lost, so a lost frame there is
    caused by the blanks."""
    from seedmap.slam.pipeline import run_slam

    ref = run_slam(tiny_range, tmp_path / "ref", matcher="seeds", detector="gt", progress=False)
    assert ref.metrics.lost_frame is None, ref.metrics.lost_reason


@pytest.mark.slow
@pytest.mark.parametrize("blank", [{4, 5}, {7}])
def test_blank_rendered_frames_are_lost_at_the_right_frame(tiny_range, tmp_path, blank):
    from seedmap.slam.pipeline import run_slam

    data = _blank_copy(tiny_range, tmp_path / "blanked", blank)
    res = run_slam(data, tmp_path / "res", matcher="seeds", detector="gt", progress=False)
    m = res.metrics
    assert m.lost_frame == min(blank), (m.lost_frame, m.lost_reason)
    assert m.frames_tracked == min(blank)
    assert "match" in (m.lost_reason or "") or "keypoint" in (m.lost_reason or "")
    # distance mapped = the estimate's travel up to the last tracked frame (0.04 m per frame)
    assert m.mdm_m == pytest.approx(0.04 * (min(blank) - 1), abs=0.01)
