"""The bad-input matrix: small valid inputs made once, and a table of ways a user breaks them.

Only the public surface is used: the ``seedmap`` command line (run in-process through ``seedmap.cli.main``) and
the files it reads and writes. Valid inputs are made with seedmap's own commands once per test run
(:func:`make_assets`); every case copies what it needs into its own folder and breaks it (:data:`CASES`).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
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
        ["slam", rng, "--out", slam, "-q"],
        ["detect", rng, "--out", det, "--detector", "fast-classic"],
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
    """A copy of the simulated range (``gt=False``: a user's own recording, no ground truth)."""
    dst = t / name
    shutil.copytree(a.range, dst, ignore=None if gt else shutil.ignore_patterns("gt"))
    return dst


def copy_of(src: Path, dst: Path) -> Path:
    if src.is_dir():
        shutil.copytree(src, dst)
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


def m_times_long(ds):
    return _times(ds, _t(ds) + ["9.0"])


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
            "slam": ["slam", ds, "--out", out, "-q"],
            "detect": ["detect", ds, "--out", out, "--detector", "fast-classic"],
            "eval-associate": ["eval", "associate", ds, "--out", out],
            "benchmark": ["benchmark", "run", ds, "--out", out, "--methods", "orb", "--workers", "1"],
        }[cmd]
        return Setup(argv, [ds], out, names, record_ok=cmd == "benchmark")

    return build


SLAM_MUTATIONS = list(MUTATIONS)
DETECT_MUTATIONS = ["img-corrupt", "img-truncated", "img-empty", "img-grayscale", "img-16bit", "img-lr-size",
                    "img-calib-size", "frame-missing-right", "frames-more-than-times", "times-shorter", "times-nan",
                    "times-binary", "calib-binary", "calib-utf16", "calib-fx-nan", "calib-width-zero",
                    "no-right-folder", "no-frames"]
ASSOC_MUTATIONS = ["img-corrupt", "times-nan", "times-not-matching-gt", "calib-utf16", "calib-baseline-zero",
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


# ---- --config / --set on every command that takes them -------------------------------------------------------


def _cmd_argv(a: Assets, t: Path, cmd: str) -> tuple[list, list[Path], Path | None, str]:
    """(argv without config options, inputs, out, the config.yaml whose first float field is broken)."""
    out = t / "out"
    if cmd == "simulate-range":
        return (["simulate", "range", "--out", out, "-q", "--length", "0.2", "--set", "camera.scale=0.1"], [], out,
                a.range / "gt" / "config.yaml")
    if cmd == "simulate-panicle":
        return (["simulate", "panicle", "--out", out, "-q", "--views", "3", "--set", "sim.camera.scale=0.12"], [],
                out, a.scan / "gt" / "scan.yaml")
    if cmd == "detect":
        ds = copy_range(a, t)
        return ["detect", ds, "--out", out, "--detector", "fast-classic"], [ds], out, a.det / "config.yaml"
    if cmd == "slam":
        ds = copy_range(a, t)
        return ["slam", ds, "--out", out, "-q"], [ds], out, a.slam / "config.yaml"
    if cmd == "eval-associate":
        ds = copy_range(a, t)
        return ["eval", "associate", ds, "--out", out], [ds], out, a.slam / "config.yaml"
    if cmd == "reconstruct":
        scan = copy_of(a.scan, t / "scan")
        return ["reconstruct", scan, "--out", out, "-q"], [scan], out, a.recon / "config.yaml"
    if cmd == "count":
        rec = copy_of(a.recon, t / "rec")
        return ["count", rec, "--out", out], [rec], out, a.recon / "config.yaml"
    if cmd == "benchmark-run":
        ds = copy_range(a, t)
        return (["benchmark", "run", ds, "--out", out, "--methods", "orb", "--workers", "1"], [ds], out,
                None)
    if cmd == "batch":
        field = t / "field"
        copy_range(a, field, "r1")
        return ["batch", field, "--out", out, "-q"], [field], out, a.slam / "config.yaml"
    raise KeyError(cmd)


CONFIG_COMMANDS = ["simulate-range", "simulate-panicle", "detect", "slam", "eval-associate", "reconstruct", "count",
                   "benchmark-run", "batch"]


def config_case(cmd: str, kind: str) -> Callable[[Assets, Path], Setup]:
    def build(a: Assets, t: Path) -> Setup:
        argv, inputs, out, cfg_yaml = _cmd_argv(a, t, cmd)
        key = first_float_leaf(cfg_yaml) if cfg_yaml is not None else "workers"
        cfg = t / "my_config.yaml"
        canary = None
        if kind == "config-binary":
            cfg.write_bytes(BINARY)
        elif kind == "config-utf16":
            cfg.write_bytes(utf16(f"{key.split('.')[0]}: 1\n"))
        elif kind == "config-list":
            cfg.write_text("- a\n- b\n")
        elif kind == "config-yaml-syntax":
            cfg.write_text("seed: [1, 2\n")
        elif kind == "config-python-tag":
            canary = t / "PWNED"
            cfg.write_text("seed: " + PWN_TAG.format(canary=canary))
        elif kind == "config-unknown-key":
            cfg.write_text("no_such_key_xyz: 1\n")
        if kind.startswith("config-"):
            if kind == "config-missing":
                cfg = t / "no_such_config.yaml"
            else:
                inputs = [*inputs, cfg]
            return Setup([*argv, "--config", cfg], inputs, out, (str(cfg), cfg.name), canary=canary)
        value = {"set-nan": "nan", "set-inf": "inf", "set-text": "abc", "set-unknown-key": "1"}.get(kind)
        if kind == "set-unknown-key":
            key = "no_such_key_xyz"
        if kind == "set-no-equals":
            item = key
        else:
            item = f"{key}={value}"
        return Setup([*argv, "--set", item], inputs, out, (key, "--set"))

    return build


CONFIG_KINDS = ["config-binary", "config-utf16", "config-missing", "config-list", "config-yaml-syntax",
                "config-python-tag", "config-unknown-key", "set-nan", "set-inf", "set-text", "set-unknown-key",
                "set-no-equals"]
for _c in CONFIG_COMMANDS:
    for _k in CONFIG_KINDS:
        add(f"{_c}-{_k}", "config", config_case(_c, _k))


@case("slam-set-stereo_max_dy_px-nan", "config")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["slam", ds, "--out", t / "out", "-q", "--set", "gates.stereo_max_dy_px=nan"], [ds], t / "out",
                 ("gates.stereo_max_dy_px",))


