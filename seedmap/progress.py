"""One progress bar for every long loop: tqdm on stderr, silent when disabled or stderr is not a terminal.

Use it as a context manager (``with Progress(total, "slam", "frame", enabled) as bar: bar.advance()``) or wrap an
iterable (``for x in track(items, "detect", "frame", enabled=progress): ...``).
"""

from __future__ import annotations

import sys
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")

__all__ = ["Progress", "track"]


class Progress:
    """A tqdm bar on stderr, or nothing (``enabled=False`` or no terminal): every method is then a no-op."""

    def __init__(self, total: int | None = None, desc: str = "", unit: str = "it", enabled: bool = True,
                 initial: int = 0) -> None:
        self._bar = None
        if enabled:
            from tqdm import tqdm

            # disable=None: tqdm stays silent when stderr is not a TTY (logs, CI, pipes)
            self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr, disable=None,
                             dynamic_ncols=True)

    def advance(self, n: int = 1) -> None:
        """Count ``n`` finished items."""
        if self._bar is not None:
            self._bar.update(n)

    def note(self, text: str) -> None:
        """Show ``text`` after the bar (the item just finished or started)."""
        if self._bar is not None:
            self._bar.set_postfix_str(text)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def track(items: Iterable[T], desc: str = "", unit: str = "it", total: int | None = None,
          enabled: bool = True) -> Iterator[T]:
    """Yield ``items``, advancing a :class:`Progress` bar (``total`` defaults to ``len(items)`` when known)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with Progress(total, desc, unit, enabled) as bar:
        for x in items:
            yield x
            bar.advance()
