"""The online back-end's state along a row: what iSAM2 and the SLAM object keep per frame stays bounded."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from seedmap.associate import make_matcher
from seedmap.slam.config import SlamConfig
from seedmap.slam.core import SemanticSlam
from seedmap.slam.synthetic import make_range, observe


def _row(length: float):
    rng = np.random.default_rng(5)
    rg = make_range(rng, length=length, seeds_per_panicle=150)
    cfg = SlamConfig()
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    nnz = []
    for i in range(len(rg.gt)):
        r = slam.register_frame(m.features_from_detections(observe(rg, i, rng)))
        assert r.ok, r.lost_reason
        nnz.append((slam.backend.isam.treeNnz(), slam.initial.size()))
    return rg, slam, np.array(nnz, float)


def test_bayes_tree_grows_with_the_variables_not_with_the_view():
    rg, slam, nnz = _row(0.8)
    # the active window's poses are ordered last, landmarks before them: the root clique holds poses, not every
    # landmark seen in the frame, so the factorisation costs ~100 entries per variable (iSAM2's default order,
    # all observed variables last: > 1000, and growing)
    per_var = nnz[:, 0] / nnz[:, 1]
    assert per_var[-1] < 300, per_var
    half = len(nnz) // 2
    growth_late = (nnz[-1, 0] - nnz[half, 0]) / (nnz[-1, 1] - nnz[half, 1])
    assert growth_late < 300, growth_late


def test_no_per_frame_copy_of_the_estimate_is_kept():
    rg, slam, _ = _row(0.3)
    # the graph's initial values are the only Values the object holds; the estimate is computed on demand
    held = [name for name, v in vars(slam).items() if isinstance(v, gtsam.Values)]
    assert held == ["initial"]
    est = slam.estimate
    assert est.size() == slam.initial.size() == slam.graph.keys().size()
    # ... and its newest pose is the one the last frame returned
    np.testing.assert_array_equal(est.atPose3(gtsam.symbol("x", slam.frames[-1])).matrix(), slam.online_poses[-1])


@pytest.mark.parametrize(("online", "name"), [("isam2", "isam2"), ("fixed_lag", "fixed-lag")])
def test_a_frame_rejected_after_the_update_leaves_the_accepted_map(monkeypatch, online, name):
    import seedmap.slam.core as core

    rng = np.random.default_rng(5)
    rg = make_range(rng, length=0.3, seeds_per_panicle=150)
    cfg = SlamConfig()
    cfg.backend.online = online
    cfg.backend.lag_frames = 2
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    n = len(rg.gt)
    for i in range(n - 1):
        assert slam.register_frame(m.features_from_detections(observe(rg, i, rng))).ok
    monkeypatch.setattr(core, "MAX_CORRECTION_M", -1.0)  # the smoother takes the last frame, the check rejects it
    r = slam.register_frame(m.features_from_detections(observe(rg, n - 1, rng)))
    assert not r.ok and "diverged" in r.lost_reason
    assert slam.estimate.size() == slam.initial.size()  # the rejected frame's variables are left out
    traj, values, backend = slam.finalize()
    assert len(traj) == n - 1 and backend == f"{name}+lm"
    err = np.linalg.norm(traj.positions - rg.gt.positions[: n - 1], axis=1)
    assert err.max() < 0.005
