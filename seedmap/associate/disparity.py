"""Dense stereo disparity as the prior of the semantic stereo association (``stereo_prior="sgbm"``),
and the image-patch descriptors (NCC) that verify stereo and temporal matches.

Why: seeds have no distinctive appearance, but the *image* around a seed (its neighbours, the
panicle's silhouette, the shading of the flash) is the same in the two rectified views, so a dense
stereo matcher (OpenCV's semi-global block matching, a chosen dependency) finds the disparity of
almost every seed pixel to well below the seed spacing (gt oracle, 1434 px, slam_r1: median error
0.27 px, 90 % within 1 px, while neighbouring seeds are 3-4 px apart). The keypoint matcher then
only has to pick the right keypoint next to ``(u - D(u, v), v)`` (see
:func:`seedmap.associate.semantic.match_stereo_keypoints`), where the geometry-only field prior
(the disparity of a seed = its neighbours') is ambiguous for seeds in front of or behind their
panicle.

Cost control: SGBM's CPU time grows with the number of disparities searched, so the search is
restricted to the disparities the scene can have: the range of the previous frame's stereo
matches (or of a first keypoint-only matching) widened by a margin (:func:`disparity_search_range`).
Full resolution is kept: at half resolution the error doubles (median 0.6 px, 90th percentile
~2 px) and the recall of the 1-px match drops from 0.88 to 0.70 (slam_r1 frame 5).
Both images are padded on the left by the largest disparity searched, so keypoints near the left
image border (which SGBM leaves without disparity otherwise) still get one. The SGBM call itself is
:func:`seedmap.stereo.sgbm_disparity` (grey matching), the same one the reconstruction uses.
"""

from __future__ import annotations

import numpy as np

from seedmap.stereo import sgbm_disparity  # noqa: F401  (the one SGBM call, shared with seedmap.recon)


