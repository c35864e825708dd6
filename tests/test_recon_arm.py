"""UR5 kinematics, the simulated arm capture and the joints file (seedmap.sim.arm)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from seedmap.errors import InputError
from seedmap.geometry import invert, rotation_angle_deg
from seedmap.sim.arm import (
    UR5,
    ArmConfig,
    ArmErrorConfig,
    arm_yaml_dict,
    fk,
    fk_camera_poses,
    ik,
    planned_camera_poses,
    read_joints_csv,
    simulate_capture,
    write_joints_csv,
)


def test_fk_all_zeros_is_the_known_ur5_pose():
    T = fk(np.zeros(6))
    # standard-DH UR5 at zero: arm stretched along -x, tool offset along -y (d4 + d6), z = d1 - d5
    np.testing.assert_allclose(T[:3, 3], [-0.81725, -0.19145, -0.005491], atol=1e-9)
    # all theta = 0: the orientation is the product of the Rx(alpha_i) = Rx(+90 deg)
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-9)


def test_fk_shoulder_pan_rotates_about_base_z_and_batches():
    q = np.array([0.3, -1.1, 1.4, -0.6, 1.2, 0.5])
    T0 = fk(q)
    q2 = q.copy()
    q2[0] += 0.7
    T1 = fk(q2)
    c, s = np.cos(0.7), np.sin(0.7)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(T1[:3, 3], Rz @ T0[:3, 3], atol=1e-12)
    np.testing.assert_allclose(fk(np.stack([q, q2])), np.stack([T0, T1]), atol=1e-12)
    # elbow straight, links in line: distance shoulder->wrist = |a2| + |a3| when elbow = 0
    q3 = np.array([0.0, -0.4, 0.0, 0.0, 0.0, 0.0])
    assert np.linalg.norm(fk(q3)[:3, 3]) > 0.8


@pytest.mark.parametrize("k", range(5))
def test_ik_round_trip(k):
    rng = np.random.default_rng(k)
    q_true = np.array([rng.uniform(-3, 3), rng.uniform(-2.2, -0.8), rng.uniform(0.6, 2.2),
                       rng.uniform(-2, 0), rng.uniform(0.6, 2.4), rng.uniform(-3, 3)])
    T = fk(q_true)
    q = ik(T, q_true + rng.normal(0, 0.15, 6), UR5, rng=rng)
    np.testing.assert_allclose(fk(q), T, atol=1e-7)


def test_wrong_number_of_joints_is_an_input_error():
    with pytest.raises(InputError, match="6 joints"):
        fk(np.zeros(5))


def test_capture_without_errors_matches_the_plan_and_looks_at_the_axis():
    cfg = ArmConfig(views=12, errors=ArmErrorConfig(encoder_offset_deg=0, encoder_noise_deg=0, link_length_mm=0,
                                                    hand_eye_mm=0, hand_eye_deg=0, sway_deg=0))
    cap = simulate_capture(cfg, [0.12], np.random.default_rng(0))
    plan = planned_camera_poses(cfg, [0.12])
    np.testing.assert_allclose(cap.T_world_cam_fk, plan, atol=1e-6)
    np.testing.assert_allclose(cap.T_world_cam_true, plan, atol=1e-6)
    for T in plan:  # optical axis passes through the rachis axis, 0.3 m away
        c, z = T[:3, 3], T[:3, 2]
        s = -c[:2] @ z[:2] / (z[:2] @ z[:2])
        np.testing.assert_allclose((c + s * z)[:2], 0, atol=1e-9)
        assert s == pytest.approx(cfg.radius)
    # 360 degrees: joint 1 unwraps continuously (no jumps between neighbouring views)
    assert np.all(np.abs(np.diff(cap.q_cmd[:, 0])) < np.radians(45))


def test_default_errors_give_millimetre_scale_fk_error():
    cap = simulate_capture(ArmConfig(views=12), [0.12], np.random.default_rng(3))
    E = invert(cap.T_rest_cam_true) @ cap.T_world_cam_fk
    t = np.linalg.norm(E[:, :3, 3], axis=1) * 1000
    r = rotation_angle_deg(E[:, :3, :3])
    assert 0.2 < np.median(t) < 10 and 0.05 < np.median(r) < 2


def test_joints_file_round_trip_and_fk_from_arm_yaml(tmp_path):
    cfg = ArmConfig(views=5)
    cap = simulate_capture(cfg, [0.1], np.random.default_rng(1))
    write_joints_csv(tmp_path / "joints.csv", cap)
    views, q = read_joints_csv(tmp_path / "joints.csv")
    np.testing.assert_array_equal(views, np.arange(5))
    np.testing.assert_allclose(q, cap.q_meas, atol=1e-8)
    arm = yaml.safe_load(yaml.safe_dump(arm_yaml_dict(cap, cfg)))
    np.testing.assert_allclose(fk_camera_poses(q, arm), cap.T_world_cam_fk, atol=1e-7)


def test_bad_joint_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_joints_csv(tmp_path / "missing.csv")
    head = "view,t," + ",".join(f"cmd_j{i}" for i in range(6)) + "," + ",".join(f"meas_j{i}" for i in range(6))
    p = tmp_path / "short.csv"
    p.write_text(head + "\n0,0.0," + ",".join(["0.1"] * 11) + "\n")
    with pytest.raises(InputError, match="wrong length"):
        read_joints_csv(p)
    p.write_text("view,t," + ",".join(f"meas_j{i}" for i in range(5)) + "\n0,0," + ",".join(["0"] * 5) + "\n")
    with pytest.raises(InputError, match="6 meas_"):
        read_joints_csv(p)


def test_joint_angles_in_degrees_are_refused(tmp_path):
    """A joints.csv written in degrees (a common export mistake) used to give 0 seeds and 0.3 m pose error, exit 0."""
    cap = simulate_capture(ArmConfig(views=4), [0.1], np.random.default_rng(2))
    write_joints_csv(tmp_path / "joints.csv", cap)
    lines = (tmp_path / "joints.csv").read_text().splitlines()
    head = lines[0].split(",")
    meas = [i for i, h in enumerate(head) if h.startswith("meas_")]
    out = [lines[0]]
    for ln in lines[1:]:
        parts = ln.split(",")
        for i in meas:
            parts[i] = repr(float(np.degrees(float(parts[i]))))
        out.append(",".join(parts))
    p = tmp_path / "deg.csv"
    p.write_text("\n".join(out) + "\n")
    assert np.abs(cap.q_meas).max() > 0.5  # some joint far enough from 0 that degrees exceed 2 pi
    with pytest.raises(InputError, match="radians; degrees"):
        read_joints_csv(p)
