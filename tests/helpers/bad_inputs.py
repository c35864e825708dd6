"""The bad-input matrix: small valid inputs made once, and a table of ways a user breaks them.

Only the public surface is used: the ``seedmap`` command line (run in-process through ``seedmap.cli.main``) and
the files it reads and writes. Valid inputs are made with seedmap's own commands once per test run
(:func:`make_assets`); every case copies what it needs into its own folder and breaks it. This module holds the
machinery, the dataset mutations and the dataset cases; ``bad_input_cases_safety`` (config, data loss, output
paths, options) and ``bad_input_cases_files`` (weights, training data, counts, reconstruct/count/eval inputs, bags,
paths) add the rest to :data:`CASES` when imported (:func:`all_cases`).
"""

from __future__ import annotations

import hashlib
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import yaml

# ------------------------------------------------------------------------------------------------
# running the command line in-process
# ------------------------------------------------------------------------------------------------


def run_main(argv: list) -> tuple[int | None, BaseException | None]:
    """(exit code, None) of ``seedmap ARGV``, or (None, exception) when ``main()`` raised something else."""
    from seedmap import cli

    old = sys.argv
    sys.argv = ["seedmap", *[str(a) for a in argv]]
    try:
        cli.main()
    except SystemExit as e:
        code = e.code
        return (0 if code is None else code if isinstance(code, int) else 1), None
    except BaseException as e:  # noqa: BLE001 - reported by the test
        return None, e
    finally:
        sys.argv = old
    return 0, None


# ------------------------------------------------------------------------------------------------
# valid inputs, made once
# ------------------------------------------------------------------------------------------------


@dataclass
class Assets:
    """Valid inputs made by seedmap itself (read only: cases copy them)."""

    root: Path
    range: Path  # simulated range with GT: 6 stereo pairs of 410x300 px
    scan: Path  # simulated 3-view arm scan of one panicle with GT (joints.csv, arm.yaml)
    recon: Path  # `seedmap reconstruct` result of the scan
    slam: Path  # `seedmap slam` result of the range
    det: Path  # `seedmap detect` result of the range
    bag: Path  # ROS1 stereo bag, 3 frames of 48x32 px with CameraInfo
    ros2: Path  # ROS2 (sqlite3) stereo bag folder, same content


def make_assets(root: Path) -> Assets:
    """Render, reconstruct, run SLAM and detect once (about 10 s CPU)."""
    rng = root / "range"
    scan = root / "scan"
    rec = root / "recon"
    slam = root / "slam"
    det = root / "det"
    steps = [
        ["simulate", "range", "--out", rng, "-q", "--length", "0.2", "--seed", "3", "--set", "camera.scale=0.1"],
        ["simulate", "panicle", "--out", scan, "-q", "--views", "3", "--seed", "3", "--set", "sim.camera.scale=0.12"],
        ["reconstruct", scan, "--out", rec, "-q", "--set", "detector_overrides=[gt.min_area_px=4]"],
        ["slam", rng, "--out", slam, "-q", "--detector", "gt"],  # the fast detector tracks no frame at 410 px
        ["detect", rng, "--out", det, "--detector", "fast"],
    ]
    for argv in steps:
        code, exc = run_main(argv)
        assert code == 0 and exc is None, f"making the matrix's valid inputs failed: seedmap {argv}: {code} {exc!r}"
    bag = write_bag(root / "stereo.bag", "ros1")
    ros2 = write_bag(root / "stereo_ros2", "sqlite3")
    return Assets(root, rng, scan, rec, slam, det, bag, ros2)


BAG_W, BAG_H, BAG_FX, BAG_BASE = 48, 32, 60.0, 0.12