def disparity_search_range(disparities: np.ndarray, margin_px: float, min_disparity_px: float,
                           max_disparities: int) -> tuple[int, int] | None:
    """``(min_disparity, num_disparities)`` for SGBM (image px) covering ``disparities`` (the
    disparities of known stereo matches) widened by ``margin_px`` on both sides.

    The range never goes below the stereo gate ``min_disparity_px``; ``num_disparities`` is a
    multiple of 16 (SGBM's requirement) and at most ``max_disparities`` (the range is then centred
    on the median). ``None`` when fewer than 10 disparities are known (no basis for a range)."""
    d = np.asarray(disparities, np.float64).reshape(-1)
    d = d[np.isfinite(d)]
    if len(d) < 10:
        return None
    lo, hi = np.percentile(d, [0.5, 99.5])
    lo = max(float(min_disparity_px), lo - margin_px)
    hi = max(lo + 16.0, hi + margin_px)
    nmax = max(16, int(max_disparities) // 16 * 16)
    num = int(np.ceil((hi - lo) / 16.0)) * 16
    if num > nmax:
        lo = max(float(min_disparity_px), float(np.median(d)) - nmax / 2)
        num = nmax
    return int(np.floor(lo)), num


def disparity_at(disp: np.ndarray, kp: np.ndarray, radius: int = 1) -> np.ndarray:
    """Disparity of each keypoint ``kp`` (N, 2; u, v image px): the median of the valid values in
    the ``(2 radius + 1)^2`` pixel window around it (a seed is a blob a few px wide, and the median
    ignores single-pixel holes and speckles); NaN when the window holds none."""
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    if len(kp) == 0:
        return np.zeros(0)
    h, w = disp.shape
    x = np.clip(np.round(kp[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(kp[:, 1]).astype(int), 0, h - 1)
    offs = np.arange(-radius, radius + 1)
    xs = np.clip(x[:, None, None] + offs[None, None, :], 0, w - 1)
    ys = np.clip(y[:, None, None] + offs[None, :, None], 0, h - 1)
    win = disp[ys, xs].reshape(len(kp), -1).astype(np.float64)
    ok = np.isfinite(win)
    cnt = ok.sum(1)
    # median of the valid values without nanmedian's all-NaN warnings: sort NaN last, pick the middle
    srt = np.sort(np.where(ok, win, np.inf), axis=1)
    lo = np.take_along_axis(srt, np.maximum((cnt - 1) // 2, 0)[:, None], 1)[:, 0]
    hi = np.take_along_axis(srt, np.maximum(cnt // 2, 0)[:, None], 1)[:, 0]
    out = 0.5 * (lo + hi)
    out[cnt == 0] = np.nan
    return out



def patch_descriptors(image: np.ndarray, kp: np.ndarray, size: int) -> np.ndarray:
    """Zero-mean, unit-norm grey patches ``(N, size * size)`` float32 centred on the keypoints ``kp``
    (N, 2; u, v image px, sub-pixel, bilinear interpolation; borders reflected).

    Why: a seed itself looks like its neighbours, but a patch a few seed spacings wide also holds
    the neighbours' arrangement and the panicle's shading, which are the same in the two rectified
    views and in consecutive frames; the dot product of two descriptors is their normalised
    cross-correlation (NCC, -1..1). One ``cv2.remap`` call for all keypoints (no loop); a constant
    patch gives the zero vector (NCC 0 with everything)."""
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    size = max(1, int(size))
    if len(kp) == 0:
        return np.zeros((0, size * size), np.float32)
    return _normalised(_raw_patches(grey_image(image), kp, size).reshape(len(kp), -1))


def grey_image(image: np.ndarray) -> np.ndarray:
    """The grey image :func:`patch_descriptors` samples (uint8 from RGB; a 2-D image unchanged): convert
    once when sampling several patch sizes of one image."""
    import cv2

    a = np.asarray(image)
    if a.ndim == 3:
        a = cv2.cvtColor(np.ascontiguousarray(a[..., :3]).astype(np.uint8, copy=False), cv2.COLOR_RGB2GRAY)
    return a


def _raw_patches(a: np.ndarray, kp: np.ndarray, size: int) -> np.ndarray:
    """Bilinear samples ``(N, size, size[, C])`` of image ``a`` on the ``size x size`` px grid centred
    on each keypoint (one ``cv2.remap``; borders reflected)."""
    import cv2

    r = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    dx, dy = np.meshgrid(r, r)
    mx = (kp[:, :1] + dx.reshape(1, -1)).astype(np.float32)
    my = (kp[:, 1:2] + dy.reshape(1, -1)).astype(np.float32)
    out = cv2.remap(np.ascontiguousarray(a), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return out.reshape(len(kp), size, size, *out.shape[2:])


def _normalised(out: np.ndarray) -> np.ndarray:
    """Rows zero-mean and unit-norm (float32; a constant row becomes zeros)."""
    out = np.ascontiguousarray(out).astype(np.float32)
    out -= out.mean(1, keepdims=True)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    out /= np.where(norm > 1e-6, norm, 1.0)
    return out


def patch_ncc(desc_a: np.ndarray, desc_b: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """NCC of the descriptor pairs ``(desc_a[ia[k]], desc_b[ib[k]])`` (K,), see :func:`patch_descriptors`."""
    ia, ib = np.asarray(ia, np.int64), np.asarray(ib, np.int64)
    if len(ia) == 0:
        return np.zeros(0)
    return np.einsum("ij,ij->i", desc_a[ia], desc_b[ib]).astype(np.float64)


def colour_descriptors(image: np.ndarray, kp: np.ndarray, size: int) -> np.ndarray:
    """Colour patches ``(N, 3 * size * size)`` float32 around the keypoints: each RGB channel
    zero-mean and unit-norm (:func:`patch_descriptors`), concatenated and scaled to unit norm, so the
    dot product is the mean of the three channels' NCCs.

    Why (session 7): a seed and its neighbour look alike in grey, but the leaves behind them are
    green and the panicles differ in colour (white, tan, red, brown), which grey NCC cannot see."""
    img = np.asarray(image)
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    size = max(1, int(size))
    if img.ndim != 3:
        img = img[..., None]
    if len(kp) == 0:
        return np.zeros((0, img.shape[2] * size * size), np.float32)
    raw = _raw_patches(img, kp, size).reshape(len(kp), size * size, -1)  # one remap of all channels
    parts = [_normalised(raw[:, :, c]) for c in range(raw.shape[2])]
    out = np.concatenate(parts, 1)
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-6)
    return out


def mean_colour(image: np.ndarray, kp: np.ndarray, radius: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Chromaticity ``(N, 3)`` (RGB / (R + G + B)) and brightness ``(N,)`` (R + G + B, 0..765) of the
    ``(2 radius + 1)^2`` box around each keypoint (rounded position). Only the pixels read are
    averaged (no full-image filter)."""
    img = np.asarray(image)
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    if img.ndim != 3:
        img = np.repeat(img[..., None], 3, 2)
    h, w = img.shape[:2]
    if len(kp) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    offs = np.arange(-radius, radius + 1)
    xs = np.clip(np.round(kp[:, 0]).astype(int)[:, None] + offs[None], 0, w - 1)
    ys = np.clip(np.round(kp[:, 1]).astype(int)[:, None] + offs[None], 0, h - 1)
    c = img[ys[:, :, None], xs[:, None, :], :3].reshape(len(kp), -1, 3).astype(np.float64).mean(1)
    b = c.sum(1)
    return c / np.maximum(b, 1.0)[:, None], b


def disparity_edge_range(disp: np.ndarray, kp: np.ndarray, half: int) -> np.ndarray:
    """Range (max - min, image px) of the valid dense disparities on the keypoint's row within
    ``half`` px left and right of it; 0 where fewer than one valid value. Large at depth edges,
    where SGBM's disparity of a seed may be the occluder's (foreground fattening)."""
    kp = np.asarray(kp, np.float64).reshape(-1, 2)
    if len(kp) == 0:
        return np.zeros(0)
    h, w = disp.shape
    y = np.clip(np.round(kp[:, 1]).astype(int), 0, h - 1)
    xs = np.clip(np.round(kp[:, 0]).astype(int)[:, None] + np.arange(-half, half + 1)[None], 0, w - 1)
    d = disp[y[:, None], xs].astype(np.float64)
    ok = np.isfinite(d)
    hi = np.where(ok, d, -np.inf).max(1)
    lo = np.where(ok, d, np.inf).min(1)
    return np.where(ok.any(1), hi - lo, 0.0)


def occlusion_margin(disp: np.ndarray, u: np.ndarray, v: np.ndarray, d: np.ndarray, reach: int) -> np.ndarray:
    """How far (image px) a nearer surface of the left dense disparity map ``disp`` reaches over
    the right-image position ``u - d`` of a left point ``(u, v)`` with disparity ``d``:
    ``max over x in (u, u + reach] of disp(x, v) - d - (x - u)``. Positive: a pixel right of the
    point in the left image maps to the left of ``u - d`` in the right image while being nearer,
    so (for a continuous surface) it covers the point there, which is then hidden in the right view
    (its partner cannot be a right keypoint at ``u - d``). ``-inf`` where no valid disparity."""
    u = np.asarray(u, np.float64)
    if len(u) == 0:
        return np.zeros(0)
    h, w = disp.shape
    y = np.clip(np.round(np.asarray(v, np.float64)).astype(int), 0, h - 1)
    xs = np.round(u).astype(int)[:, None] + np.arange(1, int(reach) + 1)[None]
    dd = disp[y[:, None], np.clip(xs, 0, w - 1)].astype(np.float64)
    val = dd - np.asarray(d, np.float64)[:, None] - (xs - u[:, None])
    val = np.where(np.isfinite(val) & (xs < w), val, -np.inf)
    return val.max(1)