# ---- never lose a user's data ----------------------------------------------------------------------------------


def _slam(ds: Path, out: Path, *extra) -> list:
    return ["slam", ds, "--out", out, "-q", *extra]


@case("overwrite-slam-out-user-folder", "data-loss")
def _(a, t):
    ds, m = copy_range(a, t), mine(t)
    return Setup(_slam(ds, m, "--overwrite"), [ds, m], m, (str(m),))


@case("overwrite-slam-out-user-folder-via-symlink", "data-loss")
def _(a, t):
    ds, m = copy_range(a, t), mine(t)
    link = t / "link"
    link.symlink_to(m, target_is_directory=True)
    return Setup(_slam(ds, link, "--overwrite"), [ds, m, link], link, (str(link), str(m)))


@case("overwrite-simulate-range-out-user-folder", "data-loss")
def _(a, t):
    m = mine(t)
    return Setup(["simulate", "range", "--out", m, "-q", "--length", "0.2", "--set", "camera.scale=0.1",
                  "--overwrite"], [m], m, (str(m),))


@case("overwrite-simulate-panicle-out-user-folder", "data-loss")
def _(a, t):
    m = mine(t)
    return Setup(["simulate", "panicle", "--out", m, "-q", "--views", "3", "--set", "sim.camera.scale=0.12",
                  "--overwrite"], [m], m, (str(m),))


@case("overwrite-simulate-range-out-recorded-dataset", "data-loss")
def _(a, t):
    rec = copy_range(a, t, "rec", gt=False)
    return Setup(["simulate", "range", "--out", rec, "-q", "--length", "0.2", "--set", "camera.scale=0.1",
                  "--overwrite"], [rec], rec, (str(rec),))


@case("overwrite-detect-out-user-folder", "data-loss")
def _(a, t):
    ds, m = copy_range(a, t), mine(t)
    return Setup(["detect", ds, "--out", m, "--detector", "fast-classic", "--overwrite"], [ds, m], m, (str(m),))


@case("overwrite-reconstruct-out-user-folder", "data-loss")
def _(a, t):
    scan, m = copy_of(a.scan, t / "scan"), mine(t)
    return Setup(["reconstruct", scan, "--out", m, "-q", "--overwrite"], [scan, m], m, (str(m),))


@case("overwrite-count-out-user-folder", "data-loss")
def _(a, t):
    rec, m = copy_of(a.recon, t / "rec"), mine(t)
    return Setup(["count", rec, "--out", m, "--overwrite"], [rec, m], m, (str(m),))


