"""Ellipse fitting on seed masks: the ellipse centre is the semantic keypoint.

Convention of every ellipse row: ``(cx, cy, major, minor, angle_deg)`` in pixels, with *full* axis
lengths (as ``cv2.fitEllipse`` reports its rotated-rect size) and ``angle_deg`` the direction of the
**major** axis, measured like OpenCV (from +u towards +v, i.e. clockwise on screen), in ``[0, 180)``.
``cv2.ellipse(img, (cx, cy), (major / 2, minor / 2), angle_deg, ...)`` draws it.

Two fitters:

* ``"contour"`` — the paper's choice: ``cv2.fitEllipse`` on the outer contour of the mask's largest
  component. Seeds are only 4–8 px across at the default resolution, where a contour has few points,
  so masks with fewer than 5 contour points (or a degenerate fit) fall back to moments.
* ``"moments"`` — the ellipse with the same area centroid and second moments as the mask
  (full axes ``4 * sqrt(eigenvalues of the pixel covariance)``, plus the 1/12 px² pixel-area term).
  Vectorised over all labels of a label image at once (``np.bincount``), so the oracle detector can
  fit thousands of seeds per frame in milliseconds; its centre is the mask centroid, which is the
  least-biased centre estimate for tiny masks.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

EllipseMethod = Literal["contour", "moments"]


def _normalise(cx: float, cy: float, w: float, h: float, angle: float) -> tuple[float, float, float, float, float]:
    """OpenCV rotated-rect ``(w, h, angle)`` -> major/minor with the angle of the major axis."""
    if h > w:
        w, h = h, w
        angle += 90.0
    return cx, cy, w, h, float(angle % 180.0)


def ellipse_from_moments(m00: np.ndarray, mx: np.ndarray, my: np.ndarray, mxx: np.ndarray, myy: np.ndarray,
                         mxy: np.ndarray) -> np.ndarray:
    """Ellipses ``(N, 5)`` from raw pixel moments (sums of 1, x, y, x², y², xy over each mask).

    The 1/12 px² term is the variance of a uniform pixel, so a single pixel gives a ~1.15 px circle
    and large masks are unaffected.
    """
    m00 = np.maximum(np.asarray(m00, np.float64), 1e-12)
    cx = mx / m00
    cy = my / m00
    sxx = mxx / m00 - cx * cx + 1.0 / 12.0
    syy = myy / m00 - cy * cy + 1.0 / 12.0
    sxy = mxy / m00 - cx * cy
    tr = sxx + syy
    disc = np.sqrt(np.maximum(((sxx - syy) * 0.5) ** 2 + sxy * sxy, 0.0))
    l1 = np.maximum(tr * 0.5 + disc, 1e-12)
    l2 = np.maximum(tr * 0.5 - disc, 1e-12)
    angle = np.degrees(0.5 * np.arctan2(2.0 * sxy, sxx - syy)) % 180.0
    return np.stack([cx, cy, 4.0 * np.sqrt(l1), 4.0 * np.sqrt(l2), angle], axis=1)


def fit_ellipse_mask(mask: np.ndarray, method: EllipseMethod = "contour", offset: tuple[float, float] = (0.0, 0.0),
                     largest_component: bool = True) -> np.ndarray | None:
    """Fit one ellipse to a binary mask; returns ``(5,)`` or ``None`` for an empty mask.

    ``offset`` ``(u0, v0)`` is added to the centre (the crop's top-left pixel in the full image).
    With ``largest_component`` only the largest 8-connected component is used (a segmenter may
    output specks next to the seed).
    """
    m = (np.asarray(mask) > 0).astype(np.uint8)
    if m.ndim != 2 or not m.any():
        return None
    if largest_component:
        n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        if n > 2:
            k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
            m = (lab == k).astype(np.uint8)
    if method == "contour":
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if contours:
            c = max(contours, key=len)
            if len(c) >= 5:
                (cx, cy), (w, h), ang = cv2.fitEllipse(c)
                area = float(m.sum())
                # a degenerate fit (collinear points) gives nan/huge axes: fall back to moments
                if np.isfinite([cx, cy, w, h]).all() and 0 < w * h < 16.0 * max(area, 1.0):
                    e = _normalise(cx, cy, w, h, ang)
                    return np.array([e[0] + offset[0], e[1] + offset[1], e[2], e[3], e[4]])
    elif method != "moments":
        raise ValueError(f"unknown ellipse method {method!r}")
    ys, xs = np.nonzero(m)
    xs = xs.astype(np.float64)
    ys = ys.astype(np.float64)
    e = ellipse_from_moments(np.array([len(xs)]), xs.sum(keepdims=True), ys.sum(keepdims=True),
                             (xs * xs).sum(keepdims=True), (ys * ys).sum(keepdims=True),
                             (xs * ys).sum(keepdims=True))[0]
    e[0] += offset[0]
    e[1] += offset[1]
    return e


def fit_ellipses_labels(labels: np.ndarray, ids: np.ndarray, method: EllipseMethod = "moments",
                        boxes: np.ndarray | None = None) -> np.ndarray:
    """Fit one ellipse per label value in ``ids`` of an integer label image -> ``(len(ids), 5)``.

    ``"moments"`` is fully vectorised. ``"contour"`` fits each mask in its own box crop
    (``boxes`` ``(N, 4)`` x0, y0, x1, y1 inclusive-exclusive, computed when not given).
    Labels with no pixels give NaN rows.
    """
    ids = np.asarray(ids, np.int64).reshape(-1)
    out = np.full((len(ids), 5), np.nan)
    if len(ids) == 0:
        return out
    lab = np.asarray(labels)
    if method == "moments":
        h, w = lab.shape
        # coordinates of foreground pixels only (no full-frame coordinate grids: seeds cover a small part)
        idx = np.flatnonzero(lab.reshape(-1))
        f = lab.reshape(-1)[idx].astype(np.int64)
        nb = int(max(f.max(initial=0), ids.max()) + 1)
        yi, xi = np.divmod(idx, w)
        # moments about the crop centre keep the variance subtraction well conditioned in float64
        x = xi.astype(np.float64) - w / 2
        y = yi.astype(np.float64) - h / 2
        m00 = np.bincount(f, minlength=nb)[ids]
        sx = np.bincount(f, x, nb)[ids]
        sy = np.bincount(f, y, nb)[ids]
        sxx = np.bincount(f, x * x, nb)[ids]
        syy = np.bincount(f, y * y, nb)[ids]
        sxy = np.bincount(f, x * y, nb)[ids]
        ok = m00 > 0
        e = ellipse_from_moments(m00[ok], sx[ok], sy[ok], sxx[ok], syy[ok], sxy[ok])
        e[:, 0] += w / 2
        e[:, 1] += h / 2
        out[ok] = e
        return out
    if boxes is None:
        from scipy import ndimage

        objs = ndimage.find_objects(lab.astype(np.int64) if lab.dtype != np.int64 else lab)
        boxes = np.zeros((len(ids), 4), np.int64)
        for k, i in enumerate(ids):
            s = objs[i - 1] if 0 < i <= len(objs) else None
            if s is not None:
                boxes[k] = (s[1].start, s[0].start, s[1].stop, s[0].stop)
    b = np.asarray(boxes, np.int64).reshape(-1, 4)
    for k, i in enumerate(ids):
        x0, y0, x1, y1 = (int(v) for v in b[k])
        if x1 <= x0 or y1 <= y0:
            continue
        crop = lab[y0:y1, x0:x1] == i
        # pad by one pixel so the contour of a mask touching the crop edge stays closed
        crop = np.pad(crop, 1)
        e = fit_ellipse_mask(crop, method, offset=(x0 - 1, y0 - 1))
        if e is not None:
            out[k] = e
    return out


def ellipse_boxes(ellipses: np.ndarray) -> np.ndarray:
    """Axis-aligned bounding boxes ``(N, 4)`` x0, y0, x1, y1 (pixel-edge bounds) of ellipses."""
    e = np.asarray(ellipses, np.float64).reshape(-1, 5)
    a = e[:, 2] / 2
    b = e[:, 3] / 2
    t = np.radians(e[:, 4])
    hw = np.sqrt((a * np.cos(t)) ** 2 + (b * np.sin(t)) ** 2)
    hh = np.sqrt((a * np.sin(t)) ** 2 + (b * np.cos(t)) ** 2)
    return np.stack([e[:, 0] - hw, e[:, 1] - hh, e[:, 0] + hw, e[:, 1] + hh], axis=1)


def draw_ellipses(image: np.ndarray, ellipses: np.ndarray, color: tuple[int, int, int] = (255, 0, 255),
                  thickness: int = 1, centres: bool = True) -> np.ndarray:
    """A copy of the RGB image with ellipses (and their centres) drawn, sub-pixel accurate."""
    out = np.ascontiguousarray(image.copy())
    sh = 4  # fixed-point bits for cv2's sub-pixel drawing
    f = 1 << sh
    for cx, cy, ma, mi, ang in np.asarray(ellipses, np.float64).reshape(-1, 5):
        if not np.isfinite([cx, cy, ma, mi, ang]).all():
            continue
        c = (int(round(cx * f)), int(round(cy * f)))
        ax = (max(int(round(ma / 2 * f)), 1), max(int(round(mi / 2 * f)), 1))
        cv2.ellipse(out, c, ax, float(ang), 0, 360, color, thickness, cv2.LINE_AA, sh)
        if centres:
            cv2.circle(out, c, f // 2, color, -1, cv2.LINE_AA, sh)
    return out
