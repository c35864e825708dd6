"""Each panicle seen in one image: its best frame, the seeds detected on it there, and a thumbnail.

The seed map holds a poor count of a panicle's seeds (tracks break and duplicate, stretches go unmapped), but
one image of the panicle shows most of its front half. Through the estimated trajectory the panicle's landmarks
are projected into every frame that sees them whole; the detector's seeds inside the projected outline are
counted there, and the frame with the most (the view least hidden by leaves) gives ``seeds_in_view`` and the
thumbnail, with the outline and the counted seeds drawn. See docs/method/phenotype.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from seedmap.records import StereoCalib, Trajectory

#: a panicle is seen whole in a frame when its projected landmarks keep this fraction of the image size away
#: from every border
BORDER_FRACTION = 0.02
#: detections whose centre lies outside the outline by less than this many median seed radii still count (the
#: outline runs through the outermost landmarks' centres, and the panicle's flanks, seen obliquely, are mapped
#: least; chosen on the tuning ranges: leave-one-out count MAPE 15.2 / 15.1 / 14.9 / 14.9 % at 0 / 1 / 2 / 3)
OUTLINE_MARGIN_RADII = 2.0
#: thumbnails: crop margin around the outline (px) and the longest side of the written image (px)
THUMB_MARGIN_PX = 24
THUMB_MAX_PX = 320
#: thumbnail files in the output folder: NNN the panicle id zero-padded to 3 digits
THUMB_PATTERN = "thumbs/panicle_{:03d}.png"


@dataclass
class PanicleView:
    """Where one panicle is best seen: the dataset ``frame``, its outline (convex hull of the projected
    landmarks, px in the left image), whether the outline lies wholly inside the image (``whole``) and the
    seeds detected inside it (``seeds``: their centres, px)."""

    frame: int
    outline: np.ndarray
    whole: bool
    seeds: np.ndarray

    @property
    def count(self) -> int:
        return len(self.seeds)


def frames_of_poses(traj: Trajectory, timestamps: np.ndarray) -> np.ndarray:
    """Dataset frame index of every pose (nearest timestamp)."""
    ts = np.asarray(timestamps, float)
    order = np.argsort(ts)
    k = np.clip(np.searchsorted(ts[order], traj.timestamps), 1, max(len(ts) - 1, 1))
    lo, hi = order[k - 1], order[np.minimum(k, len(ts) - 1)]
    return np.where(np.abs(ts[lo] - traj.timestamps) <= np.abs(ts[hi] - traj.timestamps), lo, hi)


def _project(xyz: np.ndarray, T_world_cam: np.ndarray, calib: StereoCalib) -> np.ndarray:
    T = np.linalg.inv(T_world_cam)
    uv, _ = calib.project(xyz @ T[:3, :3].T + T[:3, 3])
    return uv


def whole_poses(xyz: np.ndarray, traj: Trajectory, calib: StereoCalib) -> tuple[np.ndarray, bool]:
    """Indices into ``traj`` of the poses that see ``xyz`` whole (see :data:`BORDER_FRACTION`), in time order,
    and True; when no pose sees them whole, the one pose that sees most of them, and False."""
    mx, my = BORDER_FRACTION * calib.width, BORDER_FRACTION * calib.height
    # only poses whose image holds the points' centre (cheap, all poses at once) are looked at in full
    c = np.asarray(xyz, float).mean(axis=0)
    R, t = traj.poses[:, :3, :3], traj.poses[:, :3, 3]
    uc, _ = calib.project(np.einsum("nji,nj->ni", R, c - t))  # R^T (c - t): the centre in every camera
    near = np.flatnonzero(np.isfinite(uc).all(1) & (uc[:, 0] >= 0) & (uc[:, 0] < calib.width) & (uc[:, 1] >= 0)
                          & (uc[:, 1] < calib.height))
    if len(near) == 0:
        near = np.arange(len(traj))
    whole, seen = [], []
    for j in near.tolist():
        uv = _project(xyz, traj.poses[j], calib)
        inside = np.isfinite(uv).all(1) & (uv[:, 0] >= mx) & (uv[:, 0] < calib.width - mx) & (uv[:, 1] >= my) \
            & (uv[:, 1] < calib.height - my)
        seen.append(float(inside.mean()))
        if inside.all():
            whole.append(j)
    if whole:
        return np.asarray(whole, np.int64), True
    return np.asarray([int(near[int(np.argmax(seen))])], np.int64), False


def outline_of(uv: np.ndarray) -> np.ndarray:
    """Convex hull (K x 2, px) of projected points."""
    import cv2

    uv = uv[np.isfinite(uv).all(1)].astype(np.float32)
    if len(uv) < 3:
        return uv.reshape(-1, 2)
    return cv2.convexHull(uv).reshape(-1, 2)


def seeds_inside(ellipses: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """Centres (px) of the detected seeds (``ellipses``: rows ``cx, cy, major, minor, ...``) inside
    ``outline`` or within :data:`OUTLINE_MARGIN_RADII` median seed radii of it."""
    import cv2

    ellipses = np.asarray(ellipses, np.float32).reshape(len(ellipses), -1)
    centres = ellipses[:, :2]
    if len(centres) == 0 or len(outline) < 3:
        return np.zeros((0, 2), np.float32)
    radius = 0.25 * float(np.median(ellipses[:, 2] + ellipses[:, 3]))
    contour = outline.reshape(-1, 1, 2).astype(np.float32)
    d = np.array([cv2.pointPolygonTest(contour, (float(u), float(v)), True) for u, v in centres])
    return centres[d >= -OUTLINE_MARGIN_RADII * radius]


def panicle_views(groups: Sequence[np.ndarray], traj: Trajectory, frames: np.ndarray, calib: StereoCalib,
                  seeds_of: Callable[[int], np.ndarray | None], stride: int = 1) -> list[PanicleView]:
    """The best view of every panicle (``groups``: world landmark positions, one array per panicle): of every
    ``stride``-th pose that sees it whole, the one with the most detected seeds inside its outline (the view
    least hidden by leaves). ``frames``: the dataset frame of each pose; ``seeds_of(frame)``: the detector's
    seeds in that frame's left image (ellipse rows), None when the frame has none recorded."""
    cache: dict[int, np.ndarray | None] = {}
    out = []
    for xyz in groups:
        poses, whole = whole_poses(xyz, traj, calib)
        best: PanicleView | None = None
        for j in poses[::max(int(stride), 1)].tolist():
            f = int(frames[j])
            if f not in cache:
                cache[f] = seeds_of(f)
            if cache[f] is None:
                continue
            outline = outline_of(_project(xyz, traj.poses[j], calib))
            v = PanicleView(frame=f, outline=outline, whole=whole, seeds=seeds_inside(cache[f], outline))
            if best is None or v.count > best.count:
                best = v
        if best is None:  # no frame with seeds recorded: the outline in the first candidate, nothing counted
            j = int(poses[0])
            best = PanicleView(frame=int(frames[j]), outline=outline_of(_project(xyz, traj.poses[j], calib)),
                               whole=whole, seeds=np.zeros((0, 2), np.float32))
        out.append(best)
    return out


