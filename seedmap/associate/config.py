"""Parameters of the semantic seed association (full-resolution px, i.e. of a 4096 px wide image)."""

from __future__ import annotations

from typing import Literal

from seedmap.config import ConfigModel


class SemanticConfig(ConfigModel):
    """The paper's neighbour-sum cost and, with ``refine="field"``, the displacement-field prior.

    Defaults are the paper's method (docs/method/association.md); the SLAM pipeline's defaults are
    :class:`seedmap.slam.config.SlamAssociationConfig`.
    """

    #: neighbour search range Δ along a row (left/right sets) or a column (top/bottom sets), paper 1000
    delta_px: float = 1000.0
    #: half-width ε of the band a neighbour must lie in, paper 15
    eps_px: float = 15.0
    #: weight r of the neighbour-ratio terms of the cost, paper 10
    r: float = 10.0
    #: a pair is kept when its paper cost is at most this, paper 200
    max_cost: float = 200.0
    #: "none": the paper (one gated assignment on its cost); "field": the cost inside a local displacement field
    refine: Literal["none", "field"] = "none"
    #: gate temporal pairs around the constant-velocity prediction of the image shift (median of the last pair)
    temporal_prediction: bool = False
    #: half-width of the constant-velocity gate along u
    prediction_tol_px: float = 150.0
    #: field: expected spread (u, v) of a true stereo displacement around the local field
    field_stereo_sigma_px: tuple[float, float] = (4.5, 1.5)
    #: field: expected spread (u, v) of a true temporal displacement around the local field
    field_temporal_sigma_px: tuple[float, float] = (2.0, 1.0)
    #: field: candidates lie within this many spreads of the field (normalised residual)
    field_gate_sigma: float = 3.5
    #: field: weight of the squared normalised residual added to the paper cost
    field_weight: float = 20.0
    #: field: a kept pair's residual must be below this fraction of every competitor's (ambiguity test)
    field_ratio: float = 0.7
