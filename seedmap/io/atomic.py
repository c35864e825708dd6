"""No half-written files: write to a temporary name in the same folder, then rename.

Output folders (what may be replaced, markers, leftovers of killed runs) are :mod:`seedmap.outputs`."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from seedmap.errors import InputError


class WriteError(InputError):
    """Writing a file failed (full disk, read-only or special file system); ``errno`` and ``reason`` say why."""

    def __init__(self, e: OSError, path: Path) -> None:
        self.errno, self.reason = e.errno, e.strerror or str(e)
        super().__init__(f"cannot write here ({self.reason}); nothing was written", path)


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
        raise WriteError(e, path) from None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file normal permissions
        os.replace(tmp, path)
    except OSError as e:  # a full disk while writing
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise WriteError(e, path) from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))
