"""How a command opens its input sequence: one config section shared by every command that reads data."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from seedmap.config import ConfigModel
from seedmap.errors import ConfigError


class DatasetOptions(ConfigModel):
    """Loader options; ``None`` means "the loader's default". Only options the chosen format has may be set.

    ``format``: seedmap | rosbag | euroc | kitti | folder (``None``: detect from the path).
    ``calib``/``right_calib``: calibration file(s) overriding what the dataset carries (folder, rosbag).
    ``fps``: frame rate used when a folder/KITTI sequence has no timestamps (Hz).
    ``sync_tol_s``: stereo time-sync tolerance (s) for bags and EuRoC.
    ``left_topic``/``right_topic``/``rectified``: bag image topics and whether they are already rectified.
    ``rectify_alpha``: OpenCV free scaling for rectification (0 = valid pixels only, 1 = all pixels).
    ``poses``: ground-truth pose file for KITTI.
    """

    format: str | None = None
    calib: str | None = None
    right_calib: str | None = None
    fps: float | None = Field(None, gt=0)
    sync_tol_s: float | None = Field(None, ge=0)
    left_topic: str | None = None
    right_topic: str | None = None
    rectified: bool | None = None
    rectify_alpha: float | None = None
    poses: str | None = None

    def loader_kwargs(self) -> dict:
        return {k: v for k, v in self.model_dump().items() if k != "format" and v is not None}

    def open(self, path: str | Path):
        """Open ``path`` with these options (see :func:`seedmap.io.open_dataset`)."""
        from seedmap.io import loader_names, open_dataset

        if self.format is not None and self.format not in loader_names():
            raise ConfigError(f"unknown dataset format {self.format!r} (known: {', '.join(loader_names())})")
        return open_dataset(path, self.format, **self.loader_kwargs())
