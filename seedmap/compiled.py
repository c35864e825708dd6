"""The decorator of seedmap's compiled (numba) kernels: ``@kernel`` = ``numba.njit(cache=True, nogil=True)``.

The machine code is cached on disk (next to the module, else in the user's cache folder, or ``NUMBA_CACHE_DIR``) so
only the first run after installing compiles it; where no cache folder is writable the kernels are compiled in memory
on every run instead. ``nogil``: the prefetch thread's detector kernels run alongside the association's.

:func:`cell_members` is the one kernel the association's and the detector's grid searches share.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit


def kernel(fn: Callable) -> Callable:
    """``fn`` compiled with numba in nopython mode, cached on disk when a cache folder is writable."""
    try:
        return njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available" (read-only install and home)
        return njit(nogil=True)(fn)


@kernel
def cell_members(cid: np.ndarray, ncell: int) -> tuple[np.ndarray, np.ndarray]:
    """The points of each of ``ncell`` grid cells, given each point's cell ``cid`` (N,): ``counts`` (ncell + 1,)
    and ``members`` (N,), the points of cell ``c`` being ``members[counts[c]:counts[c + 1]]`` in increasing order."""
    counts = np.zeros(ncell + 1, np.int64)
    for p in range(len(cid)):
        counts[cid[p] + 1] += 1
    for c in range(ncell):
        counts[c + 1] += counts[c]
    fill = counts[:-1].copy()
    members = np.empty(len(cid), np.int64)
    for p in range(len(cid)):
        members[fill[cid[p]]] = p
        fill[cid[p]] += 1
    return counts, members
