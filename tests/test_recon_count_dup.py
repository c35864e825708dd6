"""Duplicate detections of one seed (issue #6: the ``fast`` CNN fires twice on dark seeds) in the
``multiview`` count, on the synthetic 24-view cylinder scan of test_recon_multiview (touching 4 mm
seeds, neighbours >= 0.96 diameters apart): the view-sharing track join (``mv_dedupe_shared``, the
``fast`` profile's 0.6 median diameters)."""

from __future__ import annotations

import numpy as np

from helpers.arm_scans import CALIB, SEED_D, scan

from seedmap.geometry import invert
from seedmap.recon.config import CountConfig
from seedmap.recon.count import StereoKeypoints, count_multiview


def _with_duplicates(rng: np.random.Generator, offset_m: float, share: float = 0.33, big: float = 1.0):
    """The cylinder scan plus a second detection (left and right image) on ``share`` of the seeds,
    ``offset_m`` along the cylinder axis from the seed centre on the same spot in every view (a
    detector firing on both ends of a seed); those seeds' detections are ``big`` x the others' size
    (1.0: the same size): views, poses, countable ids."""
    views, poses, ids_l, countable, centres = scan(rng)
    ids_r = scan.ids_r
    twice = rng.random(len(centres)) < share
    dup_xyz = centres + [0.0, 0.0, offset_m]
    out = []
    for v, kp in enumerate(views):
        Tcw = invert(poses[v])
        uv, ur = CALIB.project(dup_xyz @ Tcw[:3, :3].T + Tcw[:3, 3])
        il = ids_l[v][(ids_l[v] >= 0) & twice[np.maximum(ids_l[v], 0)]]
        ir = ids_r[v][ids_r[v] >= 0]
        ir = ir[twice[ir]]
        size = kp.left_size * np.where(twice[ids_l[v]], big, 1.0)
        out.append(StereoKeypoints(
            np.vstack([kp.left, uv[il] + rng.normal(0, 0.3, (len(il), 2))]),
            np.vstack([kp.right, np.column_stack([ur[ir], uv[ir, 1]]) + rng.normal(0, 0.3, (len(ir), 2))]),
            np.concatenate([size, np.full(len(il), big * np.median(kp.left_size))])))
    return out, poses, countable


def test_view_sharing_join_absorbs_a_second_detection_half_a_seed_away():
    # duplicates 0.45 diameters (1.8 mm, ~4 px) from the centre: two consistent tracks through the
    # same views; a join radius of 0.4 leaves them, the fast profile's 0.6 joins them
    views, poses, countable = _with_duplicates(np.random.default_rng(3), 0.45 * SEED_D)
    n = len(countable)
    off = count_multiview(views, poses, CALIB, CountConfig(mv_dedupe_shared=0.0)).count
    old = count_multiview(views, poses, CALIB, CountConfig(mv_dedupe_shared=0.4)).count
    new = count_multiview(views, poses, CALIB, CountConfig().for_detector("fast").model_copy(
        update={k: getattr(CountConfig(), k) for k in ("mv_scale_ref_px", "mv_stereo_dv_px", "mv_link_px",
                                                         "mv_max_reproj_px", "mv_grow_px", "mv_min_support")})).count
    assert CountConfig().for_detector("fast").mv_dedupe_shared == 0.6
    assert off > 1.15 * n and old > 1.15 * n, (off, old, n)
    assert abs(new - n) <= 0.03 * n, (new, n)


def test_view_sharing_join_keeps_touching_seeds_apart():
    # no duplicates: neighbouring seeds (>= 0.96 diameters apart) share views, and the 0.6-diameter
    # join must not fuse any of them
    views, poses, ids_l, countable, _ = scan(np.random.default_rng(4))
    plain = count_multiview(views, poses, CALIB, CountConfig(mv_dedupe_shared=0.0)).count
    joined = count_multiview(views, poses, CALIB, CountConfig(mv_dedupe_shared=0.6)).count
    assert joined == plain
    assert abs(joined - len(countable)) <= 0.03 * len(countable), (joined, len(countable))
