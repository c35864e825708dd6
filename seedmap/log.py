"""User-facing warnings: one path, one line each.

Library code calls :func:`warn` for what the user should know and can act on (a scan whose views are far
apart, grayscale images converted, frames dropped). It logs to the ``seedmap`` logger: the command line prints
each message as one ``warning: <message>`` line on stderr (:func:`cli_messages`); a library user gets Python's
logging (its last-resort handler prints the message). Python warnings from other libraries reach the user the
same way during a command (the message only, without the source file and line). Numerical warnings inside
seedmap's own maths are silenced where they arise (``np.errstate``), not printed.
"""

from __future__ import annotations

import logging
import sys
import warnings
from contextlib import contextmanager
from typing import Iterator, TextIO

__all__ = ["LOGGER", "warn", "cli_messages", "one_line"]

#: name of the logger every seedmap warning goes through (``seedmap.io`` and other children included)
LOGGER = "seedmap"


def warn(message: str) -> None:
    """Tell the user something that changes what a result means (printed as one ``warning: `` line)."""
    logging.getLogger(LOGGER).warning(message)


def one_line(message: object) -> str:
    """``message`` as one line (line breaks become spaces)."""
    return " ".join(str(message).split())


class _OneLine(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"warning: {one_line(record.getMessage())}"


class _StderrHandler(logging.StreamHandler):
    """Writes to the ``sys.stderr`` of the moment (tests replace it), each distinct message once."""

    def __init__(self) -> None:
        super().__init__()
        self.setFormatter(_OneLine())
        self._said: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if text not in self._said:  # e.g. the same scan warning for every reconstruction of a calibration
            self._said.add(text)
            super().emit(record)

    @property
    def stream(self) -> TextIO:  # type: ignore[override]
        return sys.stderr

    @stream.setter
    def stream(self, value: TextIO) -> None:  # StreamHandler.__init__ assigns it
        pass


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
    """``warnings.showwarning`` replacement: the message on one ``warning: `` line, no source location."""
    try:
        (file or sys.stderr).write(f"warning: {one_line(message)}\n")
    except (OSError, ValueError):  # stderr closed: nowhere to say it
        pass


@contextmanager
def cli_messages() -> Iterator[None]:
    """Within: seedmap's warnings and Python warnings print as ``warning: <message>`` lines on stderr."""
    log = logging.getLogger(LOGGER)
    handler = _StderrHandler()
    old_propagate, old_show = log.propagate, warnings.showwarning
    log.addHandler(handler)
    log.propagate = False  # not twice through a handler the application configured on the root logger
    warnings.showwarning = _show_warning
    try:
        yield
    finally:
        warnings.showwarning = old_show
        log.removeHandler(handler)
        log.propagate = old_propagate


def cli_messages_forever() -> None:
    """:func:`cli_messages` for the rest of this process (worker processes of a command)."""
    cli_messages().__enter__()
