"""Reading the user's text files: decoded as UTF-8, numbers parsed and checked, one-line errors naming the file.

Every text file seedmap reads (calibrations, times.txt, joints.csv, arm.yaml, counts CSV, COCO json,
detections.jsonl, a result's calib.yaml/config.yaml) goes through :func:`read_text`, so a binary or UTF-16
file is an :class:`~seedmap.errors.InputError`, never a ``UnicodeDecodeError``.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from seedmap.errors import InputError


def read_text(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of ``path``; ``what`` names the file in the error ("calibration file", "joints.csv")."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{what} is not UTF-8 text (a binary file, or another encoding such as UTF-16: "
                         "save it as UTF-8)", path) from None
    except FileNotFoundError:
        raise InputError(f"{what} not found", path) from None
    except IsADirectoryError:
        raise InputError(f"{what} is a folder, not a file", path) from None
    except OSError as e:
        raise InputError(f"cannot read {what} ({e.strerror or type(e).__name__})", path) from None


def read_table(path: str | Path, what: str, skip_header: int = 1, delimiter: str | None = ",",
               finite: bool = True) -> np.ndarray:
    """A numeric table (CSV with ``skip_header`` header lines) as an ``N x C`` float array (``0 x 0`` if empty).

    Non-numeric cells, ragged rows and (with ``finite``) NaN/inf are one-line errors naming the file.
    """
    path = Path(path)
    text = read_text(path, what)
    try:
        with warnings.catch_warnings():  # an empty table is reported by the caller, not by numpy's warning
            warnings.simplefilter("ignore", UserWarning)
            a = np.loadtxt(io.StringIO(text), delimiter=delimiter, skiprows=skip_header, ndmin=2)
    except ValueError as e:
        raise InputError(f"{what} must hold numbers only ({str(e).splitlines()[0][:100]})", path) from None
    if finite and not np.all(np.isfinite(a)):
        row = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
        raise InputError(f"{what} has NaN or inf (data row {row + 1})", path)
    return a
