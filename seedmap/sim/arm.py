"""A simulated UR5 arm that carries the stereo camera 360 degrees around one panicle.

The UR5 hangs upside down above the panicle, coaxial with the rachis, so joint 1 circles the camera
around it. ``simulate_capture`` plans the views, solves IK on the nominal arm and applies the error
sources (encoder offsets and noise, link lengths, hand-eye, panicle sway). Geometry and error model:
docs/method/simulator.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import Field, model_validator
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from seedmap.config import ConfigModel
from seedmap.errors import ConfigError, InputError
from seedmap.geometry import invert, make_pose
from seedmap.io.text import read_text
from seedmap.sim.config import drop_retired

JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")


#: standard DH table of a UR5: d, a (m), alpha (rad)
UR5_DH = {"d": [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823], "a": [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0],
          "alpha": [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]}
#: nominal camera mount on the flange: translation (m) and rotation vector (deg) of T_flange_cam
HAND_EYE = {"t": [-0.055, 0.0, 0.06], "rotvec_deg": [0.0, 0.0, 0.0]}
#: height of the inverted UR5 base above the panicle base (m)
BASE_HEIGHT = 0.75
#: time between views (s)
VIEW_PERIOD_S = 1.0


class ArmErrorConfig(ConfigModel):
    """Standard deviations of the simulated error sources (0 disables one)."""

    #: constant offset of each joint encoder (deg)
    encoder_offset_deg: float = Field(0.03, ge=0)
    #: per-view encoder noise (deg)
    encoder_noise_deg: float = Field(0.01, ge=0)
    #: error of the DH link lengths (mm)
    link_length_mm: float = Field(0.3, ge=0)
    #: translation error of the camera mount (mm)
    hand_eye_mm: float = Field(1.5, ge=0)
    #: rotation error of the camera mount (deg)
    hand_eye_deg: float = Field(0.3, ge=0)
    #: rigid tilt of the panicle about its base per view (deg)
    sway_deg: float = Field(0.3, ge=0)


class ArmConfig(ConfigModel):
    """Arm capture: the circle of views and the error sources (the arm itself: the constants above)."""

    #: number of views around the panicle
    views: int = Field(36, ge=3)
    #: camera stand-off from the rachis axis (m)
    radius: float = Field(0.3, gt=0.05)
    #: camera heights above the panicle base (m), one ring each; None = mid-panicle
    heights: list[float] | None = None
    #: camera pitch (deg, positive looks down)
    tilt_deg: float = 0.0
    errors: ArmErrorConfig = Field(default_factory=ArmErrorConfig)

    @model_validator(mode="before")
    @classmethod
    def _retired(cls, data: Any) -> Any:
        return drop_retired(data, {"dh": UR5_DH, "hand_eye": HAND_EYE, "base_height": BASE_HEIGHT,
                                   "view_period_s": VIEW_PERIOD_S})


# ------------------------------------------------------------------------------------------------
# kinematics
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DHParams:
    """DH table as arrays (6,) each: d, a (m), alpha (rad)."""

    d: np.ndarray
    a: np.ndarray
    alpha: np.ndarray

    def to_dict(self) -> dict:
        return {"d": self.d.tolist(), "a": self.a.tolist(), "alpha": self.alpha.tolist()}


UR5 = DHParams(*(np.asarray(UR5_DH[k], float) for k in ("d", "a", "alpha")))


def _check_q(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    if q.shape[-1] != 6:
        raise InputError(f"a UR5 has 6 joints, got {q.shape[-1]} joint angles")
    return q


def fk(q: np.ndarray, dh: DHParams = UR5) -> np.ndarray:
    """Forward kinematics: joint angles (rad, (6,) or (N, 6)) -> T_base_flange (4, 4) or (N, 4, 4)."""
    q = _check_q(q)
    single = q.ndim == 1
    q = q.reshape(-1, 6)
    T = np.tile(np.eye(4), (len(q), 1, 1))
    for i in range(6):
        ct, st = np.cos(q[:, i]), np.sin(q[:, i])
        ca, sa = np.cos(dh.alpha[i]), np.sin(dh.alpha[i])
        A = np.zeros((len(q), 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, dh.a[i] * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, dh.a[i] * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, dh.d[i]
        A[:, 3, 3] = 1.0
        T = T @ A
    return T[0] if single else T


def pose_residual(T: np.ndarray, T_target: np.ndarray, rot_weight: float = 0.3) -> np.ndarray:
    """6-vector: position error (m) and rotation-vector error (rad, scaled by ``rot_weight`` m/rad)."""
    dp = T[:3, 3] - T_target[:3, 3]
    dr = Rotation.from_matrix(T_target[:3, :3].T @ T[:3, :3]).as_rotvec()
    return np.concatenate([dp, rot_weight * dr])


def ik(
    T_target: np.ndarray,
    q0: np.ndarray,
    dh: DHParams = UR5,
    rng: np.random.Generator | None = None,
    restarts: int = 8,
    tol_m: float = 1e-6,
) -> np.ndarray:
    """Numerical inverse kinematics for T_base_flange; warm start ``q0`` (rad), random restarts from
    ``rng`` if the warm start does not converge. Raises :class:`ConfigError` when unreachable."""
    q0 = _check_q(np.asarray(q0, float).reshape(6))

    def res(q: np.ndarray) -> np.ndarray:
        return pose_residual(fk(q, dh), T_target)

    best = None
    starts = [q0]
    rng = rng if rng is not None else np.random.default_rng(0)
    for _ in range(restarts):
        starts.append(q0 + rng.normal(0.0, 0.6, 6))
    for s in starts:
        sol = least_squares(res, s, method="lm", xtol=1e-12, ftol=1e-12, max_nfev=400)
        err = float(np.linalg.norm(sol.fun))
        if best is None or err < best[0]:
            best = (err, sol.x)
        if err < tol_m:
            break
    assert best is not None
    if best[0] > 1e-4:
        raise ConfigError(f"camera pose not reachable by the arm (IK residual {best[0] * 1000:.1f} mm); "
                          "reduce arm.radius")
    q = best[1]
    # keep every joint within one turn of the warm start (continuity around the circle)
    return q0 + (q - q0 + np.pi) % (2 * np.pi) - np.pi


# ------------------------------------------------------------------------------------------------
# capture plan and simulated errors
# ------------------------------------------------------------------------------------------------


def hand_eye_matrix() -> np.ndarray:
    """Nominal T_flange_cam."""
    return make_pose(Rotation.from_rotvec(np.radians(HAND_EYE["rotvec_deg"])).as_matrix(), HAND_EYE["t"])


def base_pose() -> np.ndarray:
    """T_world_base: the base hangs ``BASE_HEIGHT`` above the panicle base, z axis pointing down."""
    return make_pose(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [0.0, 0.0, BASE_HEIGHT])


def look_at_axis(azimuth: float, height: float, radius: float, tilt_deg: float = 0.0) -> np.ndarray:
    """T_world_cam of a camera at azimuth ``azimuth`` (rad), ``radius`` m from the z axis and
    ``height`` m up, looking at the axis (pitched down by ``tilt_deg``), image up = world +z."""
    c = np.array([radius * np.cos(azimuth), radius * np.sin(azimuth), height])
    inward = -np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    t = np.radians(tilt_deg)
    z = np.cos(t) * inward + np.sin(t) * np.array([0.0, 0.0, -1.0])
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), c)


def planned_camera_poses(cfg: ArmConfig, heights: list[float]) -> np.ndarray:
    """(views, 4, 4) desired T_world_cam: azimuths evenly over 360 deg, rings cycled view by view."""
    n = cfg.views
    az = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.stack([look_at_axis(a, heights[i % len(heights)], cfg.radius, cfg.tilt_deg) for i, a in enumerate(az)])


@dataclass
class ArmCapture:
    """Result of a simulated scan (all arrays per view)."""

    q_cmd: np.ndarray  # (N, 6) commanded joint angles (rad), IK of the planned pose on the nominal model
    q_meas: np.ndarray  # (N, 6) encoder readings (rad)
    q_true: np.ndarray  # (N, 6) true joint angles (rad)
    T_world_cam_fk: np.ndarray  # (N, 4, 4) nominal camera pose from FK(measured joints) + nominal hand-eye
    T_world_cam_true: np.ndarray  # (N, 4, 4) true camera pose in the world
    panicle_motion: np.ndarray  # (N, 4, 4) sway D: p_world = D p_rest
    times: np.ndarray  # (N,) s
    T_world_base: np.ndarray
    dh_nominal: DHParams
    dh_true: DHParams
    T_flange_cam_nominal: np.ndarray
    T_flange_cam_true: np.ndarray

    @property
    def T_rest_cam_true(self) -> np.ndarray:
        """True camera poses in the panicle's rest frame (what a panicle model can recover)."""
        return invert(self.panicle_motion) @ self.T_world_cam_true


