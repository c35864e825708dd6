"""Calibration formats -> StereoRig -> rectified StereoCalib + maps, on synthetic rigs and real fixtures."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from seedmap.errors import InputError
from seedmap.io.calibration import (CameraModel, StereoRig, check_rig, load_rig, parse_kitti_calib, rectified_rotation,
                                    rectify, save_calib_yaml)
from seedmap.records import StereoCalib

from helpers.calibration_files import H, W, _write, make_rig, write_euroc_pair, write_kalibr

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="shared/realdata not present")



def _dense(m):
    """CV_16SC2 maps back to float (map_x, map_y)."""
    mx, my = cv2.convertMaps(m[0], m[1], cv2.CV_32FC1)
    return mx, my


def _check_maps_follow_geometry(rig: StereoRig, calib: StereoCalib, maps, alpha=0.0, tol=0.15):
    """3D points projected (a) raw through the distorted cameras, (b) through the rectified calib: the remap
    table at the rectified pixel must point at the raw pixel, in both cameras; rows agree by construction."""
    rng = np.random.default_rng(3)
    R1 = rectified_rotation(rig, alpha)
    Xr = np.column_stack([rng.uniform(-0.3, 0.3, 200), rng.uniform(-0.2, 0.2, 200), rng.uniform(0.8, 2.0, 200)])
    X = Xr @ R1  # points in the raw left frame whose rectified coordinates are Xr
    uv, ur = calib.project(Xr)
    w, h = calib.width, calib.height
    ok = (uv[:, 0] > 5) & (uv[:, 0] < w - 6) & (uv[:, 1] > 5) & (uv[:, 1] < h - 6) & (ur > 5)
    assert ok.sum() > 50
    proj = cv2.fisheye.projectPoints if rig.left.distortion == "equidistant" else cv2.projectPoints
    if rig.left.distortion == "equidistant":
        rl, _ = proj(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), rig.left.K, rig.left.D[:4])
        rr, _ = proj(X.reshape(-1, 1, 3), cv2.Rodrigues(rig.R)[0], rig.T, rig.right.K, rig.right.D[:4])
    else:
        rl, _ = proj(X, np.zeros(3), np.zeros(3), rig.left.K, rig.left.D)
        rr, _ = proj(X, cv2.Rodrigues(rig.R)[0], rig.T, rig.right.K, rig.right.D)
    for m, u, raw in ((maps.left, uv[:, 0], rl.reshape(-1, 2)), (maps.right, ur, rr.reshape(-1, 2))):
        mx, my = _dense(m)
        # bilinear lookup of the map at the (sub-pixel) rectified position
        pts = np.column_stack([u, uv[:, 1]])[ok].astype(np.float32)
        sx = cv2.remap(mx, pts[:, 0:1], pts[:, 1:2], cv2.INTER_LINEAR).reshape(-1)
        sy = cv2.remap(my, pts[:, 0:1], pts[:, 1:2], cv2.INTER_LINEAR).reshape(-1)
        err = np.hypot(sx - raw[ok, 0], sy - raw[ok, 1])
        assert np.median(err) < tol, np.median(err)


@pytest.mark.parametrize("distortion", ["radtan", "equidistant"])
def test_rectify_maps_follow_the_geometry(distortion):
    rig = make_rig(1, distortion=distortion)
    calib, maps = rectify(rig)
    assert maps is not None and maps.size == (W, H)
    assert calib.baseline == pytest.approx(rig.baseline, rel=1e-9)
    _check_maps_follow_geometry(rig, calib, maps)


def test_already_rectified_rig_needs_no_maps():
    c = StereoCalib(300.0, 300.0, 159.5, 119.5, 0.2, W, H)
    calib, maps = rectify(StereoRig.from_calib(c))
    assert maps is None and calib == c


def write_ros_pair(folder: Path, rig: StereoRig) -> tuple[Path, Path]:
    R1, R2, P1, P2, *_ = cv2.stereoRectify(rig.left.K, rig.left.D, rig.right.K, rig.right.D, (W, H), rig.R,
                                           rig.T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    out = []
    for name, c, Ri, Pi in (("left", rig.left, R1, P1), ("right", rig.right, R2, P2)):
        d = {"image_width": W, "image_height": H, "camera_name": name,
             "camera_matrix": {"rows": 3, "cols": 3, "data": c.K.reshape(-1).tolist()},
             "distortion_model": "plumb_bob",
             "distortion_coefficients": {"rows": 1, "cols": 5, "data": c.D.tolist()},
             "rectification_matrix": {"rows": 3, "cols": 3, "data": Ri.reshape(-1).tolist()},
             "projection_matrix": {"rows": 3, "cols": 4, "data": Pi.reshape(-1).tolist()}}
        out.append(_write(folder / f"{name}.yaml", d))
    return out[0], out[1]


def _mat(name: str, a: np.ndarray) -> str:
    a = np.atleast_2d(a)
    data = ", ".join(repr(float(x)) for x in a.reshape(-1))
    return f"{name}: !!opencv-matrix\n   rows: {a.shape[0]}\n   cols: {a.shape[1]}\n   dt: d\n   data: [{data}]\n"


def write_orbslam3(path: Path, rig: StereoRig) -> Path:
    lines = ["%YAML:1.0", "Camera.type: \"PinHole\""]
    for p, c in (("Camera1", rig.left), ("Camera2", rig.right)):
        K = c.K
        lines += [f"{p}.fx: {float(K[0, 0])!r}", f"{p}.fy: {float(K[1, 1])!r}", f"{p}.cx: {float(K[0, 2])!r}", f"{p}.cy: {float(K[1, 2])!r}"]
        lines += [f"{p}.{k}: {float(v)!r}" for k, v in zip(("k1", "k2", "p1", "p2", "k3"), c.D.tolist(), strict=True)]
    lines += [f"Camera.width: {W}", f"Camera.height: {H}"]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rig.R, rig.T
    path.write_text("\n".join(lines) + "\n" + _mat("Stereo.T_c1_c2", np.linalg.inv(T)))
    return path


def write_orbslam2(path: Path, rig: StereoRig) -> Path:
    R1, R2, P1, P2, *_ = cv2.stereoRectify(rig.left.K, rig.left.D, rig.right.K, rig.right.D, (W, H), rig.R,
                                           rig.T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    text = "%YAML:1.0\n" + f"Camera.fx: {float(P1[0, 0])!r}\nCamera.fy: {float(P1[1, 1])!r}\nCamera.cx: {float(P1[0, 2])!r}\n" \
        f"Camera.cy: {float(P1[1, 2])!r}\nCamera.width: {W}\nCamera.height: {H}\nCamera.bf: {float(-P2[0, 3])!r}\n" \
        f"LEFT.height: {H}\nLEFT.width: {W}\nRIGHT.height: {H}\nRIGHT.width: {W}\n"
    text += _mat("LEFT.D", rig.left.D[None]) + _mat("LEFT.K", rig.left.K) + _mat("LEFT.R", R1) + _mat("LEFT.P", P1)
    text += _mat("RIGHT.D", rig.right.D[None]) + _mat("RIGHT.K", rig.right.K) + _mat("RIGHT.R", R2)
    text += _mat("RIGHT.P", P2)
    path.write_text(text)
    return path


def _same_rig(a: StereoRig, b: StereoRig, D_n: int = 5):
    np.testing.assert_allclose(a.left.K, b.left.K, atol=1e-9)
    np.testing.assert_allclose(a.right.K, b.right.K, atol=1e-9)
    np.testing.assert_allclose(a.left.D[:D_n], b.left.D[:D_n], atol=1e-12)
    np.testing.assert_allclose(a.R, b.R, atol=1e-9)
    np.testing.assert_allclose(a.T, b.T, atol=1e-9)


def test_kalibr_round_trip(tmp_path):
    rig = make_rig(2)
    rig4 = StereoRig(CameraModel(rig.left.K, rig.left.D[:4], W, H), CameraModel(rig.right.K, rig.right.D[:4], W, H),
                     rig.R, rig.T)
    got = load_rig(write_kalibr(tmp_path / "camchain.yaml", rig4))
    _same_rig(got, rig4, 4)
    calib, maps = rectify(got)
    _check_maps_follow_geometry(got, calib, maps)


def test_ros_camera_info_round_trip(tmp_path):
    rig = make_rig(4)
    lp, rp = write_ros_pair(tmp_path, rig)
    got = load_rig(lp)  # right.yaml found next to left.yaml
    np.testing.assert_allclose(got.R, rig.R, atol=1e-6)
    np.testing.assert_allclose(got.T, rig.T, atol=1e-6)
    assert got.rect is not None
    calib, maps = rectify(got)
    _check_maps_follow_geometry(got, calib, maps)


def test_orbslam3_and_orbslam2_settings(tmp_path):
    rig = make_rig(5)
    got = load_rig(write_orbslam3(tmp_path / "orb3.yaml", rig))
    _same_rig(got, rig)
    got2 = load_rig(write_orbslam2(tmp_path / "orb2.yaml", rig))
    np.testing.assert_allclose(got2.R, rig.R, atol=1e-6)
    np.testing.assert_allclose(got2.T, rig.T, atol=1e-6)
    c2, maps = rectify(got2)
    _check_maps_follow_geometry(got2, c2, maps)


def test_orbslam_rectified_camera_bf(tmp_path):
    p = tmp_path / "orb.yaml"
    p.write_text("%YAML:1.0\nCamera.fx: 435.2\nCamera.fy: 435.2\nCamera.cx: 367.45\nCamera.cy: 252.2\n"
                 "Camera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\nCamera.width: 752\n"
                 "Camera.height: 480\nCamera.fps: 20.0\nCamera.bf: 47.90639384423901\nCamera.RGB: 1\n")
    calib, maps = rectify(load_rig(p))
    assert maps is None
    assert calib.baseline == pytest.approx(47.90639384423901 / 435.2) and calib.width == 752
    p.write_text(p.read_text().replace("Camera.bf: 47.9", "Camera.bf: -47.9"))
    with pytest.raises(InputError, match="sign"):
        load_rig(p)


def test_euroc_pair_round_trip(tmp_path):
    rig = make_rig(6)
    lp, _ = write_euroc_pair(tmp_path, rig)
    got = load_rig(lp)  # cam1/sensor.yaml found from cam0/
    _same_rig(got, rig, 4)


def test_seedmap_calib_round_trip(tmp_path):
    c = StereoCalib(400.0, 401.0, 300.5, 200.25, 0.11, 640, 480)
    save_calib_yaml(c, tmp_path / "calib.yaml")
    assert rectify(load_rig(tmp_path / "calib.yaml"))[0] == c
    p = tmp_path / "calib.yaml"
    p.write_text(p.read_text().replace("baseline_m: 0.11", "baseline_m: -0.11"))
    with pytest.raises(InputError, match="swapped cameras or a sign error"):
        load_rig(p)


def test_swapped_cameras_and_wrong_sign_are_explained(tmp_path):
    rig = make_rig(7)
    swapped = StereoRig(rig.right, rig.left, rig.R.T, -rig.R.T @ rig.T)  # left/right exchanged
    with pytest.raises(InputError, match="swapped") as e:
        rectify(load_rig(write_kalibr(tmp_path / "camchain.yaml", swapped)))
    assert "camchain.yaml" in str(e.value) and "\n" not in str(e.value)
    flipped = StereoRig(rig.left, rig.right, rig.R, -rig.T)  # sign error in T
    with pytest.raises(InputError, match="baseline sign"):
        check_rig(flipped)
    vertical = StereoRig(rig.left, rig.right, np.eye(3), np.array([0.0, -0.1, 0.0]))
    with pytest.raises(InputError, match="horizontal"):
        check_rig(vertical)


def test_missing_fields_name_the_field(tmp_path):
    rig = make_rig(8)
    p = write_kalibr(tmp_path / "camchain.yaml", rig)
    d = yaml.safe_load(p.read_text())
    del d["cam1"]["T_cn_cnm1"]
    _write(p, d)
    with pytest.raises(InputError, match="T_cn_cnm1"):
        load_rig(p)
    q = tmp_path / "orb.yaml"
    q.write_text("%YAML:1.0\nCamera.fx: 400.0\nCamera.fy: 400.0\nCamera.cx: 300.0\nCamera.width: 600\n"
                 "Camera.height: 400\nCamera.bf: 40.0\n")
    with pytest.raises(InputError, match="Camera.cy"):
        load_rig(q)
    lp, rp = write_ros_pair(tmp_path, rig)
    d = yaml.safe_load(rp.read_text())
    d["projection_matrix"]["data"] = [1.0, 2.0]
    _write(rp, d)
    with pytest.raises(InputError, match="projection_matrix"):
        load_rig(lp)


def test_unknown_format(tmp_path):
    p = _write(tmp_path / "x.yaml", {"hello": 1})
    with pytest.raises(InputError, match="unrecognised calibration format"):
        load_rig(p)


# ---------------------------------------------------------------------------------------------
# real fixtures (../shared/realdata)
# ---------------------------------------------------------------------------------------------


@needs_real
def test_real_euroc_sensor_yaml():
    rig = load_rig(REAL / "euroc_v101_micro_stereo" / "mav0" / "cam0" / "sensor.yaml")
    assert rig.left.K[0, 0] == pytest.approx(458.654) and rig.right.K[0, 2] == pytest.approx(379.999)
    assert rig.left.D.tolist() == pytest.approx([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    c = rig.right_center_in_left
    assert c[0] == pytest.approx(0.1100, abs=5e-4) and abs(c[1]) < 0.002 and abs(c[2]) < 0.002
    calib, maps = rectify(rig)
    assert calib.baseline == pytest.approx(0.110078, abs=1e-5)
    assert maps is not None and (calib.width, calib.height) == (752, 480)
    # the Kimera fixtures carry the same calibration (CRLF files in ForStereoFrame)
    rig2 = load_rig(REAL / "kimera_stereo_fixtures" / "ForStereoFrame" / "sensorLeft.yaml")
    np.testing.assert_allclose(rig2.T, rig.T, atol=1e-12)


@needs_real
def test_real_kimera_fisheye_pair_rectifies():
    f = REAL / "kimera_stereo_fixtures" / "ForStereoFrame"
    rig = load_rig(f / "left_sensor_fisheye.yaml", f / "right_sensor_fisheye.yaml")
    assert rig.left.distortion == "equidistant"
    calib, maps = rectify(rig)
    assert calib.baseline == pytest.approx(rig.baseline) and 0.10 < calib.baseline < 0.14
    _check_maps_follow_geometry(rig, calib, maps, tol=0.3)


@needs_real
def test_real_kimera_stereo_tracker_triangulates_known_depths():
    """Synthetic rectified pair of Kimera's tests: 35 corners, all at depth 480 (units of T_BS)."""
    f = REAL / "kimera_stereo_fixtures" / "ForStereoTracker"
    rig = load_rig(f / "camLeft.yaml", f / "camRight.yaml")
    assert rig.baseline == pytest.approx(96.0, abs=1e-3)
    assert any("millimetres" in w for w in rig.warnings)  # 96 "m": these fixtures use other units

    def rd(name):
        return np.loadtxt(f / name, skiprows=1)

    depth = rd("depth_left.txt")
    # (a) distorted corners through our rectification (the maps' geometry, as cv2.undistortPoints)
    calib, _ = rectify(rig)
    R1 = rectified_rotation(rig)
    Rr = rig.R @ R1.T  # raw right <- rectified frame, via left
    ul = cv2.undistortPoints(rd("corners_normal_left.txt").reshape(-1, 1, 2), rig.left.K, rig.left.D,
                             R=R1, P=calib.K).reshape(-1, 2)
    R2 = R1 @ rig.R.T  # rectified <- raw right (rotation part of the rectified right frame)
    ur = cv2.undistortPoints(rd("corners_normal_right.txt").reshape(-1, 1, 2), rig.right.K, rig.right.D,
                             R=R2, P=calib.K).reshape(-1, 2)
    assert Rr.shape == (3, 3)
    assert np.max(np.abs(ul[:, 1] - ur[:, 1])) < 0.5  # rows aligned after rectification
    X = calib.triangulate(ul, ur[:, 0])
    assert np.median(np.abs(X[:, 2] / depth - 1)) < 0.01
    # (b) the already-undistorted corners with the original intrinsics and the 96-unit baseline
    K = rig.left.K
    plain = StereoCalib(K[0, 0], K[1, 1], K[0, 2], K[1, 2], rig.baseline, 752, 480)
    Xu = plain.triangulate(rd("corners_undistort_left.txt"), rd("corners_undistort_right.txt")[:, 0])
    np.testing.assert_allclose(Xu[:, 2], depth, rtol=1e-4)