@case("overwrite-slam-out-is-input-dataset", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(_slam(ds, ds, "--overwrite"), [ds], ds, (str(ds),))


@case("overwrite-detect-out-is-input-dataset", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["detect", ds, "--out", ds, "--detector", "fast-classic", "--overwrite"], [ds], ds, (str(ds),))


@case("overwrite-reconstruct-out-is-input-scan", "data-loss")
def _(a, t):
    scan = copy_of(a.scan, t / "scan")
    return Setup(["reconstruct", scan, "--out", scan, "-q", "--overwrite"], [scan], scan, (str(scan),))


@case("overwrite-slam-out-is-input-left", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(_slam(ds, ds / "left", "--overwrite"), [ds], ds / "left", (str(ds / "left"), str(ds)))


@case("overwrite-slam-out-is-input-gt", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(_slam(ds, ds / "gt", "--overwrite"), [ds], ds / "gt", (str(ds / "gt"), str(ds)))


@case("overwrite-detect-out-is-input-gt-masks", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    out = ds / "gt" / "masks"
    return Setup(["detect", ds, "--out", out, "--detector", "fast-classic", "--overwrite"], [ds], out,
                 (str(out), str(ds)))


@case("overwrite-slam-out-contains-input", "data-loss")
def _(a, t):
    parent = t / "P"
    ds = copy_range(a, parent, "r1")
    (parent / "notes.txt").write_text("plot notes\n")
    return Setup(_slam(ds, parent, "--overwrite"), [parent], parent, (str(parent), str(ds)))


@case("overwrite-slam-out-contains-recorded-input", "data-loss")
def _(a, t):
    parent = t / "P"
    ds = copy_range(a, parent, "r1", gt=False)
    return Setup(_slam(ds, parent, "--overwrite", "--matcher", "orb"), [parent], parent, (str(parent), str(ds)))


@case("overwrite-slam-out-is-left-of-recorded-dataset", "data-loss")
def _(a, t):
    ds = copy_range(a, t, "rec", gt=False)
    return Setup(_slam(ds, ds / "left", "--overwrite", "--matcher", "orb"), [ds], ds / "left",
                 (str(ds / "left"), str(ds)))


@case("overwrite-count-out-is-its-reconstruction", "data-loss")
def _(a, t):
    rec = copy_of(a.recon, t / "rec")
    return Setup(["count", rec, "--out", rec, "--overwrite"], [rec], rec, (str(rec),))


@case("overwrite-count-out-is-a-slam-result", "data-loss")
def _(a, t):
    rec, res = copy_of(a.recon, t / "rec"), copy_of(a.slam, t / "slamres")
    return Setup(["count", rec, "--out", res, "--overwrite"], [rec, res], res, (str(res),))


@case("overwrite-slam-out-is-a-reconstruction", "data-loss")
def _(a, t):
    ds, rec = copy_range(a, t), copy_of(a.recon, t / "rec")
    return Setup(_slam(ds, rec, "--overwrite"), [ds, rec], rec, (str(rec),))


@case("overwrite-detect-out-is-a-slam-result", "data-loss")
def _(a, t):
    ds, res = copy_range(a, t), copy_of(a.slam, t / "slamres")
    return Setup(["detect", ds, "--out", res, "--detector", "fast-classic", "--overwrite"], [ds, res], res,
                 (str(res),))


@case("rerun-file-is-input-calib", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(_slam(ds, t / "out", "--rerun", ds / "calib.yaml"), [ds], t / "out", (str(ds / "calib.yaml"),))


@case("rerun-file-is-existing-user-file", "data-loss")
def _(a, t):
    ds, f = copy_range(a, t), userfile(t, "notes.rrd")
    return Setup(_slam(ds, t / "out", "--rerun", f), [ds, f], t / "out", (str(f),))


@case("rerun-file-is-existing-user-file-with-overwrite", "data-loss")
def _(a, t):
    ds, f = copy_range(a, t), userfile(t, "notes.txt")
    return Setup(_slam(ds, t / "out", "--rerun", f, "--overwrite"), [ds, f], t / "out", (str(f),))


@case("rerun-file-is-input-folder", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(_slam(ds, t / "out", "--rerun", ds / "left"), [ds], t / "out", (str(ds / "left"),))


@case("reconstruct-rerun-file-is-input-arm-yaml", "data-loss")
def _(a, t):
    scan = copy_of(a.scan, t / "scan")
    return Setup(["reconstruct", scan, "--out", t / "out", "-q", "--rerun", scan / "arm.yaml"], [scan], t / "out",
                 (str(scan / "arm.yaml"),))


@case("reconstruct-rerun-file-is-existing-user-file", "data-loss")
def _(a, t):
    scan, f = copy_of(a.scan, t / "scan"), userfile(t, "mine.rrd")
    return Setup(["reconstruct", scan, "--out", t / "out", "-q", "--rerun", f], [scan, f], t / "out", (str(f),))


@case("batch-out-existing-user-folder", "data-loss")
def _(a, t):
    field, m = t / "field", mine(t)
    copy_range(a, field, "r1")
    return Setup(["batch", field, "--out", m, "-q"], [field, m], m, (str(m),))


@case("batch-out-is-the-field", "data-loss")
def _(a, t):
    field = t / "field"
    copy_range(a, field, "r1")
    return Setup(["batch", field, "--out", field, "-q"], [field], field, (str(field),))


@case("batch-out-inside-a-range", "data-loss")
def _(a, t):
    field = t / "field"
    r1 = copy_range(a, field, "r1")
    return Setup(["batch", field, "--out", r1 / "left", "-q"], [field], r1 / "left", (str(r1 / "left"), str(r1)))


@case("benchmark-run-out-existing-user-folder", "data-loss")
def _(a, t):
    ds, m = copy_range(a, t), mine(t)
    return Setup(["benchmark", "run", ds, "--out", m, "--methods", "orb", "--workers", "1"], [ds, m], m, (str(m),))


@case("benchmark-run-out-is-the-dataset", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["benchmark", "run", ds, "--out", ds, "--methods", "orb", "--workers", "1"], [ds], ds, (str(ds),))


@case("demo-data-is-user-folder", "data-loss")
def _(a, t):
    m = mine(t)
    return Setup(["demo", "--data", m, "--out", t / "out", "--length", "0.2"], [m], t / "out", (str(m),))


@case("demo-out-is-user-folder", "data-loss")
def _(a, t):
    ds, m = copy_range(a, t), mine(t)
    return Setup(["demo", "--data", ds, "--out", m], [ds, m], m, (str(m),))


@case("demo-out-is-the-data", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["demo", "--data", ds, "--out", ds], [ds], ds, (str(ds),))


@case("demo-out-contains-the-data", "data-loss")
def _(a, t):
    ds = copy_range(a, t / "P", "demo")
    return Setup(["demo", "--data", ds, "--out", t / "P"], [t / "P"], t / "P", (str(t / "P"), str(ds)))


@case("eval-slam-json-is-input-file", "data-loss")
def _(a, t):
    ds, res = copy_range(a, t), copy_of(a.slam, t / "res")
    return Setup(["eval", "slam", res, ds, "--json", ds / "calib.yaml"], [ds, res], None, (str(ds / "calib.yaml"),))


@case("eval-slam-json-is-existing-user-file", "data-loss")
def _(a, t):
    ds, res, f = copy_range(a, t), copy_of(a.slam, t / "res"), userfile(t, "mine.json", '{"mine": 1}\n')
    return Setup(["eval", "slam", res, ds, "--json", f], [ds, res, f], None, (str(f),))


@case("eval-detect-out-is-input-file", "data-loss")
def _(a, t):
    ds, det = copy_range(a, t), copy_of(a.det, t / "det")
    return Setup(["eval", "detect", ds, det, "--out", ds / "times.txt"], [ds, det], None, (str(ds / "times.txt"),))


@case("eval-detect-out-is-existing-user-file", "data-loss")
def _(a, t):
    ds, det, f = copy_range(a, t), copy_of(a.det, t / "det"), userfile(t, "mine.json", '{"mine": 1}\n')
    return Setup(["eval", "detect", ds, det, "--out", f], [ds, det, f], None, (str(f),))


@case("eval-associate-out-is-input-file", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["eval", "associate", ds, "--out", ds / "calib.yaml"], [ds], None, (str(ds / "calib.yaml"),))


@case("count-calibration-out-is-input-metrics", "data-loss")
def _(a, t):
    rec = copy_of(a.recon, t / "rec")
    return Setup(["train", "count-calibration", rec, "--out", rec / "metrics.json", "--overwrite"], [rec], None,
                 (str(rec / "metrics.json"),))


@case("count-calibration-out-is-user-json-with-overwrite", "data-loss")
def _(a, t):
    rec, f = copy_of(a.recon, t / "rec"), userfile(t, "mine.json", '{"mine": 1}\n')
    return Setup(["train", "count-calibration", rec, "--out", f, "--overwrite"], [rec, f], None, (str(f),))


@case("train-fast-cnn-out-is-input-dataset", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["train", "fast-cnn", ds, "--out", ds, "--steps", "1", "--batch", "1", "--crop", "32"], [ds], None,
                 (str(ds),))


@case("train-cnn-refiner-out-is-input-dataset", "data-loss")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["train", "cnn-refiner", ds, "--out", ds, "--steps", "1"], [ds], None, (str(ds),))


# ---- output paths ---------------------------------------------------------------------------------------------


OUT_COMMANDS: dict[str, Callable[[Assets, Path, Path], tuple[list, list[Path]]]] = {
    "slam": lambda a, t, o: ((ds := copy_range(a, t)) and ["slam", ds, "--out", o, "-q"], [ds]),
    "detect": lambda a, t, o: ((ds := copy_range(a, t)) and ["detect", ds, "--out", o, "--detector", "fast-classic"],
                               [ds]),
    "simulate-range": lambda a, t, o: (["simulate", "range", "--out", o, "-q", "--length", "0.2", "--set",
                                        "camera.scale=0.1"], []),
    "reconstruct": lambda a, t, o: ((s := copy_of(a.scan, t / "scan")) and ["reconstruct", s, "--out", o, "-q"],
                                    [s]),
    "count": lambda a, t, o: ((r := copy_of(a.recon, t / "rec")) and ["count", r, "--out", o], [r]),
    "batch": lambda a, t, o: ((f := t / "field") and copy_range(a, f, "r1") and ["batch", f, "--out", o, "-q"],
                              [t / "field"]),
}


def out_case(cmd: str, kind: str) -> Callable[[Assets, Path], Setup]:
    def build(a: Assets, t: Path) -> Setup:
        inputs: list[Path] = []
        if kind == "out-is-a-file":
            out = userfile(t, "out_file.txt")
            inputs.append(out)
            names = (str(out),)
        elif kind == "out-parent-is-a-file":
            f = userfile(t, "parent_file.txt")
            out = f / "out"
            inputs.append(f)
            names = (str(f), str(out))
        elif kind == "out-uncreatable":
            out = Path(f"/proc/seedmap-matrix-{cmd}/out")
            names = (str(out), "/proc")
        else:  # a non-empty folder without --overwrite
            out = mine(t)
            inputs.append(out)
            names = (str(out),)
        argv, ins = OUT_COMMANDS[cmd](a, t, out)
        return Setup(argv, [*ins, *inputs], out, names)

    return build


for _c in OUT_COMMANDS:
    for _k in ("out-is-a-file", "out-parent-is-a-file", "out-uncreatable", "out-user-folder-no-overwrite"):
        add(f"{_c}-{_k}", "output", out_case(_c, _k))


@case("slam-full-disk", "output")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(_slam(ds, t / "out"), [ds], t / "out", (str(t / "out"), "space", "large"), fsize=1 << 20)


@case("detect-full-disk", "output")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["detect", ds, "--out", t / "out", "--detector", "fast-classic"], [ds], t / "out",
                 (str(t / "out"), "space", "large"), fsize=256 << 10)


@case("reconstruct-full-disk", "output")
def _(a, t):
    scan = copy_of(a.scan, t / "scan")
    return Setup(["reconstruct", scan, "--out", t / "out", "-q"], [scan], t / "out",
                 (str(t / "out"), "space", "large"), fsize=1 << 20)


@case("simulate-range-full-disk", "output")
def _(a, t):
    return Setup(["simulate", "range", "--out", t / "out", "-q", "--length", "0.2", "--set", "camera.scale=0.1"],
                 [], t / "out", (str(t / "out"), "space", "large"), fsize=64 << 10)


# ---- unknown names and out-of-range options ----------------------------------------------------------------------


def simple(id: str, group: str, make: Callable[[Assets, Path], tuple[list, list[Path], Path | None]],
           *names: str) -> None:
    """A case whose names are fixed strings (an option)."""

    def build(a: Assets, t: Path) -> Setup:
        argv, inputs, out = make(a, t)
        return Setup(argv, inputs, out, names)

    add(id, group, build)


def _with_out(*args):
    def make(a, t):
        ds = copy_range(a, t)
        argv = [ds if x == "DS" else (t / "out" if x == "OUT" else x) for x in args]
        return argv, [ds], t / "out"

    return make


simple("detect-unknown-detector", "options", _with_out("detect", "DS", "--out", "OUT", "--detector", "nosuch"),
       "nosuch", "--detector")
simple("slam-unknown-detector", "options", _with_out("slam", "DS", "--out", "OUT", "-q", "--detector", "nosuch"),
       "nosuch", "--detector")
simple("slam-unknown-matcher", "options", _with_out("slam", "DS", "--out", "OUT", "-q", "--matcher", "nosuch"),
       "nosuch", "--matcher")
simple("eval-associate-unknown-matcher", "options", _with_out("eval", "associate", "DS", "--matcher", "nosuch"),
       "nosuch", "--matcher")
simple("eval-associate-unknown-detector", "options", _with_out("eval", "associate", "DS", "--detector", "nosuch"),
       "nosuch", "--detector")
simple("eval-associate-max-frames-zero", "options", _with_out("eval", "associate", "DS", "--max-frames", "0"),
       "--max-frames")
simple("eval-associate-max-frames-negative", "options", _with_out("eval", "associate", "DS", "--max-frames", "-2"),
       "--max-frames")
simple("benchmark-run-unknown-method", "options",
       _with_out("benchmark", "run", "DS", "--out", "OUT", "--methods", "nosuch", "--workers", "1"),
       "nosuch", "--methods")
simple("benchmark-run-workers-zero", "options",
       _with_out("benchmark", "run", "DS", "--out", "OUT", "--methods", "orb", "--workers", "0"), "workers")
simple("demo-unknown-detector", "options", _with_out("demo", "--data", "DS", "--out", "OUT", "--detector", "nosuch"),
       "nosuch", "--detector")
simple("demo-length-zero", "options", lambda a, t: (["demo", "--data", t / "d", "--out", t / "out", "--length", "0"],
                                                    [], t / "out"), "--length", "length")
simple("demo-length-nan", "options", lambda a, t: (["demo", "--data", t / "d", "--out", t / "out", "--length", "nan"],
                                                   [], t / "out"), "--length", "length")
simple("simulate-range-length-negative", "options",
       lambda a, t: (["simulate", "range", "--out", t / "out", "-q", "--length", "-1"], [], t / "out"), "--length")
simple("simulate-range-length-nan", "options",
       lambda a, t: (["simulate", "range", "--out", t / "out", "-q", "--length", "nan"], [], t / "out"), "length")
simple("simulate-range-length-inf", "options",
       lambda a, t: (["simulate", "range", "--out", t / "out", "-q", "--length", "inf"], [], t / "out"), "length")
simple("simulate-range-unknown-preset", "options",
       lambda a, t: (["simulate", "range", "--out", t / "out", "-q", "--preset", "nosuch"], [], t / "out"),
       "nosuch", "--preset")
simple("simulate-panicle-views-two", "options",
       lambda a, t: (["simulate", "panicle", "--out", t / "out", "-q", "--views", "2"], [], t / "out"),
       "views", "--views")
simple("simulate-panicle-exposure-negative", "options",
       lambda a, t: (["simulate", "panicle", "--out", t / "out", "-q", "--exposure", "-1"], [], t / "out"),
       "exposure")
simple("simulate-panicle-exposure-nan", "options",
       lambda a, t: (["simulate", "panicle", "--out", t / "out", "-q", "--exposure", "nan"], [], t / "out"),
       "exposure")
simple("reconstruct-unknown-register", "options",
       lambda a, t: ((s := copy_of(a.scan, t / "scan")) and ["reconstruct", s, "--out", t / "out", "-q",
                                                             "--register", "nosuch"], [t / "scan"], t / "out"),
       "--register", "nosuch")
simple("reconstruct-unknown-detector", "options",
       lambda a, t: ((s := copy_of(a.scan, t / "scan")) and ["reconstruct", s, "--out", t / "out", "-q",
                                                             "--detector", "nosuch"], [t / "scan"], t / "out"),
       "nosuch", "detector")
simple("batch-unknown-matcher", "options",
       lambda a, t: (copy_range(a, t / "field", "r1") and ["batch", t / "field", "--out", t / "out", "-q",
                                                          "--matcher", "nosuch"], [t / "field"], t / "out"),
       "nosuch", "--matcher")
simple("batch-unknown-detector", "options",
       lambda a, t: (copy_range(a, t / "field", "r1") and ["batch", t / "field", "--out", t / "out", "-q",
                                                          "--detector", "nosuch"], [t / "field"], t / "out"),
       "nosuch", "--detector")
simple("batch-workers-zero", "options",
       lambda a, t: (copy_range(a, t / "field", "r1") and ["batch", t / "field", "--out", t / "out", "-q",
                                                          "--workers", "0"], [t / "field"], t / "out"),
       "--workers", "workers")


def _eval_detect(*extra):
    def make(a, t):
        ds, det = copy_range(a, t), copy_of(a.det, t / "det")
        return ["eval", "detect", ds, det, *extra], [ds, det], None

    return make


simple("eval-detect-iou-zero", "options", _eval_detect("--iou", "0"), "--iou")
simple("eval-detect-iou-nan", "options", _eval_detect("--iou", "nan"), "--iou")
simple("eval-detect-unknown-matching", "options", _eval_detect("--matching", "nosuch"), "--matching")
simple("eval-detect-min-gt-area-negative", "options", _eval_detect("--min-gt-area", "-5"), "--min-gt-area")


# ---- weights --------------------------------------------------------------------------------------------------


def _weights_case(detector: str, content: bytes | None, suffix: str):
    def build(a: Assets, t: Path) -> Setup:
        ds = copy_range(a, t)
        w = t / f"weights{suffix}"
        if content is not None:
            w.write_bytes(content)
        ins = [ds, w] if content is not None else [ds]
        return Setup(["detect", ds, "--out", t / "out", "--detector", detector, "--weights", w], ins, t / "out",
                     (str(w), w.name))

    return build


add("detect-fast-cnn-weights-garbage-onnx", "weights", _weights_case("fast-cnn", BINARY, ".onnx"))
add("detect-fast-cnn-weights-empty-onnx", "weights", _weights_case("fast-cnn", b"", ".onnx"))
add("detect-fast-cnn-weights-text-onnx", "weights", _weights_case("fast-cnn", b"not a network\n", ".onnx"))
add("detect-fast-cnn-weights-missing", "weights", _weights_case("fast-cnn", None, ".onnx"))
add("detect-fast-cnn-weights-wrong-suffix", "weights", _weights_case("fast-cnn", BINARY, ".safetensors"))
add("detect-frcnn-weights-garbage-safetensors", "weights", _weights_case("frcnn-pix2pix", BINARY, ".safetensors"))


@case("detect-fast-cnn-weights-is-a-folder", "weights")
def _(a, t):
    ds, w = copy_range(a, t), mine(t, "weights_dir")
    return Setup(["detect", ds, "--out", t / "out", "--detector", "fast-cnn", "--weights", w], [ds, w], t / "out",
                 (str(w),))


@case("train-cnn-refiner-weights-garbage-onnx", "weights")
def _(a, t):
    ds, w = copy_range(a, t), t / "w.onnx"
    w.write_bytes(BINARY)
    return Setup(["train", "cnn-refiner", ds, "--out", t / "out", "--weights", w, "--steps", "1"], [ds, w], t / "out",
                 (str(w),))


@case("train-fast-cnn-init-garbage-onnx", "weights")
def _(a, t):
    ds, w = copy_range(a, t), t / "w.onnx"
    w.write_bytes(BINARY)
    return Setup(["train", "fast-cnn", ds, "--out", t / "out", "--init", w, "--steps", "1", "--batch", "1",
                  "--crop", "32"], [ds, w], t / "out", (str(w),))


@case("slam-config-detector-weights-garbage", "weights")
def _(a, t):
    ds, w = copy_range(a, t), t / "w.onnx"
    w.write_bytes(BINARY)
    return Setup(["detect", ds, "--out", t / "out", "--set", "detector=fast-cnn", "--set", f"weights={w}"], [ds, w],
                 t / "out", (str(w),))


# ---- training data --------------------------------------------------------------------------------------------


def _coco(text: str | bytes):
    def build(a: Assets, t: Path) -> Setup:
        f = t / "labels.json"
        if isinstance(text, bytes):
            f.write_bytes(text)
        else:
            f.write_text(text)
        return Setup(["train", "cnn-refiner", f, "--out", t / "out", "--steps", "1"], [f], t / "out", (str(f),))

    return build


add("train-cnn-refiner-coco-syntax-error", "training", _coco('{"images": [1, 2'))
add("train-cnn-refiner-coco-binary", "training", _coco(BINARY))
add("train-cnn-refiner-coco-utf16", "training", _coco(utf16('{"images": [], "annotations": []}')))
add("train-cnn-refiner-coco-not-an-object", "training", _coco("[1, 2, 3]"))
add("train-cnn-refiner-coco-no-annotations", "training", _coco('{"images": []}'))
add("train-cnn-refiner-coco-images-missing", "training",
    _coco(json.dumps({"images": [{"id": 1, "file_name": "nosuch.png", "width": 64, "height": 48}],
                      "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "bbox": [1, 1, 5, 5],
                                       "segmentation": [[1, 1, 6, 1, 6, 6, 1, 6]], "area": 25, "iscrowd": 0}],
                      "categories": [{"id": 1, "name": "seed"}]})))
add("train-cnn-refiner-coco-bbox-nan", "training",
    _coco('{"images": [{"id": 1, "file_name": "a.png", "width": 64, "height": 48}], "annotations": [{"id": 1, '
          '"image_id": 1, "category_id": 1, "bbox": [NaN, 1, 5, 5], "area": 25, "iscrowd": 0}], '
          '"categories": [{"id": 1, "name": "seed"}]}'))


@case("train-cnn-refiner-data-missing", "training")
def _(a, t):
    return Setup(["train", "cnn-refiner", t / "nosuch", "--out", t / "out", "--steps", "1"], [], t / "out",
                 (str(t / "nosuch"),))


@case("train-cnn-refiner-data-without-gt", "training")
def _(a, t):
    ds = copy_range(a, t, gt=False)
    return Setup(["train", "cnn-refiner", ds, "--out", t / "out", "--steps", "1"], [ds], t / "out", (str(ds), "gt"))


@case("train-cnn-refiner-hidden-not-numbers", "training")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["train", "cnn-refiner", ds, "--out", t / "out", "--steps", "1", "--hidden", "abc"], [ds], t / "out",
                 ("--hidden",))


@case("train-cnn-refiner-candidates-out-of-range", "training")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["train", "cnn-refiner", ds, "--out", t / "out", "--steps", "1", "--candidates", "2"], [ds],
                 t / "out", ("--candidates",))


