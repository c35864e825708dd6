"""SGBM clouds, seed centres, registration and counting of seedmap.recon on synthetic geometry,
and the pipeline's handling of bad arm-scan datasets."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.errors import InputError
from seedmap.geometry import invert, transform_points
from seedmap.eval.recon_metrics import pose_errors
from seedmap.recon.config import CloudConfig, CountConfig, ReconConfig, RegisterConfig, SgbmConfig
from seedmap.recon.count import count_density
from seedmap.recon.pipeline import load_fk_poses, prepare_scan
from seedmap.recon.register import ViewGeometry, estimate_normals, register_views, voxel_down
from seedmap.recon.stereo import compute_disparity, disparity_to_cloud, seed_centres
from seedmap.records import Detections
from seedmap.sim.arm import ArmConfig, simulate_capture

from helpers.arm_scan_files import CALIB, textured_pair, write_arm_scan

def synthetic_panicle(rng: np.random.Generator, n_seeds: int = 900, length: float = 0.2, width: float = 0.05,
                      seed_radius: float = 0.002):
    """Seed centres on a spindle (rachis along +z from 0.02 m), outward normals and radii."""
    # roughly even spacing: Fibonacci-like lattice on the envelope
    k = np.arange(n_seeds)
    z = 0.02 + length * (k + 0.5) / n_seeds
    phi = k * np.pi * (3 - np.sqrt(5))
    s = (z - 0.02) / length
    r = 0.5 * width * np.sin(np.pi * np.clip(s, 0.03, 0.97)) ** 0.7 + 0.004
    c = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    c += rng.normal(0, 0.0003, c.shape)
    nrm = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n_seeds)])
    return c, nrm, np.full(n_seeds, seed_radius)


def view_observations(T_world_cam: np.ndarray, centres: np.ndarray, normals: np.ndarray, radii: np.ndarray,
                      rng: np.random.Generator, pts_per_seed: int = 30, noise: float = 0.0002):
    """(cloud_cam (N,3), seed_centres_cam (M,3), seed ids (M,)) as one view would measure them."""
    cam = T_world_cam[:3, 3]
    to_cam = cam - centres
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    vis = np.sum(normals * to_cam, axis=1) > 0.25
    ids = np.flatnonzero(vis)
    # visible cap of each seed sphere
    v = rng.normal(size=(len(ids), pts_per_seed, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    front = np.sum(v * to_cam[ids, None, :], axis=2) > 0.2
    pts = (centres[ids, None, :] + v * radii[ids, None, None])[front]
    Tcw = invert(T_world_cam)
    cloud = transform_points(Tcw, pts)
    cloud += rng.normal(0, noise, cloud.shape) * np.array([0.3, 0.3, 1.0])
    cen = transform_points(Tcw, centres[ids]) + rng.normal(0, noise, (len(ids), 3)) * np.array([0.3, 0.3, 1.0])
    return cloud, cen, ids


def test_sgbm_recovers_the_depth_of_a_textured_plane():
    rng = np.random.default_rng(0)
    left, right, d = textured_pair(0.3, rng)
    cloud_cfg = CloudConfig(min_depth=0.2, max_depth=0.42)
    disp = compute_disparity(left, right, CALIB, SgbmConfig(), cloud_cfg)
    valid = np.isfinite(disp)
    assert valid[:, 320:].mean() > 0.9
    np.testing.assert_allclose(np.nanmedian(disp), d, atol=0.25)
    vc = disparity_to_cloud(disp, left, CALIB, cloud_cfg)
    assert len(vc) > 0.4 * CALIB.width * CALIB.height
    assert np.median(vc.xyz[:, 2]) == pytest.approx(CALIB.fx * CALIB.baseline / d, abs=1e-3)
    assert vc.rgb.dtype == np.uint8


def test_dark_pair_gives_no_disparity_and_out_of_range_depth_is_dropped():
    black = np.zeros((CALIB.height, CALIB.width, 3), np.uint8)
    disp = compute_disparity(black, black, CALIB, SgbmConfig(), CloudConfig())
    assert not np.isfinite(disp).any()
    rng = np.random.default_rng(1)
    left, right, _ = textured_pair(0.3, rng)
    vc = disparity_to_cloud(compute_disparity(left, right, CALIB, SgbmConfig(), CloudConfig()), left, CALIB,
                            CloudConfig(min_depth=0.35, max_depth=0.5))
    assert len(vc) == 0


def test_seed_centre_from_median_disparity_is_pushed_back_by_the_radius():
    disp = np.full((CALIB.height, CALIB.width), np.nan, np.float32)
    disp[100:140, 100:140] = 183.33  # front surface at fx*b/d = 0.3 m
    det = Detections(boxes=[[110, 110, 130, 130]], scores=[1.0], ellipses=[[120, 120, 20, 20, 0]])
    so = seed_centres(disp, det, CALIB, CloudConfig(min_depth=0.2, max_depth=0.42))
    assert len(so) == 1
    diam = 20 * 0.3 / CALIB.fx
    assert so.diameter[0] == pytest.approx(diam, rel=1e-3)
    ray = CALIB.triangulate(np.array([[120.0, 120.0]]), np.array([120 - 183.33]))[0]
    np.testing.assert_allclose(so.xyz[0], ray * (1 + 0.5 * diam / np.linalg.norm(ray)), atol=1e-6)
    # an ellipse with no valid disparity yields no centre
    det2 = Detections(boxes=[[10, 10, 20, 20]], scores=[1.0], ellipses=[[15, 15, 8, 8, 0]])
    assert len(seed_centres(disp, det2, CALIB, CloudConfig())) == 0


def _synthetic_scan(views: int, seed: int):
    rng = np.random.default_rng(seed)
    c, n, r = synthetic_panicle(rng, 700)
    cap = simulate_capture(ArmConfig(views=views), [0.12], rng)
    geo = []
    for k in range(views):
        cloud, cen, _ = view_observations(cap.T_rest_cam_true[k], c, n, r, rng, pts_per_seed=12)
        x = voxel_down(cloud, 0.002)
        geo.append(ViewGeometry(x, estimate_normals(x, 0.005), cen))
    return cap, geo


def test_seed_icp_reduces_pose_error_on_a_small_simulated_scan():
    cap, geo = _synthetic_scan(12, 5)
    ref = cap.T_rest_cam_true
    fk = pose_errors(register_views(geo, cap.T_world_cam_fk, RegisterConfig(mode="fk")).poses, ref)
    seeds = register_views(geo, cap.T_world_cam_fk, RegisterConfig(mode="seeds"))
    se = pose_errors(seeds.poses, ref)
    assert seeds.accepted.sum() >= 9
    assert np.mean(se.rot_deg) < 0.5 * np.mean(fk.rot_deg)
    assert np.mean(se.trans_mm) < np.mean(fk.trans_mm)


def test_counting_deduplicates_a_synthetic_cluster_set():
    rng = np.random.default_rng(2)
    # 300 touching seeds (4 mm lattice on a cylinder), each seen from an arc of 3..8 consecutive views
    # (of 24 around the circle) with 0.35 mm scatter
    k = np.arange(300)
    z = 0.004 * (k // 20)
    phi = (k % 20) * (2 * np.pi / 20) + 0.5 * (k // 20 % 2) * (2 * np.pi / 20)
    centres = np.column_stack([0.0127 * np.cos(phi), 0.0127 * np.sin(phi), z])
    obs, views, diam = [], [], []
    for i, c in enumerate(centres):
        vs = (rng.integers(0, 24) + np.arange(rng.integers(3, 9))) % 24
        obs.append(c + rng.normal(0, 0.00035, (len(vs), 3)))
        views.append(vs)
        diam.append(np.full(len(vs), 0.004))
    xyz, view, d = np.concatenate(obs), np.concatenate(views), np.concatenate(diam)
    cnt = count_density(xyz, view, d, CountConfig(method="density"))
    assert abs(cnt.count - 300) <= 6
    # each counted seed lies within 1 mm of a true centre
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(centres).query(cnt.xyz)
    assert np.percentile(dist, 95) < 0.001
    # a single stray observation is not a seed
    cnt2 = count_density(np.vstack([xyz, [[0.1, 0.1, 0.1]]]), np.append(view, 0), np.append(d, 0.004),
                         CountConfig(method="density"))
    assert cnt2.count == cnt.count


# ------------------------------------------------------------------------------------------------
# bad input through the real dataset path
# ------------------------------------------------------------------------------------------------


def _cfg() -> ReconConfig:
    return ReconConfig(detector="gt", cloud=CloudConfig(min_depth=0.2, max_depth=0.42))


def test_missing_joints_file_is_a_clear_error(tmp_path):
    write_arm_scan(tmp_path, 3, joints=False)
    with pytest.raises(InputError, match="joints.csv"):
        prepare_scan(tmp_path, _cfg(), progress=False)


def test_joints_rows_must_match_the_frames(tmp_path):
    write_arm_scan(tmp_path, 3)
    lines = (tmp_path / "joints.csv").read_text().splitlines()
    (tmp_path / "joints.csv").write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(InputError, match="2 rows"):
        load_fk_poses(tmp_path, 3)


def test_views_without_disparity_are_recorded_skips_and_all_dark_is_an_error(tmp_path):
    write_arm_scan(tmp_path / "a", 3, dark_views=(1,))
    prep = prepare_scan(tmp_path / "a", _cfg(), progress=False)
    assert prep.views[1] is None and prep.views[0] is not None
    assert [s["view"] for s in prep.skipped] == [1]
    write_arm_scan(tmp_path / "b", 3, dark_views=(0, 1, 2))
    with pytest.raises(InputError, match="no view has valid disparity"):
        prepare_scan(tmp_path / "b", _cfg(), progress=False)
