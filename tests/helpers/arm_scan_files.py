"""An arm scan written as files (stereo pairs of noise, joints.csv, arm.yaml) without rendering."""

from __future__ import annotations

import numpy as np
import yaml

from seedmap.io.seedmap_dataset import DatasetWriter, Instances
from seedmap.sim.arm import ArmConfig, arm_yaml_dict, simulate_capture, write_joints_csv
from seedmap.records import StereoCalib

CALIB = StereoCalib(fx=500.0, fy=500.0, cx=319.5, cy=119.5, baseline=0.11, width=640, height=240)


def textured_pair(depth: float, rng: np.random.Generator):
    """A fronto-parallel textured plane at ``depth`` (m): the right image is the left shifted by
    the exact disparity (integer here)."""
    d = int(round(CALIB.fx * CALIB.baseline / depth))
    W, H = CALIB.width, CALIB.height
    tex = (rng.uniform(40, 255, (H, W + d + 64)) * 1.0).astype(np.uint8)
    tex = np.repeat(tex[:, :, None], 3, axis=2)
    left = tex[:, 0:W].copy()  # left pixel u sees texture column u ...
    right = tex[:, d:d + W].copy()  # ... which the right camera sees at u - d
    return left, right, d


def write_arm_scan(root, n_views: int, dark_views=(), joints=True):
    rng = np.random.default_rng(0)
    cfg = ArmConfig(views=n_views)
    cap = simulate_capture(cfg, [0.1], np.random.default_rng(1))
    w = DatasetWriter(root)
    w.write_calib(CALIB)
    w.write_times(np.arange(n_views, dtype=float))
    for k in range(n_views):
        left, right, _ = textured_pair(0.3, rng)
        if k in dark_views:
            left, right = np.zeros_like(left), np.zeros_like(right)
        w.write_frame(k, left, right)
        for cam in ("left", "right"):
            w.write_gt_instances(k, cam, np.zeros((CALIB.height, CALIB.width), np.uint16), Instances.empty())
    if joints:
        write_joints_csv(root / "joints.csv", cap)
        (root / "arm.yaml").write_text(yaml.safe_dump(arm_yaml_dict(cap, cfg)))
    return cap