@case("train-cnn-refiner-steps-zero", "training")
def _(a, t):
    ds = copy_range(a, t)
    return Setup(["train", "cnn-refiner", ds, "--out", t / "out", "--steps", "0"], [ds], t / "out", ("--steps",))


def _fast_cnn(*extra, gt=True, data=None):
    def build(a: Assets, t: Path) -> Setup:
        ds = copy_range(a, t, gt=gt)
        d = data(t) if data else ds
        return Setup(["train", "fast-cnn", d, "--out", t / "out", *extra], [ds], t / "out",
                     tuple(x for x in extra if x.startswith("--")) + (str(d),))

    return build


add("train-fast-cnn-data-without-gt", "training", _fast_cnn("--steps", "1", "--batch", "1", "--crop", "32", gt=False))
add("train-fast-cnn-data-missing", "training",
    _fast_cnn("--steps", "1", "--batch", "1", "--crop", "32", data=lambda t: t / "nosuch"))
add("train-fast-cnn-steps-zero", "training", _fast_cnn("--steps", "0", "--batch", "1", "--crop", "32"))
add("train-fast-cnn-batch-zero", "training", _fast_cnn("--steps", "1", "--batch", "0", "--crop", "32"))
add("train-fast-cnn-crop-zero", "training", _fast_cnn("--steps", "1", "--batch", "1", "--crop", "0"))
add("train-fast-cnn-crop-larger-than-image", "training", _fast_cnn("--steps", "1", "--batch", "1", "--crop", "4096"))
add("train-fast-cnn-lr-nan", "training", _fast_cnn("--steps", "1", "--batch", "1", "--crop", "32", "--lr", "nan"))
add("train-fast-cnn-threads-zero", "training",
    _fast_cnn("--steps", "1", "--batch", "1", "--crop", "32", "--threads", "0"))


