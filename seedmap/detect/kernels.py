"""Compiled (numba) pixel gathers of the fast detector, each giving exactly what the numpy code it replaces gave.

* :func:`window_batch` - the network's input batch: equal windows of the padded image (a run of tiles plus the
  margin), channels first, scaled to [0, 1] (``np.stack`` + ``astype`` + ``transpose`` in one pass);
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
def window_batch(pad: np.ndarray, origins: np.ndarray, sh: int, sw: int, lut: np.ndarray) -> np.ndarray:
    """``(K, C, sh, sw)`` float32: for origin ``(y0, x0)`` of ``origins`` (K, 2) the window ``pad[y0: y0 + sh,
    x0: x0 + sw]`` of the ``(H, W, C)`` uint8 image, channels first, every value mapped by ``lut``."""
    k = len(origins)
    ch = pad.shape[2]
    out = np.empty((k, ch, sh, sw), np.float32)
    for b in range(k):
        y0 = origins[b, 0]
        x0 = origins[b, 1]
        for i in range(sh):
            for j in range(sw):
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
