"""Folder, KITTI and EuRoC loaders on files generated here, and EuRoC on the real micro sequence."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from seedmap.errors import ConfigError, InputError
from seedmap.io import StereoSequence, detect_format, open_dataset
from seedmap.io.calibration import rectified_rotation, save_calib_yaml
from seedmap.io.euroc import EurocSequence
from seedmap.io.folder import StereoFolder
from seedmap.io.kitti import KittiSequence
from seedmap.io.options import DatasetOptions
from seedmap.records import StereoCalib

from helpers.calibration_files import make_rig, write_euroc_pair, write_kalibr  # noqa: E402

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="shared/realdata not present")


def _img(i: int, cam: int, w: int = 40, h: int = 30) -> np.ndarray:
    return np.random.default_rng(10 * i + cam).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _png(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb)


def make_folder(root: Path, n: int = 4, dirs=("left", "right"), names=None, times=True, w=40, h=30) -> StereoCalib:
    calib = StereoCalib(50.0, 50.0, (w - 1) / 2, (h - 1) / 2, 0.1, w, h)
    for i in range(n):
        name = names[i] if names else f"frame_{i}.png"
        _png(root / dirs[0] / name, _img(i, 0, w, h))
        _png(root / dirs[1] / name, _img(i, 1, w, h))
    save_calib_yaml(calib, root / "calib.yaml")
    if times:
        (root / "times.txt").write_text("".join(f"{10 + 0.2 * i}\n" for i in range(n)))
    return calib


# ---------------------------------------------------------------------------------------------- folder


def test_folder_round_trip(tmp_path):
    calib = make_folder(tmp_path, n=12)  # frame_10 after frame_9 (natural order)
    seq = open_dataset(tmp_path)
    assert isinstance(seq, StereoFolder) and isinstance(seq, StereoSequence)
    assert detect_format(tmp_path) == "folder"
    assert len(seq) == 12 and seq.calib == calib and seq.maps is None
    np.testing.assert_allclose(seq.timestamps, 10 + 0.2 * np.arange(12))
    f = seq[10]
    np.testing.assert_array_equal(f.left, _img(10, 0))
    np.testing.assert_array_equal(f.right, _img(10, 1))
    assert f.timestamp == pytest.approx(12.0)
    assert seq.gt_trajectory() is None


def test_folder_cam0_cam1_without_times(tmp_path):
    names = [f"{1403715273262142976 + 50_000_000 * i}.png" for i in range(3)]
    make_folder(tmp_path, n=3, dirs=("cam0", "cam1"), names=names, times=False)
    seq = StereoFolder(tmp_path)
    np.testing.assert_allclose(seq.timestamps - seq.timestamps[0], [0.0, 0.05, 0.1], atol=1e-6)
    shutil.rmtree(tmp_path / "cam0")
    shutil.rmtree(tmp_path / "cam1")
    make_folder(tmp_path, n=3, dirs=("cam0", "cam1"), times=False)
    seq = StereoFolder(tmp_path, fps=4.0)
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.25, 0.5])
    assert any("frame index" in w for w in seq.warnings)


def test_folder_grayscale_becomes_rgb(tmp_path):
    make_folder(tmp_path, n=1)
    g = _img(0, 0)[:, :, 0]
    _png(tmp_path / "left" / "frame_0.png", g)
    seq = StereoFolder(tmp_path)
    f = seq[0]
    assert f.left.shape == (30, 40, 3)
    np.testing.assert_array_equal(f.left[:, :, 2], g)
    assert any("grayscale" in w for w in seq.warnings)


def test_folder_unrectified_pair_is_rectified(tmp_path):
    """Raw images of a textured plane at z = Z (rectified frame) seen through a distorted, rotated rig:
    after loading, both images equal the analytic rectified views and differ by disparity fx*B/Z."""
    W, H, Z = 320, 240, 1.5
    rig = make_rig(11)
    write_kalibr(tmp_path / "camchain.yaml", StereoRig4(rig))
    rig = StereoRig4(rig)
    R1 = rectified_rotation(rig)
    B = rig.baseline

    def texture(X, Y):
        return 128 + 60 * np.sin(2 * np.pi * X / 0.09) * np.cos(2 * np.pi * Y / 0.07) + 30 * np.sin(2 * np.pi * (X + Y) / 0.23)

    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    pix = np.column_stack([uu.ravel(), vv.ravel()]).reshape(-1, 1, 2)
    for cam, name in ((rig.left, "left"), (rig.right, "right")):
        n = cv2.undistortPoints(pix, cam.K, cam.D).reshape(-1, 2)
        rays = np.column_stack([n, np.ones(len(n))])
        if name == "left":
            d, c = rays @ R1.T, np.zeros(3)
        else:
            d, c = rays @ rig.R @ R1.T, np.array([B, 0.0, 0.0])  # x_l = R^T x_r (directions)
        s = (Z - c[2]) / d[:, 2]
        P = c + d * s[:, None]
        img = np.clip(texture(P[:, 0], P[:, 1]), 0, 255).reshape(H, W).astype(np.uint8)
        _png(tmp_path / name / "000000.png", np.repeat(img[:, :, None], 3, axis=2))
    seq = StereoFolder(tmp_path, calib=tmp_path / "camchain.yaml")
    assert seq.maps is not None
    f = seq[0]
    c = seq.calib
    X = (uu - c.cx) * Z / c.fx
    Y = (vv - c.cy) * Z / c.fy
    want_l = texture(X, Y)
    want_r = texture(X + B, Y)  # right rectified pixel (u, v) sees the plane point at X + B
    m = (slice(10, H - 10), slice(10, W - 10))
    err_l = np.abs(f.left[:, :, 0].astype(float) - want_l)[m]
    err_r = np.abs(f.right[:, :, 0].astype(float) - want_r)[m]
    assert np.median(err_l) < 2.0 and np.median(err_r) < 2.0
    # without rectification the raw right image is far from the rectified view
    raw_r = cv2.imread(str(tmp_path / "right" / "000000.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    assert np.median(np.abs(raw_r - want_r)[m]) > 5 * np.median(err_r)


def StereoRig4(rig):
    """Kalibr stores 4 radtan coefficients: drop k3 so file and rig agree exactly."""
    from seedmap.io.calibration import CameraModel, StereoRig

    return StereoRig(CameraModel(rig.left.K, rig.left.D[:4], rig.left.width, rig.left.height),
                     CameraModel(rig.right.K, rig.right.D[:4], rig.right.width, rig.right.height), rig.R, rig.T)


def test_folder_bad_inputs(tmp_path):
    a = tmp_path / "a"
    make_folder(a, n=3)
    (a / "left" / "frame_1.png").write_bytes(b"\x89PNG not really")
    seq = StereoFolder(a)
    with pytest.raises(InputError, match="corrupt") as e:
        seq[1]
    assert "frame_1.png" in str(e.value)
    b = tmp_path / "b"
    make_folder(b, n=3, times=False)
    (b / "times.txt").write_text("0.0\n0.4\n0.2\n")
    with pytest.raises(InputError, match="strictly increasing") as e:
        StereoFolder(b)
    assert "times.txt" in str(e.value)
    (b / "times.txt").write_text("0.0\n0.4\n")
    with pytest.raises(InputError, match="2 timestamps but there are 3"):
        StereoFolder(b)
    c = tmp_path / "c"
    make_folder(c, n=3)
    _png(c / "right" / "other.png", _img(9, 1))
    (c / "right" / "frame_0.png").unlink()
    (c / "right" / "frame_1.png").unlink()
    with pytest.raises(InputError, match="3 images but right/ has 2"):
        StereoFolder(c)
    d = tmp_path / "d"
    make_folder(d, n=2)
    save_calib_yaml(StereoCalib(50.0, 50.0, 20.0, 15.0, 0.1, 80, 60), d / "calib.yaml")
    seq = StereoFolder(d)
    with pytest.raises(InputError, match="80x60") as e:
        seq[0]
    assert "calib.yaml" in str(e.value) and "\n" not in str(e.value)
    e_ = tmp_path / "e"
    make_folder(e_, n=2)
    (e_ / "calib.yaml").unlink()
    with pytest.raises(InputError, match="no calibration found"):
        StereoFolder(e_)


def test_loader_options(tmp_path):
    make_folder(tmp_path, n=2, times=False)
    seq = DatasetOptions(fps=2.0).open(tmp_path)
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.5])
    with pytest.raises(ConfigError, match="no option sync_tol_s"):
        DatasetOptions(sync_tol_s=0.1).open(tmp_path)
    with pytest.raises(ConfigError, match="unknown dataset format"):
        DatasetOptions(format="nope").open(tmp_path)


def test_seedmap_layout_still_wins(tmp_path):
    from seedmap.io.seedmap_dataset import DatasetWriter

    w = DatasetWriter(tmp_path)
    w.write_calib(StereoCalib(50.0, 50.0, 19.5, 14.5, 0.1, 40, 30))
    w.write_times(np.array([0.0]))
    w.write_frame(0, _img(0, 0), _img(0, 1))
    assert detect_format(tmp_path) == "seedmap"


# ---------------------------------------------------------------------------------------------- KITTI

KITTI_CALIB = """P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 4.538225000000e+01 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 -1.130887000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.779761000000e-03
P3: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.372877000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 2.369057000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.915215000000e-03
Tr: 4.276802385584e-04 -9.999672484946e-01 -8.084491683471e-03 -1.198459927713e-02 -7.210626507497e-03 8.081198471645e-03 -9.999413164504e-01 -5.403984729748e-02 9.999738645903e-01 4.859485810390e-04 -7.206933692422e-03 -2.921968648686e-01
"""  # KITTI odometry sequence 00 calib.txt


def make_kitti(root: Path, n: int = 5, gray: bool = False) -> None:
    cams = (0, 1) if gray else (2, 3)
    for i in range(n):
        for k, c in enumerate(cams):
            img = _img(i, k, 124, 38)
            _png(root / f"image_{c}" / f"{i:06d}.png", img[:, :, 0] if gray else img)
    (root / "calib.txt").write_text(KITTI_CALIB)
    (root / "times.txt").write_text("".join(f"{0.103736 * i:.6e}\n" for i in range(n)))


def test_kitti_sequence(tmp_path):
    seq_dir = tmp_path / "dataset" / "sequences" / "00"
    make_kitti(seq_dir, n=5)
    seq = open_dataset(seq_dir)
    assert isinstance(seq, KittiSequence) and len(seq) == 5
    c = seq.calib
    assert c.fx == pytest.approx(718.856) and c.cx == pytest.approx(607.1928) and (c.width, c.height) == (124, 38)
    assert c.baseline == pytest.approx((45.38225 + 337.2877) / 718.856, rel=1e-9)  # 0.532 m
    np.testing.assert_array_equal(seq[3].right, _img(3, 1, 124, 38))
    assert seq.gt_trajectory() is None
    gt = REAL / "evo_trajectories" / "KITTI_00_gt.txt"
    if gt.is_file():
        poses = tmp_path / "dataset" / "poses" / "00.txt"
        poses.parent.mkdir(parents=True)
        poses.write_text("".join(gt.read_text().splitlines(keepends=True)[:5]))
        traj = KittiSequence(seq_dir).gt_trajectory()
        raw = np.loadtxt(poses).reshape(-1, 3, 4)
        # left colour camera = cam0 shifted by -P2[0,3]/fx = -0.0631 m along cam0's x axis
        off = np.linalg.solve(np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]]),
                              np.array([45.38225, -0.1130887, 0.003779761]))
        want = raw[:, :, 3] - np.einsum("nij,j->ni", raw[:, :, :3], off)
        np.testing.assert_allclose(traj.positions, want, atol=1e-9)
        np.testing.assert_allclose(traj.timestamps, seq.timestamps)


def test_kitti_grayscale_pair_and_errors(tmp_path):
    make_kitti(tmp_path, n=2, gray=True)
    seq = KittiSequence(tmp_path)
    assert seq.cams == (0, 1)
    assert seq.calib.baseline == pytest.approx(386.1448 / 718.856)
    assert seq[0].left.shape == (38, 124, 3)
    (tmp_path / "image_1" / "000001.png").unlink()
    with pytest.raises(InputError, match="image_0/ has 2 images but image_1/ has 1"):
        KittiSequence(tmp_path)


# ---------------------------------------------------------------------------------------------- EuRoC


def make_euroc(root: Path, n: int = 6, gt: bool = True, skip_right=()) -> tuple:
    rig = StereoRig4(make_rig(12))
    mav = root / "mav0"
    write_euroc_pair(mav, rig)
    stamps = 1_000_000_000_000 + np.arange(n) * 50_000_000
    for cam in (0, 1):
        rows = ["#timestamp [ns],filename"]
        for i, s in enumerate(stamps):
            if cam == 1 and i in skip_right:
                continue
            _png(mav / f"cam{cam}" / "data" / f"{s}.png", _img(i, cam, 320, 240)[:, :, 0])
            rows.append(f"{s},{s}.png")
        (mav / f"cam{cam}" / "data.csv").write_text("\n".join(rows) + "\n")
    if gt:
        d = mav / "state_groundtruth_estimate0"
        d.mkdir()
        t = 1_000_000_000_000 - 20_000_000 + np.arange(200) * 5_000_000  # 200 Hz, covers the frames
        ts = (t - t[0]) * 1e-9
        rows = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"]
        for k in range(len(t)):
            ang = 0.5 * ts[k]  # rad about z
            rows.append(f"{t[k]},{1.0 + 0.2 * ts[k]},{2.0},{0.5 + 0.1 * ts[k]},{np.cos(ang / 2)},0,0,{np.sin(ang / 2)}")
        (d / "data.csv").write_text("\n".join(rows) + "\n")
    return rig, stamps


def test_euroc_synthetic_sequence(tmp_path):
    rig, stamps = make_euroc(tmp_path, n=6)
    seq = open_dataset(tmp_path)
    assert isinstance(seq, EurocSequence) and len(seq) == 6
    np.testing.assert_allclose(seq.timestamps, stamps * 1e-9)
    assert seq.calib.baseline == pytest.approx(rig.baseline)
    f = seq[2]
    assert f.left.shape == (240, 320, 3)
    assert np.array_equal(f.left[:, :, 0], f.left[:, :, 1])  # grayscale replicated
    traj = seq.gt_trajectory()
    assert len(traj) == 6
    # body position is linear in time: interpolated camera centre = body centre + R_wb @ t_b_cam0
    tq = stamps * 1e-9 - (1_000_000_000_000 - 20_000_000) * 1e-9
    ang = 0.5 * tq
    for k in range(6):
        c, s = np.cos(ang[k]), np.sin(ang[k])
        R_wb = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        p_wb = np.array([1.0 + 0.2 * tq[k], 2.0, 0.5 + 0.1 * tq[k]])
        T_b_c0 = seq.T_body_cam0
        np.testing.assert_allclose(traj.poses[k, :3, 3], p_wb + R_wb @ T_b_c0[:3, 3], atol=1e-6)
        # orientation of the *rectified* left camera: R_wb R_bc0 R1^T
        R1 = rectified_rotation(seq.rig)
        np.testing.assert_allclose(traj.poses[k, :3, :3], R_wb @ T_b_c0[:3, :3] @ R1.T, atol=1e-6)


def test_euroc_drops_unpaired_and_reports(tmp_path):
    make_euroc(tmp_path, n=5, gt=False, skip_right=(1,))
    seq = EurocSequence(tmp_path)
    assert len(seq) == 4 and seq.gt_trajectory() is None
    assert any("1 images without a stereo partner" in w for w in seq.warnings)
    csv = tmp_path / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="strictly increasing") as e:
        EurocSequence(tmp_path)
    assert "data.csv" in str(e.value)


@needs_real
def test_real_euroc_micro_sequence():
    root = REAL / "euroc_v101_micro_stereo"
    seq = open_dataset(root)
    assert isinstance(seq, EurocSequence)
    assert len(seq) == 24
    assert seq.calib.baseline == pytest.approx(0.11, abs=0.002)
    assert seq.timestamps[0] == pytest.approx(1403715273.262143, abs=1e-6)
    np.testing.assert_allclose(np.diff(seq.timestamps), 0.2, atol=1e-3)  # every 4th frame of 20 Hz
    assert seq.gt_trajectory() is None  # the GT csv is not part of the micro set


def _row_offsets(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """|v_left - v_right| of SIFT matches (Lowe ratio 0.7) between two images."""
    sift = cv2.SIFT_create(nfeatures=1500)
    gl, gr = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY), cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
    kl, dl = sift.detectAndCompute(gl, None)
    kr, dr = sift.detectAndCompute(gr, None)
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(dl, dr, k=2)
    good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < 0.7 * n.distance]
    vl = np.array([kl[m.queryIdx].pt[1] for m in good])
    vr = np.array([kr[m.trainIdx].pt[1] for m in good])
    return np.abs(vl - vr)


@needs_real
def test_real_euroc_rectified_rows_align():
    """After rectification, SIFT matches between left and right lie on the same row (median |dv| < 1 px);
    the raw pairs do not (EuRoC's cameras are rotated and distorted)."""
    seq = EurocSequence(REAL / "euroc_v101_micro_stereo")
    dv_rect, dv_raw = [], []
    for i in (0, 12, 23):
        f = seq[i]
        dv_rect.append(_row_offsets(f.left, f.right))
        dv_raw.append(_row_offsets(*seq.raw_pair(i)))
    rect, raw = np.concatenate(dv_rect), np.concatenate(dv_raw)
    assert len(rect) > 100
    assert np.median(rect) < 1.0
    assert np.median(raw) > 2 * np.median(rect)