# ---- count calibration: counts CSV and results ------------------------------------------------------------------


def _counts(text: str | bytes | None):
    def build(a: Assets, t: Path) -> Setup:
        rec = copy_of(a.recon, t / "rec")
        c = t / "counts.csv"
        if isinstance(text, bytes):
            c.write_bytes(text)
        elif text is not None:
            c.write_text(text.replace("REC", str(rec)))
        ins = [rec, c] if text is not None else [rec]
        return Setup(["train", "count-calibration", rec, "--out", t / "cal.json", "--counts", c], ins,
                     t / "cal.json", (str(c), c.name))

    return build


add("count-calibration-counts-wrong-fields", "counts", _counts("result,count\nREC,120,7\n"))
add("count-calibration-counts-not-a-number", "counts", _counts("result,count\nREC,many\n"))
add("count-calibration-counts-negative", "counts", _counts("result,count\nREC,-3\n"))
add("count-calibration-counts-nan", "counts", _counts("result,count\nREC,nan\n"))
add("count-calibration-counts-inf", "counts", _counts("result,count\nREC,inf\n"))
add("count-calibration-counts-empty", "counts", _counts(""))
add("count-calibration-counts-binary", "counts", _counts(BINARY))
add("count-calibration-counts-utf16", "counts", _counts(utf16("result,count\nrec,120\n")))
add("count-calibration-counts-missing-file", "counts", _counts(None))
add("count-calibration-counts-no-row-for-result", "counts", _counts("result,count\nother_panicle,120\n"))


