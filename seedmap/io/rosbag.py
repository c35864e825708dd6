"""ROS1 ``.bag`` and ROS2 bags (sqlite3 ``.db3``, ``.mcap``, or a bag folder with ``metadata.yaml``).

Read with ``rosbags`` (``rosbags.highlevel.AnyReader``): no ROS installation needed.

* Images: ``sensor_msgs/Image`` (``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8``, ``bayer_*8``) and
  ``sensor_msgs/CompressedImage`` (jpeg/png) on two topics, given or guessed (``*left*``/``*right*``,
  ``*cam0*``/``*cam1*``; rectified topics preferred). Grayscale/Bayer become RGB.
* Time sync: header stamps of the two topics are paired as mutual nearest neighbours within
  ``sync_tol_s``; unmatched images are dropped and counted in :attr:`warnings`.
* Calibration: a file given as ``calib=`` (any format of :mod:`seedmap.io.calibration`), else the
  ``sensor_msgs/CameraInfo`` of each camera (topic next to the image topic). With a rectified image topic
  (``*rect*``, or ``rectified=True``) the calibration is ``P`` of each camera; with raw images the loader
  rectifies with the camera_info's own ``K, D, R, P`` exactly as ROS ``image_proc`` does.

Frames load lazily: ``seq[i]`` seeks by bag time; ``for frame in seq`` makes one pass over the bag.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from seedmap.errors import InputError
from seedmap.io.calibration import StereoRig, _calib_from_P, _rig_from_rect, check_image_size, \
    load_rig, rectify, warn_implausible_baseline
from seedmap.io.common import LoaderWarnings, decode_image_bytes, to_rgb
from seedmap.io.registry import construct, register_loader
from seedmap.io.sync import match_stamps
from seedmap.progress import track
from seedmap.records import StereoFrame, Trajectory

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
BAG_SUFFIXES = (".bag", ".db3", ".mcap")

# ROS bayer_xxxx8 -> OpenCV code (OpenCV names the pattern by its second row; cv_bridge uses the same table).
_BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerBG2RGB,
    "bayer_bggr8": cv2.COLOR_BayerRG2RGB,
    "bayer_gbrg8": cv2.COLOR_BayerGR2RGB,
    "bayer_grbg8": cv2.COLOR_BayerGB2RGB,
}


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: name, message type, message count."""

    topic: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagSummary:
    path: Path
    topics: list[TopicSummary]
    start_s: float
    end_s: float
    message_count: int

    @property
    def duration_s(self) -> float:
        return max(0.0, self.end_s - self.start_s)


def is_bag(path: Path) -> bool:
    p = Path(path)
    if p.is_file():
        return p.suffix.lower() in BAG_SUFFIXES
    return p.is_dir() and (p / "metadata.yaml").is_file()


