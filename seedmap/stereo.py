"""Dense stereo: the one OpenCV ``StereoSGBM`` call of seedmap.

Two stages need a disparity image of a rectified pair: the panicle reconstruction (SGBM clouds,
seedmap.recon.stereo) and the optional dense prior of the stereo association
(seedmap.associate.disparity). Both call :func:`sgbm_disparity`; they differ only in parameters
(colour vs grey matching, left-right check, speckle filter, left padding).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

#: SGBM stores disparities as fixed point with 4 fractional bits.
SGBM_SCALE = 16.0

_MODES = {"sgbm": 0, "hh": 1, "3way": 2}  # cv2.STEREO_SGBM_MODE_SGBM / _HH / _SGBM_3WAY


def sgbm_disparity(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int,
                   block: int = 3, uniqueness: int = 5, lr_max_diff: int = 0, *, p1_factor: int = 8,
                   p2_factor: int = 32, speckle_window: int = 0, speckle_range: int = 0,
                   mode: Literal["sgbm", "hh", "3way"] = "3way", grey: bool = True,
                   pad_left: bool = True) -> np.ndarray:
    """Dense disparity ``(H, W)`` float32 of a rectified pair (image px, NaN where SGBM found none).

    ``left``/``right``: RGB (or grey) images of one size. ``grey=True`` matches intensities, else the
    three colour channels (SGBM sums its cost over channels, so RGB and BGR give the same result).
    Smoothness penalties ``P1 = p1_factor * channels * b^2`` and ``P2 = p2_factor * channels * b^2``
    for a block of ``b`` px. ``num_disparities`` is rounded down to a multiple of 16 (at least 16).
    ``lr_max_diff``: OpenCV's ``disp12MaxDiff``, the left-right consistency tolerance (px; pixels
    occluded in one view get none); OpenCV treats values ``<= 0`` as its smallest tolerance. ``pad_left`` pads both images on the left by
    ``min_disparity + num_disparities`` replicated columns and crops them again, so that columns
    near the left border (which SGBM otherwise leaves empty) get a disparity too."""
    import cv2

    gl, gr = _prepare(left, grey), _prepare(right, grey)
    if gl.shape != gr.shape:
        raise ValueError(f"left {gl.shape} and right {gr.shape} images differ in size")
    num = max(16, int(num_disparities) // 16 * 16)
    mind = int(min_disparity)
    pad = max(0, mind + num) if pad_left else 0
    if pad:
        gl = cv2.copyMakeBorder(gl, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        gr = cv2.copyMakeBorder(gr, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    b = int(block)
    ch = 1 if gl.ndim == 2 else gl.shape[2]
    sgbm = cv2.StereoSGBM_create(minDisparity=mind, numDisparities=num, blockSize=b,
                                 P1=int(p1_factor) * ch * b * b, P2=int(p2_factor) * ch * b * b,
                                 disp12MaxDiff=int(lr_max_diff),
                                 uniquenessRatio=int(uniqueness), speckleWindowSize=int(speckle_window),
                                 speckleRange=int(speckle_range), mode=_MODES[mode])
    raw = sgbm.compute(gl, gr)[:, pad:]
    d = raw.astype(np.float32) / SGBM_SCALE
    d[raw <= (mind - 1) * SGBM_SCALE] = np.nan  # SGBM marks "no disparity" with (minDisparity - 1) * 16
    return d


def _prepare(img: np.ndarray, grey: bool) -> np.ndarray:
    import cv2

    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.clip(a, 0, 255).astype(np.uint8)
    if a.ndim == 3:
        a = a[..., :3]
        if grey:
            a = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(a)
