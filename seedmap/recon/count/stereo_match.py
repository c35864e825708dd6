"""Step 1 of the multiview counter: per view, one-to-one left/right keypoint matches verified by the
neighbouring views (docs/method/counting.md)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seedmap.geometry import transform_points
from seedmap.recon.config import CountConfig
from seedmap.recon.count.records import StereoKeypoints
from seedmap.recon.count.views import keypoint_trees, nearest, neighbour_views, project_world

#: views on each side whose images verify a stereo match
VERIFY_VIEWS = 2
#: view spacing (degrees) the minimum supports are for (the 24-view circle)
SUPPORT_REF_DEG = 15.0
#: a scan whose views are >= 5 % closer than SUPPORT_REF_DEG adds this x (ref / spacing - 1) to the minimum supports
SUPPORT_DENSITY_GAIN = 3.0


def stereo_candidates(L: np.ndarray, R: np.ndarray, d_lo: float, d_hi: float, dv: float) -> np.ndarray:
    """(P, 2) index pairs (left, right) on the same row (within ``dv`` px) with a disparity in
    [``d_lo``, ``d_hi``] px: one Chebyshev-ball query, rows scaled so both tolerances are one radius."""
    if len(L) == 0 or len(R) == 0:
        return np.zeros((0, 2), np.int64)
    half = 0.5 * (d_hi - d_lo)
    s = half / dv
    a = np.column_stack([L[:, 0] - 0.5 * (d_hi + d_lo), L[:, 1] * s])
    b = np.column_stack([R[:, 0], R[:, 1] * s])
    m = cKDTree(a).sparse_distance_matrix(cKDTree(b), half, p=np.inf, output_type="ndarray")
    if len(m) == 0:
        return np.zeros((0, 2), np.int64)
    return np.column_stack([m["i"], m["j"]]).astype(np.int64)


def stereo_matches(views: list[StereoKeypoints | None], poses: np.ndarray, Tcw: np.ndarray, calib,  # noqa: ANN001
                   cfg: CountConfig, min_support: float, depth_range: tuple[float, float]
                   ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per view, one-to-one left/right matches: candidates on the same row (``mv_stereo_dv_px``) with a
    disparity in ``depth_range`` (m), scored by the support of the neighbouring views (:func:`view_support`,
    kept when >= ``min_support``), weighted by the row residual (``mv_row_sigma_px``) and assigned one-to-one
    maximising the total weight -> (left idx, right idx, world point (m), support) per view."""
    from scipy.optimize import linear_sum_assignment

    trees = keypoint_trees(views)
    d_lo = calib.fx * calib.baseline / depth_range[1]
    d_hi = calib.fx * calib.baseline / depth_range[0]
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
    out = []
    for k, kp in enumerate(views):
        if kp is None:
            out.append(empty)
            continue
        c = stereo_candidates(kp.left, kp.right, d_lo, d_hi, cfg.mv_stereo_dv_px)
        if len(c) == 0:
            out.append(empty)
            continue
        Xw = transform_points(poses[k], calib.triangulate(kp.left[c[:, 0]], kp.right[c[:, 1], 0]))
        support = view_support(k, Xw, views, trees, Tcw, calib, cfg)
        ok = support >= min_support
        c, Xw, support = c[ok], Xw[ok], support[ok]
        if len(c) == 0:
            out.append(empty)
            continue
        w = support
        if cfg.mv_row_sigma_px > 0:
            # rank candidates by their epipolar (row) residual too: a true pair's rows differ by ~1 px,
            # a wrong partner anywhere within the (wide) row tolerance
            dv = kp.left[c[:, 0], 1] - kp.right[c[:, 1], 1]
            w = w * np.exp(-0.5 * (dv / cfg.mv_row_sigma_px) ** 2)
        lab_l, lab_r = c[:, 0], c[:, 1]
        # one-to-one, maximal total support: assignment on the candidate rows/columns only
        rows, ri = np.unique(lab_l, return_inverse=True)
        cols, ci = np.unique(lab_r, return_inverse=True)
        gain = np.zeros((len(rows), len(cols)))
        gain[ri, ci] = w
        a, b = linear_sum_assignment(gain, maximize=True)
        pick = np.full((len(rows), len(cols)), -1, np.int64)
        pick[ri, ci] = np.arange(len(c))
        q = pick[a, b]
        q = np.sort(q[q >= 0])
        out.append((c[q, 0], c[q, 1], Xw[q], support[q]))
    return out


def view_spacing_deg(poses: np.ndarray) -> float:
    """Median angle (degrees) between the optical axes of consecutive views (15 for the default 24-view circle)."""
    z = np.asarray(poses, float).reshape(-1, 4, 4)[:, :3, 2]
    if len(z) < 2:
        return float("nan")
    c = np.clip(np.einsum("ij,ij->i", z[:-1], z[1:]), -1.0, 1.0)
    return float(np.degrees(np.median(np.arccos(c))))


def support_shift(poses: np.ndarray) -> float:
    """What a scan with views closer together than SUPPORT_REF_DEG adds to the stereo matches' minimum
    supports (``mv_min_support`` and ``mv_relink_min_support``): SUPPORT_DENSITY_GAIN x (ref / spacing - 1)
    when the scan is >= 5 % denser, else 0 (neighbouring views of a dense scan verify wrong pairings too)."""
    sp = view_spacing_deg(poses)
    if not np.isfinite(sp) or sp <= 0:
        return 0.0
    r = SUPPORT_REF_DEG / sp
    return float(SUPPORT_DENSITY_GAIN * (r - 1.0)) if r >= 1.05 else 0.0


def view_support(k: int, Xw: np.ndarray, views: list[StereoKeypoints | None], trees: list, Tcw: np.ndarray,
                 calib, cfg: CountConfig) -> np.ndarray:  # noqa: ANN001
    """Support of world points ``Xw`` (N, 3) m seen in view ``k``: sum over the left and right images of the
    VERIFY_VIEWS views on each side of exp(-e^2 / 2 sigma^2), e = distance (px) of the projection to the
    nearest detection there (sigma = ``mv_support_sigma_px``)."""
    sig = cfg.mv_support_sigma_px
    support = np.zeros(len(Xw))
    for _, m in neighbour_views(k, len(views), VERIFY_VIEWS, cfg.circular, both_sides=True):
        if views[m] is None:
            continue
        uvl, ur = project_world(calib, Tcw[m], Xw)
        dl, _ = nearest(trees[m][0], uvl, 3 * sig)
        dr, _ = nearest(trees[m][1], np.column_stack([ur, uvl[:, 1]]), 3 * sig)
        support += np.exp(-0.5 * (dl / sig) ** 2) + np.exp(-0.5 * (dr / sig) ** 2)
    return support