def write_bag(path: Path, kind: str, n: int = 3) -> Path:
    """A small stereo bag (rectified images + CameraInfo) written with the ``rosbags`` library."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
        ser = ts.serialize_cdr
    T = ts.types

    def header(t: float):
        sec = int(np.floor(t))
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        if kind == "ros1":
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="cam")
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="cam")

    def info(t: float, right: bool):
        P = np.array([[BAG_FX, 0, 23.5, -BAG_FX * BAG_BASE if right else 0.0], [0, BAG_FX, 15.5, 0], [0, 0, 1, 0]])
        mats = dict(d=np.zeros(5), k=P[:, :3].reshape(-1), r=np.eye(3).reshape(-1), p=P.reshape(-1))
        if kind == "ros1":
            mats = {k.upper(): v for k, v in mats.items()}
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return T["sensor_msgs/msg/CameraInfo"](header=header(t), height=BAG_H, width=BAG_W,
                                               distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **mats)

    img_t, info_t = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"
    with writer:
        cons = [writer.add_connection(f"/stereo/{s}/image_rect", img_t, typestore=ts) for s in ("left", "right")]
        infos = [writer.add_connection(f"/stereo/{s}/camera_info", info_t, typestore=ts) for s in ("left", "right")]
        for i in range(n):
            t = 100.0 + 0.1 * i
            ns = int(round(t * 1e9))
            for cam in (0, 1):
                img = np.random.default_rng(100 * i + cam).integers(0, 256, (BAG_H, BAG_W, 3), dtype=np.uint8)
                msg = T[img_t](header=header(t), height=BAG_H, width=BAG_W, encoding="rgb8", is_bigendian=0,
                               step=BAG_W * 3, data=img.reshape(-1))
                writer.write(cons[cam], ns + cam * 1000, ser(msg, img_t))
                writer.write(infos[cam], ns, ser(info(t, cam == 1), info_t))
    return path


# ------------------------------------------------------------------------------------------------
# checksums
# ------------------------------------------------------------------------------------------------


def tree_digest(path: Path) -> dict[str, str]:
    """SHA-256 of every file under ``path`` (a file: itself), by relative path; folders and links are listed too."""
    path = Path(path)
    if path.is_symlink():
        return {".": "link:" + str(path.readlink())}
    if path.is_file():
        return {".": hashlib.sha256(path.read_bytes()).hexdigest()}
    if not path.exists():
        return {}
    out = {".": "dir"}
    for p in sorted(path.rglob("*")):
        rel = str(p.relative_to(path))
        if p.is_symlink():
            out[rel] = "link:" + str(p.readlink())
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        else:
            out[rel] = "dir"
    return out


# ------------------------------------------------------------------------------------------------
# the table
# ------------------------------------------------------------------------------------------------


@dataclass
class Setup:
    """One case, built: the command line, what it must not touch and what its error line must name."""

    argv: list
    inputs: list[Path]  # files/folders whose content must not change (a pre-existing --out included)
    out: Path | None  # the output: absent afterwards (or, when it existed, unchanged: list it in inputs too)
    names: tuple[str, ...]  # the error line contains at least one of these (the offending file or option)
    fsize: int | None = None  # RLIMIT_FSIZE during the run (bytes): the disk is "full" past it
    record_ok: bool = False  # a folder recording which runs failed (benchmark, batch) may be written, complete
    #: "error": exit 2 and one error line; "warning": the run goes on (exit 0, its output written) but says so
    #: in a ``warning: `` line naming the file (GT that does not overlap the timestamps: the issue asks a warning)
    expect: str = "error"
    canary: Path | None = None  # a file a malicious YAML tag would have created: must not exist


@dataclass
class Case:
    id: str
    group: str
    build: Callable[[Assets, Path], Setup]


CASES: list[Case] = []


def case(id: str, group: str):
    def deco(fn: Callable[[Assets, Path], Setup]) -> Callable[[Assets, Path], Setup]:
        CASES.append(Case(id, group, fn))
        return fn

    return deco


def add(id: str, group: str, fn: Callable[[Assets, Path], Setup]) -> None:
    CASES.append(Case(id, group, fn))


# ---- building blocks -----------------------------------------------------------------------------


def copy_range(a: Assets, t: Path, name: str = "ds", gt: bool = True) -> Path:
    """A copy of the simulated range (``gt=False``: a user's own recording, no ground truth and no output marker)."""
    dst = t / name
    shutil.copytree(a.range, dst, ignore=None if gt else shutil.ignore_patterns("gt", ".seedmap-output.json"))
    return dst


def copy_of(src: Path, dst: Path) -> Path:
    """A copy of a file or folder (a result's report.html, a few MB nothing reads back, is left out)."""
    if src.is_dir():
        shutil.copytree(src, dst, ignore=shutil.ignore_patterns("report.html"))
    else:
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
    return dst


def mine(t: Path, name: str = "mine") -> Path:
    """A folder of the user's own files (nothing seedmap wrote)."""
    d = t / name
    (d / "sub").mkdir(parents=True)
    (d / "thesis.tex").write_text("years of work\n")
    (d / "summary.md").write_text("# my own summary\n")
    (d / "results.csv").write_text("a,b\n1,2\n")
    (d / "sub" / "notes.txt").write_text("field notes\n")
    return d


def userfile(t: Path, name: str, text: str = "my own data\n") -> Path:
    p = t / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text)
    return p


