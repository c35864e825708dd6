"""Configuration of ``seedmap phenotype`` (``--config/--set``)."""

from __future__ import annotations

from pydantic import Field

from seedmap.config import ConfigModel


class PhenotypeConfig(ConfigModel):
    """How landmark clusters become panicles and how the ground is found."""

    #: clusters with fewer seed landmarks are dropped as stray detections (leaves, noise)
    min_landmarks: int = Field(60, ge=1)
    #: panicles with fewer seed landmarks than this are kept but flagged ``few``
    few_landmarks: int = Field(200, ge=1)
    #: a cluster wider than this across its axis (m) is split into touching panicles (k-means along the row)
    split_width_m: float = Field(0.12, gt=0)
    #: camera height above the ground (m), used when the trajectory is not in a z-up world with the ground at z = 0
    mount_height_m: float = Field(1.15, gt=0)
    #: seed-count calibration: a JSON file, the name of one shipped in seedmap/phenotype/calibrations, or auto
    #: (``fast`` when the images are at hand: seeds counted in each panicle's best view; else ``fast-shape``)
    calibration: str = "auto"
    #: every how many frames that see a panicle whole its seeds are counted (the most counted gives the view)
    view_stride: int = Field(1, ge=1)