def _open_reader(path: Path):
    """An opened ``AnyReader`` or a one-line InputError (missing, truncated, unindexed, unknown format)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise InputError("bag not found", path)
    if path.is_file() and path.suffix.lower() not in BAG_SUFFIXES:
        raise InputError(f"unknown bag suffix {path.suffix!r} (expected .bag, .db3, .mcap or a bag folder)", path)
    ros1 = path.suffix.lower() == ".bag"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([path], default_typestore=store)
        reader.open()
    except Exception as e:  # rosbags raises several unrelated types on damaged input
        msg = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
        hint = "re-index it (rosbag reindex)" if ros1 else "re-record or repair it (ros2 bag reindex)"
        raise InputError(f"not a readable bag ({msg}); it may be truncated or damaged: {hint}", path) from None
    return reader


def bag_info(path: str | Path) -> BagSummary:
    """Topics, types and message counts of a bag (what ``seedmap bag-info`` prints)."""
    path = Path(path)
    reader = _open_reader(path)
    try:
        topics = [TopicSummary(name, str(info.msgtype), int(info.msgcount)) for name, info in reader.topics.items()]
        n = int(reader.message_count)
        start = reader.start_time * 1e-9 if n else 0.0
        end = reader.end_time * 1e-9 if n else 0.0
    except Exception as e:
        raise InputError(f"could not read the bag index ({type(e).__name__}: {str(e)[:120]})", path) from None
    finally:
        reader.close()
    return BagSummary(path, sorted(topics, key=lambda t: t.topic), start, end, n)


def _score_image_topic(topic: str) -> int:
    t = topic.lower()
    score = 0
    if "rect" in t:
        score += 4
    if "color" in t or "rgb" in t:
        score += 2
    if "depth" in t or "disparity" in t:
        score -= 20
    return score


def guess_stereo_topics(topics: dict[str, str]) -> tuple[str, str]:
    """``(left, right)`` image topics from ``{topic: msgtype}``; raises when no pair can be told apart."""
    images = [t for t, ty in topics.items() if ty in IMAGE_TYPES]
    pats = [(re.compile(r"left|cam0|/0/|_l\b|/l/", re.I), re.compile(r"right|cam1|/1/|_r\b|/r/", re.I))]
    for lp, rp in pats:
        left = [t for t in images if lp.search(t) and not rp.search(t)]
        right = [t for t in images if rp.search(t) and not lp.search(t)]
        if left and right:
            # prefer left/right topics that differ only in the camera word
            best = None
            for lt in left:
                for rt in right:
                    twin = lp.sub("#", lt) == rp.sub("#", rt)
                    key = (twin, _score_image_topic(lt) + _score_image_topic(rt), -len(lt))
                    if best is None or key > best[0]:
                        best = (key, lt, rt)
            assert best is not None
            return best[1], best[2]
    listing = ", ".join(images) if images else "none"
    raise InputError(f"cannot tell the left and right image topics apart (image topics: {listing}); "
                     "pass --set dataset.left_topic=... --set dataset.right_topic=... "
                     "(bag-info: --left-topic, --right-topic)")


def _info_topic_for(image_topic: str, infos: list[str]) -> str | None:
    if not infos:
        return None
    ns = image_topic.rsplit("/", 1)[0]
    if f"{ns}/camera_info" in infos:
        return f"{ns}/camera_info"

    def common(a: str, b: str) -> int:
        n = 0
        for x, y in zip(a, b):
            if x != y:
                break
            n += 1
        return n

    return max(infos, key=lambda t: common(t, image_topic))


def _stamp(msg) -> float:
    st = msg.header.stamp
    return float(st.sec) + float(st.nanosec) * 1e-9


def decode_ros_image(msg, where: str) -> tuple[np.ndarray, bool]:
    """A ``sensor_msgs/Image`` or ``CompressedImage`` -> ``(RGB uint8, was_grayscale)``."""
    if hasattr(msg, "format"):  # CompressedImage
        if "compresseddepth" in str(msg.format).lower():
            raise InputError("compressedDepth images are not camera images", where)
        return decode_image_bytes(np.asarray(msg.data, np.uint8), where)
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, np.uint8).reshape(-1)
    ch = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3, "8uc4": 4}
    ch.update({k: 1 for k in _BAYER})
    if enc not in ch:
        raise InputError(f"image encoding {msg.encoding!r} unsupported (seedmap reads 8-bit rgb8, bgr8, rgba8, "
                         "bgra8, mono8, bayer_*8 or CompressedImage)", where)
    c = ch[enc]
    if h <= 0 or w <= 0 or step < w * c or data.size < step * h:
        raise InputError(f"image message is inconsistent ({w}x{h}, step {step}, {data.size} bytes)", where)
    img = data[: step * h].reshape(h, step)[:, : w * c].reshape(h, w, c)
    if enc in _BAYER:
        return cv2.cvtColor(np.ascontiguousarray(img[:, :, 0]), _BAYER[enc]), False
    if c == 1:
        return to_rgb(img[:, :, 0]), True
    bgr = enc in ("bgr8", "bgra8", "8uc3", "8uc4")
    return to_rgb(np.ascontiguousarray(img), bgr=bgr), False


def _camera_info_matrices(msg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[int, int], str]:
    def f(name: str):
        return np.asarray(getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper()), float)

    K = f("k").reshape(3, 3)
    D = f("d").reshape(-1)
    R = f("r").reshape(3, 3)
    P = f("p").reshape(3, 4)
    model = str(msg.distortion_model).lower()
    return K, D, R, P, (int(msg.width), int(msg.height)), model


class RosbagSequence:
    """A stereo sequence inside a ROS1/ROS2 bag (see the module docstring)."""

    name = "rosbag"

    def __init__(self, path: str | Path, left_topic: str | None = None, right_topic: str | None = None,
                 calib: str | Path | None = None, right_calib: str | Path | None = None,
                 sync_tol_s: float = 0.01, rectified: bool | None = None, rectify_alpha: float = 0.0) -> None:
        self.path = Path(path)
        self.root = self.path
        self.warnings: list[str] = LoaderWarnings(self.path)
        self._gray_topics: set[str] = set()
        self._reader = _open_reader(self.path)
        try:
            self._init(left_topic, right_topic, calib, right_calib, sync_tol_s, rectified, rectify_alpha)
        except BaseException:
            self.close()
            raise

    # ---- setup ----
    def _init(self, left_topic, right_topic, calib, right_calib, sync_tol_s, rectified, alpha) -> None:
        reader = self._reader
        topics = {name: str(info.msgtype) for name, info in reader.topics.items()}
        if left_topic is None or right_topic is None:
            gl, gr = guess_stereo_topics(topics)
            left_topic = left_topic or gl
            right_topic = right_topic or gr
        for t in (left_topic, right_topic):
            if t not in topics:
                raise InputError(f"topic {t!r} not in the bag (topics: {', '.join(sorted(topics))})", self.path)
            if topics[t] not in IMAGE_TYPES:
                raise InputError(f"topic {t!r} is {topics[t]}, not an image topic", self.path)
        if left_topic == right_topic:
            raise InputError(f"left and right topic are the same ({left_topic})", self.path)
        self.left_topic, self.right_topic = left_topic, right_topic
        counts = {name: int(info.msgcount) for name, info in reader.topics.items()}
        for t in (left_topic, right_topic):
            if counts.get(t, 0) == 0:
                raise InputError(f"topic {t!r} has no messages (record the cameras, or pick other topics)", self.path)

        conns = [c for c in reader.connections if c.topic in (left_topic, right_topic)]
        infos = [t for t, ty in topics.items() if ty == INFO_TYPE]
        info_l = _info_topic_for(left_topic, infos) if calib is None else None
        info_r = _info_topic_for(right_topic, [t for t in infos if t != info_l]) if calib is None else None
        info_conns = [c for c in reader.connections if c.topic in (info_l, info_r)]

        # one pass over the headers: (stamp, bag time, occurrence at that bag time) per image
        entries: dict[str, list[tuple[float, int, int]]] = {left_topic: [], right_topic: []}
        self._conn = {}
        seen: dict[tuple[str, int], int] = {}
        info_msgs: dict[str, object] = {}
        total = counts[left_topic] + counts[right_topic]
        try:
            for conn, t_ns, raw in track(reader.messages(connections=conns + info_conns), "indexing bag", "msg",
                                         total=total + sum(counts.get(t, 0) for t in {info_l, info_r} if t),
                                         enabled=total >= 2000):
                if conn.topic in (info_l, info_r):
                    if conn.topic not in info_msgs:
                        info_msgs[conn.topic] = reader.deserialize(raw, conn.msgtype)
                    continue
                msg = reader.deserialize(raw, conn.msgtype)
                key = (conn.topic, t_ns)
                occ = seen.get(key, 0)
                seen[key] = occ + 1
                entries[conn.topic].append((_stamp(msg), int(t_ns), occ))
                self._conn[conn.topic] = conn
        except InputError:
            raise
        except Exception as e:
            raise InputError(f"bag is damaged or truncated while reading messages ({type(e).__name__}: "
                             f"{str(e)[:100]}); re-index or re-record it", self.path) from None
        stamps = {}
        for t in (left_topic, right_topic):
            e = sorted(entries[t])
            if not e:
                raise InputError(f"topic {t!r} has no readable messages", self.path)
            s = np.array([x[0] for x in e])
            dup = np.concatenate([[False], np.diff(s) <= 0])
            if dup.any():
                self.warnings.append(f"{t}: {int(dup.sum())} images with a repeated header stamp skipped")
                e = [x for x, d in zip(e, dup, strict=True) if not d]
                s = s[~dup]
            entries[t] = e
            stamps[t] = s
        il, ir, dropped = match_stamps(stamps[left_topic], stamps[right_topic], sync_tol_s)
        if len(il) == 0:
            raise InputError(f"no left/right images within {sync_tol_s * 1e3:g} ms of each other "
                             "(raise --set dataset.sync_tol_s=SECONDS, bag-info: --sync-tol; or check the topics)",
                             self.path)
        if dropped:
            self.warnings.append(f"{dropped} images without a stereo partner within {sync_tol_s * 1e3:g} ms dropped "
                                 f"({len(stamps[left_topic])} left, {len(stamps[right_topic])} right, "
                                 f"{len(il)} pairs)")
        self.dropped = dropped
        self._frames = [(entries[left_topic][i], entries[right_topic][j]) for i, j in zip(il, ir, strict=True)]
        self.timestamps = stamps[left_topic][il]

        if rectified is None:
            rectified = "rect" in left_topic.lower() and "rect" in right_topic.lower()
        self.images_rectified = bool(rectified)
        if calib is not None:
            rig = load_rig(calib, right=right_calib, image_size=self._first_size())
        else:
            rig = self._rig_from_camera_info(info_l, info_r, info_msgs)
            warn_implausible_baseline(rig, f"{self.path}:{info_r}")
        self.rig = rig
        self.calib, self.maps = rectify(rig, alpha=alpha)
        self.warnings.extend(rig.warnings)

    def _first_size(self) -> tuple[int, int]:
        left, _ = self._load(0)
        return (left.shape[1], left.shape[0])

    def _rig_from_camera_info(self, info_l, info_r, msgs) -> StereoRig:
        if info_l is None or info_r is None or info_l == info_r or info_l not in msgs or info_r not in msgs:
            raise InputError("no CameraInfo for both cameras in the bag: pass a calibration file "
                             "(--set dataset.calib=FILE)", self.path)
        K1, D1, R1, P1, s1, m1 = _camera_info_matrices(msgs[info_l])
        K2, D2, R2, P2, s2, m2 = _camera_info_matrices(msgs[info_r])
        where = Path(f"{self.path}:{info_r}")  # bag:topic (a topic is absolute: path / topic would drop the bag)
        if not np.any(P2[:, :3]) or not np.any(P1[:, :3]):
            raise InputError("CameraInfo has no projection matrix P (no stereo rectification): pass a calibration "
                             "file with extrinsics (--set dataset.calib=camchain.yaml)", where)
        if self.images_rectified:
            calib = _calib_from_P(P1, P2, s1, where)
            return StereoRig.from_calib(calib, source=where)
        model = "equidistant" if m1 in ("equidistant", "fisheye") else "radtan"
        if len(D1) == 0:
            D1 = np.zeros(5)
        if len(D2) == 0:
            D2 = np.zeros(5)
        return _rig_from_rect(K1, D1, R1, P1, K2, D2, R2, P2, s1, s2, model, where)

    # ---- frames ----
    @staticmethod
    def is_dataset(path: Path) -> bool:
        return is_bag(path)

    def __len__(self) -> int:
        return len(self._frames)

    def _fetch(self, topic: str, entry: tuple[float, int, int]):
        _, t_ns, occ = entry
        conn = self._conn[topic]
        k = 0
        try:
            for c, _, raw in self._reader.messages(connections=[conn], start=t_ns, stop=t_ns + 1):
                if k == occ:
                    return self._reader.deserialize(raw, c.msgtype)
                k += 1
        except Exception as e:
            raise InputError(f"could not read {topic} at bag time {t_ns} ns ({type(e).__name__}: {str(e)[:100]}); "
                             "the bag may be damaged", self.path) from None
        raise InputError(f"message of {topic} at bag time {t_ns} ns vanished (bag changed while open?)", self.path)

    def _decode(self, topic: str, msg) -> np.ndarray:
        img, gray = decode_ros_image(msg, f"{self.path}:{topic}")
        if gray and topic not in self._gray_topics:
            self._gray_topics.add(topic)
            self.warnings.append(f"{topic}: grayscale images converted to 3-channel RGB")
        return img

    def _load(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        le, re_ = self._frames[i]
        left = self._decode(self.left_topic, self._fetch(self.left_topic, le))
        right = self._decode(self.right_topic, self._fetch(self.right_topic, re_))
        return left, right

    def _finish(self, i: int, left: np.ndarray, right: np.ndarray) -> StereoFrame:
        where = f"{self.path}:{self.left_topic}"
        if left.shape != right.shape:
            raise InputError(f"left {left.shape[1]}x{left.shape[0]} and right {right.shape[1]}x{right.shape[0]} "
                             f"images differ in size at frame {i}", where)
        check_image_size(self.rig.left.size, left, where, self.rig.source)
        if self.maps is not None:
            left, right = self.maps.apply(left, right)
        return StereoFrame(index=i, timestamp=float(self.timestamps[i]), left=left, right=right)

    def __getitem__(self, i: int) -> StereoFrame:
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        left, right = self._load(int(i))
        return self._finish(int(i), left, right)

    def __iter__(self) -> Iterator[StereoFrame]:
        """All frames in order in one pass over the bag."""
        want: dict[tuple[str, int, int], tuple[int, int]] = {}
        for i, (le, re_) in enumerate(self._frames):
            want[(self.left_topic, le[1], le[2])] = (i, 0)
            want[(self.right_topic, re_[1], re_[2])] = (i, 1)
        pending: dict[int, list] = {}
        nxt = 0
        seen: dict[tuple[str, int], int] = {}
        conns = [self._conn[self.left_topic], self._conn[self.right_topic]]
        for conn, t_ns, raw in self._reader.messages(connections=conns):
            occ = seen.get((conn.topic, t_ns), 0)
            seen[(conn.topic, t_ns)] = occ + 1
            hit = want.get((conn.topic, int(t_ns), occ))
            if hit is None:
                continue
            i, side = hit
            slot = pending.setdefault(i, [None, None])
            slot[side] = self._decode(conn.topic, self._reader.deserialize(raw, conn.msgtype))
            while nxt in pending and pending[nxt][0] is not None and pending[nxt][1] is not None:
                left, right = pending.pop(nxt)
                yield self._finish(nxt, left, right)
                nxt += 1
        while nxt < len(self):  # anything out of bag order
            yield self[nxt]
            nxt += 1

    def gt_trajectory(self) -> Trajectory | None:
        """Bags carry no ground truth seedmap can trust without a frame convention: ``None``."""
        return None

    def close(self) -> None:
        r = getattr(self, "_reader", None)
        if r is not None:
            try:
                r.close()
            except Exception:
                pass
            self._reader = None

    def __enter__(self) -> RosbagSequence:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


register_loader("rosbag", is_bag, lambda p, **kw: construct(RosbagSequence, p, kw), order=20)
