"""Small ROS 1 / ROS 2 (sqlite3, mcap) stereo bags written with the rosbags library's own writers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

W, H = 48, 32
FX, CX, CY, BASE = 60.0, 23.5, 15.5, 0.12


def _image(i: int, cam: int) -> np.ndarray:
    rng = np.random.default_rng(100 * i + cam)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)


def _store(kind: str):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


def _header(ts, kind: str, t: float, frame: str):
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    sec = int(np.floor(t))
    stamp = Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))
    if kind == "ros1":
        return Header(seq=0, stamp=stamp, frame_id=frame)
    return Header(stamp=stamp, frame_id=frame)


def _image_msg(ts, kind, t, img_rgb, encoding="rgb8", compressed=False, frame="cam"):
    hdr = _header(ts, kind, t, frame)
    if compressed:
        ok, buf = cv2.imencode(".png", cv2.cvtColor(img_rgb, cv2.COLOR_RGB2BGR))
        assert ok
        return ts.types["sensor_msgs/msg/CompressedImage"](header=hdr, format="png", data=buf.reshape(-1))
    if encoding == "rgb8":
        data, step = img_rgb, W * 3
    elif encoding == "bgr8":
        data, step = img_rgb[:, :, ::-1], W * 3
    elif encoding == "mono8":
        data, step = img_rgb[:, :, 1], W
    else:
        raise ValueError(encoding)
    return ts.types["sensor_msgs/msg/Image"](header=hdr, height=H, width=W, encoding=encoding, is_bigendian=0,
                                             step=step, data=np.ascontiguousarray(data).reshape(-1))


def _info_msg(ts, kind, t, right: bool):
    P = np.array([[FX, 0, CX, -FX * BASE if right else 0.0], [0, FX, CY, 0], [0, 0, 1, 0]], float)
    K = P[:, :3].reshape(-1)
    fields = dict(header=_header(ts, kind, t, "cam"), height=H, width=W, distortion_model="plumb_bob",
                  binning_x=0, binning_y=0,
                  roi=ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                                    do_rectify=False))
    mats = dict(d=np.zeros(5), k=K, r=np.eye(3).reshape(-1), p=P.reshape(-1))
    if kind == "ros1":
        mats = {k.upper(): v for k, v in mats.items()}
    return ts.types["sensor_msgs/msg/CameraInfo"](**fields, **mats)


def write_bag(path: Path, kind: str, n: int = 5, encoding: str = "rgb8", compressed: bool = False,
              right_skip: tuple[int, ...] = (), jitter: float = 0.001, info: bool = True,
              topics=("/stereo/left/image_rect", "/stereo/right/image_rect"), empty_right: bool = False) -> Path:
    """A stereo bag of ``n`` frames at 10 Hz; right stamps offset by ``jitter`` s; ``right_skip`` frames missing."""
    ts = _store(kind)
    imgtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        ser = ts.serialize_cdr
    with writer:
        cl = writer.add_connection(topics[0], imgtype, typestore=ts)
        cr = writer.add_connection(topics[1], imgtype, typestore=ts)
        if info:
            il = writer.add_connection("/stereo/left/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
            ir = writer.add_connection("/stereo/right/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        for i in range(n):
            t = 100.0 + 0.1 * i
            ns = int(round(t * 1e9))
            msg = _image_msg(ts, kind, t, _image(i, 0), encoding, compressed)
            writer.write(cl, ns, ser(msg, imgtype))
            if info:
                writer.write(il, ns, ser(_info_msg(ts, kind, t, False), "sensor_msgs/msg/CameraInfo"))
                writer.write(ir, ns, ser(_info_msg(ts, kind, t, True), "sensor_msgs/msg/CameraInfo"))
            if i in right_skip or empty_right:
                continue
            msg = _image_msg(ts, kind, t + jitter, _image(i, 1), encoding, compressed)
            writer.write(cr, ns + int(jitter * 1e9) + 1000, ser(msg, imgtype))
    return path
