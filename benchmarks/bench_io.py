"""Loader speed: what rectification at load and bag access cost, as ratios to a baseline measured in the same run.

* ``rectify_overhead``: time per frame of :class:`StereoFolder` on an unrectified 752x480 rig (decode + remap)
  divided by decoding the same two PNGs alone.
* ``bag_random_over_stream``: time per frame of ``seq[i]`` on a ROS1 bag divided by one streaming pass
  (``for frame in seq``).

Writes JSON (``--out``, default ``benchmarks/results/bench_io.json``). Usage: ``python benchmarks/bench_io.py [--frames N]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


def _timeit(fn, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _camchain(path: Path, w: int, h: int) -> None:
    import yaml

    cam = {"camera_model": "pinhole", "intrinsics": [458.6, 457.3, 367.2, 248.4], "distortion_model": "radtan",
           "distortion_coeffs": [-0.28, 0.07, 2e-4, 2e-5], "resolution": [w, h]}
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.003, -0.01, 0.002]))[0]
    T[:3, 3] = [-0.11, 0.0004, -0.0009]
    path.write_text(yaml.safe_dump({"cam0": cam, "cam1": {**cam, "T_cn_cnm1": T.tolist()}}))


def bench_folder(root: Path, n: int) -> dict:
    from seedmap.io.common import read_image_rgb
    from seedmap.io.folder import StereoFolder

    w, h = 752, 480
    rng = np.random.default_rng(0)
    for cam in ("left", "right"):
        (root / cam).mkdir(parents=True)
        for i in range(n):
            img = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), (0, 0), 2)
            cv2.imwrite(str(root / cam / f"{i:06d}.png"), img)
    _camchain(root / "camchain.yaml", w, h)
    seq = StereoFolder(root)

    def decode_only():
        for lp, rp in seq._pairs:
            read_image_rgb(lp)
            read_image_rgb(rp)

    def load_rectified():
        for i in range(len(seq)):
            seq[i]

    t_dec = _timeit(decode_only) / n
    t_rect = _timeit(load_rectified) / n
    return {"frames": n, "size": [w, h], "decode_ms": 1e3 * t_dec, "load_rectified_ms": 1e3 * t_rect,
            "rectify_overhead": t_rect / t_dec}


def bench_bag(root: Path, n: int) -> dict:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from seedmap.io.rosbag import RosbagSequence

    ts = get_typestore(Stores.ROS1_NOETIC)
    Image, Header, Time = (ts.types[k] for k in ("sensor_msgs/msg/Image", "std_msgs/msg/Header",
                                                  "builtin_interfaces/msg/Time"))
    w, h = 640, 480
    rng = np.random.default_rng(1)
    path = root / "bench.bag"
    with Writer(path) as wr:
        conns = [wr.add_connection(t, "sensor_msgs/msg/Image", typestore=ts) for t in ("/left/image_rect",
                                                                                      "/right/image_rect")]
        for i in range(n):
            for c in conns:
                img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
                msg = Image(header=Header(seq=i, stamp=Time(sec=100 + i, nanosec=0), frame_id="c"), height=h, width=w,
                            encoding="rgb8", is_bigendian=0, step=3 * w, data=img.reshape(-1))
                wr.write(c, (100 + i) * 10**9, ts.serialize_ros1(msg, "sensor_msgs/msg/Image"))
    calib = root / "calib.yaml"
    calib.write_text(f"fx: 500.0\nfy: 500.0\ncx: 319.5\ncy: 239.5\nbaseline_m: 0.11\nimage_width: {w}\n"
                     f"image_height: {h}\n")
    t0 = time.perf_counter()
    seq = RosbagSequence(path, calib=calib)
    t_open = time.perf_counter() - t0

    def random_access():
        for i in range(len(seq)):
            seq[i]

    def stream():
        for _ in seq:
            pass

    t_rand = _timeit(random_access) / n
    t_stream = _timeit(stream) / n
    seq.close()
    return {"frames": n, "size": [w, h], "open_s": t_open, "random_ms": 1e3 * t_rand, "stream_ms": 1e3 * t_stream,
            "bag_random_over_stream": t_rand / t_stream}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/bench_io.json"))
    args = ap.parse_args()
    from seedmap.io.atomic import atomic_write_text

    with tempfile.TemporaryDirectory() as tmp:
        res = {"folder": bench_folder(Path(tmp) / "folder", args.frames),
               "rosbag": bench_bag(Path(tmp), args.frames)}
    atomic_write_text(args.out, json.dumps(res, indent=2) + "\n")
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
