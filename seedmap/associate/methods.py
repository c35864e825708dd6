"""Stereo and temporal association of two keypoint sets, one pair of functions per method.

``METHODS`` maps ``SemanticConfig.refine`` to the method: ``"none"`` is the paper (gated Hungarian
on the neighbour-sum cost), ``"field"`` the displacement-field matcher. :class:`SeedMatcher` picks
one at construction; :func:`match_stereo_keypoints` / :func:`match_temporal_keypoints` look it up
for one call.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from seedmap.associate.assignment import assign_sparse
from seedmap.associate.base import GateConfig
from seedmap.associate.config import SemanticConfig
from seedmap.associate.cost import candidate_pairs, full_res_scale, full_res_sums, pair_cost
from seedmap.associate.field import (
    FIELD_MAX_DISPARITY_PX,
    FIELD_MAX_SHIFT_PX,
    FIELD_STEREO_BAND_PX,
    field_assign,
)
from seedmap.records import Matches

Sums = tuple[np.ndarray, np.ndarray]


def _inside(u: np.ndarray, width: int, border: float) -> np.ndarray:
    return (u >= border) & (u <= width - 1 - border)


def stereo_gate_fn(kl: np.ndarray, kr: np.ndarray, g: GateConfig, width: int):
    """``gate(ia, ib) -> bool``: the stereo gates (|Δv|, minimum disparity, border margins) of
    pairs ``(kl[ia], kr[ib])``; ``g`` already scaled to ``width``."""
    def gate(ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
        return (((kl[ia, 0] - kr[ib, 0]) >= g.stereo_min_disparity_px)
                & (np.abs(kl[ia, 1] - kr[ib, 1]) <= g.stereo_max_dy_px)
                & _inside(kl[ia, 0], width, g.stereo_border_px) & _inside(kr[ib, 0], width, g.stereo_border_px))
    return gate


def temporal_gate_fn(ka: np.ndarray, kb: np.ndarray, g: GateConfig, width: int):
    """``gate(ia, ib) -> bool``: the temporal gates of pairs ``(ka[ia], kb[ib])`` (``g`` scaled)."""
    def gate(ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
        return ((g.travel_sign * (kb[ib, 0] - ka[ia, 0]) >= g.temporal_min_shift_px)
                & (np.abs(kb[ib, 1] - ka[ia, 1]) <= min(g.temporal_max_dy_px, g.temporal_post_max_dy_px))
                & _inside(ka[ia, 0], width, g.temporal_border_px) & _inside(kb[ib, 0], width, g.temporal_border_px))
    return gate


def _extent(ka: np.ndarray, kb: np.ndarray, width: int) -> tuple[float, float]:
    """Image extent (u, v) covered by both keypoint sets."""
    return float(width), float(max(ka[:, 1].max(), kb[:, 1].max())) + 1.0


# ----------------------------------------------------------------------------------------------
# the paper: gated Hungarian on the neighbour-sum cost
# ----------------------------------------------------------------------------------------------


def paper_stereo(kl: np.ndarray, kr: np.ndarray, width: int, g: GateConfig, cfg: SemanticConfig,
                 sums: Sums) -> Matches:
    """Stereo pairs of the paper: every gated pair's cost, one gated assignment, ``max_cost`` cap."""
    s = full_res_scale(width)
    ia, ib = candidate_pairs(kl, kr, g.stereo_max_dy_px)
    ok = (kl[ia, 0] - kr[ib, 0]) >= g.stereo_min_disparity_px
    ok &= _inside(kl[ia, 0], width, g.stereo_border_px) & _inside(kr[ib, 0], width, g.stereo_border_px)
    ia, ib = ia[ok], ib[ok]
    cost = pair_cost(kl * s, kr * s, sums[0], sums[1], cfg, ia, ib)
    return assign_sparse(len(kl), len(kr), ia, ib, cost, cfg.max_cost)


def paper_temporal(ka: np.ndarray, kb: np.ndarray, width: int, g: GateConfig, cfg: SemanticConfig, sums: Sums,
                   shift: float | None, shift_v: float | None) -> Matches:
    """Temporal pairs of the paper (gated assignment, then the |Δv| post-filter); with
    ``temporal_prediction`` and a predicted u ``shift`` only pairs within ``prediction_tol_px`` of it."""
    s = full_res_scale(width)
    ia, ib = candidate_pairs(ka, kb, g.temporal_max_dy_px)
    du = kb[ib, 0] - ka[ia, 0]
    ok = g.travel_sign * du >= g.temporal_min_shift_px
    if cfg.temporal_prediction and shift is not None:
        ok &= np.abs(du - shift) <= cfg.prediction_tol_px / s
    ok &= _inside(ka[ia, 0], width, g.temporal_border_px) & _inside(kb[ib, 0], width, g.temporal_border_px)
    ia, ib = ia[ok], ib[ok]
    cost = pair_cost(ka * s, kb * s, sums[0], sums[1], cfg, ia, ib)
    m = assign_sparse(len(ka), len(kb), ia, ib, cost, cfg.max_cost)
    # post-filter on the vertical offset (facts.md: 60 px at full resolution)
    keep = np.abs(kb[m.idx_b, 1] - ka[m.idx_a, 1]) <= g.temporal_post_max_dy_px
    return Matches(m.idx_a[keep], m.idx_b[keep], m.cost[keep])