def recon_set(a: Assets, t: Path) -> list[Path]:
    """Three copies of the reconstruction: the fewest a one-parameter count calibration fits (``--features ""``)."""
    return [copy_of(a.recon, t / "recs" / f"rec{i}") for i in (1, 2, 3)]


GOOD_COUNTS = "result,count\nrec1,100\nrec2,110\nrec3,120\n"


BINARY = bytes(range(256)) * 4 + b"\xff\xfe\x00\x00garbage"
PWN_TAG = "!!python/object/apply:os.system ['touch {canary}']\n"


def utf16(text: str) -> bytes:
    return text.encode("utf-16")


def png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


def first_float_leaf(config_yaml: Path) -> str:
    """The dotted key of the first float value in a config.yaml seedmap wrote (robust to renamed fields)."""
    data = yaml.safe_load(config_yaml.read_text())

    def walk(node, prefix):
        if isinstance(node, dict):
            for k, v in node.items():
                if isinstance(v, float):
                    return prefix + str(k)
                if isinstance(v, dict) and (r := walk(v, prefix + str(k) + ".")):
                    return r
        return None

    key = walk(data, "")
    assert key, f"no float field in {config_yaml}"
    return key


# ---- dataset mutations (each returns the names the error line should carry) ---------------------------------


def _img(ds: Path, cam: str, i: int) -> Path:
    return ds / cam / f"{i:06d}.png"


def m_img_corrupt(ds):
    p = _img(ds, "left", 1)
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 100)
    return (str(p), p.name)


