"""The counters' records: per-view 2D keypoints, counted seeds, and a cannot-link union-find."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SeedCount:
    """Counted seeds: positions (m, world), diameters (m), supporting views, and per-observation
    assignment (index into the counted seeds, -1 = not counted)."""

    xyz: np.ndarray  # (S, 3)
    diameter: np.ndarray  # (S,)
    n_views: np.ndarray  # (S,)
    assignment: np.ndarray  # (N_obs,)
    spread: np.ndarray  # (S,) RMS distance of the observations to the centre (m)

    @property
    def count(self) -> int:
        return len(self.xyz)


@dataclass
class StereoKeypoints:
    """The 2D seed detections of one stereo view: ``left`` (N, 2) and ``right`` (M, 2) keypoints
    (px, rectified images) and ``left_size`` (N,) the mean full ellipse axis of each left detection
    (px; gives the seed diameter once the depth is known)."""

    left: np.ndarray
    right: np.ndarray
    left_size: np.ndarray
    left_disp: np.ndarray | None = None  # (N,) SGBM disparity at each left keypoint (px, NaN = none)

    def __post_init__(self) -> None:
        self.left = np.asarray(self.left, float).reshape(-1, 2)
        self.right = np.asarray(self.right, float).reshape(-1, 2)
        self.left_size = np.asarray(self.left_size, float).reshape(-1)
        if len(self.left_size) != len(self.left):
            raise ValueError(f"StereoKeypoints: {len(self.left_size)} sizes for {len(self.left)} left keypoints")
        if self.left_disp is not None:
            self.left_disp = np.asarray(self.left_disp, float).reshape(-1)
            if len(self.left_disp) != len(self.left):
                raise ValueError(f"StereoKeypoints: {len(self.left_disp)} disparities for {len(self.left)} "
                                 "left keypoints")

    @classmethod
    def from_detections(cls, left, right, disparity: np.ndarray | None = None,  # noqa: ANN001 - Detections
                        disp_radius_px: int = 2) -> StereoKeypoints:
        """From the left and right :class:`seedmap.records.Detections` of a view; with the view's
        SGBM ``disparity`` map (px, NaN = invalid) also the surface disparity at every left keypoint
        (:func:`keypoint_disparity`; written to detections.csv)."""
        ld = None if disparity is None else keypoint_disparity(disparity, left.keypoints, disp_radius_px)
        return cls(left.keypoints, right.keypoints, 0.5 * (left.ellipses[:, 2] + left.ellipses[:, 3]), ld)


def keypoint_disparity(disparity: np.ndarray, uv: np.ndarray, radius_px: int = 2) -> np.ndarray:
    """Median of the valid SGBM disparities (px) in the (2r+1)^2 window around each keypoint ``uv``
    (N, 2) px; NaN where fewer than a quarter of the window is valid (SGBM often has no depth on a
    seed-sized patch: no evidence then, rather than a wrong one)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    if len(uv) == 0:
        return np.zeros(0)
    H, W = disparity.shape[:2]
    r = int(radius_px)
    off = np.arange(-r, r + 1)
    u = np.clip(np.round(uv[:, 0]).astype(np.int64)[:, None, None] + off[None, None, :], 0, W - 1)
    v = np.clip(np.round(uv[:, 1]).astype(np.int64)[:, None, None] + off[None, :, None], 0, H - 1)
    patch = np.asarray(disparity, float)[v, u].reshape(len(uv), -1)
    valid = np.isfinite(patch)
    out = np.full(len(uv), np.nan)
    ok = valid.sum(axis=1) >= max(1, patch.shape[1] // 4)
    if ok.any():
        out[ok] = np.nanmedian(patch[ok], axis=1)
    return out


@dataclass
class MultiViewDetail:
    """Intermediate results of :func:`count_multiview` (diagnostics and tests): every stereo match
    (view, left index, right index, support) and the track it ended in (index into ``xyz``,
    -1 = dropped for its reprojection error)."""

    view: np.ndarray
    left: np.ndarray
    right: np.ndarray
    support: np.ndarray
    track: np.ndarray
    xyz: np.ndarray  # (T, 3) triangulated point of every track (m, world)
    track_views: np.ndarray  # (T,) distinct views of every track


class CannotLinkUnionFind:
    """Union-find over observations that refuses to join two groups seen by a common view."""

    def __init__(self, view: np.ndarray) -> None:
        self.parent = np.arange(len(view))
        self.vmask = [1 << int(v) for v in view]  # views of each group (python ints: any number of views)

    def find(self, i: int) -> int:
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union(self, x: int, y: int, force: bool = False) -> bool:
        rx, ry = self.find(x), self.find(y)
        if rx == ry or (self.vmask[rx] & self.vmask[ry] and not force):
            return False  # cannot-link: one view sees a seed at most once
        self.parent[ry] = rx
        self.vmask[rx] |= self.vmask[ry]
        return True
