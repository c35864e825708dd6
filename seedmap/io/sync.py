"""Pairing two cameras' timestamps: mutual nearest neighbours within a tolerance."""

from __future__ import annotations

import numpy as np


def match_stamps(a: np.ndarray, b: np.ndarray, tol_s: float) -> tuple[np.ndarray, np.ndarray, int]:
    """One-to-one pairs ``(ia, ib)`` of two sorted stamp lists (seconds) with ``|a - b| <= tol_s``.

    A pair is kept when each stamp is the other's nearest (so a missing frame in one camera drops one
    frame instead of shifting every later pair). Returns the index arrays (increasing) and the number of
    stamps left without a partner in either list.
    """
    a = np.asarray(a, float).reshape(-1)
    b = np.asarray(b, float).reshape(-1)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), len(a) + len(b)

    def nearest(x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(ref, x), 1, len(ref) - 1) if len(ref) > 1 else np.zeros(len(x), np.int64)
        if len(ref) == 1:
            return k
        left_closer = np.abs(x - ref[k - 1]) <= np.abs(ref[k] - x)
        return np.where(left_closer, k - 1, k)

    ab = nearest(a, b)
    ba = nearest(b, a)
    ia = np.flatnonzero((ba[ab] == np.arange(len(a))) & (np.abs(a - b[ab]) <= tol_s))
    ib = ab[ia]
    dropped = (len(a) - len(ia)) + (len(b) - len(ib))
    return ia.astype(np.int64), ib.astype(np.int64), int(dropped)
