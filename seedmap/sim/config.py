"""Configuration of the procedural sorghum world and its ground-truth stereo renderer.

Units: metres, seconds, degrees (where the name says ``_deg``), pixels. World frame: x along the row
(direction of travel), y from the robot towards the row, z up, ground at z = 0, row line at y = 0.
The UPPER_CASE constants are model values no user needs to change; they are fixed, not configurable.
"""

from __future__ import annotations

import copy
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from seedmap.config import ConfigModel
from seedmap.errors import ConfigError
from seedmap.records import StereoCalib
from seedmap.sim.conditions import ConditionsConfig

# ---- world ----
#: std of plant offsets across the row line (m)
ROW_JITTER = 0.025
#: leaf length range (m)
LEAF_LENGTH = (0.45, 0.85)
#: leaf width range (m)
LEAF_WIDTH = (0.045, 0.075)
#: stalk radius at the ground (m)
STALK_RADIUS = 0.011
#: distance of the dim neighbouring row behind the range (m)
BACKGROUND_ROW_OFFSET = 0.76

# ---- panicles ----
#: panicle centre height above ground: mean and std (m)
PANICLE_HEIGHT = (1.15, 0.07)
#: std of the lean of the panicle axis from vertical (deg)
PANICLE_TILT_SD_DEG = 8.0

# ---- wind ----
#: frequency range of the sway sinusoids (Hz)
SWAY_FREQ = (0.3, 1.2)

# ---- motion ----
#: amplitudes of the robot's wobble from uneven ground: height, stand-off, along the row (m) and roll/pitch/yaw (deg)
HEIGHT_WOBBLE, LATERAL_WOBBLE, ALONG_WOBBLE, ANGLE_WOBBLE_DEG = 0.004, 0.004, 0.003, 0.3

# ---- flash and sensor ----
#: flash position in the left camera frame (m): between the lenses, above them
FLASH_OFFSET = (0.055, -0.06, 0.0)
#: flash disc radius (m): soft shadows
FLASH_RADIUS = 0.015
#: ambient light relative to the flash at 0.7 m
AMBIENT = 0.025
#: distance beyond which the flash fades to black (m): the far background of flash imaging is dark
LIGHT_CUTOFF = 1.5
#: electrons at full scale (shot noise)
FULL_WELL = 3000.0
#: read noise (electrons)
READ_NOISE = 6.0
#: optical blur (pixels)
PSF_SIGMA_PX = 0.45
#: relative brightness fall-off at the image corners
VIGNETTING = 0.25


#: a retired key that any value may carry (it never changed the output)
ANY = object()


def _same(a: Any, b: Any) -> bool:
    if isinstance(b, dict):
        return isinstance(a, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in b)
    try:
        x, y = np.asarray(a, float), np.asarray(b, float)
    except (TypeError, ValueError):
        return False
    return x.shape == y.shape and bool(np.all(x == y))


def drop_retired(data: Any, retired: dict[str, Any]) -> Any:
    """``data`` without the keys of fields that became constants, so configs written by earlier versions
    (a dataset's ``gt/config.yaml``, ``gt/scan.yaml``) still load; a retired key with a value other than
    the constant's is an error (that world can no longer be rendered)."""
    if not isinstance(data, dict) or not retired.keys() & data.keys():
        return data
    data = dict(data)
    for key, value in retired.items():
        if key in data:
            got = data.pop(key)
            if value is not ANY and not _same(got, value):
                raise ValueError(f"{key} is no longer configurable: fixed at {value!r}, got {got!r}")
    return data


