"""The SGBM surface-depth check of the ``multiview`` count (``mv_surface_tol``) on synthetic
geometry: the 24-view cylinder scan of test_recon_multiview plus "ghost" keypoint pairs that are
consistent across neighbouring views but lie 20 mm in front of the panicle surface (what a stereo
match at the wrong depth looks like); the SGBM disparity at every left keypoint is the surface's."""

from __future__ import annotations

import numpy as np
from test_recon_multiview import CALIB, VIEWS, scan  # pytest puts tests/ on sys.path

from seedmap.geometry import invert
from seedmap.recon.config import CountConfig
from seedmap.recon.count import StereoKeypoints, count_multiview, keypoint_disparity

CYL_R = 0.0135  # radius of the seed-centre cylinder of test_recon_multiview (m)
FB = CALIB.fx * CALIB.baseline


def _surface_depth(T_wc: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Depth (m, camera z) where the left rays of pixels ``uv`` first hit the cylinder of seed
    surfaces (radius CYL_R + 2 mm around the world z axis); NaN where they miss (background)."""
    c = T_wc[:3, 3]
    d = np.column_stack([(uv[:, 0] - CALIB.cx) / CALIB.fx, (uv[:, 1] - CALIB.cy) / CALIB.fy, np.ones(len(uv))])
    dw = d @ T_wc[:3, :3].T  # camera z = 1 along each ray: the ray parameter is the depth
    r = CYL_R + 0.002
    a = np.sum(dw[:, :2] ** 2, axis=1)
    b = 2 * dw[:, :2] @ c[:2]
    cc = c[:2] @ c[:2] - r * r
    disc = b * b - 4 * a * cc
    with np.errstate(invalid="ignore"):
        return np.where(disc >= 0, (-b - np.sqrt(disc)) / (2 * a), np.nan)


def ghost_scan(rng: np.random.Generator, n_ghosts: int = 40, sgbm_noise: float = 0.002, sgbm_missing: float = 0.3):
    """scan() plus ghost keypoint pairs 20 mm in front of the surface and the surface disparity at
    every left keypoint (depth noise ``sgbm_noise`` m, a fraction ``sgbm_missing`` without SGBM)."""
    views, poses, ids_l, countable, centres = scan(rng)
    phi = rng.uniform(0, 2 * np.pi, n_ghosts)
    ghosts = np.column_stack([(CYL_R + 0.02) * np.cos(phi), (CYL_R + 0.02) * np.sin(phi),
                              rng.uniform(0.005, 0.05, n_ghosts)])
    out = []
    for v, kp in enumerate(views):
        Tcw = invert(poses[v])
        pc = ghosts @ Tcw[:3, :3].T + Tcw[:3, 3]
        uv, ur = CALIB.project(pc)
        # a ghost is "seen" where it lies in front of the surface (its ray hits the cylinder behind it)
        behind = _surface_depth(poses[v], uv)
        seen = np.isfinite(behind) & (behind > pc[:, 2] + 0.01)
        left = np.vstack([kp.left, uv[seen] + rng.normal(0, 0.3, (seen.sum(), 2))])
        right = np.vstack([kp.right, np.column_stack([ur[seen], uv[seen, 1]]) + rng.normal(0, 0.3, (seen.sum(), 2))])
        size = np.concatenate([kp.left_size, np.full(seen.sum(), np.median(kp.left_size))])
        z = _surface_depth(poses[v], left) + rng.normal(0, sgbm_noise, len(left))
        disp = FB / z
        disp[rng.random(len(left)) < sgbm_missing] = np.nan
        out.append(StereoKeypoints(left, right, size, disp))
    return out, poses, countable


def test_surface_check_rejects_wrong_depth_matches_and_keeps_the_seeds():
    # SGBM missing at 10 % of the keypoints: a ghost seen in ~3 views rarely keeps two unchecked ones
    views, poses, countable = ghost_scan(np.random.default_rng(5), sgbm_missing=0.1)
    n = len(countable)
    off = count_multiview(views, poses, CALIB, CountConfig()).count
    on = count_multiview(views, poses, CALIB, CountConfig(mv_surface_tol=0.009)).count
    assert off - n > 15, (off, n)  # the ghosts count as seeds without the check
    assert abs(on - n) <= 0.02 * n, (on, off, n)
    # without any SGBM disparity the check has no evidence and changes nothing
    blind = [StereoKeypoints(k.left, k.right, k.left_size, np.full(len(k.left), np.nan)) for k in views]
    assert count_multiview(blind, poses, CALIB, CountConfig(mv_surface_tol=0.009)).count == off
    nodisp = [StereoKeypoints(k.left, k.right, k.left_size) for k in views]
    assert count_multiview(nodisp, poses, CALIB, CountConfig(mv_surface_tol=0.009)).count == off


def test_surface_check_tolerance_below_the_sgbm_scatter_loses_seeds():
    # with 4 mm SGBM depth noise a 2 mm tolerance rejects many true matches: the tolerance must
    # cover the measured scatter (p90 ~ 9 mm on the simulated scans)
    views, poses, countable = ghost_scan(np.random.default_rng(6), sgbm_noise=0.004, sgbm_missing=0.0)
    tight = count_multiview(views, poses, CALIB, CountConfig(mv_surface_tol=0.002)).count
    wide = count_multiview(views, poses, CALIB, CountConfig(mv_surface_tol=0.012)).count
    assert abs(wide - len(countable)) <= 0.03 * len(countable), (wide, len(countable))
    assert tight < wide - 10, (tight, wide)


def test_keypoint_disparity_is_a_robust_window_median():
    H, W = 60, 80
    disp = np.full((H, W), 40.0, np.float32)
    disp[:, 40:] = 20.0  # a depth edge at column 40
    disp[10:20, 10:20] = np.nan  # an SGBM hole
    disp[30, 30] = 500.0  # a speckle
    uv = np.array([[30.0, 30.0], [15.0, 15.0], [60.2, 40.7], [0.0, 0.0], [79.0, 59.0], [8.0, 15.0]])
    d = keypoint_disparity(disp, uv, radius_px=2)
    np.testing.assert_allclose(d[[0, 2, 3, 4]], [40.0, 20.0, 40.0, 20.0])  # speckle ignored, borders clamped
    assert np.isnan(d[1])  # inside the hole: no evidence
    assert d[5] == 40.0  # window partly in the hole: the valid pixels decide
    assert keypoint_disparity(disp, np.zeros((0, 2))).shape == (0,)


def test_detections_csv_round_trips_the_keypoint_disparity(tmp_path):
    from seedmap.recon.pipeline import detections_csv_text, read_detections

    views, _, _ = ghost_scan(np.random.default_rng(7), n_ghosts=5)
    views = views[:VIEWS]
    (tmp_path / "detections.csv").write_text(detections_csv_text(views))
    back = read_detections(tmp_path, VIEWS)
    for a, b in zip(views, back, strict=True):
        np.testing.assert_allclose(b.left_disp, a.left_disp, rtol=1e-5)
        np.testing.assert_allclose(b.left, a.left, rtol=1e-5)
    # files of older versions (5 columns) still read, without disparities
    lines = (tmp_path / "detections.csv").read_text().splitlines()
    (tmp_path / "detections.csv").write_text("\n".join(",".join(x.split(",")[:5]) for x in lines) + "\n")
    old = read_detections(tmp_path, VIEWS)
    assert old[0].left_disp is None and len(old[0].left) == len(views[0].left)


def test_duplicate_detections_are_merged_before_counting():
    # a detector firing twice on a third of the seeds (a second peak 0.7 mm ~ 1.5 px off the centre,
    # on the same spot of the seed in every view): without merging the duplicates form their own
    # consistent tracks and count again
    from seedmap.recon.count import merge_close_keypoints

    rng = np.random.default_rng(8)
    views, poses, ids_l, countable, centres = scan(rng)
    ids_r = scan.ids_r
    twice = rng.random(len(centres)) < 0.33
    tangent = np.cross(centres, [0.0, 0.0, 1.0])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    dup_xyz = centres + 0.0007 * tangent
    dup_views = []
    for v, kp in enumerate(views):
        Tcw = invert(poses[v])
        uv, ur = CALIB.project(dup_xyz @ Tcw[:3, :3].T + Tcw[:3, 3])
        src = np.flatnonzero((ids_l[v] >= 0) & twice[np.maximum(ids_l[v], 0)])  # left index of the original
        il = ids_l[v][src]
        if v == 0:
            src0 = src
        ir = ids_r[v][(ids_r[v] >= 0)]
        ir = ir[twice[ir]]
        dup_views.append(StereoKeypoints(
            np.vstack([kp.left, uv[il] + rng.normal(0, 0.3, (len(il), 2))]),
            np.vstack([kp.right, np.column_stack([ur[ir], uv[ir, 1]]) + rng.normal(0, 0.3, (len(ir), 2))]),
            np.concatenate([kp.left_size, np.full(len(il), np.median(kp.left_size))])))
    n = len(countable)
    raw = count_multiview(dup_views, poses, CALIB, CountConfig())
    merged = count_multiview(dup_views, poses, CALIB, CountConfig(mv_merge_px=2.5))
    assert raw.count > 1.1 * n, (raw.count, n)
    assert abs(merged.count - n) <= 0.03 * n, (merged.count, n)
    # the assignment still indexes the ORIGINAL left detections: a duplicate shares its seed
    n_left = np.array([len(k.left) for k in dup_views])
    assert len(merged.assignment) == n_left.sum()
    n0 = len(views[0].left)
    kp0, lab = merge_close_keypoints(dup_views[0], 2.5)
    a0 = merged.assignment[:n_left[0]]
    same = lab[n0:] == lab[src0]  # (a duplicate pushed > 2.5 px off by the keypoint noise stays apart)
    assert np.mean(same) > 0.9
    assert np.array_equal(a0[n0:][same], a0[src0][same]) and np.mean(a0[src0] >= 0) > 0.8
    # seeds (8 px apart here) are never merged with each other
    assert len(kp0.left) == n0 + np.sum(~same)
