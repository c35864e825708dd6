"""The SGBM surface disparity at every left keypoint (``StereoKeypoints.left_disp``, written to detections.csv)
on synthetic geometry: the 24-view cylinder scan of test_recon_multiview plus "ghost" keypoint pairs 20 mm in
front of the panicle surface; the SGBM disparity at every left keypoint is the surface's."""

from __future__ import annotations

import numpy as np

from helpers.arm_scans import CALIB, VIEWS, scan

from seedmap.geometry import invert
from seedmap.recon.count import StereoKeypoints, keypoint_disparity

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