class WorldConfig(ConfigModel):
    """Row layout. Plants occupy x in [0, length]; soil-only gaps lie beyond both ends."""

    #: range length (m) = distance the camera travels
    length: float = Field(4.0, gt=0, le=100)
    #: empty soil before and after the plants (m)
    gap: float = Field(0.75, ge=0)
    #: in-row plant spacing, lower bound (m)
    spacing_min: float = Field(0.12, gt=0)
    #: in-row plant spacing, upper bound (m)
    spacing_max: float = Field(0.20, gt=0)
    #: leaves per plant, lower bound
    leaves_min: int = Field(5, ge=0)
    #: leaves per plant, upper bound
    leaves_max: int = Field(8, ge=0)
    #: a dim neighbouring row (stalks and leaves) behind the range
    background_row: bool = True

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        return drop_retired(data, {
            "row_jitter": ROW_JITTER, "leaf_length_min": LEAF_LENGTH[0], "leaf_length_max": LEAF_LENGTH[1],
            "leaf_width_min": LEAF_WIDTH[0], "leaf_width_max": LEAF_WIDTH[1], "stalk_radius": STALK_RADIUS,
            "background_row_offset": BACKGROUND_ROW_OFFSET})

    @model_validator(mode="after")
    def _check(self) -> WorldConfig:
        if self.spacing_max < self.spacing_min:
            raise ValueError("spacing_max must be >= spacing_min")
        if self.leaves_max < self.leaves_min:
            raise ValueError("leaves_max must be >= leaves_min")
        return self


class PanicleConfig(ConfigModel):
    """Panicles: spindle-shaped seed clusters on branches around a rachis."""

    #: seeds per panicle, lower bound
    seeds_min: int = Field(1000, ge=1)
    #: seeds per panicle, upper bound
    seeds_max: int = Field(4000, ge=1)
    #: panicle length, lower bound (m)
    length_min: float = Field(0.15, gt=0)
    #: panicle length, upper bound (m)
    length_max: float = Field(0.30, gt=0)
    #: panicle envelope diameter, lower bound (m)
    width_min: float = Field(0.04, gt=0)
    #: panicle envelope diameter, upper bound (m)
    width_max: float = Field(0.08, gt=0)
    #: seed diameter, lower bound (m)
    seed_diameter_min: float = Field(0.003, gt=0)
    #: seed diameter, upper bound (m)
    seed_diameter_max: float = Field(0.005, gt=0)
    #: share of loose (open) panicles
    loose_fraction: float = Field(0.4, ge=0, le=1)
    #: grain colours drawn from per panicle (a range may hold several varieties)
    seed_colors: list[Literal["white", "tan", "red", "brown"]] = Field(
        default_factory=lambda: ["white", "tan", "red", "brown"])

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        return drop_retired(data, {"center_height_mean": PANICLE_HEIGHT[0], "center_height_sd": PANICLE_HEIGHT[1],
                                   "tilt_sd_deg": PANICLE_TILT_SD_DEG})

    @model_validator(mode="after")
    def _check(self) -> PanicleConfig:
        for lo, hi in (("seeds_min", "seeds_max"), ("length_min", "length_max"), ("width_min", "width_max"),
                       ("seed_diameter_min", "seed_diameter_max")):
            if getattr(self, hi) < getattr(self, lo):
                raise ValueError(f"{hi} must be >= {lo}")
        if not self.seed_colors:
            raise ValueError("seed_colors must not be empty")
        return self


class WindConfig(ConfigModel):
    """Sway: rigid rotation of each panicle and leaf about its base, a sum of sinusoids."""

    #: sway on (off: everything at rest)
    enabled: bool = True
    #: peak tilt of a panicle (deg)
    panicle_amplitude_deg: float = Field(1.5, ge=0, le=30)
    #: peak tilt of a leaf (deg)
    leaf_amplitude_deg: float = Field(3.0, ge=0, le=45)

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        return drop_retired(data, {"freq_min": SWAY_FREQ[0], "freq_max": SWAY_FREQ[1]})


