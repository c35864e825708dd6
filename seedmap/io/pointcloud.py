"""Point clouds with per-point labels as binary PLY (Open3D tensor API): the one PLY writer and reader.

Labels are stored as extra int32 vertex properties (e.g. ``seed_id``, ``landmark_id``, ``cluster_id``,
``seed_label``) that Open3D's ``o3d.t.io.read_point_cloud`` returns unchanged; colours are 0..255 RGB.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError


def write_labelled_ply(path: Path, xyz: np.ndarray, labels: dict[str, np.ndarray] | None = None,
                       rgb: np.ndarray | None = None) -> None:
    """Write ``xyz`` (N, 3, metres) with optional RGB (N, 3, 0..255) and int32 label arrays (N,)."""
    import open3d as o3d

    xyz = np.ascontiguousarray(np.asarray(xyz, np.float32).reshape(-1, 3))
    pc = o3d.t.geometry.PointCloud(o3d.core.Tensor(xyz))
    if rgb is not None:
        # uint8 colours become standard uchar red/green/blue properties that every PLY reader understands
        # (float colours are written as float properties, which Open3D's legacy reader scales again).
        rgb8 = np.clip(np.rint(np.asarray(rgb, np.float64).reshape(-1, 3)), 0, 255).astype(np.uint8)
        pc.point.colors = o3d.core.Tensor(np.ascontiguousarray(rgb8))
    for name, values in (labels or {}).items():
        v = np.ascontiguousarray(np.asarray(values, np.int32).reshape(-1, 1))
        if len(v) != len(xyz):
            raise ValueError(f"label {name!r} has {len(v)} values for {len(xyz)} points")
        pc.point[name] = o3d.core.Tensor(v)
    if len(xyz) == 0:
        # Open3D refuses to write an empty cloud; an empty PLY with the same header keeps readers happy.
        props = "".join(f"property int {n}\n" for n in (labels or {}))
        colour = "property uchar red\nproperty uchar green\nproperty uchar blue\n" if rgb is not None else ""
        Path(path).write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                              f"property float z\n{colour}{props}end_header\n")
        return
    if not o3d.t.io.write_point_cloud(str(path), pc, write_ascii=False):
        raise InputError("could not write the point cloud", path)


def read_labelled_ply(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``(xyz (N, 3), {label: (N,) int})`` from a PLY written by :func:`write_labelled_ply`."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise InputError("point cloud not found", path)
    pc = o3d.t.io.read_point_cloud(str(path))
    if "positions" not in pc.point:
        return np.zeros((0, 3)), {}
    xyz = pc.point.positions.numpy().astype(float)
    labels = {k: pc.point[k].numpy().reshape(-1).astype(np.int64)
              for k in pc.point if k not in ("positions", "colors", "normals")}
    return xyz, labels