def simulate_capture(cfg: ArmConfig, heights: list[float], rng: np.random.Generator) -> ArmCapture:
    """Plan the circle, solve IK on the nominal arm, and apply the configured error sources."""
    e = cfg.errors
    dh_nom = UR5
    T_wb = base_pose()
    X_nom = hand_eye_matrix()
    # true arm: perturbed link lengths and mount (constant over the scan)
    sig_l = e.link_length_mm / 1000.0
    d_true = dh_nom.d + np.where(dh_nom.d != 0, rng.normal(0.0, sig_l, 6), 0.0)
    a_true = dh_nom.a + np.where(dh_nom.a != 0, rng.normal(0.0, sig_l, 6), 0.0)
    dh_true = DHParams(d_true, a_true, dh_nom.alpha.copy())
    dX = make_pose(Rotation.from_rotvec(rng.normal(0.0, np.radians(e.hand_eye_deg), 3)).as_matrix(),
                   rng.normal(0.0, e.hand_eye_mm / 1000.0, 3))
    X_true = X_nom @ dX
    enc_offset = rng.normal(0.0, np.radians(e.encoder_offset_deg), 6)

    planned = planned_camera_poses(cfg, heights)
    T_base_world = invert(T_wb)
    X_inv = invert(X_nom)
    # warm start: elbow-up configuration pointing the tool at the first view
    q = np.array([0.0, -1.2, 1.6, -0.4, 1.57, 0.0])
    q_cmd = np.zeros((cfg.views, 6))
    for k in range(cfg.views):
        T_bf = T_base_world @ planned[k] @ X_inv
        if k == 0:
            q = _first_solution(T_bf, dh_nom, rng)
        q = ik(T_bf, q, dh_nom, rng=rng)
        q_cmd[k] = q
    noise = rng.normal(0.0, np.radians(e.encoder_noise_deg), (cfg.views, 6))
    q_meas = q_cmd.copy()  # the servo loop brings the encoders to the command
    q_true = q_meas - enc_offset - noise
    T_fk = T_wb @ fk(q_meas, dh_nom) @ X_nom
    T_true = T_wb @ fk(q_true, dh_true) @ X_true
    sway = rng.normal(0.0, np.radians(e.sway_deg), (cfg.views, 2))
    D = np.stack([make_pose(Rotation.from_rotvec([s[0], s[1], 0.0]).as_matrix()) for s in sway])
    times = np.arange(cfg.views) * VIEW_PERIOD_S
    return ArmCapture(q_cmd, q_meas, q_true, T_fk, T_true, D, times, T_wb, dh_nom, dh_true, X_nom, X_true)


