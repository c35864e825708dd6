"""The decorator of seedmap's compiled (numba) kernels: ``@kernel`` = ``numba.njit(cache=True, nogil=True)``.

The machine code is cached on disk (next to the module, else in the user's cache folder, or ``NUMBA_CACHE_DIR``) so
only the first run after installing compiles it; where no cache folder is writable the kernels are compiled in memory
on every run instead. ``nogil``: the prefetch thread's detector kernels run alongside the association's.
"""

from __future__ import annotations

from collections.abc import Callable

from numba import njit


def kernel(fn: Callable) -> Callable:
    """``fn`` compiled with numba in nopython mode, cached on disk when a cache folder is writable."""
    try:
        return njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available" (read-only install and home)
        return njit(nogil=True)(fn)
