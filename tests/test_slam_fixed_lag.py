"""The bounded online back-end (``backend.online=fixed_lag``) on synthetic seed geometry against ground truth."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from seedmap.associate import make_matcher
from seedmap.slam.config import SlamConfig
from seedmap.slam.core import SemanticSlam
from seedmap.slam.synthetic import make_range, observe


def _row(length: float, online: str, lag: int = 0, seed: int = 4):
    rng = np.random.default_rng(seed)
    rg = make_range(rng, length=length, seeds_per_panicle=150)
    cfg = SlamConfig()
    cfg.backend.online = online
    cfg.backend.lag_frames = lag
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    sizes = []
    for i in range(len(rg.gt)):
        r = slam.register_frame(m.features_from_detections(observe(rg, i, rng)))
        assert r.ok, r.lost_reason
        sizes.append(slam.backend.size() if online == "fixed_lag" else slam.initial.size())
    return rg, slam, np.array(sizes)


@pytest.fixture(scope="module")
def two_metres():
    return _row(2.0, "fixed_lag")


def test_the_smoother_holds_a_bounded_number_of_variables(two_metres):
    rg, slam, sizes = two_metres
    n = len(sizes)
    # the graph grows with the row; the smoother holds what is in view (plus the lag): the same at mid-row and the end
    assert slam.initial.size() > 3 * sizes.max()
    mid = sizes[n // 2 - 5: n // 2 + 5].mean()
    assert sizes[-10:].mean() < 1.2 * mid, (mid, sizes[-10:])
    assert slam.backend.size() == len(slam.backend.smoother.timestamps())  # its own count is GTSAM's


def test_what_left_the_smoother_keeps_its_estimate_and_the_map_matches_ground_truth(two_metres):
    rg, slam, _ = two_metres
    be = slam.backend
    est = slam.estimate
    assert est.size() == slam.initial.size()  # every accepted variable: in the smoother or left with its estimate
    assert be.left.size() + be.size() == slam.initial.size()
    # a landmark seen in the last frame is in the smoother; one not seen for more than the lag has left
    last = slam.frames[-1]
    for tid, tr in slam.tracks.items():
        if not tr.admitted:
            continue
        if tr.obs[-1][0] == last:
            assert not be.left.exists(L(tid))
        elif tr.obs[-1][0] < last - be.lag:
            assert be.left.exists(L(tid))
    assert be.left.exists(X(slam.frames[0])) and not be.left.exists(X(last))
    lm = slam.landmarks()
    sel = lm.in_graph & (lm.seed_ids >= 0)
    err = np.linalg.norm(lm.xyz[sel] - rg.seeds[lm.seed_ids[sel]], axis=1)
    assert sel.sum() > 1000 and np.median(err) < 0.003, np.median(err)


def test_online_and_final_trajectories_follow_ground_truth(two_metres):
    rg, slam, _ = two_metres
    on = slam.online_trajectory()
    err_on = np.linalg.norm(on.positions - rg.gt.positions, axis=1)
    assert err_on.max() < 0.005 * 2.0  # < 0.5 % of the distance
    traj, _, name = slam.finalize()
    assert name == "fixed-lag+lm"
    err = np.linalg.norm(traj.positions - rg.gt.positions, axis=1)
    assert err.max() < 0.005 * 2.0


@pytest.mark.parametrize("lag", [0, 5])
def test_the_online_poses_are_those_of_isam2_over_the_whole_graph(lag):
    # what left the smoother is out of view: marginalising it leaves the online estimate as full iSAM2 has it
    _, a, _ = _row(0.8, "isam2")
    _, b, sizes = _row(0.8, "fixed_lag", lag=lag)
    assert b.backend.left.size() > 0 and sizes.max() < b.initial.size()
    pa = a.online_trajectory().positions
    pb = b.online_trajectory().positions
    assert np.abs(pa - pb).max() < 1e-6
    assert isinstance(b.estimate, gtsam.Values) and b.estimate.size() == b.initial.size()
