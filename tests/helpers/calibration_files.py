"""Stereo rigs and the calibration files of other tools (Kalibr, EuRoC) written for the loader tests."""

from __future__ import annotations

from pathlib import Path
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from seedmap.io.calibration import CameraModel, StereoRig

#: image size of the synthetic rigs (px)
W, H = 320, 240


def _write(path: Path, d: dict) -> Path:
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


def make_rig(seed: int = 0, baseline: float = 0.11, distortion: str = "radtan") -> StereoRig:
    """A realistic unrectified rig: different intrinsics, distortion, ~1 deg relative rotation."""
    rng = np.random.default_rng(seed)
    def K():
        f = rng.uniform(250, 300)
        return np.array([[f, 0, W / 2 + rng.uniform(-5, 5)], [0, f * rng.uniform(0.99, 1.01), H / 2 + rng.uniform(-5, 5)],
                         [0, 0, 1]])
    if distortion == "radtan":
        D = lambda: np.array([rng.uniform(-0.2, -0.1), rng.uniform(0.01, 0.05), 1e-4, -1e-4, 0.0])  # noqa: E731
    else:
        D = lambda: rng.uniform(-0.02, 0.02, 4)  # noqa: E731
    R = Rotation.from_rotvec(rng.normal(0, np.radians(0.7), 3)).as_matrix()
    c = np.array([baseline, rng.uniform(-0.003, 0.003), rng.uniform(-0.003, 0.003)])  # right centre in left frame
    T = -R @ c
    return StereoRig(CameraModel(K(), D(), W, H, distortion), CameraModel(K(), D(), W, H, distortion), R, T)


def write_kalibr(path: Path, rig: StereoRig) -> Path:
    def cam(c: CameraModel) -> dict:
        K = c.K
        return {"camera_model": "pinhole", "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
                "distortion_model": "radtan" if c.distortion == "radtan" else "equidistant",
                "distortion_coeffs": [float(x) for x in c.D[:4]], "resolution": [c.width, c.height]}
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rig.R, rig.T
    return _write(path, {"cam0": cam(rig.left), "cam1": {**cam(rig.right), "T_cn_cnm1": T.tolist()}})


def write_euroc_pair(folder: Path, rig: StereoRig) -> tuple[Path, Path]:
    T_B0 = np.eye(4)
    T_B0[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    T_B0[:3, 3] = [0.01, -0.05, 0.0]
    T_01 = np.eye(4)
    T_01[:3, :3], T_01[:3, 3] = rig.R, rig.T  # cam0 -> cam1
    T_B1 = T_B0 @ np.linalg.inv(T_01)
    out = []
    for i, (c, T) in enumerate(((rig.left, T_B0), (rig.right, T_B1))):
        (folder / f"cam{i}").mkdir(parents=True, exist_ok=True)
        K = c.K
        text = ("%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: ["
                + ", ".join(repr(float(x)) for x in T.reshape(-1)) + "]\n"
                f"rate_hz: 20\nresolution: [{W}, {H}]\ncamera_model: pinhole\n"
                f"intrinsics: [{float(K[0, 0])!r}, {float(K[1, 1])!r}, {float(K[0, 2])!r}, {float(K[1, 2])!r}]\n"
                "distortion_model: radial-tangential\n"
                f"distortion_coefficients: [{', '.join(repr(float(x)) for x in c.D[:4])}]\n")
        p = folder / f"cam{i}" / "sensor.yaml"
        p.write_text(text)
        out.append(p)
    return out[0], out[1]
