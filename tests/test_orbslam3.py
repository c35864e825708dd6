"""ORB-SLAM3 as a benchmark peer: the DBoW2 vocabulary writer, the settings file, the n/a path, a real run."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from seedmap.errors import InputError
from seedmap.peers import PEERS
from seedmap.peers import orb_vocabulary as ov
from seedmap.peers.orbslam3 import (
    NOT_INSTALLED,
    OrbSlam3Config,
    first_track,
    segments,
    settings_text,
    unavailable,
)
from seedmap.records import StereoCalib, Trajectory

SEEDMAP = [sys.executable, "-m", "seedmap.cli"]


def _clustered(n_protos=4, per=60, flips=6, images=3, seed=1):
    """Descriptors around ``n_protos`` random prototypes (``flips`` random bits changed), split into images."""
    rng = np.random.default_rng(seed)
    protos = rng.integers(0, 256, (n_protos, 32), dtype=np.uint8)
    bits = np.unpackbits(np.repeat(protos, per, axis=0), axis=1)
    for row in bits:
        row[rng.choice(256, flips, replace=False)] ^= 1
    desc = np.packbits(bits, axis=1)
    proto_of = np.repeat(np.arange(n_protos), per)
    order = rng.permutation(len(desc))
    return protos, [desc[order][i::images] for i in range(images)], proto_of[order]


def test_vocabulary_round_trip_and_tree_structure(tmp_path):
    protos, per_image, _ = _clustered()
    voc = ov.train_vocabulary(per_image, k=4, L=3, seed=0)
    p = tmp_path / "voc.txt"
    p.write_text(ov.vocabulary_text(voc))
    lines = p.read_text().split("\n")
    assert lines[0].split() == ["4", "3", "0", "0"]  # k L scoring(L1) weighting(TF-IDF)
    assert all(len(ln.split()) == 35 for ln in lines[1:]) and not p.read_text().endswith("\n")
    back = ov.read_vocabulary(p)
    assert (back.k, back.L) == (4, 3)
    np.testing.assert_array_equal(back.parent, voc.parent)
    np.testing.assert_array_equal(back.desc, voc.desc)
    np.testing.assert_allclose(back.weight, voc.weight, rtol=1e-5)
    # a tree: parents before children, at most k children each, depth at most L, words are the leaves
    assert np.all(back.parent[1:] < np.arange(1, len(back)))
    assert np.bincount(back.parent[1:]).max() <= 4
    depth = np.zeros(len(back), int)
    for i in range(1, len(back)):
        depth[i] = depth[back.parent[i]] + 1
    assert depth.max() <= 3
    assert np.array_equal(back.is_leaf, np.isin(np.arange(len(back)), back.parent[1:], invert=True)
                          & (np.arange(len(back)) > 0))
    # k-means with k = number of prototypes recovers them at the first level (majority bits undo the flips)
    first = back.desc[back.parent == 0]
    d = ov.hamming(ov._pack(first), ov._pack(protos))
    assert len(first) == 4 and sorted(d.argmin(axis=1)) == [0, 1, 2, 3] and d.min(axis=1).max() <= 2


def test_words_are_the_nearest_child_descent_and_weights_are_tfidf():
    protos, per_image, _ = _clustered(images=3)
    voc = ov.train_vocabulary(per_image, k=4, L=2, seed=3)
    alld = np.concatenate(per_image)
    words = voc.words_of(alld)
    assert voc.is_leaf[words].all()
    # brute-force descent (first minimum, as DBoW2)
    for q, w in zip(alld[:40], words[:40], strict=True):
        node = 0
        while (kids := np.flatnonzero(voc.parent == node)).size:
            node = int(kids[np.argmin(ov.hamming(ov._pack(q[None]), ov._pack(voc.desc[kids]))[0])])
        assert node == w
    seen = np.zeros(len(voc), int)
    for d in per_image:
        seen[np.unique(voc.words_of(d))] += 1
    leaf = voc.is_leaf & (seen > 0)
    np.testing.assert_allclose(voc.weight[leaf], np.log(3 / seen[leaf]))
    assert np.all(voc.weight[~voc.is_leaf] == 0)


def test_bad_vocabulary_is_one_line_input_error(tmp_path):
    bad = tmp_path / "ORBvoc.bin"
    bad.write_bytes(b"\x00\x01binary")
    with pytest.raises(InputError, match="not a DBoW2 text vocabulary"):
        PEERS["orbslam3"].check({"vocabulary": str(bad)})
    with pytest.raises(InputError, match="not found"):
        PEERS["orbslam3"].check({"vocabulary": str(tmp_path / "missing.txt")})
    PEERS["orbslam3"].check({})  # the shipped vocabulary


def test_settings_file_from_a_calibration_is_what_opencv_reads(tmp_path):
    calib = StereoCalib(fx=904.3, fy=902.3, cx=704.4, cy=533.7, baseline=0.11, width=1434, height=1050)
    p = tmp_path / "s.yaml"
    p.write_text(settings_text(calib, 5.0, OrbSlam3Config(features=1500)))
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    assert fs.getNode("Camera.type").string() == "PinHole"
    assert fs.getNode("Camera.fx").real() == pytest.approx(904.3)
    assert fs.getNode("Camera.cy").real() == pytest.approx(533.7)
    assert fs.getNode("Camera.bf").real() == pytest.approx(904.3 * 0.11)
    assert [fs.getNode(f"Camera.{k}").real() for k in ("k1", "k2", "p1", "p2")] == [0, 0, 0, 0]
    assert (fs.getNode("Camera.width").real(), fs.getNode("Camera.height").real()) == (1434, 1050)
    assert fs.getNode("Camera.fps").real() == 5.0 and fs.getNode("Camera.RGB").real() == 1
    assert fs.getNode("ORBextractor.nFeatures").real() == 1500 and fs.getNode("ThDepth").real() == 35.0
    fs.release()


def test_segments_and_first_track_anchor_at_ground_truth():
    states = np.array([1, 2, 2, 2, 3, 4, 2, 2, 2, 2, 2])
    poses = np.repeat(np.eye(4)[None], len(states), axis=0)
    poses[:, 0, 3] = np.arange(len(states)) * 0.1
    poses[[0, 4, 5], :, :] = np.nan
    segs = segments(states, poses)
    assert [(s.start, s.end) for s in segs] == [(1, 4), (6, 11)]
    assert max(segs, key=lambda s: s.length_m).start == 6
    ts = np.arange(len(states)) * 0.2
    gt_poses = np.repeat(np.eye(4)[None], len(states), axis=0)
    gt_poses[:, :3, 3] = [[0.1 * i, 1.0, 2.0] for i in range(len(states))]
    traj, lost, why = first_track(states, poses, ts, Trajectory(ts, gt_poses))
    assert lost == 4 and "RECENTLY_LOST" in why
    np.testing.assert_allclose(traj.timestamps, ts[1:4])
    np.testing.assert_allclose(traj.positions, gt_poses[1:4, :3, 3])  # anchored at GT of frame 1
    empty, lost0, why0 = first_track(np.ones(3, int), np.full((3, 4, 4), np.nan), ts[:3], None)
    assert len(empty) == 0 and lost0 == 0 and "never tracked" in why0


def test_without_pyorbslam3_the_method_is_na_not_a_crash(tiny_range, tmp_path, monkeypatch):
    from seedmap.eval.benchmark import BenchmarkConfig, default_methods, run_benchmark, user_ranges

    monkeypatch.setitem(sys.modules, "pyorbslam3", None)  # import pyorbslam3 -> ImportError
    assert unavailable() == NOT_INSTALLED
    ms = {m.name: m for m in default_methods(BenchmarkConfig())}
    assert ms["orbslam3"].unavailable == NOT_INSTALLED
    cfg = BenchmarkConfig(methods=["orbslam3"], workers=1)
    recs = run_benchmark(user_ranges([tiny_range]), tmp_path / "b", cfg, progress=False)
    assert [(r.method, r.status, r.note) for r in recs] == [("orbslam3", "n/a", NOT_INSTALLED)]
    assert "| n/a |" in (tmp_path / "b" / "report.md").read_text()
    with pytest.raises(Exception, match="install seedmap\\[peers\\]"):
        PEERS["orbslam3"].run(tiny_range, tmp_path / "r", {})
    assert not (tmp_path / "r").exists()


def test_cli_train_vocabulary_from_a_dataset_and_refuses_bad_input(tiny_range, tmp_path):
    out = tmp_path / "voc.txt"
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    r = subprocess.run([*SEEDMAP, "train", "orb-vocabulary", str(tiny_range), "--out", str(out), "--levels", "3",
                        "--features", "500"], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    voc = ov.read_vocabulary(out)
    assert (voc.k, voc.L) == (10, 3) and voc.n_words > 100
    r = subprocess.run([*SEEDMAP, "train", "orb-vocabulary", str(tmp_path / "nope"), "--out",
                        str(tmp_path / "v2.txt")], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and "not found" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "v2.txt").exists()
    r = subprocess.run([*SEEDMAP, "train", "orb-vocabulary", str(tiny_range), "--out", str(out)],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and "--overwrite" in r.stderr


@pytest.mark.slow
def test_orbslam3_tracks_a_simulated_range_with_the_shipped_vocabulary(tiny_range, tmp_path):
    pytest.importorskip("pyorbslam3")
    import json

    from seedmap.io import open_dataset
    from seedmap.io.trajectory import read_tum

    res = PEERS["orbslam3"].run(tiny_range, tmp_path / "r", {}, progress=False)
    m = res.metrics
    peer = json.loads((tmp_path / "r" / "peer.json").read_text())
    assert "orbvoc_sim" in peer["vocabulary"] and "orbvoc_sim" in m.backend
    ds = open_dataset(tiny_range)
    assert m.frames == len(ds) and m.frames_tracked >= len(ds) - 1
    # 819 x 600 px frames: ORB-SLAM3 drifts a few cm over the 0.4 m (on full-size ranges ~1 cm ATE)
    assert m.ate_rmse_m is not None and m.ate_rmse_m < 0.03 and m.ate_first_pose_rmse_m < 0.06
    assert m.gt_mdm_fraction is not None and m.gt_mdm_fraction > 0.3
    est = read_tum(tmp_path / "r" / "trajectory.tum")
    gt = ds.gt_trajectory()
    np.testing.assert_allclose(est.poses[0], gt.poses[0], atol=1e-5)  # T_world_cam, anchored at GT
    step_est, step_gt = est.positions[-1] - est.positions[0], gt.positions[len(est) - 1] - gt.positions[0]
    assert step_est @ step_gt > 0.8 * (step_gt @ step_gt)  # moves the way the camera moved (not T_cam_world)
    rows = (tmp_path / "r" / "matches_per_frame.csv").read_text().splitlines()
    assert rows[0] == "frame,timestamp,state,inliers,ok" and len(rows) == len(ds) + 1


def test_orbslam3_sits_beside_the_published_orb_slam2_figure():
    from seedmap.eval.benchmark import RunRecord, scenario_tables, side_by_side_table
    from seedmap.eval.published import PUBLISHED_MDM, published_key

    assert published_key("orbslam3") == "orb-slam2" and published_key("orb") == "orb"
    recs = [RunRecord("paper", "paper1", "seeds+fast", "ok", range_length_m=3.56, mdm_fraction=1.0, mdm_m=3.56),
            RunRecord("paper", "paper1", "orbslam3", "ok", note="vocabulary: v; longest tracked segment 3.60 m",
                      range_length_m=3.56, mdm_fraction=0.5, mdm_m=1.78)]
    side = side_by_side_table(recs)
    assert "| orbslam3 | 50% |" in side and "6% (ORB-SLAM2)" in side and "not run here" not in side
    assert "Runs: paper1 orbslam3: vocabulary: v" in scenario_tables(recs, "paper")
    assert PUBLISHED_MDM["orb-slam2"][0] == 0.35
