"""Camera-side field conditions of a range: the robot's shake, the exposure interval, gains and frame drops.

All drawn from the conditions' own random streams (one per condition, so turning one on never changes the draws
of another) and only when that condition is on; model values: ``seedmap.sim.conditions``, docs/method/conditions.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from seedmap.sim.conditions import (
    AE_RHO,
    AE_SD,
    BLUR_SAMPLES,
    DROP_P,
    DUPLICATE_P,
    EXPOSURE_TIME,
    FLASH_SD,
    GROUND_HEAVE,
    GROUND_TILT_DEG,
    GROUND_WAVELENGTHS,
    VIBRATION_AMP,
    VIBRATION_DEG,
    VIBRATION_FREQ,
    ConditionsConfig,
)


def condition_streams(seed: int) -> dict[str, np.random.Generator]:
    """One generator per condition, independent of the world's, trajectory's and frames' streams."""
    ss = np.random.SeedSequence(seed).spawn(4)[3]  # children 0-2 are the world, trajectory and frames
    return {k: np.random.default_rng(c) for k, c in zip(("wind", "vibration", "flicker", "drops"), ss.spawn(4),
                                                          strict=True)}


@dataclass
class RobotShake:
    """Roll/pitch/heave from uneven ground (over the distance travelled) and drive-train vibration (over time),
    as a rigid motion of the rig about the ground point below the camera."""

    ground: np.ndarray  # (3, G, 3) roll, pitch, heave: amplitude, wavelength (m), phase
    vib: np.ndarray  # (6, 3) roll, pitch, yaw (rad), x, y, z (m): amplitude, frequency (Hz), phase

    @staticmethod
    def draw(strength: float, rng: np.random.Generator) -> RobotShake:
        G = len(GROUND_WAVELENGTHS)
        amp = np.array([np.radians(GROUND_TILT_DEG)] * 2 + [GROUND_HEAVE])
        w = rng.uniform(0.5, 1.0, (3, G))
        w /= w.sum(axis=1, keepdims=True)
        ground = np.stack([strength * amp[:, None] * w,
                           np.asarray(GROUND_WAVELENGTHS)[None, :] * rng.uniform(0.8, 1.25, (3, G)),
                           rng.uniform(0, 2 * np.pi, (3, G))], -1)
        vamp = np.array([np.radians(VIBRATION_DEG)] * 3 + [VIBRATION_AMP] * 3) * rng.uniform(0.5, 1.0, 6)
        vib = np.column_stack([strength * vamp, rng.uniform(*VIBRATION_FREQ, 6), rng.uniform(0, 2 * np.pi, 6)])
        return RobotShake(ground, vib)

    def apply(self, poses: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``poses`` (n, 4, 4) ``T_world_cam`` shaken at nominal distances ``x`` (m) and times ``t`` (s)."""
        a, lam, ph = (self.ground[..., k] for k in range(3))
        g = np.sum(a[None] * np.sin(2 * np.pi * np.asarray(x, float)[:, None, None] / lam[None] + ph[None]), axis=2)
        a, f, ph = self.vib.T
        v = a[None] * np.sin(2 * np.pi * f[None] * np.asarray(t, float)[:, None] + ph[None])  # (n, 6)
        R = Rotation.from_rotvec(np.column_stack([g[:, 0] + v[:, 0], g[:, 1] + v[:, 1], v[:, 2]])).as_matrix()
        pivot = poses[:, :3, 3] * np.array([1.0, 1.0, 0.0])
        P = np.tile(np.eye(4), (len(poses), 1, 1))
        P[:, :3, :3] = R
        P[:, :3, 3] = pivot - np.einsum("nij,nj->ni", R, pivot) + v[:, 3:] + np.outer(g[:, 2], [0.0, 0.0, 1.0])
        return P @ poses


def exposure_offsets(cond: ConditionsConfig) -> np.ndarray:
    """Times (s) of the sub-samples of the exposure interval relative to its middle (empty: no blur)."""
    if cond.blur <= 0:
        return np.zeros(0)
    tau = cond.blur * EXPOSURE_TIME
    return (np.arange(BLUR_SAMPLES) + 0.5) / BLUR_SAMPLES * tau - tau / 2


def exposure_gains(n: int, strength: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) gain multipliers of the left and right camera per frame: the flash energy (shared) times each
    camera's auto-exposure, an AR(1) process in log gain."""
    flash = strength * FLASH_SD * rng.standard_normal(n)
    e = rng.standard_normal((n, 2))
    ae = np.zeros((n, 2))
    sd = strength * AE_SD
    ae[0] = sd * e[0]
    for k in range(1, n):
        ae[k] = AE_RHO * ae[k - 1] + np.sqrt(1 - AE_RHO ** 2) * sd * e[k]
    return np.exp(flash[:, None] + ae)


def frame_schedule(n: int, strength: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Which of ``n`` captures are written: ``(stamp, source)`` index arrays, one entry per written frame.

    A dropped capture is missing; a duplicated one repeats the previous written image (a stale buffer) under
    its own time stamp. The first and the last capture are always written as themselves."""
    r = rng.random(n)
    stamp, source = [0], [0]
    for i in range(1, n):
        if i < n - 1 and r[i] < strength * DROP_P:
            continue
        dup = i < n - 1 and r[i] < strength * (DROP_P + DUPLICATE_P)
        stamp.append(i)
        source.append(source[-1] if dup else i)
    return np.array(stamp, np.int64), np.array(source, np.int64)
