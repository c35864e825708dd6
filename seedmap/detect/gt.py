"""The ``gt`` detector — an ORACLE that reads the simulator's ground truth, not the pixels.

For every GT instance of a frame and camera it fits an ellipse to the instance's mask (so the
keypoint is the mask's ellipse centre, exactly what a perfect segmenter would give) and carries
the true ``seed_id``. It exists to measure association and SLAM independently of detection errors;
it must never be used to report results on real data (``is_oracle = True``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.detect.base import Detector, register_detector
from seedmap.detect.config import GtConfig, min_visible_seed_px
from seedmap.detect.ellipse import fit_ellipses_labels
from seedmap.errors import InputError, SeedmapError
from seedmap.records import Detections, StereoDetections, StereoFrame


def _open(dataset: object) -> object:
    from seedmap.io.seedmap_dataset import SeedmapDataset

    if isinstance(dataset, SeedmapDataset):
        return dataset
    if dataset is None:
        raise SeedmapError("the gt oracle detector needs the dataset (it reads ground-truth masks)")
    if hasattr(dataset, "gt_instances") and hasattr(dataset, "gt_label_image"):
        return dataset
    if not isinstance(dataset, (str, Path)):
        # an opened sequence of another format (EuRoC, KITTI, a bag, an image folder): it has no ground truth
        root = getattr(dataset, "root", None) or getattr(dataset, "path", None)
        raise InputError(f"the gt oracle detector needs a simulated seedmap dataset with ground truth; got a "
                         f"{type(dataset).__name__}", root if root is not None else "dataset")
    return SeedmapDataset(Path(dataset))


class GtDetector(Detector):
    """Ground-truth oracle: ``GtDetector(dataset).detect_frame(i, "left")``."""

    name = "gt"
    is_oracle = True

    def __init__(self, dataset: object, config: GtConfig | None = None) -> None:
        self.dataset = _open(dataset)
        self.cfg = config or GtConfig()
        root = Path(getattr(self.dataset, "root", "."))
        if not (root / "gt" / "instances").is_dir():
            raise InputError("dataset has no ground-truth instances (gt/instances/); "
                             "the gt oracle works on simulated datasets only", root)

    def min_area_px(self, camera: str = "left", i: int = 0) -> float:
        """Visible-pixel threshold of a keypoint: the configured one, else the detectable-seed size
        (seedmap.detect.config.min_visible_seed_px) at this dataset's image width."""
        if self.cfg.min_area_px is not None:
            return float(self.cfg.min_area_px)
        calib = getattr(self.dataset, "calib", None)
        width = calib.width if calib is not None else self.dataset.gt_label_image(i, camera).shape[1]
        return min_visible_seed_px(width)

    def detect_frame(self, i: int, camera: str = "left") -> Detections:
        """Oracle detections of frame ``i`` in ``camera`` (``left`` | ``right``)."""
        if camera not in ("left", "right"):
            raise SeedmapError(f"camera must be 'left' or 'right', got {camera!r}")
        inst = self.dataset.gt_instances(i, camera)
        if len(inst) == 0:
            return Detections()
        keep = inst.area >= self.min_area_px(camera, i)
        labels = self.dataset.gt_label_image(i, camera)
        ids = inst.label[keep].astype(np.int64)
        boxes = inst.boxes[keep].astype(np.float64)
        ell = fit_ellipses_labels(labels, ids, self.cfg.ellipse, boxes=boxes)
        ok = np.isfinite(ell).all(axis=1)
        return Detections(boxes=boxes[ok], scores=np.ones(int(ok.sum()), np.float32), ellipses=ell[ok],
                          seed_ids=inst.seed_id[keep][ok])

    def detect_stereo(self, frame: StereoFrame) -> StereoDetections:
        return StereoDetections(index=frame.index, timestamp=frame.timestamp,
                                left=self.detect_frame(frame.index, "left"),
                                right=self.detect_frame(frame.index, "right"))

    def detect(self, image: np.ndarray) -> Detections:
        raise SeedmapError("the gt oracle detector reads ground truth by frame index: use "
                           "detect_frame(i, camera) or detect_stereo(frame), not detect(image)")


def _factory(dataset=None, weights=None, config=None) -> GtDetector:
    return GtDetector(dataset, config.gt if config is not None else None)


register_detector("gt", _factory, "ORACLE: ground-truth masks of a simulated dataset (ellipse per GT mask)",
                  oracle=True)
