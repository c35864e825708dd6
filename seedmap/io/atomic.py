"""No half-written outputs: write to a temporary name in the same folder, then rename."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from seedmap.errors import InputError
from seedmap.io.registry import detect_format


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as e:  # read-only or special file system, permission denied (also as root), disk full
        raise InputError(f"cannot write here ({e.strerror or e})", path) from None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file normal permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def check_output_parent(out: Path) -> None:
    """Fail early (one line) when ``out`` cannot be created: parent not writable or a file."""
    out = Path(out)
    parent = out.parent if str(out.parent) else Path(".")
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError("output parent is not a folder", probe)
    if not os.access(probe, os.W_OK | os.X_OK):
        raise InputError("output folder is not writable", probe)
    if out.exists() and not out.is_dir():
        raise InputError("output path exists and is not a folder", out)


def refuse_replacing_data(out: Path) -> None:
    """``--overwrite`` replaces result folders and simulated datasets, never recorded data.

    ``seedmap detect DATA --out DATA --overwrite`` (or slam, reconstruct) deleted the user's dataset and put
    the results in its place. A folder any loader recognises is refused, except a simulated seedmap dataset
    (``gt/config.yaml``), which ``seedmap simulate ... --overwrite`` re-renders.
    """
    def recorded(p: Path) -> str | None:
        fmt = detect_format(p)
        return None if fmt == "seedmap" and (p / "gt" / "config.yaml").is_file() else fmt

    fmt = recorded(out)
    if fmt is not None:
        raise InputError(f"is a {fmt} dataset: --overwrite replaces result folders and simulated datasets, never "
                         "recorded data (pick another --out)", out)
    if (out / "config.yaml").is_file() or detect_format(out) is not None:
        return  # a seedmap result folder (they all hold config.yaml) or a simulated dataset
    for child in sorted(out.iterdir())[:1000]:  # `--out ~/data --overwrite` with the input inside ~/data
        fmt = recorded(child)
        if fmt is not None:
            raise InputError(f"holds a {fmt} dataset ({child.name}) that --overwrite would delete (pick another "
                             "--out)", out)


@contextlib.contextmanager
def atomic_output_dir(out: Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling folder; on success it replaces ``out`` in one rename.

    ``out`` must not exist unless ``overwrite`` is set (then the old folder is removed only after
    the new one is complete). On any error the temporary folder is deleted and ``out`` is untouched.
    """
    out = Path(out)
    check_output_parent(out)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise InputError("output folder exists and is not empty (pass --overwrite to replace it)", out)
        refuse_replacing_data(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    except OSError as e:  # os.access() above says yes to root even where the file system refuses
        raise InputError(f"cannot create the output folder here ({e.strerror or e})", out) from None
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp creates 0700
    try:
        yield tmp
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
