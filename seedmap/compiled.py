"""The decorator of seedmap's compiled (numba) kernels: ``@kernel`` = ``numba.njit(cache=True, nogil=True)``.

The machine code is cached on disk (next to the module, else in the user's cache folder, or ``NUMBA_CACHE_DIR``) so
only the first run after installing compiles it; where no cache folder is writable the kernels are compiled in memory
on every run instead. ``nogil``: the prefetch thread's detector kernels run alongside the association's.

:func:`cell_members` and :func:`insert_sorted` are the kernels the association's and the detector's grid searches
share.
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


@kernel
def insert_sorted(bd: np.ndarray, bi: np.ndarray, cnt: int, cap: int, d: float, j: int) -> int:
    """Insert ``(d, j)`` into the ascending best list ``bd``/``bi`` of ``cnt`` entries (at most ``cap``; an entry
    equal to others goes after them); the new count."""
    if cnt == cap and d >= bd[cap - 1]:
        return cnt
    p = cnt if cnt < cap else cap - 1
    while p > 0 and bd[p - 1] > d:
        if p < cap:
            bd[p] = bd[p - 1]
            bi[p] = bi[p - 1]
        p -= 1
    bd[p] = d
    bi[p] = j
    return cnt + 1 if cnt < cap else cnt
