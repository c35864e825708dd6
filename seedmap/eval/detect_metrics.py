"""Detection metrics against simulator ground truth.

* Precision / recall / F1: a detection is a true positive when it is matched one-to-one to a GT
  instance box with IoU >= ``iou_threshold`` (default 0.5). Matching is greedy by descending IoU
  (the usual detection-benchmark rule) or optimal (Hungarian, ``scipy.optimize.linear_sum_assignment``
  on the candidate pairs). Box convention on both sides: x0, y0 inclusive, x1, y1 exclusive pixel
  indices.
* Keypoint error (px): distance from each matched detection's keypoint (ellipse centre) to the
  projection of the true 3D centre of its GT seed, over GT instances with ``center_visible``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from seedmap.io.seedmap_dataset import Instances
from seedmap.progress import track
from seedmap.records import Detections


def box_iou_pairs(a: np.ndarray, b: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """IoU of box pairs ``a[ia]`` vs ``b[ib]`` (x0, y0, x1, y1)."""
    A, B = a[ia], b[ib]
    w = np.clip(np.minimum(A[:, 2], B[:, 2]) - np.maximum(A[:, 0], B[:, 0]), 0, None)
    h = np.clip(np.minimum(A[:, 3], B[:, 3]) - np.maximum(A[:, 1], B[:, 1]), 0, None)
    inter = w * h
    area_a = (A[:, 2] - A[:, 0]) * (A[:, 3] - A[:, 1])
    area_b = (B[:, 2] - B[:, 0]) * (B[:, 3] - B[:, 1])
    return inter / np.maximum(area_a + area_b - inter, 1e-12)


def match_boxes(det: np.ndarray, gt: np.ndarray, iou_threshold: float = 0.5,
                method: Literal["greedy", "hungarian"] = "greedy") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one matches ``(idx_det, idx_gt, iou)`` with IoU >= threshold.

    Candidate pairs come from a KD-tree on box centres (two boxes with IoU >= 0.5 have centres
    closer than the larger box's diagonal), so thousands of seeds per image stay cheap.
    """
    det = np.asarray(det, np.float64).reshape(-1, 4)
    gt = np.asarray(gt, np.float64).reshape(-1, 4)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(det) == 0 or len(gt) == 0:
        return empty
    cd = (det[:, :2] + det[:, 2:]) / 2
    cg = (gt[:, :2] + gt[:, 2:]) / 2
    diag = max(np.hypot(det[:, 2] - det[:, 0], det[:, 3] - det[:, 1]).max(),
               np.hypot(gt[:, 2] - gt[:, 0], gt[:, 3] - gt[:, 1]).max())
    pairs = cKDTree(cd).query_ball_tree(cKDTree(cg), r=float(diag))
    ia = np.repeat(np.arange(len(det)), [len(p) for p in pairs])
    ib = np.fromiter((j for p in pairs for j in p), np.int64, count=len(ia))
    if len(ia) == 0:
        return empty
    iou = box_iou_pairs(det, gt, ia, ib)
    keep = iou >= iou_threshold
    ia, ib, iou = ia[keep], ib[keep], iou[keep]
    if len(ia) == 0:
        return empty
    if method == "hungarian":
        rows, ri = np.unique(ia, return_inverse=True)
        cols, ci = np.unique(ib, return_inverse=True)
        cost = np.full((len(rows), len(cols)), 1e6)
        cost[ri, ci] = -iou
        r, c = linear_sum_assignment(cost)
        ok = cost[r, c] < 0
        r, c = r[ok], c[ok]
        return rows[r], cols[c], -cost[r, c]
    order = np.argsort(-iou, kind="stable")
    used_d = np.zeros(len(det), bool)
    used_g = np.zeros(len(gt), bool)
    md, mg, mi = [], [], []
    for k in order:
        a, b = ia[k], ib[k]
        if not used_d[a] and not used_g[b]:
            used_d[a] = used_g[b] = True
            md.append(a)
            mg.append(b)
            mi.append(iou[k])
    return np.asarray(md, np.int64), np.asarray(mg, np.int64), np.asarray(mi)


@dataclass
class FrameDetectMetrics:
    frame: int
    camera: str
    n_det: int
    n_gt: int
    tp: int
    precision: float
    recall: float
    f1: float
    kp_err_median_px: float | None
    kp_err_mean_px: float | None
    n_kp: int


@dataclass
class DetectMetrics:
    """Overall numbers (TP/FP/FN pooled over frames) plus the per-frame rows."""

    frames: int
    n_det: int
    n_gt: int
    tp: int
    precision: float
    recall: float
    f1: float
    kp_err_median_px: float | None
    kp_err_mean_px: float | None
    kp_err_p90_px: float | None
    kp_within_1px: float | None
    n_kp: int
    iou_threshold: float
    matching: str
    per_frame: list[FrameDetectMetrics] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def prf(tp: int, nd: int, ng: int) -> tuple[float, float, float]:
    """Precision, recall and F1 from true positives, detections and counted GT (summed over any set of images)."""
    p = tp / nd if nd else (1.0 if ng == 0 else 0.0)
    r = tp / ng if ng else 1.0
    f = 2 * p * r / (p + r) if (p + r) > 0 else 0.0
    return p, r, f


