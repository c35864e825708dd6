"""Compiled (numba) pixel gathers of the fast detector, each giving exactly what the numpy code it replaces gave.

* :func:`tile_batch` - the network's input batch: ``tile + 2 * margin`` px windows of the padded image, channels
  first, scaled to [0, 1] (``np.stack`` + ``astype`` + ``transpose`` in one pass);
* :func:`gather_patches` - the refiner's RGB patches around peaks, written straight into its feature rows.

Both map every uint8 value through a 256-entry table computed by the numpy expression they replace, so the floats
are the same bit for bit. Kernels compile on first use and are cached on disk (:func:`seedmap.compiled.kernel`).
"""

from __future__ import annotations

import numpy as np

from seedmap.compiled import kernel

#: ``uint8 -> float32`` of the network input (``x.astype(np.float32) * (1.0 / 255.0)``)
INPUT_LUT = np.arange(256).astype(np.uint8).astype(np.float32) * (1.0 / 255.0)
#: ``uint8 -> float32`` of the refiner's patches (``x.astype(np.float32) / 255.0``)
PATCH_LUT = np.arange(256).astype(np.uint8).astype(np.float32) / 255.0


@kernel
def tile_batch(pad: np.ndarray, tiles: np.ndarray, t: int, s: int, lut: np.ndarray) -> np.ndarray:
    """``(K, C, s, s)`` float32: for tile ``(ty, tx)`` of ``tiles`` (K, 2) the window ``pad[ty t: ty t + s,
    tx t: tx t + s]`` of the ``(H, W, C)`` uint8 image, channels first, every value mapped by ``lut``."""
    k = len(tiles)
    ch = pad.shape[2]
    out = np.empty((k, ch, s, s), np.float32)
    for b in range(k):
        y0 = tiles[b, 0] * t
        x0 = tiles[b, 1] * t
        for i in range(s):
            for j in range(s):
                for c in range(ch):
                    out[b, c, i, j] = lut[pad[y0 + i, x0 + j, c]]
    return out


@kernel
def gather_patches(img: np.ndarray, x: np.ndarray, y: np.ndarray, r: int, lut: np.ndarray, out: np.ndarray) -> None:
    """Write into ``out[p, :(2r+1)^2 C]`` the square of half size ``r`` around pixel ``(x[p], y[p])`` of the
    ``(H, W, C)`` uint8 ``img``, row-major with the channels of a pixel together, every value mapped by ``lut``,
    0 outside the image."""
    h, w, ch = img.shape
    flat = img.reshape(-1)
    rowlen = (2 * r + 1) * ch
    for p in range(len(x)):
        k = 0
        if r <= x[p] < w - r and r <= y[p] < h - r:  # the whole square inside: one contiguous run per row
            for yy in range(y[p] - r, y[p] + r + 1):
                s0 = (yy * w + x[p] - r) * ch
                for e in range(rowlen):
                    out[p, k + e] = lut[flat[s0 + e]]
                k += rowlen
            continue
        for dy in range(-r, r + 1):
            yy = y[p] + dy
            for dx in range(-r, r + 1):
                xx = x[p] + dx
                inside = 0 <= yy < h and 0 <= xx < w
                for c in range(ch):
                    out[p, k] = lut[img[yy, xx, c]] if inside else np.float32(0.0)
                    k += 1
