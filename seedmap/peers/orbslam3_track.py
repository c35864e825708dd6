"""Child process that runs ORB-SLAM3 (``pyorbslam3``) frame by frame and saves what it returned.

``python -m seedmap.peers.orbslam3_track JOB.json``: JOB holds the dataset path, the loader options, the number
of frames, the ORB-SLAM3 settings and vocabulary files and the output ``.npz``. ORB-SLAM3 prints to stdout and
ends the process on some errors; the parent (:mod:`seedmap.peers.orbslam3`) keeps both away from seedmap's own
process and reads the ``.npz``: per frame the tracking state, tracked map points, ``T_map_cam`` (NaN when ORB-SLAM3
gave none) and the milliseconds spent loading and tracking.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def track(job: dict) -> None:
    """Run the job (see the module docstring) and write its ``.npz``."""
    import pyorbslam3

    from seedmap.io.options import DatasetOptions

    ds = DatasetOptions.model_validate(job["dataset_options"]).open(job["dataset"])
    n = int(job["frames"])
    states = np.zeros(n, np.int64)
    points = np.zeros(n, np.int64)
    poses = np.full((n, 4, 4), np.nan)
    ms_load = np.zeros(n)
    ms_track = np.zeros(n)
    slam = pyorbslam3.Slam(job["vocabulary"], job["settings"], pyorbslam3.Sensor.STEREO)
    try:
        for i in range(n):
            t0 = time.perf_counter()
            f = ds[i]
            t1 = time.perf_counter()
            r = slam.track_stereo(f.left, f.right, f.timestamp)
            ms_track[i] = (time.perf_counter() - t1) * 1e3
            ms_load[i] = (t1 - t0) * 1e3
            states[i] = int(r.state)
            points[i] = int(r.num_tracked_points)
            if r.pose_valid and r.pose_wc is not None:
                poses[i] = np.asarray(r.pose_wc, np.float64)
            print(f"seedmap-progress {i + 1}/{n}", file=sys.stderr, flush=True)
    finally:
        slam.shutdown()
    np.savez(job["out"], states=states, points=points, poses=poses, ms_load=ms_load, ms_track=ms_track,
             version=np.asarray(getattr(pyorbslam3, "__version__", "") or _version()))


def _version() -> str:
    from importlib.metadata import version

    try:
        return version("pyorbslam3")
    except Exception:
        return ""


if __name__ == "__main__":  # pragma: no cover - run as a child process
    with open(sys.argv[1]) as fh:
        track(json.load(fh))
