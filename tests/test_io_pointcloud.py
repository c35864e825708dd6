"""Labelled PLY: what seedmap writes, Open3D reads back with labels and colours intact."""

from __future__ import annotations

import numpy as np

from seedmap.io.pointcloud import read_labelled_ply, write_labelled_ply


def test_labels_survive_an_open3d_round_trip(tmp_path):
    import open3d as o3d

    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 3))
    labels = {"seed_id": rng.integers(-1, 60000, 50), "cluster_id": rng.integers(-1, 5, 50)}
    rgb = rng.integers(0, 256, (50, 3))
    write_labelled_ply(tmp_path / "c.ply", xyz, labels, rgb=rgb)
    back, lab = read_labelled_ply(tmp_path / "c.ply")
    np.testing.assert_allclose(back, xyz, atol=1e-6)
    for k, v in labels.items():
        np.testing.assert_array_equal(lab[k], v)
    legacy = o3d.io.read_point_cloud(str(tmp_path / "c.ply"))  # plain Open3D users see points and colours
    assert len(legacy.points) == 50
    np.testing.assert_allclose(np.asarray(legacy.colors) * 255.0, rgb, atol=0.6)


def test_empty_cloud_is_still_a_valid_ply(tmp_path):
    write_labelled_ply(tmp_path / "e.ply", np.zeros((0, 3)), {"seed_id": np.zeros(0)})
    xyz, lab = read_labelled_ply(tmp_path / "e.ply")
    assert xyz.shape == (0, 3)
