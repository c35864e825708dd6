"""Live mode: ``seedmap slam --follow`` on a folder a writer process fills at 5 Hz, and the completeness rule of
a frame (times.txt line + both PNGs whole)."""

from __future__ import annotations

import multiprocessing as mp
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from seedmap.errors import InputError
from seedmap.io.trajectory import read_tum
from seedmap.slam.follow import FolderFollower

SRC = str(Path(__file__).resolve().parents[1])


def _write_frames(src: str, dst: str, hz: float, first_delay: float = 0.0) -> None:
    """A robot's recorder: calib.yaml, then per frame both PNGs (written under a temporary name and renamed into
    place) and the frame's times.txt line, ``hz`` frames per second."""
    src_p, dst_p = Path(src), Path(dst)
    for cam in ("left", "right"):
        (dst_p / cam).mkdir(parents=True, exist_ok=True)
    shutil.copy(src_p / "calib.yaml", dst_p / "calib.yaml")
    times = (src_p / "times.txt").read_text().split("\n")
    time.sleep(first_delay)
    t0 = time.monotonic()
    for i, line in enumerate(t for t in times if t.strip()):
        for cam in ("left", "right"):
            tmp = dst_p / cam / f".{i:06d}.png.tmp"
            shutil.copy(src_p / cam / f"{i:06d}.png", tmp)
            os.replace(tmp, dst_p / cam / f"{i:06d}.png")
        with open(dst_p / "times.txt", "a") as f:
            f.write(line + "\n")
        time.sleep(max(0.0, t0 + (i + 1) / hz - time.monotonic()))


def _copy_without_gt(src: Path, dst: Path, n: int | None = None) -> Path:
    """The same frames as a finished dataset without gt/ (so the offline run starts at identity, like --follow)."""
    times = [t for t in (src / "times.txt").read_text().split("\n") if t.strip()][:n]
    for cam in ("left", "right"):
        (dst / cam).mkdir(parents=True)
        for i in range(len(times)):
            shutil.copy(src / cam / f"{i:06d}.png", dst / cam / f"{i:06d}.png")
    shutil.copy(src / "calib.yaml", dst / "calib.yaml")
    (dst / "times.txt").write_text("\n".join(times) + "\n")
    return dst


