"""The seeds' size in an image, estimated by a ``fast`` network itself (``cnn.scale = auto``).

The network runs over a geometric ladder of input scales (``LADDER_STEP`` apart, from ``MAX_SCALE`` down to where
seeds of ~``MAX_SEED_PX`` px would reach the target size below), small scales first. Each level runs on at most
``LEVEL_PX`` network pixels: the whole image while it fits, else ``CROPS`` windows cut from the image (or one of its
halvings) before resizing, placed where the smaller scales found the most confident peaks, so an 18 MP photo costs
about what a small frame does. Per level: the confident heatmap peaks (seed probability >= ``CONFIDENT``), their
density, mean score and the median of their predicted box sizes (geometric mean of the box sides, network px).

The predicted box size tracks the true size over ~1-2.5x the network's operating seed size, floors near it below
(clusters, background texture) and the network stops firing on seeds much larger. So the box size falls with the
scale, and where it passes ``TARGET`` x the operating size (log-interpolated between two levels with at least
``MIN_PEAKS`` confident peaks; of several passes, the one with the most peaks; without one, the level whose boxes
come closest) the network sees seeds of that size: the seed size is that size divided by the scale. A final
correction removes the blur that makes small seeds look larger (size^2 = apparent size^2 - (``BLUR`` x operating
size)^2, at most ``BLUR_MAX`` of it). The ladder stops two levels past the target size.

That is the ``boxes`` cue (the field and arm networks). A network trained on photos of many textures predicts boxes
of about its operating size at every scale, so its cue is ``score`` (:data:`CUES`): the whole ladder runs, then the
midpoints between its levels around the peak of the confident peaks' mean score, and the seeds have ``score_size`` x
the operating size at that peak (the score-weighted centre of the curve's upper half around its highest level,
:func:`size_from_scores`); the multiple belongs to the network (``info["score_size"]``,
:func:`seedmap.detect.cnn.network_score_size`). Method and measured accuracy: docs/method/detection.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

#: ladder levels are this factor apart (input scales 4, 4/step, ...)
LADDER_STEP = 2.0 ** 0.5
#: largest input scale of the ladder (the detector's own upper bound)
MAX_SCALE = 4.0
#: the ladder reaches down to seeds of about this size (px)
MAX_SEED_PX = 250.0
#: network pixels per ladder level (at most)
LEVEL_PX = 160_000
#: a level's pixels come from this many crops spread over the image (when the resized image is larger)
CROPS = 4
#: smallest side (network px) of a level's resized image
MIN_SIDE = 48
#: seed probability of a peak that counts as evidence
CONFIDENT = 0.5
#: a level needs this many confident peaks to count
MIN_PEAKS = 12
#: the size is read where the network's predicted boxes are this multiple of its operating seed size
TARGET = 1.8
#: blur removed from the apparent seed size, as a multiple of the operating seed size: size^2 = apparent^2 - blur^2 ...
BLUR = 0.45
#: ... removing at most this fraction of the apparent size
BLUR_MAX = 0.25
#: ``score`` cue of the shipped photo network (and of networks trained from scratch with its recipe): the seeds
#: measure this multiple of the operating size where the confident peaks score highest (1.05 chosen on the
#: validation photos: 92 % of the estimates within 15 %, against 88 % for 1.0 and 81 % for 1.1)
SCORE_SIZE = 1.05
#: ``cnn.scale = auto`` on a folder: the folder is one setup (camera, distance, seed lot) when at least AGREE_MIN
#: photos have an estimate and AGREE_SHARE of them lie within AGREE_BAND x their median; every photo then runs at the
#: agreeing photos' median size, and those whose own differed by more than REDO_TOLERANCE run again
#: (:func:`folder_agreement`)
AGREE_MIN = 5
AGREE_SHARE = 0.6
AGREE_BAND = 1.2
REDO_TOLERANCE = 1.05
#: the multiple of a ``score``-cue network whose file records none (networks fine-tuned from the photo network
#: seedmap shipped up to 0.6.0, which read its seed size at 1.2x)
UNRECORDED_SCORE_SIZE = 1.2


@dataclass
class Level:
    """One ladder level: input ``scale``, confident ``peaks``, their ``density`` (per 10^4 network px), ``score``
    (mean seed probability) and ``box_px`` (median predicted box size, network px; nan without peaks)."""

    scale: float
    peaks: int
    density: float
    score: float
    box_px: float


@dataclass
class SeedSizeEstimate:
    """The estimated seed size (px of the input image; None when no level had evidence of seeds), the levels, and
    ``run_px``: the seed size the network is run for (its input scale is its operating size / ``run_px``). With the
    ``boxes`` cue that is ``seed_px``; with the ``score`` cue the ladder level where the network scores highest
    (:func:`run_size_from_scores`), which detects better than the seed size read between levels."""

    seed_px: float | None
    levels: list[Level] = field(default_factory=list)
    run_px: float | None = None


def _crops(h: int, w: int, s: float, points: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Input-image regions ``(y0, y1, x0, x1)`` whose resized pixels at scale ``s`` stay within LEVEL_PX: the whole
    image, or CROPS windows placed where the confident peaks of the smaller scales (``points``, (N, 2) x, y input
    px) are densest (windows on a half-window grid, greedily, without overlap; spread over the image without peaks)."""
    if h * w * s * s <= LEVEL_PX:
        return [(0, h, 0, w)]
    ch = min(int(np.sqrt(LEVEL_PX / CROPS) / s), h)
    cw = min(int(LEVEL_PX / CROPS / (ch * s * s)), w)  # wider crops when the image is thin
    gy, gx = max(ch // 2, 1), max(cw // 2, 1)
    ny, nx = -(-h // gy), -(-w // gx)
    hist = np.zeros((ny + 1, nx + 1))
    if len(points):
        iy = np.clip((points[:, 1] // gy).astype(int), 0, ny - 1)
        ix = np.clip((points[:, 0] // gx).astype(int), 0, nx - 1)
        np.add.at(hist, (iy, ix), 1.0)
    out = []
    for k in range(CROPS):
        win = hist[:-1, :-1] + hist[1:, :-1] + hist[:-1, 1:] + hist[1:, 1:]
        if win.max() > 0:
            cy, cx = np.unravel_index(int(np.argmax(win)), win.shape)
            hist[cy:cy + 2, cx:cx + 2] = 0.0
            y0, x0 = cy * gy, cx * gx
        else:
            g = int(np.ceil(np.sqrt(CROPS)))
            y0 = int(round((k // g + 0.5) / g * h - ch / 2))
            x0 = int(round((k % g + 0.5) / g * w - cw / 2))
        y0, x0 = min(max(y0, 0), h - ch), min(max(x0, 0), w - cw)
        out.append((y0, y0 + ch, x0, x0 + cw))
    return out


def ladder(h: int, w: int, operating_px: float) -> np.ndarray:
    """The input scales tried on an ``h`` x ``w`` image for a network operating at ``operating_px``-px seeds."""
    lo = max(TARGET * operating_px / MAX_SEED_PX, MIN_SIDE / min(h, w))
    n = int(np.floor(np.log(MAX_SCALE / lo) / np.log(LADDER_STEP))) + 1
    return MAX_SCALE / LADDER_STEP ** np.arange(max(n, 1))


def _halvings(image: np.ndarray, smallest: float) -> list[np.ndarray]:
    """``image`` and its successive INTER_AREA halvings down to the scale ``smallest``."""
    out = [image]
    while 0.5 ** len(out) >= smallest and min(out[-1].shape[:2]) >= 2 * MIN_SIDE:
        h, w = out[-1].shape[:2]
        out.append(cv2.resize(out[-1], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    return out


def measure_level(peaks_fn, pyramid: list[np.ndarray], s: float, points: np.ndarray  # noqa: ANN001 - CnnDetector.peaks
                  ) -> tuple[Level, np.ndarray]:
    """The confident peaks of ``peaks_fn`` on the image (``pyramid[0]``, with its halvings) resized by ``s`` (crops
    of at most LEVEL_PX pixels placed by ``points``, see :func:`_crops`) and their positions (input px). Each crop is
    cut from the smallest halving still at least the size it is resized to."""
    h, w = pyramid[0].shape[:2]
    k = 0
    while k + 1 < len(pyramid) and 0.5 ** (k + 1) >= s:
        k += 1
    image, f = pyramid[k], pyramid[k].shape[1] / w
    n, px, sc, box, xy = 0, 0, [], [], []
    for y0, y1, x0, x1 in _crops(h, w, s, points):
        ws, hs = max(1, int(round((x1 - x0) * s))), max(1, int(round((y1 - y0) * s)))
        if min(ws, hs) < 16:
            continue
        c = image[int(y0 * f):max(int(y1 * f), int(y0 * f) + 1), int(x0 * f):max(int(x1 * f), int(x0 * f) + 1)]
        crop = cv2.resize(c, (ws, hs), interpolation=cv2.INTER_AREA if s < f else cv2.INTER_LINEAR)
        pk = peaks_fn(crop)
        px += ws * hs
        if len(pk) == 0:
            continue
        p = 1.0 / (1.0 + np.exp(-pk.raw[:, 0]))
        keep = p >= CONFIDENT
        r = pk.raw[keep]
        n += int(keep.sum())
        xy.append(np.stack([x0 + (pk.x[keep] + 0.5) * (x1 - x0) / ws, y0 + (pk.y[keep] + 0.5) * (y1 - y0) / hs], 1))
        sc.append(p[keep])
        e = np.maximum(r[:, 1:5], 0.0)
        box.append(np.sqrt((e[:, 0] + e[:, 2] + 1.0) * (e[:, 1] + e[:, 3] + 1.0)))
    if n == 0 or px == 0:
        return Level(float(s), 0, 0.0, 0.0, float("nan")), np.zeros((0, 2))
    return (Level(float(s), n, 1e4 * n / px, float(np.concatenate(sc).mean()), float(np.median(np.concatenate(box)))),
            np.concatenate(xy))


def estimate_seed_px(peaks_fn, image: np.ndarray, operating_px: float, cue: str = "boxes",  # noqa: ANN001
                     score_size: float = SCORE_SIZE) -> SeedSizeEstimate:
    """The seeds' typical size (px) in RGB ``image`` (module docstring); ``peaks_fn(img) -> CnnPeaks`` is a
    network's peak finder at its own resolution (:meth:`seedmap.detect.cnn.CnnDetector.peaks`), ``operating_px``
    the seed size it is trained for, ``cue`` how the size is read off the ladder (:data:`CUES`) and
    ``score_size`` the network's multiple for the ``score`` cue."""
    if cue not in CUES:
        raise ValueError(f"unknown seed-size cue {cue!r} (known: {', '.join(CUES)})")
    h, w = image.shape[:2]
    target = TARGET * operating_px
    scales = ladder(h, w, operating_px)
    pyramid = _halvings(image, float(scales[-1]))
    levels, points, above = [], np.zeros((0, 2)), 0
    for s in scales[::-1]:  # small scales first: they see the whole image and place the crops
        lv, xy = measure_level(peaks_fn, pyramid, float(s), points)
        levels.insert(0, lv)
        points = np.concatenate([points, xy])
        if cue != "boxes":
            continue
        # past the target size (boxes larger than it seen): two levels with larger boxes or too few peaks end it
        crossed = any(v.peaks >= MIN_PEAKS and v.box_px > target for v in levels)
        above = above + 1 if crossed and not (lv.peaks >= MIN_PEAKS and lv.box_px <= target) else 0
        if above >= 2:
            break
    if cue != "score":
        size = CUES[cue](levels, operating_px)
        return SeedSizeEstimate(size, levels, size)
    run_px = run_size_from_scores(levels, operating_px, score_size)
    for s in score_midpoints(levels):  # the score peak read between levels: the midpoints around it measured too
        lv, xy = measure_level(peaks_fn, pyramid, float(s), points)
        levels.append(lv)
        points = np.concatenate([points, xy])
    levels.sort(key=lambda v: -v.scale)
    return SeedSizeEstimate(size_from_scores(levels, operating_px, score_size), levels, run_px)


def folder_agreement(estimates: list[tuple[float | None, float | None]]
                     ) -> tuple[float, float, np.ndarray] | None:
    """The sizes a folder of photos agrees on and the photos to run again at them. ``estimates`` are each photo's
    ``(seed_px, run_px)`` (:class:`SeedSizeEstimate`; None: no seeds found). The folder is one setup when at least
    AGREE_MIN photos have an estimate and AGREE_SHARE of them run within AGREE_BAND x the median run size, or else
    estimate seeds within AGREE_BAND x the median seed size. Then ``(seed_px, run_px, redo)``: the medians over the
    agreeing photos, and a mask of the photos whose own run size is more than REDO_TOLERANCE off the folder's or
    that found no seeds; else None (photos of different setups keep their own sizes)."""
    seed = np.array([np.nan if r is None or s is None else s for s, r in estimates], dtype=float)
    run = np.array([np.nan if r is None or s is None else r for s, r in estimates], dtype=float)
    ok = np.isfinite(seed)
    if ok.sum() < AGREE_MIN:
        return None
    for v in (run, seed):  # the run sizes agree more often (the seed sizes where the run sizes split between levels)
        agree = ok.copy()
        agree[ok] = np.abs(np.log(v[ok] / np.median(v[ok]))) <= np.log(AGREE_BAND)
        if agree.sum() >= AGREE_SHARE * ok.sum():
            break
    else:
        return None
    r_med = float(np.median(run[agree]))
    redo = ~ok
    redo[ok] = np.abs(np.log(run[ok] / r_med)) > np.log(REDO_TOLERANCE)
    return float(np.median(seed[agree])), r_med, redo


def _usable(levels: list[Level]) -> list[Level]:
    """The ``levels`` (in their order) with MIN_PEAKS confident peaks: the ones that count as evidence."""
    return [lv for lv in levels if lv.peaks >= MIN_PEAKS]


def _score_peak(levels: list[Level]) -> tuple[list[Level], int, int, float] | None:
    """The levels with MIN_PEAKS confident peaks (largest scale first), the run ``[j0, j1]`` of them that makes the
    score curve's peak and its cut: around the highest level of the curve smoothed over 1-2-1 neighbours, the levels
    that score above the cut, halfway from the lowest to the highest score. None without such levels."""
    use = _usable(levels)
    if not use:
        return None
    y = np.array([lv.score for lv in use])
    i = int(np.argmax(np.convolve(np.pad(y, 1, mode="edge"), [0.25, 0.5, 0.25], "valid")))
    cut = y.max() - 0.5 * (y.max() - y.min())
    j0, j1 = i, i
    while j0 > 0 and y[j0 - 1] > cut:
        j0 -= 1
    while j1 < len(y) - 1 and y[j1 + 1] > cut:
        j1 += 1
    return use, j0, j1, float(cut)


def score_midpoints(levels: list[Level]) -> list[float]:
    """Scales halfway (in log scale) between neighbouring ladder ``levels`` over the score peak's run and one level
    beyond each end, where the ``score`` cue reads its peak more finely; [] without a peak."""
    peak = _score_peak(levels)
    if peak is None:
        return []
    use, j0, j1, _ = peak
    hi, lo = use[j0].scale * LADDER_STEP * 1.001, use[j1].scale / LADDER_STEP / 1.001
    scales = sorted({lv.scale for lv in levels}, reverse=True)
    return [float(np.sqrt(a * b)) for a, b in zip(scales, scales[1:]) if lo <= b and a <= hi]


def size_from_scores(levels: list[Level], operating_px: float, score_size: float = SCORE_SIZE) -> float | None:
    """The ``score`` cue: ``score_size`` x ``operating_px`` over the scale where the confident peaks' mean score
    peaks (module docstring): the score-weighted centre (log scale) of the peak's run of levels
    (:func:`_score_peak`), weighted by how far each scores above the run's cut, so one level's noise neither picks nor
    pins the peak and a second bump elsewhere on the ladder does not pull it. None when no level has MIN_PEAKS
    confident peaks."""
    peak = _score_peak(levels)
    if peak is None:
        return None
    use, j0, j1, cut = peak
    run = use[j0:j1 + 1]
    x = np.log([lv.scale for lv in run])
    w = np.maximum(np.array([lv.score for lv in run]) - cut, 0.0)
    s = float(np.exp((w * x).sum() / w.sum())) if w.sum() > 0 else max(run, key=lambda v: v.score).scale
    return score_size * operating_px / s


def run_size_from_scores(levels: list[Level], operating_px: float, score_size: float = SCORE_SIZE) -> float | None:
    """The seed size a ``score``-cue network is run for, from the ladder's own ``levels`` (no midpoints):
    ``score_size`` x ``operating_px`` over the level with the highest mean score of confident peaks (a parabola
    through it and its neighbours when it has one on each side); None when no level has MIN_PEAKS confident peaks.
    The network detects best where it scores highest: on the validation photos F1 0.766 run there against 0.731 at
    the seed size read between levels (:func:`size_from_scores`) and 0.738 at the true size
    (docs/method/detection.md)."""
    use = _usable(levels)
    if not use:
        return None
    i = int(np.argmax([lv.score for lv in use]))
    s = use[i].scale
    if 0 < i < len(use) - 1:
        x = np.log([use[i - 1].scale, use[i].scale, use[i + 1].scale])
        y = np.array([use[i - 1].score, use[i].score, use[i + 1].score])
        a, b = np.polyfit(x, y, 2)[:2]
        if a < 0:
            s = float(np.exp(np.clip(-b / (2 * a), x.min(), x.max())))
    return score_size * operating_px / s


def size_from_levels(levels: list[Level], operating_px: float) -> float | None:
    """The seed size (px) read off ladder ``levels`` (largest scale first) of a network operating at
    ``operating_px`` (module docstring); None when no level has MIN_PEAKS confident peaks."""
    target = TARGET * operating_px
    use = _usable(levels)
    if not use:
        return None
    # the predicted box size falls with the scale: where it passes the target (log-interpolated between the two
    # levels), the network sees seeds of the target size; of several passes, the one with the most peaks
    best, est = -1, None
    for la, lb in zip(use, use[1:]):
        if la.box_px > target >= lb.box_px and la.peaks + lb.peaks > best:
            t = np.log(la.box_px / target) / np.log(la.box_px / lb.box_px)
            est = target / float(np.exp(np.log(la.scale) + t * np.log(lb.scale / la.scale)))
            best = la.peaks + lb.peaks
    if est is None:  # no pass (seeds too small at the largest scale, too large at the smallest, or boxes that
        # never quite reach the target): the level whose box size comes closest to it
        lv = min(use, key=lambda v: abs(np.log(v.box_px / target)))
        est = lv.box_px / lv.scale
    b = BLUR * operating_px
    return float(np.sqrt(max(est * est - b * b, (1.0 - BLUR_MAX) ** 2 * est * est)))


#: how a network's seed size is read off the ladder: ``boxes`` (predicted box sizes) or ``score`` (peak scores)
CUES = {"boxes": size_from_levels, "score": size_from_scores}