def frame_metrics(det: Detections, gt: Instances, frame: int = 0, camera: str = "left", iou_threshold: float = 0.5,
                  method: Literal["greedy", "hungarian"] = "greedy", min_gt_area: float = 0
                  ) -> tuple[FrameDetectMetrics, np.ndarray]:
    """Metrics of one image and the keypoint errors (px) of its matched, centre-visible seeds.

    ``min_gt_area`` drops GT instances smaller than that many pixels *and* any detection matched
    to them from the counts (slivers of hidden seeds that no detector should be asked to find).
    """
    keep = gt.area >= min_gt_area
    md, mg, _ = match_boxes(det.boxes, gt.boxes, iou_threshold, method)
    if min_gt_area > 0 and (~keep).any():
        # detections of ignored tiny GT are neither TP nor FP
        small = np.isin(mg, np.nonzero(~keep)[0])
        n_ignored_det = int(small.sum())
        md, mg = md[~small], mg[~small]
    else:
        n_ignored_det = 0
    nd = len(det) - n_ignored_det
    ng = int(keep.sum())
    tp = len(md)
    p, r, f = prf(tp, nd, ng)
    vis = gt.center_visible[mg]
    err = np.linalg.norm(det.keypoints[md[vis]] - gt.center_uv[mg[vis]], axis=1)
    m = FrameDetectMetrics(frame, camera, nd, ng, tp, p, r, f,
                           float(np.median(err)) if len(err) else None, float(err.mean()) if len(err) else None,
                           len(err))
    return m, err


def aggregate(rows: list[FrameDetectMetrics], errors: list[np.ndarray], iou_threshold: float,
              method: str) -> DetectMetrics:
    nd = sum(r.n_det for r in rows)
    ng = sum(r.n_gt for r in rows)
    tp = sum(r.tp for r in rows)
    p, r, f = prf(tp, nd, ng)
    e = np.concatenate(errors) if errors else np.zeros(0)
    has = len(e) > 0
    return DetectMetrics(
        frames=len({x.frame for x in rows}), n_det=nd, n_gt=ng, tp=tp, precision=p, recall=r, f1=f,
        kp_err_median_px=float(np.median(e)) if has else None, kp_err_mean_px=float(e.mean()) if has else None,
        kp_err_p90_px=float(np.percentile(e, 90)) if has else None,
        kp_within_1px=float((e <= 1.0).mean()) if has else None, n_kp=len(e), iou_threshold=iou_threshold,
        matching=method, per_frame=rows)


def evaluate_detections(dataset: object, detections: dict[tuple[int, str], Detections], iou_threshold: float = 0.5,
                        method: Literal["greedy", "hungarian"] = "greedy", min_gt_area: float = 0,
                        progress: bool = False) -> DetectMetrics:
    """Evaluate ``{(frame, camera): Detections}`` against the GT instances of a SeedmapDataset."""
    rows, errs = [], []
    keys = sorted(detections)
    it = track(keys, "eval detect", "img", enabled=progress)
    for frame, cam in it:
        gt = dataset.gt_instances(frame, cam)
        m, e = frame_metrics(detections[(frame, cam)], gt, frame, cam, iou_threshold, method, min_gt_area)
        rows.append(m)
        errs.append(e)
    return aggregate(rows, errs, iou_threshold, method)


def gt_from_boxes(boxes: np.ndarray, areas: np.ndarray | None = None) -> Instances:
    """Labelled boxes (x0, y0, x1, y1) as GT instances: keypoint = box centre (pixel-centre coordinates), area =
    ``areas`` (else the box's)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    n = len(b)
    ar = np.asarray(areas, np.float64) if areas is not None else (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return Instances(np.arange(1, n + 1, dtype=np.uint16), np.full(n, -1, np.int64), np.full(n, -1, np.int64), b,
                     np.c_[(b[:, 0] + b[:, 2]) / 2 - 0.5, (b[:, 1] + b[:, 3]) / 2 - 0.5], ar, np.ones(n, bool))


def evaluate_labelled(gt: list[dict], detections: dict[str, Detections], iou_threshold: float = 0.5,
                      method: Literal["greedy", "hungarian"] = "greedy", min_gt_area: float = 0) -> DetectMetrics:
    """Evaluate ``{image name: Detections}`` against labelled images (``seedmap.detect.labels.read_coco_boxes``
    rows, matched by ``file_name``); per-image rows carry the image's index and its name as ``camera``."""
    rows, errs = [], []
    for k, g in enumerate(gt):
        m, e = frame_metrics(detections[g["file_name"]], gt_from_boxes(g["boxes"], g["areas"]), k, g["file_name"],
                             iou_threshold, method, min_gt_area)
        rows.append(m)
        errs.append(e)
    return aggregate(rows, errs, iou_threshold, method)
