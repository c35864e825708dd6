"""RerunLogger: a tiny synthetic stereo sequence recorded to .rrd and read back with rerun's reader."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.records import Detections, Matches, StereoCalib, Trajectory
from seedmap.viz.rerun_log import RerunLogger, ellipse_polylines, rrd_entity_paths

from helpers.rerun_read import rrd_column

CALIB = StereoCalib(fx=200.0, fy=200.0, cx=79.5, cy=59.5, baseline=0.11, width=160, height=120)


def _sequence(n_frames: int = 4, n_seeds: int = 30, seed: int = 0):
    """Seeds in front of a camera moving along +x; per frame: poses, keypoints, stereo matches."""
    rng = np.random.default_rng(seed)
    seeds = np.c_[rng.uniform(-0.1, 0.3, n_seeds), rng.uniform(-0.1, 0.1, n_seeds), rng.uniform(0.6, 0.9, n_seeds)]
    frames = []
    for k in range(n_frames):
        T = np.eye(4)
        T[0, 3] = 0.02 * k
        pc = seeds - T[:3, 3]
        uv, ur = CALIB.project(pc)
        ell = np.c_[uv, np.full(n_seeds, 6.0), np.full(n_seeds, 3.0), np.full(n_seeds, 30.0)]
        det_l = Detections(np.c_[uv - 3, uv + 3], np.ones(n_seeds), ell, np.arange(n_seeds))
        det_r = Detections(np.c_[np.c_[ur, uv[:, 1]] - 3, np.c_[ur, uv[:, 1]] + 3], np.ones(n_seeds),
                           np.c_[ur, ell[:, 1:]], np.arange(n_seeds))
        frames.append((k, 0.2 * k, T, det_l, det_r))
    return seeds, frames


def test_ellipse_outline_lies_on_the_ellipse():
    e = np.array([[10.0, 20.0, 8.0, 4.0, 30.0], [0.0, 0.0, 2.0, 2.0, 0.0]])
    poly = ellipse_polylines(e, n_pts=16)
    assert poly.shape == (2, 17, 2)
    np.testing.assert_allclose(poly[:, 0], poly[:, -1], atol=1e-12)  # closed
    th = np.deg2rad(30.0)
    d = poly[0] - [10.0, 20.0]
    x = d[:, 0] * np.cos(th) + d[:, 1] * np.sin(th)  # into the ellipse's own axes
    y = -d[:, 0] * np.sin(th) + d[:, 1] * np.cos(th)
    np.testing.assert_allclose((x / 4.0) ** 2 + (y / 2.0) ** 2, 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(poly[1], axis=1), 1.0, atol=1e-12)


def test_records_a_sequence_that_reads_back(tmp_path):
    seeds, frames = _sequence()
    path = tmp_path / "run.rrd"
    img = np.zeros((CALIB.height, CALIB.width, 3), np.uint8)
    img[::7] = 200
    with RerunLogger(path) as log:
        prev = None
        for k, t, T, dl, dr in frames:
            n = len(dl)
            log.log_stereo_frame(k, t, img, img, det_left=dl, det_right=dr, stereo=Matches(np.arange(n),
                                 np.arange(n), np.zeros(n)),
                                 temporal=None if prev is None else Matches(np.arange(n), np.arange(n), np.zeros(n)),
                                 prev_kp_left=prev)
            log.log_pose(k, t, T, CALIB)
            log.log_landmarks(seeds[: 10 + 5 * k], np.arange(10 + 5 * k))
            log.log_scalars(k, {"stereo": n, "temporal": 0 if prev is None else n})
            prev = dl.keypoints
        log.log_trajectory("ground truth", Trajectory(np.arange(4) * 0.2, np.stack([f[2] for f in frames])))
        assert not path.exists()  # written under a temporary name until closed
    assert path.is_file() and path.stat().st_size > 10_000
    assert path.read_bytes()[:4] == b"RRF2"  # rerun's file magic
    assert not list(tmp_path.glob(".*tmp"))

    ents = rrd_entity_paths(path)
    for e in ("/cam/left", "/cam/right", "/cam/left/keypoints", "/cam/left/ellipses", "/cam/left/stereo_matches",
              "/world/landmarks", "/world/camera", "/stats/stereo"):
        assert ents.get(e) == 4 or (e == "/world/camera" and ents.get(e) == 8), (e, ents.get(e))
    assert ents["/cam/left/temporal_matches"] == 3
    assert ents["/world/trajectory/estimate"] == 3  # a strip needs two poses
    assert ents["/world/trajectory/ground_truth"] == 1

    # the numbers survive the round trip: last landmark map and the keypoints of frame 0
    lm = rrd_column(path, "/world/landmarks", "Points3D:positions")
    np.testing.assert_allclose(np.asarray(lm[-1], float), seeds[:25], atol=1e-6)
    kp = rrd_column(path, "/cam/left/keypoints", "Points2D:positions")
    np.testing.assert_allclose(np.asarray(kp[0], float), frames[0][3].keypoints, atol=1e-3)
    ids = rrd_column(path, "/world/landmarks", "Points3D:class_ids")
    assert list(ids[-1]) == list(range(25))


def test_image_scale_keeps_overlays_aligned(tmp_path):
    _, frames = _sequence(n_frames=1)
    path = tmp_path / "half.rrd"
    with RerunLogger(path, image_scale=0.5, jpeg_quality=None) as log:
        k, t, T, dl, dr = frames[0]
        log.log_stereo_frame(k, t, np.zeros((120, 160, 3), np.uint8), None, det_left=dl)
    kp = np.asarray(rrd_column(path, "/cam/left/keypoints", "Points2D:positions")[0], float)
    np.testing.assert_allclose(kp, (dl.keypoints + 0.5) * 0.5 - 0.5, atol=1e-3)


def test_reconstruction_entities(tmp_path):
    rng = np.random.default_rng(1)
    poses = np.stack([np.eye(4)] * 3)
    poses[:, 0, 3] = [0.0, 0.05, 0.1]
    views = [(rng.normal(size=(50, 3)) * 0.01, rng.integers(0, 255, (50, 3), dtype=np.uint8)) for _ in range(3)]
    cloud = np.concatenate([v[0] for v in views])
    with RerunLogger(tmp_path / "recon.rrd") as log:
        log.log_reconstruction(poses, CALIB, views, cloud, None, seeds_xyz=cloud[:7], fk_poses=poses)
    ents = rrd_entity_paths(tmp_path / "recon.rrd")
    assert {"/recon/views/0/cloud", "/recon/views/2/pose", "/recon/cloud", "/recon/seeds",
            "/world/trajectory/forward_kinematics"} <= set(ents)
    seeds = rrd_column(tmp_path / "recon.rrd", "/recon/seeds", "Points3D:positions")
    np.testing.assert_allclose(np.asarray(seeds[0], float), cloud[:7], atol=1e-6)


def test_disabled_logger_is_a_no_op(tmp_path):
    log = RerunLogger(None)
    assert not log.enabled
    log.log_stereo_frame(0, 0.0, np.zeros((4, 4, 3), np.uint8), None)
    log.log_pose(0, 0.0, np.eye(4))
    log.log_landmarks(np.zeros((3, 3)))
    assert log.close() is None
    assert list(tmp_path.iterdir()) == []


def test_error_leaves_no_file(tmp_path):
    path = tmp_path / "x.rrd"
    with pytest.raises(RuntimeError):
        with RerunLogger(path) as log:
            log.log_landmarks(np.zeros((3, 3)))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_bad_paths_are_one_line_errors(tmp_path):
    from seedmap.errors import InputError

    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        RerunLogger(blocker / "x.rrd")
    with pytest.raises(InputError, match="is a folder"):
        RerunLogger(tmp_path)


def test_dropped_logger_leaves_no_partial_file(tmp_path):
    import gc

    log = RerunLogger(tmp_path / "y.rrd")
    log.log_landmarks(np.zeros((3, 3)))
    del log
    gc.collect()
    assert list(tmp_path.iterdir()) == []
