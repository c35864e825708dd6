"""Bad-input cases: weights, training data, count CSVs, reconstruct/count/eval inputs, bags, paths."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from helpers.bad_inputs import (
    BINARY,
    GOOD_COUNTS,
    Assets,
    Setup,
    add,
    case,
    copy_of,
    copy_range,
    m_calib_baseline_zero,
    m_calib_binary,
    m_img_corrupt,
    m_times_nan,
    mine,
    recon_set,
    userfile,
    utf16,
)


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


add("detect-fast-cnn-weights-garbage-onnx", "weights", _weights_case("fast", BINARY, ".onnx"))
add("detect-fast-cnn-weights-empty-onnx", "weights", _weights_case("fast", b"", ".onnx"))
add("detect-fast-cnn-weights-text-onnx", "weights", _weights_case("fast", b"not a network\n", ".onnx"))
add("detect-fast-cnn-weights-missing", "weights", _weights_case("fast", None, ".onnx"))
add("detect-fast-cnn-weights-wrong-suffix", "weights", _weights_case("fast", BINARY, ".safetensors"))


@case("detect-frcnn-weights-garbage-safetensors", "weights")
def _(a, t):
    ds, w = copy_range(a, t), t / "w"
    w.mkdir()
    for n in ("detector.safetensors", "segmenter.safetensors"):
        (w / n).write_bytes(BINARY)
    return Setup(["detect", ds, "--out", t / "out", "--detector", "frcnn-pix2pix", "--weights",
                  w / "detector.safetensors"], [ds, w], t / "out", (str(w / "detector.safetensors"),
                                                                    str(w / "segmenter.safetensors")))


@case("detect-fast-cnn-weights-is-a-folder", "weights")
def _(a, t):
    ds, w = copy_range(a, t), mine(t, "weights_dir")
    return Setup(["detect", ds, "--out", t / "out", "--detector", "fast", "--weights", w], [ds, w], t / "out",
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
    return Setup(["detect", ds, "--out", t / "out", "--set", "detector=fast", "--set", f"weights={w}"], [ds, w],
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
add("train-fast-cnn-lr-nan", "training", _fast_cnn("--steps", "1", "--batch", "1", "--crop", "32", "--lr", "nan"))


def _labelled_photos(t: Path, n: int = 3) -> tuple[Path, dict]:
    """``t/photos``: ``n`` small PNG photos of bright 8-px seeds on a dark background, and their COCO labels."""
    import cv2
    import numpy as np

    root = t / "photos"
    root.mkdir()
    images, anns = [], []
    for i in range(n):
        img = np.full((64, 80, 3), 40, np.uint8)
        for j, (x, y) in enumerate(((10, 12), (40, 30), (60, 50))):
            cv2.ellipse(img, (x + 4, y + 4), (4, 3), 0, 0, 360, (230, 220, 200), -1)
            anns.append({"id": len(anns) + 1, "image_id": i + 1, "category_id": 1, "bbox": [x, y + 1, 9, 7],
                         "area": 50, "iscrowd": 0})
        cv2.imwrite(str(root / f"p{i}.png"), img)
        images.append({"id": i + 1, "file_name": f"p{i}.png", "width": 80, "height": 64})
    return root, {"images": images, "annotations": anns, "categories": [{"id": 1, "name": "seed"}]}


def _fast_coco(mutate: Callable[[dict, Path], None], names: tuple[str, ...] = ()):
    """``train fast-cnn LABELS.json --images-root photos`` with the labels (or photos) spoilt by ``mutate``."""

    def build(a: Assets, t: Path) -> Setup:
        root, coco = _labelled_photos(t)
        mutate(coco, root)
        f = t / "labels.json"
        f.write_text(json.dumps(coco))
        return Setup(["train", "fast-cnn", f, "--images-root", root, "--out", t / "out", "--steps", "1", "--batch",
                      "1", "--crop", "32"], [f, root], t / "out", (str(f), *names))

    return build


def _set(key: str, value):  # noqa: ANN202
    def f(c: dict, root: Path) -> None:
        c[key] = value

    return f


def _ann0(**kw):  # noqa: ANN202
    def f(c: dict, root: Path) -> None:
        c["annotations"][0].update(kw)

    return f


def _only_first_image(c: dict, root: Path) -> None:
    c["annotations"] = [a for a in c["annotations"] if a["image_id"] == 1]


def _unknown_name(c: dict, root: Path) -> None:
    c["images"][1]["file_name"] = "elsewhere/p1.png"


def _truncated(c: dict, root: Path) -> None:
    p = root / "p1.png"
    p.write_bytes(p.read_bytes()[:60])


def _empty_png(c: dict, root: Path) -> None:
    (root / "p2.png").write_bytes(b"")


add("train-fast-cnn-coco-image-not-under-root", "training", _fast_coco(_unknown_name, ("elsewhere/p1.png",)))
add("train-fast-cnn-coco-no-annotations", "training", _fast_coco(_set("annotations", [])))
add("train-fast-cnn-coco-bbox-outside", "training", _fast_coco(_ann0(bbox=[75, 10, 20, 8])))
add("train-fast-cnn-coco-polygon-outside", "training",
    _fast_coco(_ann0(segmentation=[[10, 10, 200, 10, 200, 300, 10, 300]])))
add("train-fast-cnn-coco-one-labelled-image", "training", _fast_coco(_only_first_image))
add("train-fast-cnn-coco-truncated-image", "training", _fast_coco(_truncated, ("p1.png",)))
add("train-fast-cnn-coco-empty-image", "training", _fast_coco(_empty_png, ("p2.png",)))


@case("eval-detect-coco-gt-image-not-detected", "training")
def _(a, t):
    root, coco = _labelled_photos(t)
    coco["images"][0]["file_name"] = "other.png"
    f = t / "labels.json"
    f.write_text(json.dumps(coco))
    det = copy_of(a.det, t / "det")
    return Setup(["eval", "detect", f, det, "--out", t / "m.json"], [f, det], t / "m.json", (str(f), "other.png"))


# ---- count calibration: counts CSV and results ------------------------------------------------------------------


def _counts(text: str | bytes | None):
    def build(a: Assets, t: Path) -> Setup:
        recs = recon_set(a, t)
        c = t / "counts.csv"
        if isinstance(text, bytes):
            c.write_bytes(text)
        elif text is not None:
            c.write_text(text)
        ins = [t / "recs", c] if text is not None else [t / "recs"]
        return Setup(["train", "count-calibration", *recs, "--out", t / "cal.json", "--features", "", "--counts", c],
                     ins, t / "cal.json", (str(c), c.name))

    return build


add("count-calibration-counts-wrong-fields", "counts", _counts(GOOD_COUNTS.replace("rec1,100", "rec1,100,7")))
add("count-calibration-counts-not-a-number", "counts", _counts(GOOD_COUNTS.replace("rec1,100", "rec1,many")))
add("count-calibration-counts-negative", "counts", _counts(GOOD_COUNTS.replace("rec1,100", "rec1,-3")))
add("count-calibration-counts-nan", "counts", _counts(GOOD_COUNTS.replace("rec1,100", "rec1,nan")))
add("count-calibration-counts-inf", "counts", _counts(GOOD_COUNTS.replace("rec1,100", "rec1,inf")))
add("count-calibration-counts-empty", "counts", _counts(""))
add("count-calibration-counts-binary", "counts", _counts(BINARY))
add("count-calibration-counts-utf16", "counts", _counts(utf16(GOOD_COUNTS)))
add("count-calibration-counts-missing-file", "counts", _counts(None))
add("count-calibration-counts-no-row-for-result", "counts", _counts(GOOD_COUNTS.replace("rec3,120\n", "")))


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
    recs = recon_set(a, t)
    return Setup(["train", "count-calibration", *recs, "--features", "", "--out", t / "cal.txt"], [t / "recs"],
                 t / "cal.txt", (str(t / "cal.txt"),))


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


for _name, _cmd in {"slam": ["slam", "P", "--out", "OUT", "-q", "--detector", "gt"],
                    "detect": ["detect", "P", "--out", "OUT", "--detector", "fast"],
                    "reconstruct": ["reconstruct", "P", "--out", "OUT", "-q"],
                    "eval-associate": ["eval", "associate", "P"],
                    "batch": ["batch", "P", "--out", "OUT", "-q", "--detector", "gt"],
                    "benchmark-run": ["benchmark", "run", "P", "--out", "OUT", "--methods", "orb", "--workers", "1"],
                    "train-fast-cnn": ["train", "fast-cnn", "P", "--out", "OUT", "--steps", "1"]}.items():
    for _w in ("missing", "file", "empty-folder", "user-folder"):
        add(f"{_name}-input-{_w}", "paths", _path_case(_cmd, _w))


@case("batch-one-range-broken-image", "dataset")
def _(a, t):
    field = t / "field"
    r1 = copy_range(a, field, "r1")
    m_img_corrupt(r1)
    return Setup(["batch", field, "--out", t / "out", "-q", "--detector", "gt"], [field], t / "out",
                 (str(r1 / "left" / "000001.png"), "000001.png"), record_ok=True)


@case("benchmark-run-cjk-name-broken-image", "dataset")
def _(a, t):
    ds = copy_range(a, t, "高粱_range")
    m_img_corrupt(ds)
    return Setup(["benchmark", "run", ds, "--out", t / "out", "--methods", "orb", "--workers", "1"], [ds], t / "out",
                 ("000001.png",), record_ok=True)
