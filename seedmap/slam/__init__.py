"""Semantic stereo SLAM: seeds as landmarks, GTSAM back-end.

* :class:`~seedmap.slam.core.SemanticSlam` — the core, one verb per frame (``register_frame``).
* :func:`~seedmap.slam.pipeline.run_slam` — dataset in, result folder out (``seedmap slam``).

Heavy modules (gtsam, open3d) load only when these are used.
"""

from __future__ import annotations

from seedmap.slam.config import SlamConfig

__all__ = ["SlamConfig", "run_slam", "SlamResult", "SlamMetrics", "SemanticSlam"]


def __getattr__(name: str):
    if name in ("run_slam", "SlamResult", "SlamMetrics"):
        from seedmap.slam import pipeline

        return getattr(pipeline, name)
    if name == "SemanticSlam":
        from seedmap.slam.core import SemanticSlam

        return SemanticSlam
    raise AttributeError(name)
