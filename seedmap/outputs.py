"""Where seedmap writes: one policy for every output folder and output file.

* Every folder seedmap writes holds a marker file (:data:`MARKER`) with the kind of output and the version.
* An existing, non-empty output folder is replaced only with ``overwrite`` and only when its marker names the
  same kind; a folder that is, contains or lies inside an input of the command is never an output, and neither is
  a dataset that any loader recognises (unless the command writes datasets and the marker says it wrote it).
* A folder is written under a temporary sibling name ``.NAME.<pid>.<token>.partial`` and renamed when complete;
  such leftovers of killed runs are removed by the next run of the same output.
* A single output file (a recording, a calibration) is replaced only with ``overwrite``, only when it is not an
  input and only when its content shows that seedmap wrote it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from seedmap import __version__
from seedmap.errors import InputError
from seedmap.io import detect_format
from seedmap.io.atomic import WriteError, atomic_write_text

#: name of the marker file written into every output folder
MARKER = ".seedmap-output.json"

#: kinds of output folders and the files that made older seedmap versions' folders of that kind recognisable (kinds
#: newer than the marker, such as ``photos``, are recognised by their marker only)
LEGACY_FILES: dict[str, tuple[str, ...]] = {
    "panicle-scan": ("calib.yaml", "arm.yaml", "gt/scan.yaml"),
    "slam": ("config.yaml", "metrics.json", "trajectory.tum"),
    "detect": ("config.yaml", "detections_coco.json"),
    "reconstruct": ("config.yaml", "metrics.json", "seeds.csv"),
    "count": ("count.json",),
    "dataset": ("calib.yaml", "times.txt", "gt/config.yaml"),
    "benchmark": ("config.yaml", "results.csv"),
    "tune": ("config.yaml", "tune.json"),
    "batch": ("summary.md", "summary.json"),
    "training": ("config.yaml",),
}
#: kinds whose folders are datasets (a loader recognises them): --overwrite may re-render them
DATASET_KINDS = frozenset({"dataset", "panicle-scan", "photos"})
#: fields of a dataset options section (seedmap.io.options.DatasetOptions) that name input files
DATASET_FILE_FIELDS = ("calib", "right_calib", "poses")

_PARTIAL = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.(?P<tok>[0-9a-f]{8})\.partial$")
_OLD_PARTIAL = re.compile(r"^\.(?P<name>.+)\.[A-Za-z0-9_]{8}\.partial$")  # tempfile.mkdtemp names


def resolved(p: Path) -> Path:
    """``p`` made absolute, links followed where possible."""
    try:
        return Path(p).expanduser().resolve()
    except (OSError, RuntimeError):
        return Path(os.path.abspath(Path(p).expanduser()))


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def check_not_input(out: Path, inputs: Iterable[str | Path | None], what: str = "output") -> None:
    """Refuse an output path that is, contains or lies inside one of ``inputs``."""
    o = resolved(out)
    for inp in inputs:
        if inp is None:
            continue
        i = resolved(Path(inp))
        if o == i:
            raise InputError(f"is an input of this command; pick another {what} path", out)
        if _inside(o, i):
            raise InputError(f"lies inside the input {inp}; pick a path outside it", out)
        if _inside(i, o):
            raise InputError(f"contains the input {inp}; pick a path that does not", out)


def read_marker(folder: Path) -> dict | None:
    """The marker of a folder seedmap wrote (``None``: none, or not readable as one)."""
    p = Path(folder) / MARKER
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("kind"), str) else None


def output_kind(folder: Path) -> str | None:
    """The kind of output a folder holds: its marker's, else a recognisable older seedmap output, else ``None``."""
    folder = Path(folder)
    marker = read_marker(folder)
    if marker is not None:
        return marker["kind"]
    for kind, files in LEGACY_FILES.items():
        if all((folder / f).is_file() for f in files):
            return kind
    return None


