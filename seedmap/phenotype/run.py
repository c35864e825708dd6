"""The phenotype table of a ``seedmap slam`` result: panicles, their best views, seed counts, written files.

``seedmap slam`` calls it on its own result with the seeds it detected in every frame (:class:`FrameSeeds`);
``seedmap phenotype RESULT --data DATASET`` calls it on a result folder and detects again where it looks.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from seedmap.errors import InputError
from seedmap.phenotype.config import PhenotypeConfig
from seedmap.phenotype.shape import RowFrame, row_frame
from seedmap.phenotype.table import (COLUMNS, PLOT_COLUMNS, load_calibration, panicle_groups, panicle_rows,
                                     plot_summaries, read_landmarks, rows_csv)
from seedmap.phenotype.views import PanicleView, frames_of_poses, panicle_views, write_thumbnails
from seedmap.records import StereoCalib

#: the calibration ``calibration: auto`` picks with images (the seeds counted in the best view) and without
AUTO_CALIBRATION = {True: "fast", False: "fast-shape"}
#: the summary written beside panicles.csv
SUMMARY = "panicles.json"


class FrameSeeds:
    """The detector's seeds in the left image of every frame of a run, recorded as they are detected (centre and
    axes, 16 bytes a seed), with the frames' times."""

    def __init__(self) -> None:
        self.ellipses: dict[int, np.ndarray] = {}
        self.times: dict[int, float] = {}

    def add(self, index: int, timestamp: float, ellipses: np.ndarray) -> None:
        self.ellipses[int(index)] = np.asarray(ellipses, np.float32).reshape(-1, 5)[:, :4].copy()
        self.times[int(index)] = float(timestamp)

    def __call__(self, index: int) -> np.ndarray | None:
        return self.ellipses.get(int(index))

    def timestamps(self) -> tuple[np.ndarray, np.ndarray]:
        """Frame indices and their times, in index order."""
        idx = np.asarray(sorted(self.times), np.int64)
        return idx, np.asarray([self.times[i] for i in idx.tolist()], float)


@dataclass
class Images:
    """What the panicles' views need: the left camera, every frame's index and time, the detector's seeds in a
    frame's left image (None: not available) and the left image itself."""

    calib: StereoCalib
    indices: np.ndarray
    timestamps: np.ndarray
    seeds_of: Callable[[int], np.ndarray | None]
    left: Callable[[int], np.ndarray]


def dataset_images(dataset: Path, detector: str, detect_config=None, dataset_config=None) -> Images:  # noqa: ANN001
    """:class:`Images` of a dataset seedmap reads, the seeds detected on demand by ``detector`` (once a frame:
    kept, 16 bytes a seed)."""
    from seedmap.detect import make_detector
    from seedmap.io.options import DatasetOptions

    ds = (dataset_config or DatasetOptions()).open(dataset)
    det = make_detector(detector, dataset=Path(dataset), config=detect_config)
    found = FrameSeeds()

    def seeds_of(f: int) -> np.ndarray | None:
        if found(f) is None:
            frame = ds[f]
            found.add(f, frame.timestamp, det.detect_stereo(frame).left.ellipses)
        return found(f)

    return Images(ds.calib, np.arange(len(ds)), np.asarray(ds.timestamps, float), seeds_of, lambda f: ds[f].left)


def result_images(result: Path, data: Path | None = None, detector: str | None = None) -> Images | None:
    """:class:`Images` of a ``seedmap slam`` result: ``data`` (else the dataset its :data:`SUMMARY` records; None
    when that is gone), searched with ``detector`` (else the result's own, with the result's ``detect`` and
    ``dataset`` settings)."""
    from seedmap.config import load_config
    from seedmap.slam.config import SlamConfig

    result = Path(result)
    if data is None:
        try:
            data = Path(json.loads((result / SUMMARY).read_text(encoding="utf-8"))["dataset"])
        except (OSError, ValueError, KeyError, TypeError):
            return None
        if not data.exists():
            return None
    cfg = load_config(SlamConfig, result / "config.yaml", []) if (result / "config.yaml").is_file() else SlamConfig()
    if detector is None:
        if cfg.detector is None or cfg.matcher not in (None, "seeds"):
            raise InputError("the result was not mapped with seeds: give --detector to count seeds in its images",
                             result)
        detector = cfg.detector
    return dataset_images(data, detector, cfg.detect, cfg.dataset)


@dataclass
class Phenotype:
    """Rows of panicles.csv, the row frame, the calibration used (name and content), each panicle's best view
    (None without images)."""

    rows: list[dict]
    frame: RowFrame
    calibration: str
    cal: dict
    views: list[PanicleView] | None

    def summary(self, **more: object) -> dict:
        rows = self.rows
        return {"panicles": len(rows), "panicles_ok": sum(r["quality"] == "ok" for r in rows),
                "height_source": self.frame.height_source, "calibration": self.calibration,
                "count_from": "+".join(self.cal["coef"]), "seeds_est": float(sum(r["seeds_est"] for r in rows)),
                **more}


def phenotype_result(result: Path, cfg: PhenotypeConfig, images: Images | None = None) -> Phenotype:
    """Panicles of a ``seedmap slam`` result folder (``landmarks.csv``, ``trajectory.tum``); with ``images`` each
    panicle's best view and the seeds counted in it."""
    from seedmap.io.trajectory import read_tum

    result = Path(result)
    if not result.is_dir():
        raise InputError("result folder not found", result)
    lm = read_landmarks(result / "landmarks.csv")
    traj = read_tum(result / "trajectory.tum")
    frame = row_frame(traj, cfg.mount_height_m)
    name = AUTO_CALIBRATION[images is not None] if cfg.calibration == "auto" else cfg.calibration
    cal = load_calibration(name)
    if "seeds_in_view" in cal["coef"] and images is None:
        raise InputError(f"the seed-count calibration {name!r} counts seeds in the images: give the dataset "
                         "(--data) or --set calibration=fast-shape", result)
    groups = panicle_groups(lm, frame, cfg)
    views = None
    if images is not None and groups and len(traj):
        frames = images.indices[frames_of_poses(traj, images.timestamps)]
        views = panicle_views([lm.xyz[idx] for idx, _ in groups], traj, frames, images.calib, images.seeds_of,
                              cfg.view_stride)
    return Phenotype(panicle_rows(lm, frame, cfg, cal, groups, views), frame, name, cal, views)


def write_phenotype(folder: Path, ph: Phenotype, images: Images | None = None,
                    plots: Sequence[tuple[str, float, float]] | None = None, title: str = "seedmap phenotype",
                    **summary: object) -> None:
    """``panicles.csv``, ``panicles.json`` (summary), ``plots.csv`` with ``plots``, ``thumbs/panicle_NNN.png``
    with the views, ``phenotype.html`` (:mod:`seedmap.phenotype.report`)."""
    from seedmap.io.atomic import atomic_write_text
    from seedmap.phenotype.report import write_phenotype_report

    folder = Path(folder)
    atomic_write_text(folder / "panicles.csv", rows_csv(ph.rows, COLUMNS))
    plot_rows = plot_summaries(ph.rows, list(plots)) if plots is not None else None
    if plot_rows is not None:
        atomic_write_text(folder / "plots.csv", rows_csv(plot_rows, PLOT_COLUMNS))
    atomic_write_text(folder / SUMMARY, json.dumps(ph.summary(**summary), indent=2) + "\n")
    if ph.views is not None and images is not None:
        write_thumbnails(folder, [r["panicle_id"] for r in ph.rows], ph.views, images.left)
    write_phenotype_report(folder, ph.rows, plot_rows, title=title)
