"""Configuration of the procedural sorghum world and its ground-truth stereo renderer.

Units: metres, seconds, degrees (where the field name says ``_deg``), pixels.
World frame: x along the row (direction of travel), y from the robot towards the row, z up,
ground at z = 0, row line at y = 0.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from seedmap.config import ConfigModel
from seedmap.errors import ConfigError
from seedmap.records import StereoCalib


class WorldConfig(ConfigModel):
    """Row layout. Plants occupy x in [0, length]; soil-only gaps lie beyond both ends."""

    length: float = Field(4.0, gt=0, le=100, description="range length (m) = distance the camera travels")
    gap: float = Field(0.75, ge=0, description="empty soil before and after the plants (m)")
    spacing_min: float = Field(0.12, gt=0, description="in-row plant spacing, lower bound (m)")
    spacing_max: float = Field(0.20, gt=0, description="in-row plant spacing, upper bound (m)")
    row_jitter: float = Field(0.025, ge=0, description="std of plant offsets across the row line (m)")
    leaves_min: int = Field(5, ge=0)
    leaves_max: int = Field(8, ge=0)
    leaf_length_min: float = Field(0.45, gt=0)
    leaf_length_max: float = Field(0.85, gt=0)
    leaf_width_min: float = Field(0.045, gt=0)
    leaf_width_max: float = Field(0.075, gt=0)
    stalk_radius: float = Field(0.011, gt=0)
    background_row: bool = Field(True, description="a dim neighbouring row (stalks+leaves) behind the range")
    background_row_offset: float = Field(0.76, gt=0, description="distance of that row behind the range (m)")

    @model_validator(mode="after")
    def _check(self) -> WorldConfig:
        if self.spacing_max < self.spacing_min:
            raise ValueError("spacing_max must be >= spacing_min")
        if self.leaves_max < self.leaves_min:
            raise ValueError("leaves_max must be >= leaves_min")
        return self


class PanicleConfig(ConfigModel):
    """Panicles: spindle-shaped seed clusters on branches around a rachis."""

    seeds_min: int = Field(1000, ge=1)
    seeds_max: int = Field(4000, ge=1)
    length_min: float = Field(0.15, gt=0, description="panicle length (m)")
    length_max: float = Field(0.30, gt=0)
    width_min: float = Field(0.04, gt=0, description="panicle envelope diameter (m)")
    width_max: float = Field(0.08, gt=0)
    seed_diameter_min: float = Field(0.003, gt=0, description="seed diameter (m)")
    seed_diameter_max: float = Field(0.005, gt=0)
    center_height_mean: float = Field(1.15, gt=0, description="panicle centre height (m)")
    center_height_sd: float = Field(0.07, ge=0)
    loose_fraction: float = Field(0.4, ge=0, le=1, description="share of loose (open) panicles")
    tilt_sd_deg: float = Field(8.0, ge=0, description="lean of the panicle axis from vertical")
    seed_colors: list[Literal["white", "tan", "red", "brown"]] = Field(
        default_factory=lambda: ["white", "tan", "red", "brown"],
        description="grain colours drawn from per panicle (a range may hold several varieties)")

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
    """Sway: rigid rotation of each panicle/leaf about its base, a sum of sinusoids."""

    enabled: bool = True
    panicle_amplitude_deg: float = Field(1.5, ge=0, le=30)
    leaf_amplitude_deg: float = Field(3.0, ge=0, le=45)
    freq_min: float = Field(0.3, gt=0, description="Hz")
    freq_max: float = Field(1.2, gt=0, description="Hz")


class CameraConfig(ConfigModel):
    """Field camera (facts.md, full resolution 4096x3000) scaled by ``scale``."""

    fx: float = 2583.0
    fy: float = 2578.0
    cx: float = 2013.0
    cy: float = 1525.7
    width: int = 4096
    height: int = 3000
    baseline: float = Field(0.11, gt=0)
    scale: float = Field(0.35, gt=0, le=1.0)
    standoff: float = Field(0.7, gt=0, description="distance from the lens to the row line (m)")
    mount_height: float = Field(1.15, gt=0, description="camera height above ground (m)")

    def calib(self) -> StereoCalib:
        return StereoCalib(self.fx, self.fy, self.cx, self.cy, self.baseline, self.width, self.height).scaled(
            self.scale)


class MotionConfig(ConfigModel):
    """Robot motion along +x with smooth wobble from uneven ground."""

    speed: float = Field(0.2, gt=0, description="m/s")
    fps: float = Field(5.0, gt=0, description="frames per second")
    height_wobble: float = Field(0.004, ge=0, description="amplitude of height changes (m)")
    lateral_wobble: float = Field(0.004, ge=0, description="amplitude of stand-off changes (m)")
    along_wobble: float = Field(0.003, ge=0, description="amplitude of speed irregularity (m)")
    angle_wobble_deg: float = Field(0.3, ge=0, description="amplitude of roll/pitch/yaw wobble")


class ImagingConfig(ConfigModel):
    """Flash imaging and sensor model."""

    supersample: int = Field(2, ge=1, le=4, description="n x n samples on edge pixels (1 = off)")
    shadows: bool = True
    flash_offset: tuple[float, float, float] = Field(
        (0.055, -0.06, 0.0), description="flash position in the left camera frame (m): between the lenses, above")
    flash_radius: float = Field(0.015, ge=0, description="flash disc radius for soft shadows (m)")
    exposure: float = Field(1.0, gt=0, description="overall gain; 1 = a white seed at 0.7 m near full scale")
    exposure_jitter: float = Field(0.04, ge=0, le=0.5, description="per-frame relative std of the gain")
    ambient: float = Field(0.025, ge=0, description="ambient light relative to the flash at 0.7 m")
    light_cutoff: float = Field(1.5, gt=0, description="distance beyond which the flash fades to black (m)")
    full_well: float = Field(3000.0, gt=0, description="electrons at full scale (shot noise)")
    read_noise: float = Field(6.0, ge=0, description="read noise (electrons)")
    psf_sigma_px: float = Field(0.45, ge=0, description="optical blur (pixels)")
    vignetting: float = Field(0.25, ge=0, le=1, description="relative fall-off at the image corners")
    motion_blur: bool = False
    exposure_time: float = Field(0.004, gt=0, description="s, used for motion blur")
    jpeg_quality: int | None = Field(None, ge=10, le=100, description="JPEG round trip quality (None = off)")
    threads: int = Field(2, ge=1, le=2, description="render the two cameras in parallel threads (same output)")


class SimConfig(ConfigModel):
    """Everything the simulator needs; every random choice flows from ``seed``."""

    seed: int = 0
    preset: str | None = Field(None, description="name of the preset this config started from")
    world: WorldConfig = Field(default_factory=WorldConfig)
    panicle: PanicleConfig = Field(default_factory=PanicleConfig)
    wind: WindConfig = Field(default_factory=WindConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    motion: MotionConfig = Field(default_factory=MotionConfig)
    imaging: ImagingConfig = Field(default_factory=ImagingConfig)

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
    import copy

    return copy.deepcopy(PRESETS[name])
