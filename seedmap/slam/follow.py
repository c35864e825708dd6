"""Live input and output of ``seedmap slam --follow``: stereo pairs read as a robot writes them into a folder,
and the trajectory and seed map written while the run goes on.

The folder has seedmap's dataset layout (``calib.yaml``, ``left/NNNNNN.png``, ``right/NNNNNN.png``,
``times.txt``). Frame ``i`` is **complete** when ``times.txt`` holds its line (line ``i``, ended by a newline)
and both ``left/`` and ``right/`` hold its PNG whole (the PNG's end chunk is there). A writer therefore appends
the frame's timestamp line after writing both images (or writes each image under another name and renames it
into place). Frames are processed in order, 0, 1, 2, ...; the run waits for the next one and ends when none
has come for ``idle_timeout_s`` seconds, or on Ctrl-C (see docs/method/slam_live.md).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.images import png_is_whole, read_rgb
from seedmap.io.seedmap_dataset import CAMERAS, frame_name, read_calib_yaml
from seedmap.records import StereoCalib, StereoFrame

#: how often (s) the folder is looked at while waiting for a frame
POLL_S = 0.02


def _times(path: Path) -> list[float]:
    """The complete (newline-ended) lines of a growing ``times.txt`` as floats."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return []
    lines = text.split("\n")[:-1]  # the last piece is unfinished (or empty)
    out = []
    for k, line in enumerate(lines):
        s = line.split()
        if not s:
            continue
        try:
            out.append(float(s[0]))
        except ValueError:
            raise InputError(f"line {k + 1} is not a timestamp ({line[:40]!r})", path) from None
    return out


class FolderFollower:
    """The frames of a folder a robot is writing, as they become complete (module docstring).

    ``indices()`` yields 0, 1, 2, ... as each frame is complete and returns after ``idle_timeout_s`` without a
    new one or once ``stop`` is set; ``load(i)`` reads frame ``i``; ``announced()`` is the number of frames whose
    timestamp line is written (the frames waiting are ``announced() - processed``)."""

    def __init__(self, root: str | Path, idle_timeout_s: float = 10.0, stop: threading.Event | None = None) -> None:
        self.root = Path(root)
        self.idle_timeout_s = float(idle_timeout_s)
        self.stop = stop if stop is not None else threading.Event()
        if not self.root.is_dir():
            raise InputError("folder to follow not found", self.root)
        self.timestamps: list[float] = []
        self.calib = self._wait_calib()

    def _wait_calib(self) -> StereoCalib:
        p = self.root / "calib.yaml"
        t_end = time.monotonic() + self.idle_timeout_s
        while not p.is_file():
            if time.monotonic() > t_end or self.stop.is_set():
                raise InputError(f"no calib.yaml appeared within {self.idle_timeout_s:g} s (the writer puts it "
                                 "there before the first frame)", p)
            time.sleep(POLL_S)
        return read_calib_yaml(p)

    def announced(self) -> int:
        return len(_times(self.root / "times.txt"))

    def _complete(self, i: int) -> bool:
        if len(self.timestamps) <= i:
            self.timestamps = _times(self.root / "times.txt")
            if len(self.timestamps) <= i:
                return False
        for cam in CAMERAS:
            p = self.root / cam / frame_name(i)
            try:
                if not png_is_whole(np.fromfile(p, np.uint8)):
                    return False
            except (FileNotFoundError, OSError):
                return False
        return True

    def indices(self) -> Iterator[int]:
        i = 0
        last = time.monotonic()
        while not self.stop.is_set():
            if self._complete(i):
                yield i
                i += 1
                last = time.monotonic()
                continue
            if time.monotonic() - last > self.idle_timeout_s:
                return
            self.stop.wait(POLL_S)

    def load(self, i: int) -> StereoFrame:
        left = read_rgb(self.root / "left" / frame_name(i))
        right = read_rgb(self.root / "right" / frame_name(i))
        for cam, img in (("left", left), ("right", right)):
            if img.shape[:2] != (self.calib.height, self.calib.width):
                raise InputError(f"image is {img.shape[1]}x{img.shape[0]} but calib.yaml says "
                                 f"{self.calib.width}x{self.calib.height}", self.root / cam / frame_name(i))
        return StereoFrame(index=i, timestamp=float(self.timestamps[i]), left=left, right=right)


class LiveWriter:
    """Writes a run's outputs while it goes on: ``trajectory_online.tum`` gets one line per registered frame
    (flushed), ``landmarks.csv`` is replaced (atomically) every ``flush_every`` frames. ``folder`` is created
    (the caller has checked it may be)."""

    def __init__(self, folder: Path, flush_every: int = 10) -> None:
        from seedmap.outputs import write_marker

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        write_marker(self.folder, "slam")
        self.flush_every = max(1, int(flush_every))
        self._traj = open(self.folder / "trajectory_online.tum", "w")  # noqa: SIM115 - open for the whole run
        self._n = 0

    def frame(self, timestamp: float, T_world_cam: np.ndarray, slam) -> None:  # noqa: ANN001 - SemanticSlam
        from seedmap.geometry import pose_to_tum
        from seedmap.io.trajectory import tum_line

        self._traj.write(tum_line(timestamp, pose_to_tum(T_world_cam)[0]) + "\n")
        self._traj.flush()
        self._n += 1
        if self._n % self.flush_every == 0:
            self.flush_map(slam)

    def flush_map(self, slam) -> None:  # noqa: ANN001 - SemanticSlam
        from seedmap.slam.outputs import write_landmarks

        lm = slam.landmarks()
        write_landmarks(self.folder, lm, np.full(len(lm), -1, np.int64))

    def close(self) -> None:
        self._traj.close()