def _cli(*args: object, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": SRC}
    return subprocess.Popen([sys.executable, "-m", "seedmap.cli", *map(str, args)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


# ---- the completeness rule (fast) ---------------------------------------------------------------------------------
def test_a_frame_counts_once_its_times_line_and_both_pngs_are_whole(tmp_path):
    from seedmap.io.images import write_png
    from seedmap.io.seedmap_dataset import DatasetWriter
    from seedmap.records import StereoCalib

    w = DatasetWriter(tmp_path)
    w.write_calib(StereoCalib(fx=120.0, fy=120.0, cx=80.0, cy=60.0, baseline=0.1, width=160, height=120))
    img = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    f = FolderFollower(tmp_path, idle_timeout_s=0.3)
    assert not f._complete(0)
    w.write_frame(0, img, img)
    assert not f._complete(0)  # no timestamp yet
    (tmp_path / "times.txt").write_text("0.0")  # the line is not finished
    assert not f._complete(0)
    (tmp_path / "times.txt").write_text("0.0\n0.2\n")
    assert f._complete(0)
    write_png(tmp_path / "left" / "000001.png", img)
    data = (tmp_path / "left" / "000001.png").read_bytes()
    (tmp_path / "right" / "000001.png").write_bytes(data[: len(data) // 2])  # cut short: still being written
    assert not f._complete(1)
    t0 = time.monotonic()
    assert list(f.indices()) == [0]  # frame 1 never completes: the idle timeout ends the stream
    assert time.monotonic() - t0 >= 0.3
    fr = f.load(0)
    assert fr.timestamp == 0.0 and fr.left.shape == (120, 160, 3)


def test_following_a_folder_without_calibration_says_so(tmp_path):
    with pytest.raises(InputError, match="calib.yaml"):
        FolderFollower(tmp_path, idle_timeout_s=0.1)


def test_the_follower_stops_when_asked(tmp_path):
    from seedmap.io.seedmap_dataset import DatasetWriter
    from seedmap.records import StereoCalib

    DatasetWriter(tmp_path).write_calib(StereoCalib(fx=120.0, fy=120.0, cx=80.0, cy=60.0, baseline=0.1, width=160,
                                                    height=120))
    stop = threading.Event()
    f = FolderFollower(tmp_path, idle_timeout_s=60.0, stop=stop)
    threading.Timer(0.2, stop.set).start()
    t0 = time.monotonic()
    assert list(f.indices()) == []
    assert time.monotonic() - t0 < 5.0


# ---- end to end (slow): the 6-frame simulated range of the CNN tests -----------------------------------------------
@pytest.mark.slow
def test_follow_processes_frames_written_at_5_hz_as_the_offline_run_does(cnn_range, tmp_path):
    data = cnn_range.root
    live, out = tmp_path / "live", tmp_path / "out"
    writer = mp.get_context("spawn").Process(target=_write_frames, args=(str(data), str(live), 5.0, 1.0))
    writer.start()
    time.sleep(0.3)  # calib.yaml is there before the run looks (it would wait for it otherwise)
    p = _cli("slam", live, "--follow", "--idle-timeout", 4, "--out", out, "-q")
    stdout, stderr = p.communicate(timeout=600)
    writer.join(30)
    assert p.returncode == 0, stderr
    assert "stopped by no new frame" in stdout
    n = len([t for t in (data / "times.txt").read_text().split("\n") if t.strip()])
    rows = (out / "matches_per_frame.csv").read_text().splitlines()
    assert rows[0].endswith(",waiting") and len(rows) == n + 1
    # the same frames as a finished dataset give the same result, byte for byte
    ref = tmp_path / "ref"
    q = _cli("slam", _copy_without_gt(data, tmp_path / "copy"), "--out", ref, "-q")
    q.communicate(timeout=600)
    assert q.returncode == 0
    for name in ("trajectory.tum", "trajectory_online.tum", "landmarks.csv"):
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name


@pytest.mark.slow
def test_ctrl_c_leaves_a_complete_result_of_the_frames_processed(cnn_range, tmp_path):
    data = cnn_range.root
    live, out = tmp_path / "live", tmp_path / "out"
    writer = mp.get_context("spawn").Process(target=_write_frames, args=(str(data), str(live), 5.0))
    writer.start()
    time.sleep(0.3)
    p = _cli("slam", live, "--follow", "--idle-timeout", 30, "--out", out, "-q")
    online = out / "trajectory_online.tum"
    t_end = time.monotonic() + 300
    while time.monotonic() < t_end and (not online.is_file() or len(online.read_text().splitlines()) < 3):
        time.sleep(0.05)
    assert online.is_file(), "the online trajectory is written while the run goes on"
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=300)
    writer.join(30)
    assert p.returncode == 0, stderr
    assert "stopped by Ctrl-C" in stdout
    traj = read_tum(out / "trajectory.tum")
    k = len(traj)
    assert k >= 3 and np.all(np.isfinite(traj.poses))
    assert len((out / "matches_per_frame.csv").read_text().splitlines()) == k + 1
    lm = np.loadtxt(out / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(lm) > 0 and np.all(np.isfinite(lm[:, 3:6]))
    assert not list(tmp_path.glob(".out.*"))  # no half-written folder beside it
    # exactly what a finished dataset of those k frames gives
    ref = tmp_path / "ref"
    q = _cli("slam", _copy_without_gt(data, tmp_path / "copy", k), "--out", ref, "-q")
    q.communicate(timeout=600)
    assert (out / "trajectory.tum").read_bytes() == (ref / "trajectory.tum").read_bytes()


@pytest.mark.slow
def test_the_streaming_api_on_images_matches_seedmap_slam(cnn_range, tmp_path):
    from seedmap.associate import make_matcher
    from seedmap.detect import make_detector
    from seedmap.slam import SemanticSlam, SlamConfig, run_slam

    cfg = SlamConfig()
    ref = run_slam(_copy_without_gt(cnn_range.root, tmp_path / "copy"), None, detector="fast", config=cfg,
                   progress=False, html_report=False)
    m = make_matcher("seeds", cnn_range.calib, detector=make_detector("fast", config=cfg.detect), cfg=cfg)
    slam = SemanticSlam(cnn_range.calib, m, cfg)
    poses = [r.T_world_cam for r in slam.run(cnn_range) if r.ok]
    assert len(poses) == len(ref.trajectory) == len(cnn_range)
    traj, _, _ = slam.finalize()
    assert np.array_equal(traj.poses, ref.trajectory.poses)


def test_following_a_folder_where_no_frame_comes_says_so_and_leaves_nothing(tmp_path):
    from seedmap.io.seedmap_dataset import DatasetWriter
    from seedmap.records import StereoCalib

    live = tmp_path / "live"
    DatasetWriter(live).write_calib(StereoCalib(fx=120.0, fy=120.0, cx=80.0, cy=60.0, baseline=0.1, width=160,
                                                height=120))
    p = _cli("slam", live, "--follow", "--idle-timeout", 0.5, "--matcher", "orb", "--out", tmp_path / "out", "-q")
    _, err = p.communicate(timeout=120)
    assert p.returncode == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "no complete frame appeared within 0.5 s" in lines[0]
    assert not (tmp_path / "out").exists()
