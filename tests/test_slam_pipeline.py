"""End-to-end: simulated range -> gt oracle detector -> seed matcher -> SLAM -> result folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seedmap.errors import SeedmapError


@pytest.mark.slow
def test_run_slam_on_a_simulated_range(tiny_range, tmp_path):
    from seedmap.slam.config import SlamConfig
    from seedmap.slam.pipeline import run_slam

    cfg = SlamConfig()
    res = run_slam(tiny_range, tmp_path / "res", matcher="seeds", detector="gt", config=cfg, progress=False)
    m = res.metrics
    assert m.lost_frame is None, m.lost_reason
    assert m.frames_tracked == m.frames
    assert m.gt_mdm_fraction == pytest.approx(1.0, abs=0.02)
    assert m.ate_rmse_m < 0.01 * m.range_length_m
    out = tmp_path / "res"
    for name in ("config.yaml", "metrics.json", "trajectory.tum", "trajectory.kitti", "landmarks.csv",
                 "landmarks.ply", "topview.png", "matches_per_frame.csv", "report.md", "panicles.csv",
                 "panicles.json", "phenotype.html"):
        assert (out / name).is_file(), name
    # the phenotype table: each panicle counted in its best view, with a thumbnail of it
    import csv

    with (out / "panicles.csv").open() as f:
        panicles = list(csv.DictReader(f))
    assert panicles and all(int(r["seeds_in_view"]) > 0 for r in panicles)
    assert all((out / "thumbs" / f"panicle_{int(r['panicle_id']):03d}.png").is_file() for r in panicles)
    assert json.loads((out / "metrics.json").read_text())["frames_tracked"] == m.frames_tracked
    assert len(res.matches_per_frame["stereo"]) == m.frames
    # eval slam recomputes the same numbers from the files
    from seedmap.slam.evaluate import evaluate_result_dir

    m2 = evaluate_result_dir(out, tiny_range)
    assert m2.ate_rmse_m == pytest.approx(m.ate_rmse_m, rel=1e-3, abs=1e-6)
    # an existing result folder is not overwritten without --overwrite
    with pytest.raises(SeedmapError):
        run_slam(tiny_range, out, config=cfg, progress=False)


@pytest.mark.slow
def test_eval_associate_on_a_simulated_range(tiny_range):
    from seedmap.eval.associate_metrics import evaluate_association

    rep = evaluate_association(tiny_range, detector="gt", max_frames=3, progress=False)
    assert rep.stereo["matches"] > 0 and rep.stereo["precision"] is not None
    assert 0.0 <= rep.stereo["precision"] <= 1.0 and 0.0 <= rep.temporal["recall"] <= 1.0
    assert np.isfinite(rep.stereo["recall_gated"])