def _first_solution(T_bf: np.ndarray, dh: DHParams, rng: np.random.Generator) -> np.ndarray:
    """A well-conditioned elbow configuration for the first view (tries a few standard seeds)."""
    seeds = [
        np.array([0.0, -1.2, 1.6, -0.4, 1.57, 0.0]),
        np.array([np.pi, -1.2, 1.6, -0.4, 1.57, 0.0]),
        np.array([0.0, -2.0, -1.6, 0.4, -1.57, 0.0]),
        np.array([np.pi / 2, -1.0, 1.0, 0.0, 1.57, 0.0]),
    ]
    best = None
    for s in seeds:
        try:
            q = ik(T_bf, s, dh, rng=rng, restarts=4)
        except ConfigError:
            continue
        # prefer a solution away from wrist singularity (|sin q5| large)
        score = -abs(np.sin(q[4]))
        if best is None or score < best[0]:
            best = (score, q)
    if best is None:
        raise ConfigError("first camera pose not reachable by the arm; reduce arm.radius")
    return best[1]


def write_joints_csv(path, capture: ArmCapture) -> None:
    """joints.csv: view, time, commanded q1..q6, measured q1..q6 (radians)."""
    from seedmap.io.atomic import atomic_write_text

    head = ["view", "t"] + [f"cmd_{n}" for n in JOINT_NAMES] + [f"meas_{n}" for n in JOINT_NAMES]
    lines = [",".join(head)]
    for k in range(len(capture.q_cmd)):
        vals = [f"{v:.9f}" for v in np.concatenate([capture.q_cmd[k], capture.q_meas[k]])]
        lines.append(f"{k},{capture.times[k]:.6f}," + ",".join(vals))
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_joints_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Read joints.csv -> (views (N,), measured joints (N, 6) rad); clear errors for bad files."""
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise InputError("joints file not found (the arm scan needs joints.csv for FK poses)", path)
    text = read_text(path, "joints file").strip().splitlines()
    if len(text) < 2:
        raise InputError("joints file has no rows", path)
    head = [h.strip() for h in text[0].split(",")]
    meas = [i for i, h in enumerate(head) if h.startswith("meas_")]
    if len(meas) != 6:
        raise InputError(f"joints file needs 6 meas_* columns (UR5), found {len(meas)}", path)
    views, rows = [], []
    for ln, line in enumerate(text[1:], 2):
        parts = line.split(",")
        if len(parts) != len(head):
            raise InputError(f"line {ln}: {len(parts)} values, header has {len(head)} columns "
                             "(joint angles of the wrong length?)", path)
        try:
            views.append(int(parts[0]))
            vals = [float(x) for x in parts[1:]]
        except ValueError:
            raise InputError(f"line {ln}: not a number", path) from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"line {ln}: NaN or inf (every value must be a finite number)", path)
        rows.append([vals[i - 1] for i in meas])
    q = np.asarray(rows, float)
    if not np.all(np.isfinite(q)):
        raise InputError("joint angles must be finite numbers", path)
    big = np.abs(q) > 2.0 * np.pi + 1e-6
    if np.any(big):
        r, c = np.argwhere(big)[0]
        raise InputError(f"line {r + 2}: joint {head[meas[c]]} = {q[r, c]:g} is outside the UR5 range of +-2 pi rad "
                         "(joint angles must be radians; degrees?)", path)
    return np.asarray(views, int), q


def arm_yaml_dict(cap: ArmCapture, cfg: ArmConfig) -> dict:
    """The nominal robot description written next to joints.csv (URDF-like, DH convention)."""
    return {
        "robot": "UR5",
        "convention": "standard DH: T_i = Rz(theta) Tz(d) Tx(a) Rx(alpha); metres, radians",
        "joints": list(JOINT_NAMES),
        "dh": cap.dh_nominal.to_dict(),
        "T_world_base": cap.T_world_base.tolist(),
        "T_flange_cam": cap.T_flange_cam_nominal.tolist(),
        "geometry": "UR5 base inverted above the panicle, coaxial with the rachis; joint 1 circles the camera",
        "capture": cfg.model_dump(mode="json"),
    }


def fk_camera_poses(q: np.ndarray, arm_yaml: dict) -> np.ndarray:
    """Nominal camera poses T_world_cam from measured joints and the arm description (arm.yaml)."""
    try:
        dh = DHParams(*(np.asarray(arm_yaml["dh"][k], float) for k in ("d", "a", "alpha")))
        T_wb = np.asarray(arm_yaml["T_world_base"], float).reshape(4, 4)
        X = np.asarray(arm_yaml["T_flange_cam"], float).reshape(4, 4)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"arm description lacks or has a bad field ({e})") from None
    for name, v in (("dh.d", dh.d), ("dh.a", dh.a), ("dh.alpha", dh.alpha), ("T_world_base", T_wb),
                    ("T_flange_cam", X)):
        if not np.all(np.isfinite(v)):
            raise InputError(f"arm description: {name} has NaN or inf")
    if any(len(v) != 6 for v in (dh.d, dh.a, dh.alpha)):
        raise InputError("arm description: DH table needs 6 values for d, a and alpha")
    return T_wb @ fk(q, dh) @ X