# ----------------------------------------------------------------------------------------------
# the displacement-field matcher
# ----------------------------------------------------------------------------------------------


def field_stereo(kl: np.ndarray, kr: np.ndarray, width: int, g: GateConfig, cfg: SemanticConfig,
                 sums: Sums) -> Matches:
    """Stereo pairs inside a disparity field (rows fixed: rectified pairs)."""
    s = full_res_scale(width)
    band = FIELD_STEREO_BAND_PX / s
    lo = np.array([-FIELD_MAX_DISPARITY_PX / s, -band])
    hi = np.array([-g.stereo_min_disparity_px, band])
    return field_assign(kl, kr, kl * s, kr * s, sums[0], sums[1], stereo_gate_fn(kl, kr, g, width), lo, hi,
                        np.asarray(cfg.field_stereo_sigma_px) / s, cfg, s, _extent(kl, kr, width), fixed_v=0.0)


def field_temporal(ka: np.ndarray, kb: np.ndarray, width: int, g: GateConfig, cfg: SemanticConfig, sums: Sums,
                   shift: float | None, shift_v: float | None) -> Matches:
    """Temporal pairs inside a shift field; the coarse search box lies around the predicted
    ``(shift, shift_v)`` when given (``prediction_tol_px`` in u), else spans the travel gate."""
    s = full_res_scale(width)
    vband = min(g.temporal_max_dy_px, g.temporal_post_max_dy_px)
    if shift is not None:
        tol = cfg.prediction_tol_px / s
        pv = 0.0 if shift_v is None else float(shift_v)
        lo = np.array([shift - tol, pv - vband])
        hi = np.array([shift + tol, pv + vband])
    else:
        far = g.travel_sign * FIELD_MAX_SHIFT_PX / s
        near = g.travel_sign * g.temporal_min_shift_px
        lo = np.array([min(far, near), -vband])
        hi = np.array([max(far, near), vband])
    return field_assign(ka, kb, ka * s, kb * s, sums[0], sums[1], temporal_gate_fn(ka, kb, g, width), lo, hi,
                        np.asarray(cfg.field_temporal_sigma_px) / s, cfg, s, _extent(ka, kb, width))


@dataclass(frozen=True)
class Method:
    """One association method: ``stereo(kl, kr, width, gates, cfg, sums)`` and
    ``temporal(ka, kb, width, gates, cfg, sums, shift, shift_v)`` (gates scaled to ``width``,
    keypoints in image px, neighbour sums in full-res px)."""

    stereo: Callable[..., Matches]
    temporal: Callable[..., Matches]


#: ``SemanticConfig.refine`` -> method
METHODS: dict[str, Method] = {
    "none": Method(paper_stereo, paper_temporal),
    "field": Method(field_stereo, field_temporal),
}


def _inputs(kp_a: np.ndarray, kp_b: np.ndarray, width: int, gates: GateConfig | None,
            cfg: SemanticConfig | None) -> tuple[SemanticConfig, GateConfig, np.ndarray, np.ndarray]:
    """``cfg`` (default :class:`SemanticConfig`), the gates scaled to ``width`` (default
    :class:`GateConfig`) and both keypoint sets as (N, 2) float64 image px."""
    g = (gates or GateConfig()).scaled(width)
    ka = np.asarray(kp_a, np.float64).reshape(-1, 2)
    kb = np.asarray(kp_b, np.float64).reshape(-1, 2)
    return cfg or SemanticConfig(), g, ka, kb


def match_stereo_keypoints(kp_left: np.ndarray, kp_right: np.ndarray, width: int, gates: GateConfig | None = None,
                           cfg: SemanticConfig | None = None, sums: Sums | None = None) -> Matches:
    """Left<->right association of one rectified stereo pair (pixels of an image ``width`` wide)
    with the method ``cfg.refine``. ``sums``: precomputed :func:`neighbour_sums` of both images in
    full-resolution units (cache)."""
    cfg, g, kl, kr = _inputs(kp_left, kp_right, width, gates, cfg)
    if len(kl) == 0 or len(kr) == 0:
        return Matches()
    sums = full_res_sums(kl, kr, full_res_scale(width), cfg, sums)
    return METHODS[cfg.refine].stereo(kl, kr, width, g, cfg, sums)


def match_temporal_keypoints(kp_prev: np.ndarray, kp_cur: np.ndarray, width: int, gates: GateConfig | None = None,
                             cfg: SemanticConfig | None = None, predicted_shift: float | None = None,
                             predicted_shift_v: float | None = None, sums: Sums | None = None) -> Matches:
    """Previous-left <-> current-left association under the horizontal-travel gates.

    ``predicted_shift`` / ``predicted_shift_v`` (pixels of this image, cur - prev): the
    constant-velocity prediction, None = none. ``sums``: precomputed :func:`neighbour_sums`
    (full-resolution units) of both keypoint sets."""
    cfg, g, ka, kb = _inputs(kp_prev, kp_cur, width, gates, cfg)
    if len(ka) == 0 or len(kb) == 0:
        return Matches()
    sums = full_res_sums(ka, kb, full_res_scale(width), cfg, sums)
    return METHODS[cfg.refine].temporal(ka, kb, width, g, cfg, sums, predicted_shift, predicted_shift_v)