def m_img_truncated(ds):
    p = _img(ds, "left", 1)
    b = p.read_bytes()
    p.write_bytes(b[: len(b) // 3])
    return (str(p), p.name)


def m_img_empty(ds):
    p = _img(ds, "right", 1)
    p.write_bytes(b"")
    return (str(p), p.name)


def m_img_text(ds):
    p = _img(ds, "left", 0)
    p.write_text("this is not an image\n")
    return (str(p), p.name)


def m_img_gray(ds):
    p = _img(ds, "left", 1)
    p.write_bytes(png(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)))
    return (str(p), p.name)


def m_img_16bit(ds):
    p = _img(ds, "right", 0)
    p.write_bytes(png(cv2.imread(str(p)).astype(np.uint16) * 257))
    return (str(p), p.name)


def m_img_lr_size(ds):
    p = _img(ds, "right", 1)
    p.write_bytes(png(cv2.resize(cv2.imread(str(p)), (205, 150))))
    return (str(p), p.name, str(_img(ds, "left", 1)))


def m_img_calib_size(ds):
    names = []
    for cam in ("left", "right"):
        p = _img(ds, cam, 0)
        p.write_bytes(png(cv2.resize(cv2.imread(str(p)), (205, 150))))
        names += [str(p), p.name]
    return (*names, "calib.yaml")


def m_img_jpeg(ds):
    p = _img(ds, "left", 2)
    ok, buf = cv2.imencode(".jpg", cv2.imread(str(p)))
    p.with_suffix(".jpg").write_bytes(buf.tobytes())
    p.unlink()
    return (str(p), p.name, "000002.jpg")


def m_missing_left(ds):
    p = _img(ds, "left", 3)
    p.unlink()
    return (str(p), p.name)


def m_missing_right(ds):
    p = _img(ds, "right", 2)
    p.unlink()
    return (str(p), p.name)


def m_extra_frames(ds):  # more images than timestamps: frames silently dropped
    for cam in ("left", "right"):
        shutil.copy(_img(ds, cam, 5), _img(ds, cam, 6))
    return (str(ds / "times.txt"), "times.txt")


def _times(ds: Path, lines: list[str] | bytes) -> tuple[str, ...]:
    p = ds / "times.txt"
    if isinstance(lines, bytes):
        p.write_bytes(lines)
    else:
        p.write_text("".join(x + "\n" for x in lines))
    return (str(p), "times.txt")


def _t(ds: Path) -> list[str]:
    return (ds / "times.txt").read_text().split()


def m_times_short(ds):
    return _times(ds, _t(ds)[:-1])


def m_times_long(ds):  # more timestamps than images: the first missing image may be named instead
    return (*_times(ds, _t(ds) + ["9.0"]), "000006.png")


def m_times_nan(ds):
    t = _t(ds)
    t[2] = "nan"
    return _times(ds, t)


def m_times_inf(ds):
    t = _t(ds)
    t[-1] = "inf"
    return _times(ds, t)


def m_times_text(ds):
    t = _t(ds)
    t[1] = "zero point two"
    return _times(ds, t)


def m_times_empty(ds):
    return _times(ds, b"")


def m_times_decreasing(ds):
    return _times(ds, list(reversed(_t(ds))))


def m_times_duplicate(ds):
    t = _t(ds)
    t[2] = t[1]
    return _times(ds, t)


def m_times_binary(ds):
    return _times(ds, BINARY)


def m_times_utf16(ds):
    return _times(ds, utf16((ds / "times.txt").read_text()))


def m_times_gt_offset(ds):  # timestamps of another clock: none matches a GT pose
    return _times(ds, [f"{100.0 + float(x):.6f}" for x in _t(ds)])


def _calib(ds: Path, data: bytes | dict | str) -> tuple[str, ...]:
    p = ds / "calib.yaml"
    if isinstance(data, dict):
        d = yaml.safe_load(p.read_text())
        for k, v in data.items():
            if v is None:
                d.pop(k)
            else:
                d[k] = v
        p.write_text(yaml.safe_dump(d, sort_keys=False))
    elif isinstance(data, bytes):
        p.write_bytes(data)
    else:
        p.write_text(data)
    return (str(p), "calib.yaml")


def m_calib_binary(ds):
    return _calib(ds, BINARY)


def m_calib_utf16(ds):
    return _calib(ds, utf16((ds / "calib.yaml").read_text()))


def m_calib_empty(ds):
    return _calib(ds, b"")


def m_calib_list(ds):
    return _calib(ds, "- 1\n- 2\n")


def m_calib_syntax(ds):
    return _calib(ds, "fx: [1, 2\nfy: {\n")


def m_calib_baseline_zero(ds):
    return _calib(ds, {"baseline_m": 0.0})


def m_calib_baseline_negative(ds):
    return _calib(ds, {"baseline_m": -0.11})


def m_calib_fx_nan(ds):
    return _calib(ds, {"fx": float("nan")})


def m_calib_fx_inf(ds):
    return _calib(ds, {"fx": float("inf")})


def m_calib_fx_text(ds):
    return _calib(ds, {"fx": "two hundred"})


def m_calib_fx_missing(ds):
    return _calib(ds, {"fx": None})


def m_calib_width_zero(ds):
    return _calib(ds, {"image_width": 0})


def m_calib_cx_outside(ds):
    return _calib(ds, {"cx": -5000.0})


def m_swapped(ds):
    (ds / "left").rename(ds / "tmp")
    (ds / "right").rename(ds / "left")
    (ds / "tmp").rename(ds / "right")
    return (str(ds), "swap", "left/", "right/")


def m_no_right(ds):
    shutil.rmtree(ds / "right")
    return (str(ds / "right"), "right/", str(ds))


def m_no_frames(ds):
    for cam in ("left", "right"):
        for p in (ds / cam).glob("*.png"):
            p.unlink()
    return (str(ds), "left", "000000.png")


MUTATIONS: dict[str, Callable[[Path], tuple[str, ...]]] = {
    "img-corrupt": m_img_corrupt, "img-truncated": m_img_truncated, "img-empty": m_img_empty,
    "img-text": m_img_text, "img-grayscale": m_img_gray, "img-16bit": m_img_16bit, "img-lr-size": m_img_lr_size,
    "img-calib-size": m_img_calib_size, "img-jpeg-in-png-layout": m_img_jpeg, "frame-missing-left": m_missing_left,
    "frame-missing-right": m_missing_right, "frames-more-than-times": m_extra_frames,
    "times-shorter": m_times_short, "times-longer": m_times_long, "times-nan": m_times_nan,
    "times-inf": m_times_inf, "times-text": m_times_text, "times-empty": m_times_empty,
    "times-decreasing": m_times_decreasing, "times-duplicate": m_times_duplicate, "times-binary": m_times_binary,
    "times-utf16": m_times_utf16, "times-not-matching-gt": m_times_gt_offset,
    "calib-binary": m_calib_binary, "calib-utf16": m_calib_utf16, "calib-empty": m_calib_empty,
    "calib-list": m_calib_list, "calib-yaml-syntax": m_calib_syntax, "calib-baseline-zero": m_calib_baseline_zero,
    "calib-baseline-negative": m_calib_baseline_negative, "calib-fx-nan": m_calib_fx_nan,
    "calib-fx-inf": m_calib_fx_inf, "calib-fx-text": m_calib_fx_text, "calib-fx-missing": m_calib_fx_missing,
    "calib-width-zero": m_calib_width_zero, "calib-cx-outside-image": m_calib_cx_outside,
    "swapped-left-right": m_swapped, "no-right-folder": m_no_right, "no-frames": m_no_frames,
}


def dataset_case(cmd: str, mut: str) -> Callable[[Assets, Path], Setup]:
    """``cmd`` run on a copy of the simulated range broken by mutation ``mut``."""

    def build(a: Assets, t: Path) -> Setup:
        ds = copy_range(a, t)
        names = MUTATIONS[mut](ds)
        out = t / "out"
        argv = {
            "slam": ["slam", ds, "--out", out, "-q", "--detector", "gt"],  # fast tracks no frame at 410 px
            "detect": ["detect", ds, "--out", out, "--detector", "fast"],
            "eval-associate": ["eval", "associate", ds, "--out", out],
            "benchmark": ["benchmark", "run", ds, "--out", out, "--methods", "orb", "--workers", "1"],
        }[cmd]
        expect = "warning" if mut == "times-not-matching-gt" else "error"
        if expect == "warning":
            names = (*names, "poses_tum.txt", "ground truth", "GT")
        return Setup(argv, [ds], out, names, record_ok=cmd == "benchmark", expect=expect)

    return build


SLAM_MUTATIONS = list(MUTATIONS)
DETECT_MUTATIONS = ["img-corrupt", "img-truncated", "img-empty", "img-grayscale", "img-16bit", "img-lr-size",
                    "img-calib-size", "frame-missing-right", "frames-more-than-times", "times-shorter", "times-nan",
                    "times-binary", "calib-binary", "calib-utf16", "calib-fx-nan", "calib-width-zero",
                    "no-right-folder", "no-frames"]
ASSOC_MUTATIONS = ["img-corrupt", "times-nan", "times-shorter", "calib-utf16", "calib-baseline-zero",
                   "swapped-left-right"]
BENCH_MUTATIONS = ["times-nan", "calib-binary", "calib-fx-nan"]

for _m in SLAM_MUTATIONS:
    add(f"slam-{_m}", "dataset", dataset_case("slam", _m))
for _m in DETECT_MUTATIONS:
    add(f"detect-{_m}", "dataset", dataset_case("detect", _m))
for _m in ASSOC_MUTATIONS:
    add(f"eval-associate-{_m}", "dataset", dataset_case("eval-associate", _m))
for _m in BENCH_MUTATIONS:
    add(f"benchmark-run-{_m}", "dataset", dataset_case("benchmark", _m))


def all_cases() -> list[Case]:
    """Every case of the matrix (importing the case modules registers theirs)."""
    import helpers.bad_input_cases_files  # noqa: F401
    import helpers.bad_input_cases_safety  # noqa: F401

    return list(CASES)
