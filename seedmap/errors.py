"""User-facing errors.

Anything the user can fix (a bad path, a malformed file, an impossible parameter) raises
:class:`SeedmapError` with a one-line message that names the file and the problem. The CLI
prints that line and exits non-zero; it never shows a traceback for these.
"""

from __future__ import annotations

from pathlib import Path


class SeedmapError(Exception):
    """A problem with the user's input or environment, explained in one line."""

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else None
        text = f"{path}: {message}" if path is not None else message
        super().__init__(text.replace("\n", " "))


class InputError(SeedmapError):
    """A file or folder the user gave us is missing, unreadable or malformed."""


class ConfigError(SeedmapError):
    """A configuration value is invalid."""