@case("count-calibration-result-missing", "counts")
def _(a, t):
    return Setup(["train", "count-calibration", t / "nosuch", "--out", t / "cal.json"], [], t / "cal.json",
                 (str(t / "nosuch"),))


@case("count-calibration-result-is-slam-result", "counts")
def _(a, t):
    res = copy_of(a.slam, t / "res")
    return Setup(["train", "count-calibration", res, "--out", t / "cal.json"], [res], t / "cal.json", (str(res),))


@case("count-calibration-out-not-json", "counts")
def _(a, t):
    rec = copy_of(a.recon, t / "rec")
    return Setup(["train", "count-calibration", rec, "--out", t / "cal.txt"], [rec], t / "cal.txt",
                 (str(t / "cal.txt"),))


@case("count-calibration-unknown-feature", "counts")
def _(a, t):
    rec = copy_of(a.recon, t / "rec")
    return Setup(["train", "count-calibration", rec, "--out", t / "cal.json", "--features", "nosuch"], [rec],
                 t / "cal.json", ("nosuch", "--features"))


# ---- reconstruct and count inputs -------------------------------------------------------------------------------


def _scan_case(mutate: Callable[[Path], tuple[str, ...]]):
    def build(a: Assets, t: Path) -> Setup:
        scan = copy_of(a.scan, t / "scan")
        names = mutate(scan)
        return Setup(["reconstruct", scan, "--out", t / "out", "-q"], [scan], t / "out", names)

    return build


