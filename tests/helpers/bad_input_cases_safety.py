"""Bad-input cases: --config/--set on every command, the user's data, output paths, option values."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from helpers.bad_inputs import (
    BINARY,
    PWN_TAG,
    Assets,
    Setup,
    add,
    case,
    copy_of,
    copy_range,
    first_float_leaf,
    mine,
    recon_set,
    userfile,
    utf16,
)


# ---- --config / --set on every command that takes them -------------------------------------------------------


def _cmd_argv(a: Assets, t: Path, cmd: str) -> tuple[list, list[Path], Path | None, str]:
    """(argv without config options, inputs, out, the config.yaml whose first float field is broken)."""
    out = t / "out"
    if cmd == "simulate-range":
        return (["simulate", "range", "--out", out, "-q", "--set", "world.length=0.2", "--set", "camera.scale=0.1"],
                [], out, a.range / "gt" / "config.yaml")
    if cmd == "simulate-panicle":
        return (["simulate", "panicle", "--out", out, "-q", "--views", "3", "--set", "sim.camera.scale=0.12"], [],
                out, a.scan / "gt" / "scan.yaml")
    if cmd == "detect":
        ds = copy_range(a, t)
        return ["detect", ds, "--out", out, "--detector", "fast"], [ds], out, a.det / "config.yaml"
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
        # no --workers: the option would win over --set workers=...
        return ["benchmark", "run", ds, "--out", out, "--methods", "orb"], [ds], out, None
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
    return Setup(["detect", ds, "--out", m, "--detector", "fast", "--overwrite"], [ds, m], m, (str(m),))


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
    return Setup(["detect", ds, "--out", ds, "--detector", "fast", "--overwrite"], [ds], ds, (str(ds),))


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
    return Setup(["detect", ds, "--out", out, "--detector", "fast", "--overwrite"], [ds], out,
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
    return Setup(["detect", ds, "--out", res, "--detector", "fast", "--overwrite"], [ds, res], res,
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
    recs = recon_set(a, t)
    out = recs[0] / "metrics.json"
    return Setup(["train", "count-calibration", *recs, "--features", "", "--out", out, "--overwrite"], [t / "recs"],
                 None, (str(out),))


@case("count-calibration-out-is-user-json-with-overwrite", "data-loss")
def _(a, t):
    recs, f = recon_set(a, t), userfile(t, "mine.json", '{"mine": 1}\n')
    return Setup(["train", "count-calibration", *recs, "--features", "", "--out", f, "--overwrite"], [t / "recs", f],
                 None, (str(f),))


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
    "detect": lambda a, t, o: ((ds := copy_range(a, t)) and ["detect", ds, "--out", o, "--detector", "fast"],
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
    return Setup(["detect", ds, "--out", t / "out", "--detector", "fast"], [ds], t / "out",
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