class CameraConfig(ConfigModel):
    """Field camera (full resolution 4096 x 3000) scaled by ``scale``; the rig's place beside the row."""

    #: focal length x at full resolution (px)
    fx: float = 2583.0
    #: focal length y at full resolution (px)
    fy: float = 2578.0
    #: principal point x at full resolution (px)
    cx: float = 2013.0
    #: principal point y at full resolution (px)
    cy: float = 1525.7
    #: image width at full resolution (px)
    width: int = 4096
    #: image height at full resolution (px)
    height: int = 3000
    #: stereo baseline (m)
    baseline: float = Field(0.11, gt=0)
    #: image scale applied to the full-resolution camera
    scale: float = Field(0.35, gt=0, le=1.0)
    #: distance from the lens to the row line (m)
    standoff: float = Field(0.7, gt=0)
    #: camera height above ground (m)
    mount_height: float = Field(1.15, gt=0)

    def calib(self) -> StereoCalib:
        """The rectified stereo calibration at ``scale``."""
        return StereoCalib(self.fx, self.fy, self.cx, self.cy, self.baseline, self.width, self.height).scaled(
            self.scale)


class MotionConfig(ConfigModel):
    """Robot motion along +x (with a small wobble from uneven ground, see the constants above)."""

    #: speed along the row (m/s)
    speed: float = Field(0.2, gt=0)
    #: frames per second
    fps: float = Field(5.0, gt=0)

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        return drop_retired(data, {"height_wobble": HEIGHT_WOBBLE, "lateral_wobble": LATERAL_WOBBLE,
                                   "along_wobble": ALONG_WOBBLE, "angle_wobble_deg": ANGLE_WOBBLE_DEG})


class ImagingConfig(ConfigModel):
    """Flash imaging and sensor (the fixed flash and sensor model: the constants above)."""

    #: n x n samples on edge pixels (1 = no anti-aliasing)
    supersample: int = Field(2, ge=1, le=4)
    #: flash shadows
    shadows: bool = True
    #: overall gain; 1 = a white seed facing the flash at 0.7 m near full scale
    exposure: float = Field(1.0, gt=0)
    #: per-frame relative std of the gain
    exposure_jitter: float = Field(0.04, ge=0, le=0.5)
    #: JPEG round trip quality (None = lossless PNG images)
    jpeg_quality: int | None = Field(None, ge=10, le=100)

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("motion_blur") not in (None, False):
            raise ValueError("motion_blur is no longer an imaging option: set conditions.blur (exposure time = "
                             "blur x 5 ms, blurred along each pixel's motion)")
        return drop_retired(data, {
            "flash_offset": FLASH_OFFSET, "flash_radius": FLASH_RADIUS, "ambient": AMBIENT,
            "light_cutoff": LIGHT_CUTOFF, "full_well": FULL_WELL, "read_noise": READ_NOISE,
            "psf_sigma_px": PSF_SIGMA_PX, "vignetting": VIGNETTING, "threads": ANY,
            # motion blur is ``conditions.blur`` (along each pixel's motion); the exposure time went with it
            "motion_blur": False, "exposure_time": ANY})


class SimConfig(ConfigModel):
    """Everything the simulator needs; every random choice flows from ``seed``."""

    #: random seed of the world, the trajectory and the image noise
    seed: int = 0
    #: name of the preset this config started from
    preset: str | None = None
    world: WorldConfig = Field(default_factory=WorldConfig)
    panicle: PanicleConfig = Field(default_factory=PanicleConfig)
    wind: WindConfig = Field(default_factory=WindConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    motion: MotionConfig = Field(default_factory=MotionConfig)
    imaging: ImagingConfig = Field(default_factory=ImagingConfig)
    conditions: ConditionsConfig = Field(default_factory=ConditionsConfig)

    @property
    def length(self) -> float:
        return self.world.length


# The paper's eight ranges (Table of results): lengths in metres, each with a fixed seed.
# paperK uses seed 100 + K, so ``--preset paper3`` is always the same world and images.
PAPER_LENGTHS = (3.56, 5.00, 4.42, 4.10, 4.78, 3.94, 5.03, 4.43)
PRESETS: dict[str, dict] = {
    f"paper{k + 1}": {"seed": 101 + k, "preset": f"paper{k + 1}", "world": {"length": length}}
    for k, length in enumerate(PAPER_LENGTHS)
}


def preset_dict(name: str) -> dict:
    """The base dict of a named preset (raise ConfigError naming the choices when unknown)."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r} (choose from {', '.join(PRESETS)})")
    return copy.deepcopy(PRESETS[name])
