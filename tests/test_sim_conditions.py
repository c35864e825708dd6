"""Field conditions of the range simulator: off changes nothing, each one changes what it should, the ground truth
describes the images (shaken camera, moving panicles, dropped and duplicated frames), determinism.

Tiny renders (scale 0.12-0.15, ranges of 0.1-0.3 m): the file runs in about a minute.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seedmap.config import load_config
from seedmap.io.seedmap_dataset import SeedmapDataset
from seedmap.sim import SimConfig, build_range_world, render_stereo, right_pose, simulate_range
from seedmap.sim.capture import condition_streams, frame_schedule
from seedmap.sim.conditions import DROP_P, DUPLICATE_P, LADDER, STRENGTHS
from seedmap.sim.range import _rngs, range_trajectory

TINY = ["world.length=0.1", "world.gap=0.3", "camera.scale=0.15", "imaging.supersample=1", "seed=3"]


def _cfg(*extra: str) -> SimConfig:
    return load_config(SimConfig, None, [*TINY, *extra])


def _render(tmp: Path, name: str, *extra: str) -> SeedmapDataset:
    out = simulate_range(_cfg(*extra), tmp / name, progress=False)
    return SeedmapDataset(out)


def _files(ds: SeedmapDataset, *globs: str) -> dict[str, bytes]:
    return {str(p.relative_to(ds.root)): p.read_bytes() for g in globs for p in sorted(ds.root.glob(g))}


@pytest.fixture(scope="module")
def off(tmp_path_factory) -> SeedmapDataset:
    return _render(tmp_path_factory.mktemp("cond"), "off")


def test_conditions_off_renders_what_the_plain_renderer_renders(off, tmp_path):
    """The dataset with every condition off equals frames rendered by ``render_stereo`` called without any
    condition, from the world and trajectory the seed gives; ``calm`` and explicit zeros are the same dataset."""
    cfg = _cfg()
    rng_world, rng_traj, frame_ss = _rngs(cfg)
    world = build_range_world(cfg, rng_world)
    traj = range_trajectory(cfg, rng_traj)
    seeds = frame_ss.spawn(len(traj))
    assert len(off) == len(traj)
    np.testing.assert_array_equal(off.timestamps, np.round(traj.timestamps, 6))
    np.testing.assert_allclose(off.gt_trajectory().poses, traj.poses, atol=1e-6)
    for i in range(len(traj)):
        r = render_stereo(world, traj.poses[i], cfg.camera.calib(), cfg, np.random.default_rng(seeds[i]),
                          float(traj.timestamps[i]))
        np.testing.assert_array_equal(off[i].left, r.left)
        np.testing.assert_array_equal(off[i].right, r.right)
        np.testing.assert_array_equal(off.gt_label_image(i), r.left_labels)
    calm = _render(tmp_path, "calm", "conditions.preset=calm")
    zeros = _render(tmp_path, "zeros", *[f"conditions.{k}=0" for k in STRENGTHS])
    ref = _files(off, "left/*.png", "right/*.png", "gt/**/*.csv", "gt/*.txt", "times.txt")
    assert _files(calm, "left/*.png", "right/*.png", "gt/**/*.csv", "gt/*.txt", "times.txt") == ref
    assert _files(zeros, "left/*.png", "right/*.png", "gt/**/*.csv", "gt/*.txt", "times.txt") == ref


def _sharpness(img: np.ndarray) -> float:
    g = img.astype(float).mean(axis=2)
    return float(np.abs(np.diff(g, axis=1)).mean() + np.abs(np.diff(g, axis=0)).mean())


@pytest.mark.parametrize("cond", STRENGTHS)
def test_each_condition_changes_what_it_models(off, tmp_path, cond):
    ds = _render(tmp_path, cond, f"conditions.{cond}=2")
    if cond == "drops":  # the images of the frames written are the same captures; which are written is tested below
        return
    i = len(ds) // 2
    a, b = off[i].left, ds[i].left
    assert not np.array_equal(a, b)
    same_geometry = np.array_equal(off.gt_label_image(i), ds.gt_label_image(i))
    if cond in ("blur", "flicker", "wet"):  # light and exposure: nothing moves
        assert same_geometry
        np.testing.assert_array_equal(off.gt_trajectory().poses, ds.gt_trajectory().poses)
    if cond == "blur":
        assert _sharpness(b) < 0.97 * _sharpness(a)
    if cond == "flicker":  # a gain: the two images are close to a scaled copy, left and right gains differ
        ratios = [ds[k].left.mean() / off[k].left.mean() for k in range(len(ds))]
        assert np.ptp(ratios) > 0.02
    if cond == "wet":  # sharp highlights: more near-white pixels on the plants
        assert (b.max(axis=2) > 200).sum() > (a.max(axis=2) > 200).sum()
    if cond == "vibration":  # the camera moved: the ground truth says so
        d = np.linalg.norm(off.gt_trajectory().poses[:, :3, 3] - ds.gt_trajectory().poses[:, :3, 3], axis=1)
        assert d.max() > 0.005
    if cond == "wind":  # panicles and leaves moved, the camera did not
        np.testing.assert_array_equal(off.gt_trajectory().poses, ds.gt_trajectory().poses)
        assert not same_geometry
        D0, D1 = off.gt_panicle_poses()[i], ds.gt_panicle_poses()[i]
        assert max(np.abs(D0[k][:3, 3] - D1[k][:3, 3]).max() for k in D0) > 0.002


def _reprojection_hits(ds: SeedmapDataset, poses: np.ndarray) -> tuple[int, int]:
    """Of the seeds whose centre the instance tables call visible, how many project (from the GT files: rest
    seeds, panicle motions and the given left poses) onto a pixel of their own mask, left and right."""
    seeds = ds.gt_seeds()
    D = ds.gt_panicle_poses()
    calib = ds.calib
    hit = total = 0
    for i in range(len(ds)):
        for cam in ("left", "right"):
            T = poses[i] if cam == "left" else right_pose(poses[i], calib.baseline)
            inst = ds.gt_instances(i, cam)
            ids_img = ds.gt_seed_id_image(i, cam)
            for sid, pid in zip(inst.seed_id[inst.center_visible], inst.panicle_id[inst.center_visible], strict=True):
                Dk = D.get(i, {}).get(int(pid), np.eye(4))
                p = Dk[:3, :3] @ seeds.xyz[sid] + Dk[:3, 3]
                q = T[:3, :3].T @ (p - T[:3, 3])
                u = int(np.floor(calib.fx * q[0] / q[2] + calib.cx + 0.5))
                v = int(np.floor(calib.fy * q[1] / q[2] + calib.cy + 0.5))
                total += 1
                hit += bool(0 <= v < ids_img.shape[0] and 0 <= u < ids_img.shape[1] and ids_img[v, u] == sid)
    return hit, total


def test_ground_truth_is_the_shaken_pose_and_the_moving_panicles(off, tmp_path):
    """Under vibration and wind a GT seed, moved by its panicle's GT motion and seen from the GT pose, lands on its
    own mask; seen from the unshaken pose it does not."""
    ds = _render(tmp_path, "shaken", "conditions.vibration=2", "conditions.wind=2")
    hit, total = _reprojection_hits(ds, ds.gt_trajectory().poses)
    assert total > 50 and hit >= 0.97 * total
    hit0, total0 = _reprojection_hits(ds, off.gt_trajectory().poses)
    assert hit0 < 0.5 * total0


def test_frame_schedule_keeps_order_ends_and_rates():
    n = 4000
    stamp, source = frame_schedule(n, 2.0, np.random.default_rng(1))
    assert stamp[0] == source[0] == 0 and stamp[-1] == source[-1] == n - 1
    assert np.all(np.diff(stamp) > 0) and np.all(np.diff(source) >= 0) and np.all(source <= stamp)
    dup = np.sum(source[1:] == source[:-1])
    dropped = n - len(stamp)
    for got, p in ((dropped, 2 * DROP_P), (dup, 2 * DUPLICATE_P)):
        assert abs(got - p * n) < 4 * np.sqrt(p * n)
    np.testing.assert_array_equal(frame_schedule(5, 0.0, np.random.default_rng(1))[1], np.arange(5))


def test_dropped_and_duplicated_frames_keep_times_and_ground_truth_consistent(tmp_path):
    extra = ["world.length=0.3", "camera.scale=0.12", "conditions.drops=3"]
    n = len(range_trajectory(_cfg(*extra), np.random.default_rng(0)))
    seed = next(s for s in range(3, 200)  # a seed whose schedule both drops and duplicates a frame
                if (sch := frame_schedule(n, 3.0, condition_streams(s)["drops"]))
                and len(sch[0]) < n and np.any(sch[1][1:] == sch[1][:-1]))
    ds = _render(tmp_path, "drops", *extra, f"seed={seed}")
    ref = _render(tmp_path, "nodrops", "world.length=0.3", "camera.scale=0.12", f"seed={seed}")
    stamp, source = frame_schedule(n, 3.0, condition_streams(seed)["drops"])
    gt = ds.gt_trajectory()
    assert len(ds) == len(stamp) == len(list((ds.root / "left").glob("*.png"))) == len(gt)
    np.testing.assert_array_equal(ds.timestamps, ref.timestamps[stamp])
    np.testing.assert_array_equal(gt.timestamps, ds.timestamps)
    np.testing.assert_allclose(gt.poses, ref.gt_trajectory().poses[source], atol=1e-9)
    for j, i in enumerate(source):
        if j and i == source[j - 1]:  # a stale frame: the previous image under a new stamp
            np.testing.assert_array_equal(ds[j].left, ds[j - 1].left)
        else:  # the capture itself, as rendered without drops
            np.testing.assert_array_equal(ds[j].left, ref[i].left)
            np.testing.assert_array_equal(ds.gt_label_image(j), ref.gt_label_image(i))


def test_rough_field_is_seeded(tmp_path):
    a = _render(tmp_path, "a", "conditions.preset=rough")
    b = _render(tmp_path, "b", "conditions.preset=rough")
    c = _render(tmp_path, "c", "conditions.preset=rough", "seed=4")
    assert _files(a, "left/*.png", "gt/**/*.csv", "gt/*.txt") == _files(b, "left/*.png", "gt/**/*.csv", "gt/*.txt")
    assert not np.array_equal(a[1].left, c[1].left)


def test_ladder_presets_set_strengths_and_explicit_values_win():
    cfg = _cfg("conditions.wind=0.5", "conditions.preset=windy")
    assert cfg.conditions.wind == 0.5
    assert cfg.conditions.blur == LADDER["windy"]["blur"] > 0
    assert not _cfg("conditions.preset=calm").conditions.any
    assert list(LADDER) == ["calm", "breeze", "windy", "rough"]
    for k in STRENGTHS:  # each rung is at least as hard as the one before
        vals = [LADDER[p][k] for p in LADDER]
        assert vals == sorted(vals)


def test_culling_spheres_hold_the_bent_leaves_and_stalks():
    """The renderer keeps a leaf or stalk only if its bounding sphere reaches the view: under the strongest wind
    the spheres must still hold every vertex at every instant."""
    from seedmap.sim.render.culling import _leaf_spheres, _tri_spheres
    from seedmap.sim.wind import WindField

    cfg = _cfg("world.length=0.6", "wind.leaf_amplitude_deg=45")
    world = build_range_world(cfg, _rngs(cfg)[0])
    world.wind_field = wf = WindField.draw(world, 3.0, np.random.default_rng(0))
    c, r = _leaf_spheres(world)
    sc, sr = _tri_spheres(world, "stalk_spheres", world.stalk_vertices[world.stalk_triangles])
    moved = 0.0
    for t in np.linspace(0, 12, 49):
        M = world.leaf_motion(t)
        v = np.einsum("lij,lvj->lvi", M[:, :3, :3], world.leaf_vertices) + M[:, None, :3, 3]
        v += wf.leaf_offsets(world, np.arange(len(v)), t)
        assert (np.linalg.norm(v - c[:, None, :], axis=2) <= r[:, None]).all()
        sv = wf.stalk_vertices(world, t)[world.stalk_triangles]
        assert (np.linalg.norm(sv - sc[:, None, :], axis=2) <= (sr + wf.stalk_bound)[:, None]).all()
        moved = max(moved, float(np.abs(sv - world.stalk_vertices[world.stalk_triangles]).max()))
    assert moved > 0.05  # the stalks did bend (3 x (3 + 1.2) cm at most)


def test_arm_scans_refuse_field_conditions():
    from seedmap.errors import ConfigError
    from seedmap.sim.panicle_scan import PanicleScanConfig

    assert not load_config(PanicleScanConfig, None, []).sim.conditions.any
    with pytest.raises(ConfigError, match="field row"):
        load_config(PanicleScanConfig, None, ["sim.conditions.wind=1"])


def test_retired_motion_blur_points_to_the_blur_condition():
    from seedmap.errors import ConfigError

    assert not _cfg("imaging.motion_blur=false", "imaging.exposure_time=0.004").conditions.any  # older configs load
    with pytest.raises(ConfigError, match="conditions.blur"):
        _cfg("imaging.motion_blur=true")
