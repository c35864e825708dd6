"""Field conditions of a simulated range: wind, robot vibration, motion blur, flash flicker, wet leaves, frame drops.

Each condition is one strength (0 = off; 1 = the typical field value of docs/method/conditions.md; values up to 3
extrapolate linearly). With every strength 0 (the default) the renderer takes exactly the code path and the random
streams it takes without this section, so the images and ground truth are byte-identical to a render without it.
A named rung of the ladder ``calm < breeze < windy < rough`` sets all strengths at once; explicit strengths given
with it win: ``--set conditions.preset=windy`` or ``--set conditions.preset=windy --set conditions.wind=0.5``
(a field, not a string in place of the section, so no order of ``--set`` options can drop a strength).
The UPPER_CASE constants are the model values at strength 1 (sources in docs/method/conditions.md).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from seedmap.config import ConfigModel

# ---- wind (strength 1: a windy day, ~5-8 m/s at canopy height) ----
#: leaf flutter: frequency range (Hz) and tip amplitude normal to the blade (m)
FLUTTER_FREQ, FLUTTER_TIP = (1.0, 5.0), 0.03
#: gusts: frequency range of the gust envelope (Hz), speed of the gust front along the row (m/s)
GUST_FREQ, GUST_SPEED = (0.25, 1.0), 3.0
#: downwind tip deflection of a leaf in a full gust (m)
GUST_LEAF_TIP = 0.06
#: downwind displacement of a stalk's top in a full gust (m), and its own sway (m) at STALK_FREQ (Hz)
GUST_STALK_TOP, STALK_SWAY, STALK_FREQ = 0.03, 0.012, (0.7, 1.5)
#: panicle rigid-sway amplitude multiplier per unit strength, and rotation about its own axis (deg)
PANICLE_SWAY_GAIN, PANICLE_SPIN_DEG = 2.0, 5.0

# ---- robot (strength 1: a field robot on tilled soil) ----
#: roll and pitch from uneven ground (deg), heave (m), over ground wavelengths GROUND_WAVELENGTHS (m)
GROUND_TILT_DEG, GROUND_HEAVE, GROUND_WAVELENGTHS = 1.5, 0.01, (0.3, 0.7, 1.6)
#: drive-train and engine vibration: frequency range (Hz), angular (deg) and translational (m) amplitude
VIBRATION_FREQ, VIBRATION_DEG, VIBRATION_AMP = (12.0, 30.0), 0.15, 0.0005

# ---- exposure and light ----
#: exposure time at strength 1 (s): camera motion during it blurs the image
EXPOSURE_TIME = 0.005
#: sub-samples of the exposure interval along each pixel's motion (the blur's quality)
BLUR_SAMPLES = 9
#: per-frame relative std of the flash energy (shared by both cameras)
FLASH_SD = 0.06
#: auto-exposure: relative std of each camera's gain wander and its frame-to-frame correlation
AE_SD, AE_RHO = 0.12, 0.7
#: wet leaves and stalks: specular strength and exponent of the (rippled) water film, share of the surface wetted,
#: and the glint of a droplet relative to a white surface facing the flash
WET_KS, WET_SHININESS, WET_COVER, WET_DROP = 0.8, 60.0, 0.6, 1.5

# ---- frames ----
#: probability of a dropped and of a duplicated (stale) frame
DROP_P, DUPLICATE_P = 0.04, 0.03

#: the ladder from a calm to a rough field: strengths per rung (``calm`` = every condition off)
LADDER: dict[str, dict[str, float]] = {
    "calm": {"wind": 0.0, "vibration": 0.0, "blur": 0.0, "flicker": 0.0, "wet": 0.0, "drops": 0.0},
    "breeze": {"wind": 0.3, "vibration": 0.3, "blur": 0.5, "flicker": 0.3, "wet": 0.0, "drops": 0.0},
    "windy": {"wind": 1.0, "vibration": 0.7, "blur": 1.0, "flicker": 0.7, "wet": 0.0, "drops": 0.5},
    "rough": {"wind": 2.0, "vibration": 1.5, "blur": 2.0, "flicker": 1.5, "wet": 1.0, "drops": 1.0},
}
STRENGTHS = tuple(LADDER["calm"])


class ConditionsConfig(ConfigModel):
    """Strength of each field condition (0 = off, 1 = typical field value; see docs/method/conditions.md)."""

    #: rung of the calm < breeze < windy < rough ladder the strengths start from (explicit strengths win)
    preset: Literal["calm", "breeze", "windy", "rough"] | None = None
    #: non-rigid wind: leaf flutter and bending, stalk sway, gusts travelling along the row, panicle sway/spin
    wind: float = Field(0.0, ge=0, le=3)
    #: robot roll/pitch/heave from uneven ground and drive-train vibration, applied to the camera pose
    vibration: float = Field(0.0, ge=0, le=3)
    #: motion blur: exposure time = blur x 5 ms, blurred along each pixel's motion (camera path incl. vibration)
    blur: float = Field(0.0, ge=0, le=3)
    #: flash energy variation between frames and each camera's auto-exposure wander
    flicker: float = Field(0.0, ge=0, le=3)
    #: wet leaves and stalks: patchy water film with sharp flash highlights
    wet: float = Field(0.0, ge=0, le=3)
    #: dropped and duplicated (stale) frames, at drops x (4 %, 3 %) per frame
    drops: float = Field(0.0, ge=0, le=3)

    @model_validator(mode="before")
    @classmethod
    def _ladder(cls, data: Any) -> Any:
        if isinstance(data, dict) and isinstance(data.get("preset"), str) and data["preset"] in LADDER:
            data = {**LADDER[data["preset"]], **data}
        return data

    @property
    def any(self) -> bool:
        """True when some condition is on."""
        return any(getattr(self, k) > 0 for k in STRENGTHS)