def write_marker(folder: Path, kind: str) -> None:
    """Write the marker of a ``kind`` output into ``folder`` (atomically: a resumed folder may be live)."""
    atomic_write_text(Path(folder) / MARKER, json.dumps({"kind": kind, "seedmap": __version__}) + "\n")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_partials(out: Path) -> list[Path]:
    """Remove ``.NAME.*.partial`` folders that killed runs of ``out`` left beside it; returns what was removed."""
    out = Path(out)
    parent = out.parent if str(out.parent) else Path(".")
    removed: list[Path] = []
    if not parent.is_dir():
        return removed
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _PARTIAL.match(p.name)
        stale = m is not None and m["name"] == out.name and not _pid_alive(int(m["pid"]))
        if m is None:
            old = _OLD_PARTIAL.match(p.name)
            stale = old is not None and old["name"] == out.name
        if stale and p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


def check_output_parent(out: Path, what: str = "output") -> None:
    """Fail early (one line) when ``out`` cannot be created: parent not writable or a file."""
    out = Path(out)
    probe = out.parent if str(out.parent) else Path(".")
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError("output parent is not a folder", probe)
    if not os.access(probe, os.W_OK | os.X_OK):
        raise InputError("output folder is not writable", probe)
    # os.access() says yes to root where the file system refuses (/proc, read-only mounts): try it
    test = probe / f".seedmap-probe.{os.getpid()}.{secrets.token_hex(4)}"
    try:
        test.mkdir()
        test.rmdir()
    except OSError as e:
        raise InputError(f"cannot create the {what} here ({e.strerror or e})", out) from None


def dataset_option_files(options: object | None) -> list[str]:
    """The input files a dataset options section names (calibration, right calibration, GT poses)."""
    if options is None:
        return []
    return [v for v in (getattr(options, k, None) for k in DATASET_FILE_FIELDS) if v]


def _check_folder_target(out: Path, inputs: Iterable[str | Path | None]) -> None:
    """An output folder path: not an input, creatable, and not an existing file or link."""
    check_not_input(out, inputs)
    check_output_parent(out)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise InputError("output path exists and is not a folder", out)


def check_output_dir(out: Path, kind: str, inputs: Iterable[str | Path | None] = (), overwrite: bool = False) -> None:
    """Everything :func:`output_dir` checks before it writes, for commands that fail early."""
    out = Path(out)
    _check_folder_target(out, inputs)
    if not out.exists() or not any(out.iterdir()):
        return
    if not overwrite:
        raise InputError("output folder exists and is not empty (pass --overwrite to replace a seedmap "
                         f"{kind} result)", out)
    found = output_kind(out)
    if found != kind:
        what = "not a folder seedmap wrote" if found is None else f"a seedmap {found} output, not a {kind} result"
        raise InputError(f"is {what}; --overwrite replaces only a seedmap {kind} result (pick another output "
                         "path)", out)
    if kind not in DATASET_KINDS:
        fmt = detect_format(out)
        if fmt is not None:
            raise InputError(f"is a {fmt} dataset; --overwrite never replaces data (pick another output path)", out)


def _os_error(e: OSError | WriteError, path: Path) -> InputError:
    if e.errno == errno.ENOSPC:
        return InputError("no space left on the device; nothing was written", path)
    reason = e.reason if isinstance(e, WriteError) else (e.strerror or e)
    return InputError(f"cannot write here ({reason}); nothing was written", path)


