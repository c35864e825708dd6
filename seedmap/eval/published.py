"""The paper's published maximum-distance-mapped numbers (Tables 1 and 2, real field data).

Shown beside the simulated results, never mixed into their means; ``None`` is the paper's "fail".
Why these and not the abstract's figures: ``docs/method/benchmark.md``.
"""

from __future__ import annotations

#: Lengths (m) of the paper's eight ranges, in the paper's order (presets ``paper1`` .. ``paper8``).
PAPER_RANGE_LENGTHS: tuple[float, ...] = (3.56, 5.00, 4.42, 4.10, 4.78, 3.94, 5.03, 4.43)

#: Published maximum distance mapped (m) per method and range; ``None`` = "fail".
PUBLISHED_MDM: dict[str, tuple[float | None, ...]] = {
    "sift": (1.86, 0.25, 0.50, 1.47, 0.57, 1.40, 3.15, 4.04),
    "surf": (1.55, 0.25, 0.38, 0.60, 0.74, 0.19, 0.26, 0.94),
    "orb": (0.20, None, None, None, None, 0.11, None, None),
    "akaze": (1.55, 0.19, 0.38, 1.14, 0.74, 0.45, 0.46, 0.94),
    "orb-slam2": (0.35, 0.25, 0.18, 0.25, 0.31, 0.12, 0.33, 0.26),
    "seeds": (3.56, 5.00, 2.85, 2.31, 2.31, 3.20, 3.72, 4.43),
}

#: Column titles as the paper prints them.
PUBLISHED_TITLES: dict[str, str] = {
    "sift": "SIFT+BF",
    "surf": "SURF+BF",
    "orb": "ORB+BF",
    "akaze": "AKAZE+BF",
    "orb-slam2": "ORB-SLAM2",
    "seeds": "seeds (paper)",
}


def published_fraction(method: str) -> list[float]:
    """Per-range fraction mapped of a published method ("fail" counts as 0)."""
    return [(m or 0.0) / L for m, L in zip(PUBLISHED_MDM[method], PAPER_RANGE_LENGTHS, strict=True)]


def published_mean_fraction(method: str) -> float:
    """Mean fraction of range mapped, as the paper's last row (e.g. SIFT 0.38, seeds 0.78)."""
    f = published_fraction(method)
    return sum(f) / len(f)


#: Our methods compared with a different published column: ORB-SLAM3 (run here) beside the paper's ORB-SLAM2.
PUBLISHED_COUNTERPART: dict[str, str] = {"orbslam3": "orb-slam2"}


def published_key(method: str) -> str | None:
    """Which published column corresponds to one of our method names (``seeds+fast`` -> ``seeds``,
    ``orbslam3`` -> ``orb-slam2``)."""
    base = method.split("+", 1)[0].lower()
    base = PUBLISHED_COUNTERPART.get(base, base)
    return base if base in PUBLISHED_MDM else None
