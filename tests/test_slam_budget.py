"""The back-end's per-frame landmark budget (``backend.max_new_landmarks``) on synthetic seeds."""

from __future__ import annotations

import numpy as np

from seedmap.associate import make_matcher
from seedmap.eval.slam_metrics import compute_slam_metrics
from seedmap.slam.config import SlamConfig
from seedmap.slam.core import SemanticSlam
from seedmap.slam.synthetic import make_range, observe


def _run(rg, cfg, seed=3):
    rng = np.random.default_rng(seed)
    m = make_matcher("seeds", rg.calib, cfg=cfg)
    slam = SemanticSlam(rg.calib, m, cfg, first_pose=rg.gt.poses[0])
    admitted_per_frame = []
    for i in range(len(rg.gt)):
        before = sum(t.admitted for t in slam.tracks.values())
        r = slam.register_frame(m.features_from_detections(observe(rg, i, rng, noise_px=0.2, miss=0.02)))
        assert r.ok, r.lost_reason
        admitted_per_frame.append(sum(t.admitted for t in slam.tracks.values()) - before)
    return slam, np.array(admitted_per_frame)


def test_budget_caps_new_graph_landmarks_but_keeps_the_whole_map():
    rg = make_range(np.random.default_rng(11), length=0.4, seeds_per_panicle=250)
    full_cfg = SlamConfig()
    full_cfg.backend.max_new_landmarks = None
    capped_cfg = SlamConfig()
    capped_cfg.backend.max_new_landmarks = 40
    full, n_full = _run(rg, full_cfg)
    capped, n_cap = _run(rg, capped_cfg)
    assert n_full[1:].max() > 40  # the budget is binding on this sequence
    assert n_cap.max() <= 40
    # the graph holds fewer landmark variables ...
    import gtsam

    in_graph = [k for k in capped.estimate.keys() if gtsam.Symbol(k).chr() == ord("l")]
    assert len(in_graph) == sum(t.admitted for t in capped.tracks.values()) < sum(
        t.admitted for t in full.tracks.values())
    # ... but the map still has every track seen >= min_observations times, placed near its seed
    traj, values, _ = capped.finalize()
    lm = capped.landmarks(values)
    lm_full = full.landmarks(full.finalize()[1])
    assert len(lm) == len(lm_full)
    assert (~lm.in_graph).sum() > 0 and lm.in_graph.sum() > 0
    known = lm.seed_ids >= 0
    err = np.linalg.norm(lm.xyz[known] - rg.seeds[lm.seed_ids[known]], axis=1)
    assert np.median(err[~lm.in_graph[known]]) < 0.005
    # and the trajectory stays as accurate
    m = compute_slam_metrics(traj, rg.gt, len(rg.gt), None, None)
    assert m.ate_rmse_m < 0.005 * 0.4
