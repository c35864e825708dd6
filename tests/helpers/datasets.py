"""Small synthetic datasets written directly in seedmap's layout (no rendering)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.io.seedmap_dataset import DatasetWriter
from seedmap.records import StereoCalib


def tiny_stereo_dataset(root: Path, n: int = 2, width: int = 160, height: int = 120) -> Path:
    """``n`` stereo pairs of textured noise in seedmap's layout, the right image the left shifted by 8 px;
    fx = fy = 0.75 width, principal point at the centre, 0.1 m baseline."""
    rng = np.random.default_rng(0)
    w = DatasetWriter(root)
    f = 0.75 * width
    w.write_calib(StereoCalib(fx=f, fy=f, cx=width / 2, cy=height / 2, baseline=0.1, width=width, height=height))
    w.write_times(np.arange(n) * 0.2)
    for i in range(n):
        img = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        w.write_frame(i, img, np.roll(img, -8, axis=1))
    return root
