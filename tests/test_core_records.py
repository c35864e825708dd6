"""Core records, geometry, config and file formats: behaviour on real numbers."""

from __future__ import annotations

import numpy as np
import pytest

from seedmap.config import ConfigModel, apply_overrides, dump_config, load_config
from seedmap.errors import ConfigError, InputError, SeedmapError
from seedmap.geometry import invert, pose_to_tum, rotation_angle_deg, transform_points, tum_to_pose
from seedmap.outputs import MARKER, output_dir
from seedmap.io.trajectory import read_kitti, read_tum, write_kitti, write_tum
from seedmap.records import StereoCalib, Trajectory

FIELD = StereoCalib(2583.0, 2578.0, 2013.0, 1525.7, 0.11, 4096, 3000)


def random_poses(n: int, rng: np.random.Generator) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=rng.integers(1 << 31)).as_matrix()
    T[:, :3, 3] = rng.normal(size=(n, 3))
    return T


def test_projection_and_triangulation_are_inverse():
    calib = FIELD.scaled(0.35)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.2, 0.2, 50), rng.uniform(0.5, 1.0, 50)])
    uv, ur = calib.project(pts)
    np.testing.assert_allclose(calib.triangulate(uv, ur), pts, atol=1e-9)
    # disparity equals fx * b / z
    np.testing.assert_allclose(uv[:, 0] - ur, calib.fx * 0.11 / pts[:, 2])


def test_scaled_calibration_keeps_pixel_centre_convention():
    half = FIELD.scaled(0.5)
    assert (half.width, half.height) == (2048, 1500)
    # the same 3D point lands on the same relative image position
    p = np.array([[0.05, -0.02, 0.7]])
    uv_full, _ = FIELD.project(p)
    uv_half, _ = half.project(p)
    np.testing.assert_allclose((uv_half + 0.5) * 2.0, uv_full + 0.5, atol=1e-9)


def test_calibration_rejects_bad_baseline():
    with pytest.raises(ConfigError):
        StereoCalib(500, 500, 320, 240, 0.0, 640, 480)
    with pytest.raises(ConfigError):
        StereoCalib(500, 500, 320, 240, -0.1, 640, 480)


def test_opencv_matrices_agree_with_projection():
    import cv2

    calib = FIELD.scaled(0.25)
    p = np.array([[0.1, 0.05, 0.8, 1.0]])
    uv, ur = calib.project(p[:, :3])
    xl = calib.P_left @ p[0]
    xr = calib.P_right @ p[0]
    np.testing.assert_allclose(xl[:2] / xl[2], uv[0], atol=1e-9)
    np.testing.assert_allclose(xr[0] / xr[2], ur[0], atol=1e-9)
    disp = np.zeros((calib.height, calib.width), np.float32)
    r, c = int(round(uv[0, 1])), int(round(uv[0, 0]))
    disp[r, c] = uv[0, 0] - ur[0]
    xyz = cv2.reprojectImageTo3D(disp, calib.Q)[r, c]
    assert abs(xyz[2] - 0.8) < 1e-3


def test_pose_helpers_round_trip():
    rng = np.random.default_rng(1)
    T = random_poses(20, rng)
    np.testing.assert_allclose(tum_to_pose(pose_to_tum(T)), T, atol=1e-9)
    np.testing.assert_allclose(np.einsum("nij,njk->nik", T, invert(T)), np.tile(np.eye(4), (20, 1, 1)), atol=1e-9)
    pts = rng.normal(size=(5, 3))
    np.testing.assert_allclose(transform_points(invert(T[0]), transform_points(T[0], pts)), pts, atol=1e-9)
    assert rotation_angle_deg(np.eye(3)) == pytest.approx(0.0)


def test_trajectory_files_round_trip_and_evo_reads_them(tmp_path):
    rng = np.random.default_rng(2)
    traj = Trajectory(np.arange(10) * 0.2, random_poses(10, rng))
    write_tum(tmp_path / "t.tum", traj)
    write_kitti(tmp_path / "t.kitti", traj)
    back = read_tum(tmp_path / "t.tum")
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-7)
    np.testing.assert_allclose(read_kitti(tmp_path / "t.kitti").poses, traj.poses, atol=1e-7)
    from evo.tools import file_interface

    evo_traj = file_interface.read_tum_trajectory_file(str(tmp_path / "t.tum"))
    np.testing.assert_allclose(evo_traj.poses_se3, traj.poses, atol=1e-7)
    evo_kitti = file_interface.read_kitti_poses_file(str(tmp_path / "t.kitti"))
    np.testing.assert_allclose(evo_kitti.poses_se3, traj.poses, atol=1e-7)


def test_path_length():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, 0, 3] = [0.0, 0.3, 0.7]
    np.testing.assert_allclose(Trajectory(np.arange(3.0), T).path_length(), [0.0, 0.3, 0.7])


def test_malformed_tum_is_a_one_line_error(tmp_path):
    p = tmp_path / "bad.txt"
    p.write_text("0 1 2 3\n")
    with pytest.raises(InputError, match="bad.txt: line 1"):
        read_tum(p)


class _Inner(ConfigModel):
    a: float = 1.0
    n: int = 3


class _Cfg(ConfigModel):
    seed: int = 0
    inner: _Inner = _Inner()


def test_config_yaml_and_overrides(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("seed: 5\ninner:\n  a: 2.5\n")
    cfg = load_config(_Cfg, p, ["inner.n=7"])
    assert (cfg.seed, cfg.inner.a, cfg.inner.n) == (5, 2.5, 7)
    dump_config(cfg, tmp_path / "out.yaml")
    assert load_config(_Cfg, tmp_path / "out.yaml") == cfg
    with pytest.raises(ConfigError, match="inner.n"):
        load_config(_Cfg, None, ["inner.n=abc"])
    with pytest.raises(ConfigError):
        load_config(_Cfg, None, ["inner.unknown=1"])
    with pytest.raises(ConfigError):
        apply_overrides({}, ["novalue"])


def test_output_dir_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "res"
    with pytest.raises(RuntimeError):
        with output_dir(out, "slam") as tmp:
            (tmp / "half.txt").write_text("x")
            raise RuntimeError("boom")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    with output_dir(out, "slam") as tmp:
        (tmp / "ok.txt").write_text("x")
    assert (out / "ok.txt").read_text() == "x"
    with pytest.raises(SeedmapError, match="--overwrite"):
        with output_dir(out, "slam"):
            pass
    with output_dir(out, "slam", overwrite=True) as tmp:
        (tmp / "new.txt").write_text("y")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["res"]


def test_atomic_outputs_have_normal_permissions(tmp_path):
    import os
    import stat

    from seedmap.io.atomic import atomic_write_text

    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        with output_dir(tmp_path / "d", "slam") as tmp:
            (tmp / "f").write_text("y")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755