@needs_real
def test_real_kitti_raw_calib():
    p = REAL / "kimera_stereo_fixtures" / "ForKittiData" / "calib_cam_to_cam.txt"
    c23, maps = rectify(parse_kitti_calib(p, (2, 3)))
    assert maps is None and (c23.width, c23.height) == (1242, 375)
    assert c23.fx == pytest.approx(721.5377) and c23.cy == pytest.approx(172.854)
    assert c23.baseline == pytest.approx((44.85728 + 339.5242) / 721.5377, rel=1e-6)
    c01, _ = rectify(parse_kitti_calib(p, (0, 1)))
    assert c01.baseline == pytest.approx(0.537150, abs=1e-5)


@needs_real
def test_real_gtsam_calibration_reprojects_the_factors():
    """GTSAM's VO example: our calib projects each factor's camera-frame point onto its (uL, uR, v)."""
    g = REAL / "gtsam_stereo_vo"
    calib, _ = rectify(load_rig(g / "VO_calibration.txt"))
    assert calib.fx == pytest.approx(721.5377) and calib.baseline == pytest.approx(0.537150588)
    # same rig as the KITTI raw calibration of cams 0/1 (both from the KITTI 2011_09_26 drive calibration)
    k = rectify(parse_kitti_calib(REAL / "kimera_stereo_fixtures" / "ForKittiData" / "calib_cam_to_cam.txt", (0, 1)))[0]
    assert calib.baseline == pytest.approx(k.baseline, abs=1e-6)
    a = np.loadtxt(g / "VO_stereo_factors_small.txt")
    uv, ur = calib.project(a[:, 5:8])
    assert np.max(np.abs(uv[:, 0] - a[:, 2])) < 0.02
    assert np.max(np.abs(ur - a[:, 3])) < 0.02
    assert np.max(np.abs(uv[:, 1] - a[:, 4])) < 0.02