def _joints(scan: Path, f: Callable[[list[str]], list[str]]):
    p = scan / "joints.csv"
    p.write_text("\n".join(f(p.read_text().splitlines())) + "\n")
    return (str(p), "joints.csv")


def _arm(scan: Path, data: bytes | str):
    p = scan / "arm.yaml"
    p.write_bytes(data) if isinstance(data, bytes) else p.write_text(data)
    return (str(p), "arm.yaml")


add("reconstruct-joints-missing", "reconstruct",
    _scan_case(lambda s: ((s / "joints.csv").unlink(), (str(s / "joints.csv"), "joints.csv"))[1]))
add("reconstruct-joints-not-numbers", "reconstruct",
    _scan_case(lambda s: _joints(s, lambda r: [r[0], r[1].replace(r[1].split(",")[3], "abc", 1), *r[2:]])))
add("reconstruct-joints-nan", "reconstruct",
    _scan_case(lambda s: _joints(s, lambda r: [r[0], r[1].replace(r[1].split(",")[3], "nan", 1), *r[2:]])))
add("reconstruct-joints-fewer-rows-than-views", "reconstruct", _scan_case(lambda s: _joints(s, lambda r: r[:-1])))
add("reconstruct-joints-binary", "reconstruct",
    _scan_case(lambda s: ((s / "joints.csv").write_bytes(BINARY), (str(s / "joints.csv"), "joints.csv"))[1]))
add("reconstruct-arm-yaml-binary", "reconstruct", _scan_case(lambda s: _arm(s, BINARY)))
add("reconstruct-arm-yaml-utf16", "reconstruct", _scan_case(lambda s: _arm(s, utf16((s / "arm.yaml").read_text()))))
add("reconstruct-arm-yaml-not-mapping", "reconstruct", _scan_case(lambda s: _arm(s, "- 1\n")))
add("reconstruct-arm-yaml-dh-nan", "reconstruct",
    _scan_case(lambda s: _arm(s, (s / "arm.yaml").read_text().replace("0.089159", ".nan", 1))))
add("reconstruct-calib-binary", "reconstruct", _scan_case(m_calib_binary))
add("reconstruct-calib-baseline-zero", "reconstruct", _scan_case(m_calib_baseline_zero))
add("reconstruct-img-corrupt", "reconstruct", _scan_case(m_img_corrupt))
add("reconstruct-times-nan", "reconstruct", _scan_case(m_times_nan))


@case("reconstruct-dataset-missing", "reconstruct")
def _(a, t):
    return Setup(["reconstruct", t / "nosuch", "--out", t / "out", "-q"], [], t / "out", (str(t / "nosuch"),))


def _rec_case(mutate: Callable[[Path], tuple[str, ...]]):
    def build(a: Assets, t: Path) -> Setup:
        rec = copy_of(a.recon, t / "rec")
        names = mutate(rec)
        return Setup(["count", rec, "--out", t / "out"], [rec], t / "out", names)

    return build


def _rec_file(name: str, data: bytes | str):
    def mutate(rec: Path):
        p = rec / name
        p.write_bytes(data) if isinstance(data, bytes) else p.write_text(data)
        return (str(p), name)

    return mutate


add("count-results-missing", "count", lambda a, t: Setup(["count", t / "nosuch"], [], None, (str(t / "nosuch"),)))
add("count-results-is-a-file", "count",
    lambda a, t: Setup(["count", userfile(t, "f.txt")], [t / "f.txt"], None, (str(t / "f.txt"),)))
add("count-results-is-slam-result", "count",
    lambda a, t: Setup(["count", copy_of(a.slam, t / "res")], [t / "res"], None, (str(t / "res"),)))
add("count-config-yaml-binary", "count", _rec_case(_rec_file("config.yaml", BINARY)))
add("count-config-yaml-utf16", "count",
    _rec_case(lambda r: _rec_file("config.yaml", utf16((r / "config.yaml").read_text()))(r)))
add("count-detections-csv-missing", "count",
    _rec_case(lambda r: ((r / "detections.csv").unlink(), (str(r / "detections.csv"), "detections.csv"))[1]))
add("count-detections-csv-garbage", "count", _rec_case(_rec_file("detections.csv", "a;b;c\nx;y;z\n")))
add("count-detections-csv-binary", "count", _rec_case(_rec_file("detections.csv", BINARY)))
add("count-calib-yaml-binary", "count", _rec_case(_rec_file("calib.yaml", BINARY)))
add("count-poses-nan", "count",
    _rec_case(lambda r: _rec_file("poses_tum.txt", (r / "poses_tum.txt").read_text().replace(
        (r / "poses_tum.txt").read_text().split()[1], "nan", 1))(r)))


# ---- evaluation inputs ------------------------------------------------------------------------------------------


def _eval_slam(mutate_res=None, mutate_ds=None, gt=True):
    def build(a: Assets, t: Path) -> Setup:
        ds, res = copy_range(a, t, gt=gt), copy_of(a.slam, t / "res")
        names: tuple[str, ...] = (str(ds), "gt")
        if mutate_res:
            names = mutate_res(res)
        if mutate_ds:
            names = mutate_ds(ds)
        return Setup(["eval", "slam", res, ds], [ds, res], None, names)

    return build


def _tum(text_fn):
    def mutate(res: Path):
        p = res / "trajectory.tum"
        p.write_text(text_fn(p.read_text()))
        return (str(p), "trajectory.tum")

    return mutate


add("eval-slam-dataset-without-gt", "eval", _eval_slam(gt=False))
add("eval-slam-trajectory-not-numbers", "eval", _eval_slam(_tum(lambda s: s.replace(s.split()[1], "abc", 1))))
add("eval-slam-trajectory-nan", "eval", _eval_slam(_tum(lambda s: s.replace(s.split()[1], "nan", 1))))
add("eval-slam-trajectory-empty", "eval", _eval_slam(_tum(lambda s: "")))
add("eval-slam-trajectory-missing", "eval",
    _eval_slam(lambda r: ((r / "trajectory.tum").unlink(), (str(r / "trajectory.tum"), "trajectory.tum"))[1]))
