"""ROS1 / ROS2 (sqlite3, mcap) bags written here with rosbags' own writers, read back by RosbagSequence."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from seedmap.errors import InputError, SeedmapError
from seedmap.io import open_dataset
from seedmap.io.rosbag import RosbagSequence, bag_info, decode_ros_image, guess_stereo_topics

from helpers.bags import BASE, CX, CY, FX, H, W, _header, _image, _image_msg, _info_msg, _store, write_bag



def _bag_path(tmp_path: Path, kind: str) -> Path:
    return tmp_path / {"ros1": "s.bag", "sqlite3": "s_db", "mcap": "s_mcap"}[kind]


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_bag_round_trip(tmp_path, kind):
    bag = write_bag(_bag_path(tmp_path, kind), kind, n=5)
    seq = open_dataset(bag)
    assert isinstance(seq, RosbagSequence)
    assert len(seq) == 5
    assert seq.left_topic == "/stereo/left/image_rect"
    np.testing.assert_allclose(seq.timestamps, 100.0 + 0.1 * np.arange(5), atol=1e-6)
    c = seq.calib
    assert (c.width, c.height) == (W, H)
    assert c.fx == pytest.approx(FX) and c.cx == pytest.approx(CX) and c.cy == pytest.approx(CY)
    assert c.baseline == pytest.approx(BASE)
    assert seq.maps is None  # rectified topics: nothing to remap
    for i in (0, 3):
        f = seq[i]
        np.testing.assert_array_equal(f.left, _image(i, 0))
        np.testing.assert_array_equal(f.right, _image(i, 1))
    frames = list(seq)  # streaming pass gives the same
    assert [f.index for f in frames] == list(range(5))
    np.testing.assert_array_equal(frames[4].right, _image(4, 1))
    seq.close()


@pytest.mark.parametrize("encoding,compressed", [("bgr8", False), ("mono8", False), ("rgb8", True)])
def test_bag_encodings(tmp_path, encoding, compressed):
    bag = write_bag(tmp_path / "e.bag", "ros1", n=2, encoding=encoding, compressed=compressed)
    with RosbagSequence(bag) as seq:
        f = seq[1]
        want = _image(1, 0)
        if encoding == "mono8":
            want = np.repeat(want[:, :, 1:2], 3, axis=2)
            assert any("grayscale" in w for w in seq.warnings)
        np.testing.assert_array_equal(f.left, want)
        assert f.left.dtype == np.uint8 and f.left.shape == (H, W, 3)


def test_bayer_decoding_matches_colour():
    """A smooth colour image mosaiced as RGGB and decoded gives the image back (up to demosaicing error)."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    yy, xx = np.mgrid[0:64, 0:64]
    rgb = np.stack([100 + xx, 50 + yy, 180 - xx // 2], axis=2).astype(np.uint8)
    mosaic = np.zeros((64, 64), np.uint8)
    mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]
    mosaic[0::2, 1::2] = rgb[0::2, 1::2, 1]
    mosaic[1::2, 0::2] = rgb[1::2, 0::2, 1]
    mosaic[1::2, 1::2] = rgb[1::2, 1::2, 2]
    msg = ts.types["sensor_msgs/msg/Image"](header=_header(ts, "ros2", 1.0, "c"), height=64, width=64,
                                           encoding="bayer_rggb8", is_bigendian=0, step=64, data=mosaic.reshape(-1))
    out, gray = decode_ros_image(msg, "x")
    assert not gray
    err = np.abs(out[4:-4, 4:-4].astype(int) - rgb[4:-4, 4:-4].astype(int))
    assert err.mean() < 2.0


def test_sync_drops_unmatched_and_counts(tmp_path):
    bag = write_bag(tmp_path / "d.bag", "ros1", n=8, right_skip=(2, 5))
    with RosbagSequence(bag, sync_tol_s=0.01) as seq:
        assert len(seq) == 6
        assert seq.dropped == 2
        assert any("2 images without a stereo partner" in w for w in seq.warnings)
        np.testing.assert_allclose(seq.timestamps, 100.0 + 0.1 * np.array([0, 1, 3, 4, 6, 7]), atol=1e-6)
        np.testing.assert_array_equal(seq[2].right, _image(3, 1))
    # a tolerance below the 1 ms jitter pairs nothing: a one-line error
    with pytest.raises(InputError, match="no left/right images within"):
        RosbagSequence(bag, sync_tol_s=0.0001)


def test_raw_topics_are_rectified_with_camera_info(tmp_path):
    bag = write_bag(tmp_path / "raw.bag", "ros1", n=2, topics=("/cam/left/image_raw", "/cam/right/image_raw"))
    with RosbagSequence(bag) as seq:
        assert not seq.images_rectified
        assert seq.calib.baseline == pytest.approx(BASE)
        # D = 0, R = I, K = P: the camera_info describes an already rectified pair -> identity
        assert seq.maps is None
        np.testing.assert_array_equal(seq[0].left, _image(0, 0))


def test_explicit_topics_and_calib_file(tmp_path):
    bag = write_bag(tmp_path / "x.bag", "ros1", n=2, info=False, topics=("/a/img", "/b/img"))
    with pytest.raises(InputError, match="left-topic"):
        RosbagSequence(bag)
    with pytest.raises(InputError, match="CameraInfo"):
        RosbagSequence(bag, left_topic="/a/img", right_topic="/b/img")
    calib = tmp_path / "calib.yaml"
    calib.write_text(f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline_m: 0.2\nimage_width: {W}\n"
                     f"image_height: {H}\n")
    with RosbagSequence(bag, left_topic="/a/img", right_topic="/b/img", calib=calib) as seq:
        assert seq.calib.baseline == pytest.approx(0.2)
        np.testing.assert_array_equal(seq[1].right, _image(1, 1))


def test_calibration_size_mismatch_is_one_line(tmp_path):
    bag = write_bag(tmp_path / "x.bag", "ros1", n=1, info=False)
    calib = tmp_path / "calib.yaml"
    calib.write_text(f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline_m: 0.2\nimage_width: 640\nimage_height: 480\n")
    with RosbagSequence(bag, calib=calib) as seq, pytest.raises(InputError, match="calibration") as e:
        seq[0]
    assert "\n" not in str(e.value) and "640x480" in str(e.value)


def test_topic_without_messages(tmp_path):
    bag = write_bag(tmp_path / "empty.bag", "ros1", n=2, empty_right=True)
    with pytest.raises(InputError, match="has no messages"):
        RosbagSequence(bag)


def test_truncated_bag_is_one_line_error(tmp_path):
    bag = write_bag(tmp_path / "t.bag", "ros1", n=4)
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(SeedmapError) as e:
        RosbagSequence(cut)
    assert "\n" not in str(e.value) and "cut.bag" in str(e.value)
    db = write_bag(tmp_path / "t_db", "sqlite3", n=2)
    dbfile = next(db.glob("*.db3"))
    dbfile.write_bytes(dbfile.read_bytes()[:100])
    with pytest.raises(SeedmapError):
        RosbagSequence(db)


def test_guess_topics():
    topics = {"/zed/left/image_raw": "sensor_msgs/msg/Image", "/zed/left/image_rect_color": "sensor_msgs/msg/Image",
              "/zed/right/image_raw": "sensor_msgs/msg/Image",
              "/zed/right/image_rect_color": "sensor_msgs/msg/Image",
              "/zed/depth/image": "sensor_msgs/msg/Image", "/imu": "sensor_msgs/msg/Imu"}
    assert guess_stereo_topics(topics) == ("/zed/left/image_rect_color", "/zed/right/image_rect_color")
    topics = {"/cam0/image_raw": "sensor_msgs/msg/Image", "/cam1/image_raw": "sensor_msgs/msg/Image"}
    assert guess_stereo_topics(topics) == ("/cam0/image_raw", "/cam1/image_raw")
    with pytest.raises(InputError):
        guess_stereo_topics({"/image": "sensor_msgs/msg/Image"})


def test_bag_info_and_cli(tmp_path):
    bag = write_bag(tmp_path / "i_mcap", "mcap", n=3)
    info = bag_info(bag)
    counts = {t.topic: t.count for t in info.topics}
    assert counts["/stereo/left/image_rect"] == 3 and counts["/stereo/right/camera_info"] == 3
    assert info.message_count == 12
    assert info.duration_s == pytest.approx(0.201, abs=0.01)
    r = subprocess.run([sys.executable, "-m", "seedmap.cli", "bag-info", str(bag)], capture_output=True, text=True,
                       env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    assert "/stereo/left/image_rect" in r.stdout and "sensor_msgs/msg/Image" in r.stdout
    r = subprocess.run([sys.executable, "-m", "seedmap.cli", "bag-info", str(bag), "--sequence"], capture_output=True,
                       text=True, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    assert "3 pairs, 0 dropped" in r.stdout and "baseline=0.1200 m" in r.stdout
    r = subprocess.run([sys.executable, "-m", "seedmap.cli", "bag-info", str(tmp_path / "nope.bag")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1


def test_raw_distorted_camera_info_builds_maps(tmp_path):
    """CameraInfo with real distortion and rectification (as camera_calibration writes it): the loader
    rectifies with the camera_info's own R and P - calib from P, one remap per image."""
    from rosbags.rosbag1 import Writer

    ts = _store("ros1")
    K = np.array([[FX, 0, CX], [0, FX, CY], [0, 0, 1.0]])
    D = np.array([-0.2, 0.05, 0.0, 0.0, 0.0])
    R = cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))[0]
    T = np.array([-BASE, 0.0, 0.0])
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K, D, K, D, (W, H), R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    infos = []
    for Ri, Pi in ((R1, P1), (R2, P2)):
        m = _info_msg(ts, "ros1", 1.0, False)
        m.D, m.K, m.R, m.P = D, K.reshape(-1), Ri.reshape(-1), Pi.reshape(-1)
        infos.append(m)
    path = tmp_path / "raw.bag"
    with Writer(path) as w:
        cl = w.add_connection("/s/left/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        cr = w.add_connection("/s/right/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        il = w.add_connection("/s/left/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        ir = w.add_connection("/s/right/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        w.write(il, 1, ts.serialize_ros1(infos[0], "sensor_msgs/msg/CameraInfo"))
        w.write(ir, 1, ts.serialize_ros1(infos[1], "sensor_msgs/msg/CameraInfo"))
        for k, c in ((0, cl), (1, cr)):
            w.write(c, 10, ts.serialize_ros1(_image_msg(ts, "ros1", 1.0, _image(0, k)), "sensor_msgs/msg/Image"))
    with RosbagSequence(path) as seq:
        assert seq.maps is not None
        assert seq.calib.fx == pytest.approx(P1[0, 0]) and seq.calib.cy == pytest.approx(P1[1, 2])
        assert seq.calib.baseline == pytest.approx(-P2[0, 3] / P2[0, 0])
        np.testing.assert_allclose(seq.rig.T, T, atol=1e-9)  # extrinsics recovered from R1, R2, P2
        f = seq[0]
        mx, my = cv2.initUndistortRectifyMap(K, D, R1, P1, (W, H), cv2.CV_32FC1)
        want = cv2.remap(_image(0, 0), mx, my, cv2.INTER_LINEAR)
        assert np.mean(np.abs(f.left.astype(int) - want.astype(int))) < 2.0


def test_stereo_size_mismatch_in_bag(tmp_path):
    from rosbags.rosbag1 import Writer

    ts = _store("ros1")
    path = tmp_path / "m.bag"
    with Writer(path) as w:
        cl = w.add_connection("/left/image", "sensor_msgs/msg/Image", typestore=ts)
        cr = w.add_connection("/right/image", "sensor_msgs/msg/Image", typestore=ts)
        w.write(cl, 10, ts.serialize_ros1(_image_msg(ts, "ros1", 1.0, _image(0, 0)), "sensor_msgs/msg/Image"))
        small = ts.types["sensor_msgs/msg/Image"](header=_header(ts, "ros1", 1.0, "c"), height=H // 2, width=W,
                                                  encoding="rgb8", is_bigendian=0, step=W * 3,
                                                  data=_image(0, 1)[: H // 2].reshape(-1))
        w.write(cr, 10, ts.serialize_ros1(small, "sensor_msgs/msg/Image"))
    calib = tmp_path / "calib.yaml"
    calib.write_text(f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline_m: 0.2\nimage_width: {W}\nimage_height: {H}\n")
    with RosbagSequence(path, calib=calib) as seq, pytest.raises(InputError, match="differ in size"):
        seq[0]


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_cut_bags_only_raise_seedmap_errors(tmp_path, kind):
    """Bags cut at many points: either they still open and read, or a one-line SeedmapError - nothing else."""
    bag = write_bag(_bag_path(tmp_path, kind), kind, n=3)
    target = bag if bag.is_file() else next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    data = target.read_bytes()
    outcomes = set()
    for frac in np.linspace(0.05, 0.98, 12):
        target.write_bytes(data[: int(len(data) * frac)])
        try:
            with RosbagSequence(bag) as seq:
                for i in range(len(seq)):
                    seq[i]
            outcomes.add("ok")
        except SeedmapError as e:
            assert "\n" not in str(e)
            outcomes.add("error")
    assert "error" in outcomes
