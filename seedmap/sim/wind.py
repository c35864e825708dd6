"""Non-rigid wind of a range world: stalks that bend, leaves that bend and flutter, gusts along the row.

Drawn once per range from the conditions' own random stream (``WindField.draw``) and attached to the world
(``World.wind_field``); the world at rest and its rigid sway are unchanged. At time ``t``:

- a gust envelope ``g(x, t)`` in [0, 1], shared by the whole row, travels along +x at ``GUST_SPEED``;
- each stalk's top moves horizontally by ``delta(t)`` (downwind with the gust, plus its own sway), the stalk
  bends with the cantilever-like profile ``delta (z / z_top)^2``;
- a panicle rides on its stalk's top: translated by ``delta``, tilted with the stalk's end slope ``2 delta / z_top``,
  its rigid sway amplified and a rotation about its own axis added;
- a leaf follows the stalk at its attachment, bends downwind with the gust and flutters normal to its blade
  (``s^2`` profile along its length ``s``, per-leaf frequency, amplitude and phase, a wave running to the tip).

Model values and sources: ``seedmap.sim.conditions`` and docs/method/conditions.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from seedmap.sim.conditions import (
    FLUTTER_FREQ,
    FLUTTER_TIP,
    GUST_FREQ,
    GUST_LEAF_TIP,
    GUST_SPEED,
    GUST_STALK_TOP,
    PANICLE_SPIN_DEG,
    PANICLE_SWAY_GAIN,
    STALK_FREQ,
    STALK_SWAY,
)

if TYPE_CHECKING:
    from seedmap.sim.world import World

N_GUST = 3  # sinusoids of the gust envelope
FLUTTER_WAVE = 0.5  # cycles of the flutter's phase lag from a leaf's base to its tip (a wave running outwards)
SPIN_FREQ = (0.2, 1.0)  # Hz: rotation of a panicle about its axis


def _unit_h(az: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], -1)


def _leaf_normals(v: np.ndarray) -> np.ndarray:
    """(L, K, 3) unit blade normals at each station of the rest leaves ``v`` (L, 3 K, 3)."""
    st = v.reshape(len(v), -1, 3, 3)  # (L, K, across, 3)
    across = st[:, :, 2] - st[:, :, 0]
    along = np.gradient(st[:, :, 1], axis=1)
    n = np.cross(along, across)
    return n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-12)


@dataclass
class WindField:
    """The drawn wind of one range at strength ``strength`` (see the module docstring)."""

    strength: float
    wind_dir: np.ndarray  # (3,) horizontal unit vector, downwind
    gust: np.ndarray  # (N_GUST, 3) weight, frequency (Hz), phase (rad)
    stalk: np.ndarray  # (Pl, 3) sway azimuth (rad), frequency (Hz), phase (rad) per plant
    flutter: np.ndarray  # (L, 2, 3) per leaf, two components: amplitude (relative), frequency (Hz), phase
    spin: np.ndarray  # (P, 3) amplitude (rad), frequency (Hz), phase per panicle
    leaf_s: np.ndarray  # (V,) position along the leaf (0 base .. 1 tip) of each leaf vertex
    leaf_normal: np.ndarray  # (L, V, 3) blade normal at each rest vertex

    @staticmethod
    def draw(world: World, strength: float, rng: np.random.Generator) -> WindField:
        L, Pl, P = len(world.leaf_vertices), len(world.plant_top), len(world.panicles)
        az = rng.uniform(0, 2 * np.pi)
        gust = np.column_stack([rng.uniform(0.5, 1.0, N_GUST), rng.uniform(*GUST_FREQ, N_GUST),
                                rng.uniform(0, 2 * np.pi, N_GUST)])
        gust[:, 0] /= gust[:, 0].sum()
        stalk = np.column_stack([rng.uniform(0, 2 * np.pi, Pl), rng.uniform(*STALK_FREQ, Pl),
                                 rng.uniform(0, 2 * np.pi, Pl)])
        f1 = rng.uniform(*FLUTTER_FREQ, L)
        flutter = np.stack([
            np.column_stack([rng.uniform(0.5, 1.0, L), f1, rng.uniform(0, 2 * np.pi, L)]),
            np.column_stack([rng.uniform(0.15, 0.35, L), f1 * rng.uniform(1.8, 2.6, L), rng.uniform(0, 2 * np.pi, L)]),
        ], 1)
        spin = np.column_stack([np.radians(PANICLE_SPIN_DEG) * rng.uniform(0.5, 1.0, P), rng.uniform(*SPIN_FREQ, P),
                                rng.uniform(0, 2 * np.pi, P)])
        nv = world.leaf_vertices.shape[1] if L else 0
        leaf_s = np.repeat(np.linspace(0, 1, nv // 3), 3) if nv else np.zeros(0)
        normal = np.repeat(_leaf_normals(world.leaf_vertices), 3, axis=1) if L else np.zeros((0, nv, 3))
        return WindField(float(strength), _unit_h(np.array(az)), gust, stalk, flutter, spin, leaf_s, normal)

    # ---- shared pieces ----
    def gust_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """Gust envelope in [0, 1] at positions ``x`` along the row (m), time ``t`` (s)."""
        x = np.asarray(x, float)
        w, f, ph = self.gust.T
        tau = t - x[..., None] / GUST_SPEED
        return np.sum(w * (0.5 + 0.5 * np.sin(2 * np.pi * f * tau + ph)), axis=-1)

    def stalk_top_offset(self, world: World, t: float) -> np.ndarray:
        """(Pl, 3) horizontal displacement of each stalk's top (m)."""
        top = world.plant_top
        g = self.gust_at(top[:, 0], t)
        az, f, ph = self.stalk.T
        sway = STALK_SWAY * np.sin(2 * np.pi * f * t + ph)
        return self.strength * (GUST_STALK_TOP * g[:, None] * self.wind_dir + sway[:, None] * _unit_h(az))

    def _stalk_offset(self, world: World, plant: np.ndarray, z: np.ndarray, top_off: np.ndarray) -> np.ndarray:
        s = np.clip(z / np.maximum(world.plant_top[plant, 2], 1e-6), 0, 1)
        return top_off[plant] * (s * s)[..., None]

    # ---- bounds (culling) ----
    @property
    def stalk_bound(self) -> float:
        """Largest displacement of any stalk point (m)."""
        return self.strength * (GUST_STALK_TOP + STALK_SWAY) + 1e-4

    @property
    def leaf_bound(self) -> float:
        """Largest non-rigid displacement of any leaf point (m), on top of its rigid sway."""
        return self.stalk_bound + self.strength * (GUST_LEAF_TIP + 1.5 * FLUTTER_TIP * 1.35)

    # ---- geometry at time t ----
    def stalk_vertices(self, world: World, t: float) -> np.ndarray:
        """(V, 3) stalk vertices bent at time ``t``."""
        off = self.stalk_top_offset(world, t)
        v = world.stalk_vertices
        return v + self._stalk_offset(world, world.stalk_plant, v[:, 2], off)

    def leaf_offsets(self, world: World, sel: np.ndarray, t: float) -> np.ndarray:
        """(len(sel), V, 3) non-rigid displacement of the vertices of leaves ``sel`` at time ``t``."""
        attach = world.leaf_attach[sel]
        plant = world.leaf_plant[sel]
        top_off = self.stalk_top_offset(world, t)
        base = self._stalk_offset(world, plant, attach[:, 2], top_off)  # (l, 3) the stalk at the attachment
        g = self.gust_at(attach[:, 0], t)  # (l,)
        s = self.leaf_s[None, :]  # (1, V)
        a, f, ph = (self.flutter[sel][..., k][..., None] for k in range(3))  # (l, 2, 1)
        wave = np.sin(2 * np.pi * (f * t - FLUTTER_WAVE * s[:, None, :]) + ph)  # (l, 2, V)
        flut = FLUTTER_TIP * (0.5 + g)[:, None] * np.sum(a * wave, axis=1) * s * s  # (l, V)
        bend = GUST_LEAF_TIP * g[:, None] * s * s  # (l, V)
        return (base[:, None, :] + self.strength * (bend[..., None] * self.wind_dir
                                                    + flut[..., None] * self.leaf_normal[sel]))

    def panicle_motion(self, world: World, t: float) -> np.ndarray:
        """(P, 4, 4) motions ``D`` (``p_world = D p_rest``) of the panicles at time ``t``."""
        P = len(world.panicles)
        D = np.tile(np.eye(4), (P, 1, 1))
        if P == 0:
            return D
        base = np.stack([p.base for p in world.panicles])
        axis = np.stack([p.axis for p in world.panicles])
        top_off = self.stalk_top_offset(world, t)[world.panicle_plant]  # (P, 3)
        H = np.maximum(world.plant_top[world.panicle_plant, 2], 1e-6)
        tilt = 2.0 * np.cross(np.array([0.0, 0.0, 1.0]), top_off) / H[:, None]  # the stalk's end slope
        amp, f, ph = self.spin.T
        spin = (self.strength * amp * np.sin(2 * np.pi * f * t + ph))[:, None] * axis
        R = Rotation.from_rotvec(tilt).as_matrix() @ self._sway(world, t) @ Rotation.from_rotvec(spin).as_matrix()
        D[:, :3, :3] = R
        D[:, :3, 3] = base + top_off - np.einsum("nij,nj->ni", R, base)
        return D

    def _sway(self, world: World, t: float) -> np.ndarray:
        """(P, 3, 3) the rigid sway of ``World`` with its amplitude multiplied by ``1 + gain x strength``."""
        P = len(world.panicles)
        if not world.cfg.wind.enabled:
            return np.tile(np.eye(3), (P, 1, 1))
        sway = np.stack([p.sway for p in world.panicles])
        amp, freq, phase = sway[..., 0], sway[..., 1], sway[..., 2]
        ang = np.sum(amp * np.sin(2 * np.pi * freq * t + phase), axis=-1) * (1 + PANICLE_SWAY_GAIN * self.strength)
        return Rotation.from_rotvec(np.column_stack([ang[:, 0], ang[:, 1], np.zeros(P)])).as_matrix()
