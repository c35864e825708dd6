"""Data association: the semantic seed matcher and (lazily) the descriptor baselines.

:func:`make_matcher` is the one factory the SLAM pipeline and the benchmark use, so every method
runs through the same front-end, back-end, lost rule and metrics.
"""

from __future__ import annotations

from seedmap.associate.assignment import GATED, assign_capped, assign_sparse
from seedmap.associate.base import FrameFeatures, GateConfig, Matcher
from seedmap.associate.config import SemanticConfig
from seedmap.associate.cost import full_res_scale, neighbour_sums, pair_cost
from seedmap.associate.matcher import SeedMatcher
from seedmap.associate.methods import METHODS, match_stereo_keypoints, match_temporal_keypoints
from seedmap.errors import SeedmapError
from seedmap.records import StereoCalib

SEED_MATCHERS = ("seeds",)
FEATURE_MATCHERS = ("sift", "surf", "orb", "akaze")

__all__ = [
    "FrameFeatures", "GateConfig", "Matcher", "SemanticConfig", "SeedMatcher", "METHODS", "GATED",
    "assign_sparse", "assign_capped", "full_res_scale", "neighbour_sums", "pair_cost",
    "match_stereo_keypoints", "match_temporal_keypoints", "make_matcher", "available_matchers",
]


def available_matchers() -> list[str]:
    """Names :func:`make_matcher` accepts (descriptor baselines only once their module exists)."""
    names = list(SEED_MATCHERS)
    try:
        import seedmap.associate.features  # noqa: F401
    except ImportError:
        return names
    return names + list(FEATURE_MATCHERS)


def make_matcher(name: str, calib: StereoCalib, detector=None, cfg=None) -> Matcher:
    """Build a matcher by name.

    ``seeds``: :class:`SeedMatcher` (needs ``detector`` for images; ``cfg`` a
    :class:`SemanticConfig`, or an object with ``association`` and ``gates`` attributes such as
    ``SlamConfig``). ``sift|surf|orb|akaze``: the descriptor baselines
    ``seedmap.associate.features.FeatureMatcher(kind, calib, cfg)``.
    """
    key = name.strip().lower()
    if key in SEED_MATCHERS:
        gates = None
        if cfg is not None and not isinstance(cfg, SemanticConfig):
            gates = getattr(cfg, "gates", None)
            cfg = getattr(cfg, "association", None)
        return SeedMatcher(calib, detector=detector, cfg=cfg, gates=gates)
    if key in FEATURE_MATCHERS:
        try:
            from seedmap.associate.features import FeatureMatcher
        except ImportError:
            raise SeedmapError(f"matcher {name!r} is not available yet (seedmap.associate.features missing)") from None
        return FeatureMatcher(key, calib, cfg)
    raise SeedmapError(f"unknown matcher {name!r} (known: {', '.join(SEED_MATCHERS + FEATURE_MATCHERS)})")
