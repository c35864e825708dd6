"""Frame timestamps: ``times.txt`` read and checked (finite, strictly increasing, not empty)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.text import read_text


def check_timestamps(ts: np.ndarray, where: str | Path) -> np.ndarray:
    """Finite and strictly increasing, else a one-line error naming the file."""
    ts = np.asarray(ts, float).reshape(-1)
    if not np.all(np.isfinite(ts)):
        raise InputError("timestamps contain NaN or inf", where)
    if len(ts) > 1:
        bad = np.flatnonzero(np.diff(ts) <= 0)
        if len(bad):
            k = int(bad[0])
            raise InputError(f"timestamps are not strictly increasing (entry {k + 1}: {float(ts[k + 1])!r} after "
                             f"{float(ts[k])!r}); sort the frames or fix the clock", where)
    return ts


def read_times_txt(path: Path, n: int | None = None) -> np.ndarray:
    """``times.txt``: one timestamp in seconds per line (blank and ``#`` lines ignored); ``n`` = expected count."""
    path = Path(path)
    if not path.is_file():
        raise InputError("times file not found", path)
    text = read_text(path, "times file")
    vals = []
    for i, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 1:
            raise InputError(f"line {i}: expected one timestamp (seconds) per line, got {len(parts)} values", path)
        try:
            vals.append(float(parts[0]))
        except ValueError:
            raise InputError(f"line {i}: {parts[0]!r} is not a number", path) from None
    if not vals:
        raise InputError("times file is empty (one timestamp in seconds per frame)", path)
    ts = check_timestamps(np.asarray(vals, float), path)
    if n is not None and len(ts) != n:
        raise InputError(f"has {len(ts)} timestamps but there are {n} stereo pairs (one line per pair)", path)
    return ts