def thumbnail(image: np.ndarray, view: PanicleView) -> np.ndarray:
    """RGB crop round the panicle's outline with the outline (yellow) and the counted seeds (cyan) drawn."""
    import cv2

    h, w = image.shape[:2]
    rgb = image if image.ndim == 3 else np.repeat(image[..., None], 3, axis=2)
    if rgb.dtype != np.uint8:
        rgb = np.clip(rgb.astype(np.float64) / max(float(rgb.max()), 1.0) * 255, 0, 255).astype(np.uint8)
    if len(view.outline) == 0:
        return rgb[:1, :1].copy()
    lo = np.floor(view.outline.min(axis=0) - THUMB_MARGIN_PX).astype(int)
    hi = np.ceil(view.outline.max(axis=0) + THUMB_MARGIN_PX).astype(int)
    x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    x1, y1 = min(int(hi[0]), w), min(int(hi[1]), h)
    crop = np.ascontiguousarray(rgb[y0:y1, x0:x1])
    s = min(1.0, THUMB_MAX_PX / max(crop.shape[:2]))
    if s < 1.0:
        crop = cv2.resize(crop, (max(int(crop.shape[1] * s), 1), max(int(crop.shape[0] * s), 1)),
                          interpolation=cv2.INTER_AREA)
    off = np.array([x0, y0], np.float32)
    poly = np.round((view.outline - off) * s).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(crop, [poly], True, (255, 220, 0), 1, cv2.LINE_AA)
    for u, v in np.round((view.seeds - off) * s).astype(int):
        cv2.circle(crop, (int(u), int(v)), 2, (0, 230, 255), -1, cv2.LINE_AA)
    return crop


def write_thumbnails(folder: Path, ids: Sequence[int], views: Sequence[PanicleView],
                     load_left: Callable[[int], np.ndarray]) -> list[Path]:
    """``folder/`` :data:`THUMB_PATTERN` for every panicle (``ids``: the table's panicle ids)."""
    from seedmap.io.atomic import atomic_write_bytes

    import cv2

    (Path(folder) / THUMB_PATTERN.format(0)).parent.mkdir(parents=True, exist_ok=True)
    images: dict[int, np.ndarray] = {}
    paths = []
    for pid, v in zip(ids, views):
        if v.frame not in images:
            images[v.frame] = load_left(v.frame)
        ok, png = cv2.imencode(".png", cv2.cvtColor(thumbnail(images[v.frame], v), cv2.COLOR_RGB2BGR))
        if ok:
            p = Path(folder) / THUMB_PATTERN.format(int(pid))
            atomic_write_bytes(p, png.tobytes())
            paths.append(p)
    return paths
