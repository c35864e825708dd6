"""Stopping a command: Ctrl-C and SIGTERM print one line and leave nothing half written; worker processes end
with the process that started them, however it ended."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from seedmap.records import StereoCalib

from helpers.cli import run_cli

SRC = str(Path(__file__).resolve().parents[1])
ON_LINUX = Path("/proc/self/stat").is_file()


def _static_dataset(root: Path, n: int = 6) -> Path:
    """A seedmap-layout sequence of one textured stereo pair seen ``n`` times (160x120 px, 0.1 m baseline)."""
    from seedmap.io.seedmap_dataset import DatasetWriter

    img = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    w = DatasetWriter(root)
    w.write_calib(StereoCalib(fx=120.0, fy=120.0, cx=80.0, cy=60.0, baseline=0.1, width=160, height=120))
    w.write_times(np.arange(n) * 0.2)
    for i in range(n):
        w.write_frame(i, img, np.roll(img, -8, axis=1))
    return root


@pytest.mark.parametrize("sig, code, said", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
                         ids=["ctrl-c", "sigterm"])
def test_a_stopped_command_says_one_line_and_leaves_nothing(sig, code, said, tmp_path, monkeypatch, capfd, request):
    import seedmap.io.seedmap_dataset as sd

    ds = _static_dataset(tmp_path / "ds")
    out = tmp_path / "res"
    reads = []
    real_read = sd.read_rgb

    def read_then_signal(path):  # noqa: ANN001
        reads.append(path)
        if len(reads) == 3:  # the second frame (the run stops there: static camera, no row travel)
            os.kill(os.getpid(), sig)
        return real_read(path)

    monkeypatch.setattr(sd, "read_rgb", read_then_signal)
    # a shell starts background jobs with SIGINT ignored (nohup, `&`); Ctrl-C in a terminal reaches Python's handler
    old_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, old_int))
    old_term = signal.getsignal(signal.SIGTERM)
    capfd.readouterr()
    assert run_cli(["slam", ds, "--matcher", "orb", "--out", out, "-q"], monkeypatch) == code
    err = capfd.readouterr().err
    assert [ln for ln in err.splitlines() if ln.strip()] == [said]
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # no half-written `.res.*` folder
    assert signal.getsignal(signal.SIGTERM) == old_term  # main() put the previous handler back


_POOL = """
import os, sys, time
from multiprocessing import resource_tracker
from seedmap.workers import process_pool
with process_pool(2) as pool:
    pids = {f.result() for f in [pool.submit(os.getpid) for _ in range(8)]}  # every worker initialised
    [pool.submit(time.sleep, 60) for _ in range(2)]
    pids |= {p.pid for p in pool._processes.values()} | {resource_tracker._resource_tracker._pid}
    print(*pids, flush=True)
    time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not ON_LINUX, reason="needs Linux /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_pool_workers_and_resource_tracker_die_with_their_parent(sig):
    proc = subprocess.Popen([sys.executable, "-c", _POOL], env={**os.environ, "PYTHONPATH": SRC},
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    kids: list[int] = []
    try:
        kids = [int(p) for p in proc.stdout.readline().split()]
        assert len(kids) >= 3, "the pool did not start"
        proc.send_signal(sig)
        proc.wait(30)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(_alive(k) for k in kids):
            time.sleep(0.1)
        assert [k for k in kids if _alive(k)] == []
    finally:
        for k in kids:
            if _alive(k):
                os.kill(k, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()


_ORPHAN = """
import os, sys, time
import seedmap.workers as w
w.PARENT_POLL_S = 0.05
if sys.argv[1] == "poll":
    sys.platform = "other"  # no prctl: the watcher thread
w._die_with_parent(os.getppid() + 1)  # a parent that is not ours: it is gone
time.sleep(20)
"""


@pytest.mark.skipif(os.name != "posix", reason="POSIX parent pids")
@pytest.mark.parametrize("how", ["prctl", "poll"])
def test_a_worker_whose_parent_is_gone_exits(how):
    t = time.monotonic()
    r = subprocess.run([sys.executable, "-c", _ORPHAN, how], env={**os.environ, "PYTHONPATH": SRC}, timeout=15)
    assert r.returncode == 1 and time.monotonic() - t < 10
