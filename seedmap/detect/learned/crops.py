"""Box crops for the segmenter, with an exact affine map back to full-image pixels.

A crop is the square of side ``S = max(w, h) * (1 + 2 * pad)`` (pixels) centred on the box,
resampled to ``N x N``. With the pixel-centre convention, crop pixel ``c`` maps to full-image
``u = (c + 0.5) / a + x_edge - 0.5`` where ``a = N / S`` and ``x_edge`` is the left pixel edge of
the square; :func:`crop_affine` returns the 2x3 full->crop matrix for ``cv2.warpAffine``.
"""

from __future__ import annotations

import cv2
import numpy as np

#: segmenter crop padding on each side, as a fraction of the box's larger side
CROP_PAD = 0.5


def crop_windows(boxes: np.ndarray, pad: float) -> np.ndarray:
    """``(N, 3)`` crop squares: left edge, top edge (continuous px, pixel k spans [k-.5, k+.5)), side."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    side = np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]) * (1.0 + 2.0 * pad)
    side = np.maximum(side, 4.0)
    # box index bounds [x0, x1) -> continuous edges x0 - 0.5 .. x1 - 0.5
    cx = (b[:, 0] + b[:, 2]) / 2 - 0.5
    cy = (b[:, 1] + b[:, 3]) / 2 - 0.5
    return np.stack([cx - side / 2, cy - side / 2, side], axis=1)


def crop_affine(win: np.ndarray, n: int) -> np.ndarray:
    """2x3 matrix mapping full-image pixel coordinates into an ``n x n`` crop of window ``win``."""
    x_edge, y_edge, side = win
    a = n / side
    return np.array([[a, 0.0, -a * x_edge - 0.5], [0.0, a, -a * y_edge - 0.5]])


def crop_to_full(pts: np.ndarray, win: np.ndarray, n: int) -> np.ndarray:
    """Crop pixel coordinates ``(..., 2)`` -> full-image pixel coordinates."""
    x_edge, y_edge, side = win
    a = n / side
    p = np.asarray(pts, np.float64)
    return np.stack([(p[..., 0] + 0.5) / a + x_edge, (p[..., 1] + 0.5) / a + y_edge], axis=-1)


def extract_crops(image: np.ndarray, boxes: np.ndarray, n: int, pad: float,
                  labels: np.ndarray | None = None, label_ids: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(crops (K, n, n, 3) uint8, windows (K, 3), masks (K, n, n) uint8 | None)``.

    With ``labels`` (an instance label image) and ``label_ids``, the target mask of crop ``k`` is
    ``labels == label_ids[k]`` resampled with nearest neighbour.
    """
    wins = crop_windows(boxes, pad)
    k = len(wins)
    crops = np.zeros((k, n, n, 3), np.uint8)
    masks = np.zeros((k, n, n), np.uint8) if labels is not None else None
    for i, w in enumerate(wins):
        M = crop_affine(w, n)
        crops[i] = cv2.warpAffine(image, M, (n, n), flags=cv2.INTER_AREA if w[2] > n else cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if masks is not None:
            x0, y0 = int(max(np.floor(w[0]), 0)), int(max(np.floor(w[1]), 0))
            x1 = int(min(np.ceil(w[0] + w[2]) + 1, labels.shape[1]))
            y1 = int(min(np.ceil(w[1] + w[2]) + 1, labels.shape[0]))
            sub = (labels[y0:y1, x0:x1] == label_ids[i]).astype(np.uint8)
            Ms = M.copy()
            Ms[:, 2] += M[:, :2] @ np.array([x0, y0], np.float64)
            masks[i] = cv2.warpAffine(sub, Ms, (n, n), flags=cv2.INTER_NEAREST, borderValue=0)
    return crops, wins, masks