@contextlib.contextmanager
def output_dir(out: Path, kind: str, inputs: Iterable[str | Path | None] = (),
               overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling folder; when the block ends without error it becomes ``out`` in one rename.

    ``out`` is checked with :func:`check_output_dir`; leftovers of killed runs are removed first. The old folder
    (a seedmap output of the same kind) is removed only after the new one is complete. On any error — a full
    disk included — the temporary folder is deleted, ``out`` is untouched and an OS error becomes one line.
    """
    out = Path(out)
    inputs = list(inputs)
    check_output_dir(out, kind, inputs, overwrite)
    clean_stale_partials(out)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.{secrets.token_hex(4)}.partial")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()  # 0o777 less the umask, like any new folder
    except OSError as e:
        raise _os_error(e, out) from None
    try:
        try:
            yield tmp
            write_marker(tmp, kind)
            if out.exists():
                old = out.with_name(f".{out.name}.{os.getpid()}.{secrets.token_hex(4)}.old")
                os.replace(out, old)
                os.replace(tmp, out)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, out)
        except (OSError, WriteError) as e:  # a full disk while writing: one line naming the output
            raise _os_error(e, out) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def check_resume_dir(out: Path, kind: str, inputs: Iterable[str | Path | None] = (), strict: bool = True) -> None:
    """What :func:`resume_dir` checks, for commands that create the folder later (training)."""
    out = Path(out)
    _check_folder_target(out, inputs)
    if out.exists() and any(out.iterdir()):
        found = output_kind(out)
        if found != kind and (strict or found is not None):
            what = "not a folder seedmap wrote" if found is None else f"a seedmap {found} output"
            raise InputError(f"exists and is {what}; {kind} writes and resumes only in its own output folder "
                             "(pick another output path)", out)
        fmt = detect_format(out)
        if fmt is not None:
            raise InputError(f"is a {fmt} dataset; pick another output path", out)


def mark(out: Path, kind: str) -> None:
    """Create ``out`` (if needed) with its marker (kept when it has one)."""
    out = Path(out)
    with os_errors(out):
        out.mkdir(parents=True, exist_ok=True)
        if read_marker(out) is None:
            write_marker(out, kind)


def resume_dir(out: Path, kind: str, inputs: Iterable[str | Path | None] = (), strict: bool = True) -> Path:
    """Open a folder that a command fills run by run and resumes (benchmark, batch, training); returns ``out``.

    An existing non-empty folder must be a seedmap output of this ``kind`` (``strict=False``: or a folder
    seedmap did not write, never another kind's output); a folder that is, contains or lies inside an input, or
    that a loader reads as a dataset, is refused. The marker is written first, so that a killed run resumes.
    """
    out = Path(out)
    check_resume_dir(out, kind, inputs, strict)
    clean_stale_partials(out)
    mark(out, kind)
    return out


@contextlib.contextmanager
def os_errors(path: Path) -> Iterator[None]:
    """Turn an ``OSError`` (full disk, permissions) raised in the block into one line naming ``path``."""
    try:
        yield
    except (OSError, WriteError) as e:
        raise _os_error(e, Path(path)) from None


def check_output_file(path: Path, inputs: Iterable[str | Path | None] = (), overwrite: bool = False,
                      written_by_seedmap: Callable[[Path], bool] | None = None, what: str = "file") -> None:
    """Refuse to replace a file that is an input, exists without ``overwrite``, or that seedmap did not write."""
    path = Path(path)
    check_not_input(path, inputs, what)
    check_output_parent(path, what)
    if path.is_symlink() or (path.exists() and not path.is_file()):
        raise InputError(f"exists and is not a regular {what}", path)
    if not path.exists():
        return
    if not overwrite:
        raise InputError(f"exists (pass --overwrite to replace a {what} seedmap wrote)", path)
    if written_by_seedmap is not None and not written_by_seedmap(path):
        raise InputError(f"was not written by seedmap; --overwrite replaces only seedmap's own {what}s (pick "
                         "another path)", path)


def is_rerun_recording(path: Path) -> bool:
    """Whether ``path`` starts like a rerun ``.rrd`` recording (what ``--rerun FILE`` writes)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError:
        return False
    return head in (b"RRF2", b"RRF0", b"RRF1", b"RRIS")


def is_seedmap_json(path: Path, key: str = "seedmap") -> bool:
    """Whether ``path`` is a JSON object seedmap wrote (it carries a ``key`` entry)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(data, dict) and key in data
