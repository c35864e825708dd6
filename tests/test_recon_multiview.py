"""Seed counting by multi-view 2D association and triangulation (count method ``multiview``) on
synthetic geometry: known seed centres on a cylinder, a 24-view circular stereo scan, keypoints
projected with noise, dropouts and clutter -> the count of seeds seen in two or more views."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.recon.config import CountConfig, ReconConfig
from seedmap.recon.count import StereoKeypoints, count_multiview, triangulate_rays

from helpers.arm_scans import CALIB, SEED_D, VIEWS, scan


def test_triangulate_rays_recovers_a_point_from_two_cameras():
    X = np.array([0.01, -0.02, 0.3])
    c = np.array([[0.0, 0, 0], [0.11, 0, 0], [0.2, 0.05, 0.1]])
    d = X - c
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(triangulate_rays(np.zeros(3, np.int64), 1, c, d)[0], X, atol=1e-12)
    # parallel rays have no solution: NaN, not a made-up point
    assert np.isnan(triangulate_rays(np.zeros(2, np.int64), 1, c[:2], np.repeat(d[:1], 2, 0))[0]).all()


def test_multiview_counts_seeds_from_noisy_keypoints_with_dropouts():
    views, poses, ids_l, countable, centres = scan(np.random.default_rng(0))
    cnt, det = count_multiview(views, poses, CALIB, CountConfig(), detail=True)
    assert abs(cnt.count - len(countable)) <= 0.02 * len(countable), (cnt.count, len(countable))
    # counted positions are the true centres (sub-millimetre), diameters from the keypoint sizes
    d, _ = __import__("scipy.spatial", fromlist=["cKDTree"]).cKDTree(centres).query(cnt.xyz)
    assert np.median(d) < 0.0003
    assert abs(np.median(cnt.diameter) - SEED_D) < 0.0003
    # the assignment indexes the concatenated left detections; one view gives a seed at most once
    lid = np.concatenate(ids_l)
    assert len(cnt.assignment) == len(lid)
    a = cnt.assignment
    pure = [np.unique(lid[a == s]).size == 1 for s in range(cnt.count)]
    assert np.mean(pure) > 0.98
    # stereo matches need the neighbours' support (pairs claimed by growing tracks are checked by
    # their track's reprojection instead)
    _, det0 = count_multiview(views, poses, CALIB, CountConfig(mv_grow_px=0.0), detail=True)
    assert np.all(det0.support[det0.track >= 0] >= CountConfig().mv_min_support)
    assert np.median(det.support[det.track >= 0]) >= CountConfig().mv_min_support


def test_multiview_joins_a_seed_seen_from_two_arcs_and_ignores_unconfirmed_clutter():
    rng = np.random.default_rng(1)
    views, poses, _, countable, _ = scan(rng, hidden_views=(4, 5, 6, 7), clutter=0.05)
    cnt = count_multiview(views, poses, CALIB, CountConfig())
    assert abs(cnt.count - len(countable)) <= 0.03 * len(countable), (cnt.count, len(countable))
    # without the 3D de-duplication the fragments on both sides of the gap count twice
    split = count_multiview(views, poses, CALIB, CountConfig(mv_dedupe=0.0)).count
    assert split > cnt.count


def test_stereo_matches_are_chosen_by_the_neighbouring_views():
    # every left keypoint has several right candidates on its row (disparity range 169-355 px, seeds
    # 8 px apart); the support of the neighbouring views picks the true one
    views, poses, ids_l, _, _ = scan(np.random.default_rng(2), drop=0.0)
    ids_r = scan.ids_r
    d_lo, d_hi = CALIB.fx * CALIB.baseline / 0.42, CALIB.fx * CALIB.baseline / 0.2
    k = views[0]
    dd = k.left[:, None, 0] - k.right[None, :, 0]
    cands = (np.abs(k.left[:, None, 1] - k.right[None, :, 1]) <= 2) & (dd >= d_lo) & (dd <= d_hi)
    assert np.mean(cands.sum(axis=1)) > 3
    _, det = count_multiview(views, poses, CALIB, CountConfig(), detail=True)
    true_l = np.array([ids_l[v][i] for v, i in zip(det.view, det.left)])
    true_r = np.array([ids_r[v][i] for v, i in zip(det.view, det.right)])
    assert np.mean(true_l == true_r) > 0.97


def test_multiview_edge_cases():
    views, poses, _, _, _ = scan(np.random.default_rng(3))
    empty = [StereoKeypoints(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)) for _ in range(VIEWS)]
    assert count_multiview(empty, poses, CALIB, CountConfig()).count == 0
    assert count_multiview([None] * VIEWS, poses, CALIB, CountConfig()).count == 0
    with pytest.raises(ValueError, match="poses"):
        count_multiview(views, poses[:3], CALIB, CountConfig())
    assert ReconConfig().count.method == "multiview"


def test_seedmap_count_recounts_multiview_from_a_results_folder(tmp_path):
    from seedmap.errors import InputError
    from seedmap.io.calibration import save_calib_yaml
    from seedmap.io.trajectory import write_tum
    from seedmap.recon.pipeline import detections_csv_text, read_detections, recount
    from seedmap.records import Trajectory

    views, poses, _, _, _ = scan(np.random.default_rng(5))
    views[3] = None  # a skipped view stays skipped
    (tmp_path / "observations.csv").write_text("view,x,y,z,diameter_m,gt_seed_id,seed\n0,0,0,0.3,0.004,-1,0\n")
    (tmp_path / "detections.csv").write_text(detections_csv_text(views))
    save_calib_yaml(CALIB, tmp_path / "calib.yaml")
    write_tum(tmp_path / "poses_tum.txt", Trajectory(np.arange(VIEWS, dtype=float), poses))
    back = read_detections(tmp_path, VIEWS)
    assert back[3] is None and np.allclose(back[0].left, views[0].left, atol=1e-3)
    cfg = ReconConfig()
    direct = count_multiview(views, poses, CALIB, cfg.count.for_detector(cfg.detector)).count  # as the pipeline
    assert abs(recount(tmp_path, cfg).count - direct) <= 2  # csv rounding of the keypoints (6 digits)
    (tmp_path / "detections.csv").unlink()
    with pytest.raises(InputError, match="detections.csv"):
        recount(tmp_path, cfg)


def test_second_linking_pass_recovers_seeds_the_tight_first_pass_missed():
    # a too-tight first-pass tolerance (0.7 px against 0.5 px keypoint noise) leaves most seeds as
    # single-view fragments; the second pass (wider tolerance, only between observations still short
    # of min_observations views and only well-supported stereo matches) links them into seeds again
    rng = np.random.default_rng(7)
    views, poses, ids_l, countable, _ = scan(rng, noise_px=0.5, drop=0.3, clutter=0.05)
    tight = count_multiview(views, poses, CALIB, CountConfig(mv_link_px=0.7)).count
    cnt = count_multiview(views, poses, CALIB, CountConfig(mv_link_px=0.7, mv_relink_px=2.5,
                                                           mv_relink_min_support=1.5))
    assert tight < 0.5 * len(countable)
    assert abs(cnt.count - len(countable)) <= 0.2 * len(countable), (cnt.count, len(countable))
    # the relinked seeds are distinct true seeds (majority id of each), not one seed counted twice
    lid = np.concatenate(ids_l)
    major = [np.bincount(lid[(cnt.assignment == s) & (lid >= 0)]).argmax() for s in range(cnt.count)
             if np.any((cnt.assignment == s) & (lid >= 0))]
    assert len(set(major)) >= 0.97 * cnt.count
    # matches below the second pass's support threshold are not relinked
    assert count_multiview(views, poses, CALIB, CountConfig(mv_link_px=0.7, mv_relink_px=2.5,
                                                            mv_relink_min_support=9.0)).count == tight
    # off by default (mv_relink_px <= mv_link_px): the default count is the first pass alone
    assert CountConfig().mv_relink_px <= CountConfig().mv_link_px


def test_a_seed_seen_in_views_0_1_and_5_6_counts_once():
    # every seed keeps only the first two and the last two views of its arc (a gap of >= 3 views
    # in between, beyond max_lag): the long-gap join must make each one seed, not two
    views, poses, ids_l, _, _ = scan(np.random.default_rng(11), drop=0.0)
    ids_r = scan.ids_r
    seen = {}
    for v, il in enumerate(ids_l):
        for i in il[il >= 0]:
            seen.setdefault(int(i), []).append(v)
    keep_views = {}
    for i, vs in seen.items():
        vs = sorted(vs)
        if vs[0] == 0 and vs[-1] == VIEWS - 1:  # arc across the wrap: unroll it
            vs = sorted((v + VIEWS // 2) % VIEWS for v in vs)
            vs = [(v - VIEWS // 2) % VIEWS for v in vs]
        if len(vs) >= 7:
            keep_views[i] = set(vs[:2]) | set(vs[-2:])
    out = []
    for v, kp in enumerate(views):
        ml = np.array([int(i) in keep_views and v in keep_views[int(i)] for i in ids_l[v]], bool)
        mr = np.array([int(i) in keep_views and v in keep_views[int(i)] for i in ids_r[v]], bool)
        out.append(StereoKeypoints(kp.left[ml], kp.right[mr], kp.left_size[ml]))
    assert len(keep_views) > 100
    cnt = count_multiview(out, poses, CALIB, CountConfig())
    assert abs(cnt.count - len(keep_views)) <= 0.05 * len(keep_views), (cnt.count, len(keep_views))
    # without the long-gap join each seed is two fragments
    split = count_multiview(out, poses, CALIB, CountConfig(mv_dedupe=0.0)).count
    assert split > 1.4 * len(keep_views)


def biased_scan(seed: int, bias_px: float):
    """The cylinder scan with a per-seed-and-view horizontal offset of the right keypoint (uniform in
    +-``bias_px``): a partly hidden seed's visible centre differs between the left and the right
    image, so its stereo depth is off by up to ~1.3 mm per px at 0.3 m."""
    views, poses, ids_l, countable, centres = scan(np.random.default_rng(seed), noise_px=0.2, drop=0.05)
    rng = np.random.default_rng(seed + 100)
    out = [StereoKeypoints(kp.left, kp.right + np.column_stack([rng.uniform(-bias_px, bias_px, len(kp.right)),
                                                                np.zeros(len(kp.right))]), kp.left_size)
           for kp in views]
    return out, poses, ids_l, countable


def test_joint_links_count_seeds_whose_stereo_depth_is_biased():
    views, poses, ids_l, countable = biased_scan(12, 1.5)
    lid = np.concatenate(ids_l)
    cnt = count_multiview(views, poses, CALIB, CountConfig(mv_link_joint=True, mv_link_px=1.5))
    assert abs(cnt.count - len(countable)) <= 0.03 * len(countable), (cnt.count, len(countable))
    pure = [np.unique(lid[cnt.assignment == s]).size == 1 for s in range(cnt.count)]
    assert np.mean(pure) > 0.93  # the looser joint test sometimes takes a neighbour's keypoint (~5 %)
    # the joint test does link: with a single view per track nothing would count
    assert np.median(cnt.n_views) >= 5


def test_growing_stays_inside_the_arc_of_views_of_a_track():
    # at the end of its arc a seed turns away and its foreshortened neighbour projects where it would
    # be: growing only fills gaps inside the arc, so the tracks stay pure
    views, poses, ids_l, _, _ = scan(np.random.default_rng(0))
    lid = np.concatenate(ids_l)

    def purity(cfg: CountConfig) -> float:
        cnt = count_multiview(views, poses, CALIB, cfg)
        return float(np.mean([np.unique(lid[cnt.assignment == s]).size == 1 for s in range(cnt.count)]))

    assert purity(CountConfig()) > 0.98


def test_detector_profiles_are_applied_once_and_can_be_switched_off():
    cfg = CountConfig()
    gt = cfg.for_detector("gt")
    assert gt.mv_link_joint and not gt.detector_profile and gt.mv_link_px == 1.5
    assert gt.for_detector("gt") is gt  # applied once
    assert cfg.for_detector("fast").mv_scale_ref_px == 6.0
    assert cfg.for_detector("some-new-detector") is cfg
    assert not CountConfig(detector_profile=False).for_detector("gt").mv_link_joint
    assert ReconConfig(detector="gt").count.for_detector("gt").mv_link_joint


def test_reconstruction_runs_fast_with_the_arm_scan_network_and_its_profile():
    """The pipeline's detector overrides select the CNN's arm-scan weights (threshold 0.4) while plain ``fast``
    keeps the field network; ``fast`` counts with twice the pixel tolerances, scaled with the
    seed size."""
    from seedmap.detect import make_detector

    rc = ReconConfig(detector="fast")
    det = make_detector(rc.detector, overrides=list(rc.detector_overrides))
    assert det.path.name == "fast_cnn_arm.onnx" and det.cfg.threshold == 0.4
    assert make_detector("fast").path.name == "fast_cnn.onnx"
    plain = CountConfig()
    for name in ("fast",):
        c = rc.count.for_detector(name)
        assert c.mv_stereo_dv_px == 2 * plain.mv_stereo_dv_px and c.mv_link_px == 2 * plain.mv_link_px
        assert c.mv_max_reproj_px == 2 * plain.mv_max_reproj_px and c.mv_grow_px == 2 * plain.mv_grow_px
        assert c.mv_dedupe_shared == 0.6 and c.mv_min_support == 0.5
        assert c.mv_scale_ref_px == 6.0 and c.mv_scale_power == 1.5