add("eval-slam-gt-poses-binary", "eval",
    _eval_slam(mutate_ds=lambda d: ((d / "gt" / "poses_tum.txt").write_bytes(BINARY),
                                    (str(d / "gt" / "poses_tum.txt"), "poses_tum.txt"))[1]))
add("eval-slam-result-missing", "eval",
    lambda a, t: Setup(["eval", "slam", t / "nosuch", copy_range(a, t)], [t / "ds"], None, (str(t / "nosuch"),)))


def _eval_det(mutate_det=None, gt=True):
    def build(a: Assets, t: Path) -> Setup:
        ds, det = copy_range(a, t, gt=gt), copy_of(a.det, t / "det")
        names: tuple[str, ...] = (str(ds), "gt")
        if mutate_det:
            names = mutate_det(det)
        return Setup(["eval", "detect", ds, det], [ds, det], None, names)

    return build


def _det_files(data: bytes | str):
    def mutate(det: Path):
        for n in ("detections.jsonl", "detections_coco.json"):
            (det / n).write_bytes(data) if isinstance(data, bytes) else (det / n).write_text(data)
        return (str(det / "detections.jsonl"), str(det / "detections_coco.json"), "detections")

    return mutate


add("eval-detect-dataset-without-gt", "eval", _eval_det(gt=False))
add("eval-detect-detections-malformed-json", "eval", _eval_det(_det_files('{"images": [1, 2\n')))
add("eval-detect-detections-binary", "eval", _eval_det(_det_files(BINARY)))
add("eval-detect-detections-wrong-schema", "eval", _eval_det(_det_files('{"frame": "x"}\n')))
add("eval-detect-detections-folder-missing", "eval",
    lambda a, t: Setup(["eval", "detect", copy_range(a, t), t / "nosuch"], [t / "ds"], None, (str(t / "nosuch"),)))


# ---- bags -------------------------------------------------------------------------------------------------------


def _bag(kind: str, cmd: str, *extra):
    def build(a: Assets, t: Path) -> Setup:
        if kind == "missing":
            bag = t / "nosuch.bag"
            ins = []
        elif kind in ("ros2-metadata-binary", "ros2-db3-truncated"):
            bag = copy_of(a.ros2, t / "bag_ros2")
            if kind == "ros2-metadata-binary":
                (bag / "metadata.yaml").write_bytes(BINARY)
            else:
                db = next(bag.glob("*.db3"))
                db.write_bytes(db.read_bytes()[:2048])
            ins = [bag]
        elif kind == "folder-not-a-bag":
            bag = mine(t, "notabag")
            ins = [bag]
        else:
            bag = t / "stereo.bag"
            data = a.bag.read_bytes()
            bag.write_bytes({"ros1-truncated": data[: len(data) // 2], "ros1-header-only": data[:13],
                             "empty": b"", "garbage": BINARY, "ros1": data}[kind])
            ins = [bag]
        out = t / "out"
        argv = {"bag-info": ["bag-info", bag, *extra], "slam": ["slam", bag, "--out", out, "-q", "--matcher", "orb",
                                                                *extra]}[cmd]
        names = (str(bag), *[x for x in extra if x.startswith("--")])
        return Setup(argv, ins, out if cmd == "slam" else None, names)

    return build


for _k in ("ros1-truncated", "ros1-header-only", "empty", "garbage", "missing", "folder-not-a-bag",
           "ros2-metadata-binary", "ros2-db3-truncated"):
    add(f"bag-info-{_k}", "bag", _bag(_k, "bag-info"))
for _k in ("ros1-truncated", "garbage", "ros2-db3-truncated"):
    add(f"slam-bag-{_k}", "bag", _bag(_k, "slam"))
add("bag-info-unknown-left-topic", "bag", _bag("ros1", "bag-info", "--sequence", "--left-topic", "/nosuch"))
add("bag-info-sync-tol-negative", "bag", _bag("ros1", "bag-info", "--sequence", "--sync-tol", "-1"))
add("bag-info-sync-tol-nan", "bag", _bag("ros1", "bag-info", "--sequence", "--sync-tol", "nan"))
add("slam-bag-unknown-left-topic", "bag", _bag("ros1", "slam", "--set", "dataset.left_topic=/nosuch"))


# ---- paths that are not what the command reads ------------------------------------------------------------------


def _path_case(cmd: list, what: str):
    def build(a: Assets, t: Path) -> Setup:
        if what == "missing":
            p, ins = t / "nosuch", []
        elif what == "file":
            p = userfile(t, "a_file.txt")
            ins = [p]
        elif what == "empty-folder":
            p = t / "empty"
            p.mkdir()
            ins = [p]
        else:  # a folder of unrelated files
            p = mine(t)
            ins = [p]
        argv = [t / "out" if x == "OUT" else (p if x == "P" else x) for x in cmd]
        return Setup(argv, ins, t / "out" if "OUT" in cmd else None, (str(p),))

    return build


for _name, _cmd in {"slam": ["slam", "P", "--out", "OUT", "-q"],
                    "detect": ["detect", "P", "--out", "OUT", "--detector", "fast-classic"],
                    "reconstruct": ["reconstruct", "P", "--out", "OUT", "-q"],
                    "eval-associate": ["eval", "associate", "P"],
                    "batch": ["batch", "P", "--out", "OUT", "-q"],
                    "benchmark-run": ["benchmark", "run", "P", "--out", "OUT", "--methods", "orb", "--workers", "1"],
                    "train-fast-cnn": ["train", "fast-cnn", "P", "--out", "OUT", "--steps", "1"]}.items():
    for _w in ("missing", "file", "empty-folder", "user-folder"):
        add(f"{_name}-input-{_w}", "paths", _path_case(_cmd, _w))


@case("batch-one-range-broken-image", "dataset")
def _(a, t):
    field = t / "field"
    r1 = copy_range(a, field, "r1")
    m_img_corrupt(r1)
    return Setup(["batch", field, "--out", t / "out", "-q"], [field], t / "out",
                 (str(r1 / "left" / "000001.png"), "000001.png"), record_ok=True)


@case("benchmark-run-cjk-name-broken-image", "dataset")
def _(a, t):
    ds = copy_range(a, t, "高粱_range")
    m_img_corrupt(ds)
    return Setup(["benchmark", "run", ds, "--out", t / "out", "--methods", "orb", "--workers", "1"], [ds], t / "out",
                 ("000001.png",), record_ok=True)
