"""How a command opens its input sequence: one config section shared by every command that reads data."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from seedmap.config import ConfigModel
from seedmap.errors import ConfigError
from seedmap.io.registry import loader_names, open_dataset


class DatasetOptions(ConfigModel):
    """Loader options; ``None`` means "the loader's default". Only options the chosen format has may be set."""

    #: seedmap | rosbag | euroc | kitti | folder (None: detected from the path)
    format: str | None = None
    #: calibration file overriding what the dataset carries (folder, rosbag)
    calib: str | None = None
    #: the right camera's calibration file, when it is a separate file
    right_calib: str | None = None
    #: frame rate (Hz) used when a folder / KITTI sequence has no timestamps
    fps: float | None = Field(None, gt=0)
    #: stereo time-sync tolerance (s) for bags and EuRoC
    sync_tol_s: float | None = Field(None, ge=0)
    #: bag image topic of the left camera
    left_topic: str | None = None
    #: bag image topic of the right camera
    right_topic: str | None = None
    #: whether the bag's images are already rectified
    rectified: bool | None = None
    #: OpenCV free scaling of the rectification (0 = valid pixels only, 1 = all pixels)
    rectify_alpha: float | None = None
    #: ground-truth pose file for KITTI
    poses: str | None = None
    #: seedmap layout: use only the first frames when times.txt is shorter than the image list (else an error)
    allow_fewer_times: bool | None = None

    def loader_kwargs(self) -> dict:
        return {k: v for k, v in self.model_dump().items() if k != "format" and v is not None}

    def open(self, path: str | Path):
        """Open ``path`` with these options (see :func:`seedmap.io.open_dataset`)."""
        if self.format is not None and self.format not in loader_names():
            raise ConfigError(f"unknown dataset format {self.format!r} (known: {', '.join(loader_names())})")
        return open_dataset(path, self.format, **self.loader_kwargs())
