"""Training of the ``fast`` detector's small CNN (torch on CPU) and its export to ONNX.

The network (:class:`SeedNet`) is CenterNet-style and fully convolutional: for every full-resolution
pixel it predicts a seed-centre logit, the four distances (px) from that pixel to the seed's box
edges (left, top, right, bottom; GT convention x0/y0 inclusive, x1/y1 exclusive) and the sub-pixel
offset (px) from the pixel to the seed's keypoint. Most of the work runs at half resolution (one
stride-2 convolution, two 3x3 layers, one of them dilated for context); a full-resolution skip from
the stem keeps the box edges pixel-exact, which a 5 px seed needs for IoU >= 0.5.

Targets come from a simulated dataset's ground truth (``gt/masks`` + ``gt/instances``), made per crop
by :func:`crop_batch` (:class:`CropSpec`):

* heatmap: a Gaussian (sigma ``heat_sigma`` px, wider for seeds larger than 5 px) at the rounded
  keypoint of every instance of at least ``heat_min_area`` visible pixels (the detectable-seed size
  that ``seedmap eval detect`` and the ``gt`` oracle use, 10 px at 1434 px), trained with CenterNet's
  penalty-reduced focal loss; slivers from ``min_area`` up to that size are *ignored* by the heatmap
  loss (neither seed nor background: a detection there is neither a true nor a false positive);
* keypoint: the projected 3D centre where it is visible (``center_visible``), else the mask centroid;
* box edges and offset: L1 on every pixel of the instance's mask (FCOS-style: more signal than the
  centre pixel alone), plus ``iou_weight`` x (1 - GIoU) of the box the four edges describe (on a
  5 px seed a 1 px edge error halves the IoU; L1 alone pulled the widths toward 5 px); read at the
  heatmap peak at inference;
* augmentation: horizontal flip, brightness gain and, for ``scale_prob`` of the crops, a rescale by
  ``U(scale_lo, scale_hi)`` (0.8-1.7x: close-up arm scans show seeds ~1.5x larger than the field
  images, where the session-3 network fired twice on a third of the seeds).

Session-4 weights (shipped; session 7's fine-tune, run C below, was not adopted): ``seedmap train fast-cnn data/det_s1 data/det_s31 data/det_s32
data/det_s33 data/det_s34 data/det_s35 --val data/det_s36 --out DIR`` (the defaults: 5,000 steps of
12 crops of 96 px, c1/c2 = 8/16; 553 s CPU on one torch thread; ranges rendered with ``seedmap
simulate range --length 0.5 --seed N``). Session 3: 12/24 channels, L1 boxes only, heat from 4 px,
no rescale, 2,500 steps (445 s CPU).

Session 5, tried and not shipped (the session-4 weights stay): training on twice the ranges (det_s1, det_s31-35
and det_s40-44, each ``seedmap simulate range --length 0.5 --seed N``), 4,000 steps, with or without
``--box-center-weight 4`` (a mask pixel's box/offset loss weighs 1 + 4 x its heat target, so the peak's 3x3
neighbourhood that :func:`seedmap.detect.cnn.decode` reads counts most; 452 s CPU on one thread). Validation F1
at threshold 0.45 (det_s36 / det_s45): session-4 weights 0.898 / 0.883, more data 0.900 / 0.887, more data + centre
weight 0.899 / 0.888 with the keypoint median 0.31 -> 0.29 px / 0.36 -> 0.34 px. On the held-out ranges the
frozen centre-weighted network was no better: F1 det_s2 0.861 (session 4: 0.871), det_s21 0.889 (0.888),
det_s2_new 0.891 (0.892), det_s22 0.810 (0.817), fresh det_s23 0.877 (0.880). The option is kept (default 0).

Session 6, the arm-scan network ``fast_cnn_arm.onnx`` (``cnn.domain=arm``): ``seedmap train fast-cnn data/det_s1
data/det_s31 data/det_s32 data/det_s33 data/det_s34 data/det_s35 data/arm_train/p130 ... data/arm_train/p139
--val data/det_s36 --val data/arm_train/p140 --val data/arm_train/p141 --steps 6000 --arm-fraction 0.4 --out DIR``
(arm scans: ``seedmap simulate panicle --seed N --views 24 --out data/arm_train/pN``; 40 % of the crops from
them; 669 s CPU on one torch thread). Validation: panicles 140-141 box F1 0.617 (field network 0.409), seeds with
>= 2 keypoints 12 % (43 %); row range det_s36 F1 0.884 (field network 0.898), hence two networks (held-out
ranges det_s2 / det_s21 / det_s2_new / det_s22 / det_s23, default eval: arm network 0.874 / 0.877 / 0.877 / 0.798 /
0.866, field network 0.871 / 0.888 / 0.892 / 0.817 / 0.880). On the tuning panicle 99 (``seedmap eval detect``,
default GT size): box F1 0.488 -> 0.616, keypoint median 1.38 -> 0.68 px. Tried and not
shipped: fine-tuning the field network on the same mix (``--init fast_cnn.onnx --lr 1e-3 --steps 3000
--arm-fraction 0.5``, 331 s CPU): det_s36 0.875, det_s45 0.866, panicles 0.582 -- worse on both.

Session 7, error buckets and three opt-in target changes (``benchmarks/detect_errors.py``; validation det_s36 /
det_s45, default eval, threshold chosen per run on validation). Session-4 weights at 0.45: F1 0.898 / 0.883;
false positives on det_s36 4,790 = 1,693 on GT slivers below the detectable size (their box misses IoU 0.5 with the
sliver: median IoU 0.43, box area 2.1x the sliver's), 1,333 poor boxes on a seed no detection matched (median IoU
0.44), 885 duplicates, 635 background, 244 near a seed; 5,154 more detections match ignored slivers and count neither
way. The boxes are calibrated on average (GT width given the predicted width: slope 0.89) but the per-seed spread is
large (predicted width off by >= 1 px for ~50 % of the seeds), so no inference-side size correction helps.
Options (all default off, so the default recipe and the shipped weights are unchanged):
``--peak-box-radius R`` (box/offset targets also on the untrained pixels of the (2R+1)^2 window around every
instance's peak, slivers included: the pixels cnn.decode reads), ``--sliver-box-weight W`` (box loss of a sliver
pixel x (1 + W)), ``--sliver-neg-weight W`` (the heatmap's background term on sliver pixels at weight W instead of
ignoring them). Runs (``seedmap train fast-cnn data/det_s1 data/det_s31 ... data/det_s35 --val data/det_s36 ...``):
(A) ``--peak-box-radius 1 --sliver-box-weight 4``, full 5,000 steps (558 s CPU): F1 0.882 / 0.863 (t 0.45) -- sliver
FPs 1,693 -> 1,285 and duplicates 885 -> 356, but poor boxes 1,333 -> 2,798 (boxes pulled towards sliver size);
(B) fine-tuned from the shipped weights, ``--init fast_cnn.onnx --lr 5e-4 --steps 1500 --sliver-neg-weight 0.5``
(165 s CPU): 0.898 (t 0.45) / 0.884 (t 0.40) -- precision +0.014, recall -0.013: a trade along the same curve;
(C) fine-tuned the same way with ``--peak-box-radius 1`` only (``seedmap train fast-cnn data/det_s1 data/det_s31
data/det_s32 data/det_s33 data/det_s34 data/det_s35 --val data/det_s36 --init fast_cnn.onnx --lr 5e-4 --steps 1500
--peak-box-radius 1 --out DIR``, 164 s CPU on one thread after the session-4 run's 553 s): 0.902 / 0.884 at
threshold 0.50 (mean 0.893 vs 0.891), frozen at 0.50. Held-out,
run once after the freeze (``benchmarks/detect_errors.py --no-buckets``, default eval; session-4 weights at 0.45 in
brackets): det_s2 0.880 (0.871), det_s21 0.894 (0.888), det_s2_new 0.896 (0.892), det_s22 0.816 (0.817), det_s23
0.886 (0.880), pooled 0.878 (0.873); fresh det_s24 (``seedmap simulate range --config data/det_s23/gt/config.yaml
--set seed=24``, rendered after the freeze) 0.846 (0.835). Keypoint median unchanged (0.33-0.40 px).
Not shipped: with C at 0.50, ``seedmap slam --detector fast`` lost track on paper2-hard (frame 63) and paper6-hard
(frame 11) of the eight hard scenes (``data/benchmark_s4/paperK-s110K-1e083503``), which the session-4 weights at 0.45
map in full; the pooled F1 gain (+0.005) is the size of the run-to-run spread, and half of it is the higher threshold
(C at 0.45: pooled 0.875, recall 0.863 vs 0.856, det_s24 0.844). A detector threshold for SLAM should be chosen with
SLAM on training scenes, not by box F1 alone.

Session 9 (issue #3), renderer gap and three more runs; the default network is unchanged. The sim renderer changed
between the training ranges (det_s1, det_s31-36: rendered before the 22:02/00:31 session-3 renderer speed-ups) and the
hard held-out ranges det_s22-24 (and det_s40-45), with identical configs (``diff data/det_s31/gt/config.yaml
data/det_s23/gt/config.yaml``: the seed only). Re-rendering det_s36 with today's code (``seedmap simulate range --config
data/det_s36/gt/config.yaml --out data/det_s36_new``) gives the same GT (50,529 counted seeds) but other seed shading
(mean |difference| 3.1 grey levels on seed pixels after a 2 px blur, 0.7 on the background; seeds +1.2 brighter)
and other noise, and the shipped network's F1 drops 0.898 -> 0.883 at 0.45: a renderer domain gap of ~0.015. New
ranges ``seedmap simulate range --config data/det_s23/gt/config.yaml --set seed=N`` (N = 60-69, 25 s CPU each);
training on det_s1, det_s31-35, det_s40-44, det_s60-67 (19 ranges, 13 of them later-renderer), ``--val data/det_s45
--val data/det_s68``. Validation F1 at 0.45 (det_s36 / det_s45 / det_s68 / det_s69 / det_s36_new, mean):
shipped 0.898 / 0.883 / 0.866 / 0.818 / 0.883, 0.870; (B) fine-tune ``--init fast_cnn.onnx --lr 5e-4 --steps 2000``
(214 s CPU) 0.901 / 0.886 / 0.871 / 0.829 / 0.887, 0.875; (E) B plus ``--gamma-jitter 0.2 --noise-max 6`` (236 s)
0.895 / 0.880 / 0.868 / 0.822 / 0.882, 0.869 (the photometric augmentation costs precision: not used); (A) from
scratch ``--c1 10 --c2 20 --steps 6000`` (966 s) 0.903 / 0.895 / 0.876 / 0.835 / 0.890, 0.880, but 1.50x the CPU
per image (56.1 vs 37.4 ms, ``benchmarks/bench_detect.py --cnn-weights``; the limit is 1.4x); (F) ``--c1 10 --c2 16
--steps 6000`` (842 s; network alone 1.42x, estimated ~1.3x per image) 0.901 / 0.889 / 0.868 / 0.834 / 0.886, 0.876 -- no better than B. Frozen: B as
``weights/fast_cnn_s9.onnx`` (same 8/16 architecture and cost) and A as ``weights/fast_cnn_s9_wide.onnx``, both
opt-in (``--set cnn.weights=fast_cnn_s9.onnx``). Held-out, run once after the freeze (``benchmarks/detect_errors.py
--dataset D --thresholds 0.45,0.5 --no-buckets``; det_s2 / s21 / s2_new / s22 / s23 / s24, pooled over the first
five, over all six): shipped 0.871 / 0.888 / 0.892 / 0.817 / 0.880 / 0.835, 0.873, 0.867; fast_cnn_s9 0.869 / 0.893 /
0.894 / 0.826 / 0.884 / 0.849, 0.876, 0.872; fast_cnn_s9_wide 0.865 / 0.898 / 0.894 / 0.834 / 0.881 / 0.852, 0.877,
0.873. The gains (+0.003 to +0.006 pooled, +0.014 / +0.017 on the hardest range det_s24) are below the +0.01 that the
adoption rule asks for, so ``fast_cnn.onnx`` stays the default; F1 >= 0.90 is still not met. SLAM (``seedmap slam
DATA --detector fast [--set detect.cnn.weights=NAME]``, shipped vs fast_cnn_s9, run back to back; mapped = GT-validated
MDM): 1 m range data/slam_r1 100 % / 100 %, ATE 4.7 / 4.6 mm; data/benchmark_s7/paper2-s202-default 100 % / 100 %,
15.2 / 11.7 mm; the hard scenes re-rendered as ``seedmap benchmark paper --scenes`` makes them (data/bench_hard,
paper6-s1106 / paper2-s1102 with the scene overrides): paper6-hard 100 % / 100 %, 15.8 / 14.0 mm, but **paper2-hard 100 %
(17.4 mm) / 18.4 %** -- tracked to the end, yet only 0.92 m of the map GT-validated, the session-7 failure again. The
wide network maps both hard scenes in full (paper2-hard 13.8 mm, paper6-hard 13.9 mm).

Session 10 (issue #3): (A) 8/20 channels from scratch with the session-9 recipe (``--c1 8 --c2 20 --steps 6000``, same
19 ranges and --val; 1,034 s CPU) and (G) the shipped network fine-tuned on the 13 later-renderer ranges only
(det_s40-44, det_s60-67; ``--init fast_cnn.onnx --lr 5e-4 --steps 2000``, 286 s). Validation F1 at 0.45 (det_s36 /
s45 / s68 / s69 / s36_new, mean): A 0.903 / 0.894 / 0.879 / 0.842 / 0.890, 0.882; G 0.901 / 0.888 / 0.873 / 0.833 /
0.888, 0.876 (vs session-9 B on all 19 ranges 0.875: dropping the old-renderer ranges gains ~0.002). CPU per image,
timed round-robin (``benchmarks/bench_detect.py --interleave 40``): A 1.19x (gated tiles) / 1.28x (whole image), G
0.97x / 1.01x, fast_cnn_s9_wide 1.66x / 1.85x. Frozen: A as ``weights/fast_cnn_s10.onnx`` (opt-in). Held-out, run once
after the freeze (``benchmarks/detect_heldout_s10.py``; det_s2 / s21 / s2_new / s22 / s23 / s24 at 0.45): 0.867 / 0.897
/ 0.892 / 0.830 / 0.886 / 0.857 (shipped 0.871 / 0.888 / 0.892 / 0.817 / 0.880 / 0.835), pooled over five 0.8775
(0.8730), over six 0.8741 (0.8666): +0.005 / +0.007, below the +0.01 adoption bar, so it stays opt-in. SLAM passes
(100 % GT-validated on slam_r1 and both hard scenes; ATE 4.6 / 13.8 / 12.7 mm vs 4.7 / 17.4 / 15.8 mm).

Inference does not need torch: :func:`export_onnx` writes an ONNX graph that
:mod:`seedmap.detect.cnn` runs in onnxruntime. Weights/checkpoints are safetensors.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seedmap.errors import InputError

#: output channels of the network: heat logit, l, t, r, b (px), dx, dy (px)
N_OUT = 7


def build_net(c1: int = 8, c2: int = 16):
    """The torch :class:`SeedNet` (imports torch; training and export only)."""
    import torch
    from torch import nn

    class SeedNet(nn.Module):
        """Full-res stem -> half-res body (3 convs, one dilated) -> upsample + skip -> full-res head."""

        def __init__(self) -> None:
            super().__init__()
            self.c1, self.c2 = c1, c2
            self.stem = nn.Conv2d(3, c1, 3, padding=1)
            self.down = nn.Conv2d(c1, c2, 3, stride=2, padding=1)
            self.mid1 = nn.Conv2d(c2, c2, 3, padding=1)
            self.mid2 = nn.Conv2d(c2, c2, 3, padding=2, dilation=2)
            self.lat = nn.Conv2d(c2, c1, 1)
            self.fuse = nn.Conv2d(c1, c1, 3, padding=1)
            self.head = nn.Conv2d(c1, N_OUT, 1)
            with torch.no_grad():
                self.head.bias.zero_()
                self.head.bias[0] = -4.0  # CenterNet prior: few pixels are centres
                self.head.bias[1:5] = 2.0

        def forward(self, x):  # noqa: ANN001, ANN201
            r = torch.relu
            s = r(self.stem(x))
            h = r(self.down(s))
            h = r(self.mid1(h))
            h = r(self.mid2(h))
            u = nn.functional.interpolate(self.lat(h), scale_factor=2.0, mode="nearest")
            u = u[:, :, : s.shape[2], : s.shape[3]]
            f = r(self.fuse(r(s + u)))
            return self.head(f)

    return SeedNet()


# ------------------------------------------------------------------------------------------------
# training data
# ------------------------------------------------------------------------------------------------


@dataclass
class TrainImage:
    """One image with compact per-pixel targets (instance index map + per-instance arrays)."""

    rgb: np.ndarray  # H x W x 3 uint8
    inst: np.ndarray  # H x W int16: row into the per-instance arrays, -1 = background
    boxes: np.ndarray  # (N, 4) float32 GT boxes
    kp: np.ndarray  # (N, 2) float32 keypoint targets (u, v)
    centers: np.ndarray  # (N, 2) int peak pixels
    area: np.ndarray  # (N,) float32 visible pixels of each instance
    arm: bool = False  # from an arm scan (a dataset with arm.yaml: close-up panicle images)


def image_targets(rgb: np.ndarray, labels: np.ndarray, inst, min_area: int = 1) -> TrainImage:
    """Targets of one simulated image from its GT label image and instance table.

    Every instance of at least ``min_area`` visible pixels is kept; :func:`crop_batch` decides per
    crop (after scaling) which ones are heatmap positives, ignored slivers or box-only pixels.
    """
    h, w = labels.shape
    lut = np.full(int(max(labels.max(), inst.label.max(initial=0))) + 1, -1, np.int64)
    keep = inst.area >= min_area
    rows = np.flatnonzero(keep)
    lut[inst.label[rows].astype(np.int64)] = np.arange(len(rows))
    idx = lut[labels.astype(np.int64)].astype(np.int16)
    boxes = inst.boxes[rows].astype(np.float32)
    # keypoint: projected centre where visible, else the centroid of the visible mask
    cnt = np.bincount(idx[idx >= 0].astype(np.int64), minlength=len(rows)).astype(np.float64)
    ys, xs = np.nonzero(idx >= 0)
    li = idx[ys, xs].astype(np.int64)
    cx = np.bincount(li, xs, len(rows)) / np.maximum(cnt, 1)
    cy = np.bincount(li, ys, len(rows)) / np.maximum(cnt, 1)
    vis = inst.center_visible[rows].astype(bool)
    kp = np.where(vis[:, None], inst.center_uv[rows], np.c_[cx, cy]).astype(np.float32)
    c = np.round(kp).astype(np.int64)
    c[:, 0] = np.clip(c[:, 0], 0, w - 1)
    c[:, 1] = np.clip(c[:, 1], 0, h - 1)
    return TrainImage(rgb, idx, boxes, kp, c, inst.area[rows].astype(np.float32))


def is_arm_scan(dataset: str | Path) -> bool:
    """True for a simulated arm scan (``seedmap simulate panicle``: close-up panicle views, seeds ~2x the
    area of the field images' seeds, flash-saturated), recognised by its ``arm.yaml``."""
    return (Path(dataset) / "arm.yaml").is_file()


def load_training_images(datasets: list[str | Path], frames: dict | None = None, min_area: int = 1,
                         progress: bool = False) -> list[TrainImage]:
    """Every (frame, camera) image of the simulated ``datasets`` with its targets (``arm`` set for arm scans)."""
    from seedmap.io.images import read_rgb
    from seedmap.io.seedmap_dataset import SeedmapDataset

    items = []
    for d in datasets:
        ds = SeedmapDataset(d)
        if not ds.has_gt:
            raise InputError("dataset has no ground truth (gt/instances/) to train on", d)
        fr = (frames or {}).get(str(d), range(len(ds)))
        arm = is_arm_scan(ds.root)
        items += [(ds, arm, i, cam) for i in fr for cam in ("left", "right")]
    if progress:
        from tqdm import tqdm

        items = tqdm(items, desc="cnn targets", unit="img")
    out = []
    for ds, arm, i, cam in items:
        ti = image_targets(read_rgb(ds.image_path(i, cam)), ds.gt_label_image(i, cam), ds.gt_instances(i, cam),
                           min_area)
        ti.arm = arm
        out.append(ti)
    return out


def image_weights(images: list[TrainImage], arm_fraction: float | None) -> np.ndarray | None:
    """Sampling probabilities of the images so that ``arm_fraction`` of the crops come from arm scans
    (None, or only one kind present: None = every image alike)."""
    if arm_fraction is None:
        return None
    arm = np.array([im.arm for im in images], bool)
    if arm.all() or not arm.any():
        return None
    return np.where(arm, arm_fraction / arm.sum(), (1.0 - arm_fraction) / (~arm).sum())


@dataclass
class CropSpec:
    """How :func:`crop_batch` turns GT instances into targets (areas in pixels of the *scaled* crop)."""

    #: instances of at least this many visible pixels are heatmap peaks (the detectable-seed size)
    heat_min_area: float = 10.0
    #: smaller instances of at least this many pixels are ignored by the heatmap loss (neither seed
    #: nor background) but still train the box edges; below it they are background
    min_area: float = 4.0
    #: Gaussian sigma (px) of a peak; grows with the seed beyond 5 px (sqrt of the box area)
    heat_sigma: float = 1.0
    #: fraction of the crops rescaled by a factor drawn uniformly from ``scale_range``
    scale_prob: float = 0.0
    scale_range: tuple[float, float] = (0.8, 1.7)
    #: > 0: box/offset targets also on the untrained pixels of the (2r+1)^2 window around every instance's peak
    #: (slivers included), where inference reads the box (0 = mask pixels only, session 4)
    peak_box_radius: int = 0
    #: box/offset loss weight of a sliver pixel (min_area <= area < heat_min_area) = 1 + this (0 = like a seed's)
    sliver_box_weight: float = 0.0
    #: heatmap loss on ignored sliver pixels: weight of the background (negative) term there (0 = ignored,
    #: session 4; 1 = plain background)
    sliver_neg_weight: float = 0.0
    #: session 9, photometric augmentation (0 = none, session 4; with augment only): every crop gets a gamma
    #: ``exp(U(-g, g))`` and a per-channel gain ``U(1 - g/2, 1 + g/2)`` for ``gamma_jitter = g``, and Gaussian noise
    #: of standard deviation ``U(0, noise_max)`` grey levels (the renderer's seed shading and the sensor noise
    #: differ between renderer versions and cameras; see :func:`crop_batch`)
    gamma_jitter: float = 0.0
    noise_max: float = 0.0


def _render_heat(size: int, kp: np.ndarray, sigma: np.ndarray, out: np.ndarray) -> None:
    """Max of Gaussians at the rounded keypoints ``kp`` (crop pixels) into ``out`` (size x size)."""
    if len(kp) == 0:
        return
    c = np.round(kp).astype(np.int64)
    rr = int(np.ceil(3 * sigma.max()))
    for dy in range(-rr, rr + 1):
        for dx in range(-rr, rr + 1):
            g = np.exp(-(dx * dx + dy * dy) / (2 * sigma**2))
            x, y = c[:, 0] + dx, c[:, 1] + dy
            ok = (g >= 0.01) & (x >= 0) & (x < size) & (y >= 0) & (y < size)
            np.maximum.at(out, (y[ok], x[ok]), g[ok])


def crop_batch(images: list[TrainImage], n: int, size: int, rng: np.random.Generator,
               seed_fraction: float = 0.75, augment: bool = True, spec: CropSpec | None = None,
               weights: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """``(x (n,3,S,S), heat (n,S,S), reg (n,6,S,S) = l,t,r,b,dx,dy, reg_mask (n,S,S), ignore (n,S,S))``.

    ``seed_fraction`` of the crops are centred near a random seed, the rest anywhere (leaf edges,
    stalks, background as negatives). Augmentation: horizontal flip, brightness gain 0.8-1.2 and,
    for ``spec.scale_prob`` of the crops, a rescale (seeds seen larger or smaller than in the field
    images, e.g. close-up arm scans). Box targets use pixel-edge coordinates scaled with the crop,
    so ``l + r`` is the (scaled) GT box width; ``ignore`` marks sliver pixels the heatmap loss skips.
    ``weights``: sampling probability of each image (None = uniform; :func:`image_weights`).
    """
    import cv2

    sp = spec or CropSpec()
    X = np.zeros((n, 3, size, size), np.float32)
    H = np.zeros((n, size, size), np.float32)
    R = np.zeros((n, 6, size, size), np.float32)
    M = np.zeros((n, size, size), np.float32)
    IG = np.zeros((n, size, size), np.float32)
    for k in range(n):
        im = images[int(rng.integers(len(images)) if weights is None else rng.choice(len(images), p=weights))]
        h, w = im.inst.shape
        s = 1.0
        if augment and sp.scale_prob > 0 and rng.random() < sp.scale_prob:
            s = float(rng.uniform(*sp.scale_range))
        src = int(np.ceil(size / s))  # source window (original pixels)
        src = min(src, w, h)
        if rng.random() < seed_fraction and len(im.centers):
            cx, cy = im.centers[int(rng.integers(len(im.centers)))]
            x0 = int(np.clip(cx - rng.integers(src), 0, w - src))
            y0 = int(np.clip(cy - rng.integers(src), 0, h - src))
        else:
            x0 = int(rng.integers(0, w - src + 1))
            y0 = int(rng.integers(0, h - src + 1))
        if s == 1.0:
            sl = (slice(y0, y0 + size), slice(x0, x0 + size))
            rgb = im.rgb[sl].astype(np.float32) / 255.0
            idx = im.inst[sl].astype(np.int64)
        else:
            # crop pixel x' <- original pixel u: x' = s (u + 0.5 - x0) - 0.5 (pixel centres at integers)
            A = np.array([[s, 0, s * (0.5 - x0) - 0.5], [0, s, s * (0.5 - y0) - 0.5]], np.float64)
            rgb = cv2.warpAffine(im.rgb, A, (size, size), flags=cv2.INTER_LINEAR).astype(np.float32) / 255.0
            idx = cv2.warpAffine(im.inst.astype(np.float32), A, (size, size), flags=cv2.INTER_NEAREST,
                                 borderValue=-1.0).astype(np.int64)
        # per-instance targets in crop coordinates (pixel-edge boxes, pixel-centre keypoints)
        bx = (im.boxes - np.array([x0, y0, x0, y0], np.float32)) * s
        kp = (im.kp + 0.5 - np.array([x0, y0], np.float32)) * s - 0.5
        area = im.area * s * s
        m_all = idx >= 0
        ii = idx[m_all]
        ok = area[ii] >= sp.min_area
        m = np.zeros_like(m_all)
        m[m_all] = ok
        ii = ii[ok]
        reg = np.zeros((6, size, size), np.float32)
        _box_targets(reg, *np.nonzero(m), ii, bx, kp)
        near = ((kp[:, 0] > -4) & (kp[:, 0] < size + 4) & (kp[:, 1] > -4) & (kp[:, 1] < size + 4))
        own = None
        if sp.peak_box_radius > 0 or sp.sliver_box_weight > 0:
            own = np.where(m, idx, -1)
        if sp.peak_box_radius > 0:
            _peak_box_targets(reg, m, own, kp, bx, near & (area >= sp.min_area), area, int(sp.peak_box_radius))
        wgt = m.astype(np.float32)
        if sp.sliver_box_weight > 0:
            is_sliv = area < sp.heat_min_area
            wgt[own >= 0] *= np.where(is_sliv[own[own >= 0]], 1.0 + sp.sliver_box_weight, 1.0).astype(np.float32)
        pos = near & (area >= sp.heat_min_area)
        sig = sp.heat_sigma * np.maximum(1.0, np.sqrt(np.maximum((bx[:, 2] - bx[:, 0]) * (bx[:, 3] - bx[:, 1]), 0)) / 5)
        heat = np.zeros((size, size), np.float32)
        _render_heat(size, kp[pos], sig[pos], heat)
        ign = np.zeros((size, size), np.float32)
        sliv = near & (area >= sp.min_area) & (area < sp.heat_min_area)
        _render_heat(size, kp[sliv], np.full(int(sliv.sum()), 0.7, np.float32), ign)
        ign = (ign > 0.05).astype(np.float32)
        ig_pix = np.zeros(len(area), bool)
        ig_pix[sliv] = True
        ign[m_all] = np.maximum(ign[m_all], ig_pix[idx[m_all]])
        ign[heat >= 0.999] = 0.0  # never ignore a positive peak
        if augment:
            rgb = np.clip(rgb * rng.uniform(0.8, 1.2), 0, 1)
            if rng.random() < 0.5:
                rgb = rgb[:, ::-1]
                heat = heat[:, ::-1]
                ign = ign[:, ::-1]
                m = m[:, ::-1]
                wgt = wgt[:, ::-1]
                # mirrored column x' = S-1-x; inclusive/exclusive edges: l' = r - 1, r' = l + 1
                reg = reg[:, :, ::-1][[2, 1, 0, 3, 4, 5]]
                reg[0] -= 1.0
                reg[2] += 1.0
                reg[4] = -reg[4]
                reg *= m
            if sp.gamma_jitter > 0:  # drawn last, none when off: the
                # session-4 crops stay bit-identical
                g = float(sp.gamma_jitter)
                gain = rng.uniform(1 - g / 2, 1 + g / 2, 3).astype(np.float32)
                rgb = np.clip(rgb ** np.float32(np.exp(rng.uniform(-g, g))) * gain, 0, 1)
            if sp.noise_max > 0:
                sd = rng.uniform(0, sp.noise_max) / 255.0
                rgb = np.clip(rgb + rng.normal(0.0, sd, rgb.shape).astype(np.float32), 0, 1)
        X[k] = rgb.transpose(2, 0, 1)
        H[k] = heat
        R[k] = reg
        M[k] = wgt
        IG[k] = ign * (1.0 - sp.sliver_neg_weight) if sp.sliver_neg_weight > 0 else ign
    return X, H, R, M, IG


def _box_targets(reg: np.ndarray, y: np.ndarray, x: np.ndarray, ins: np.ndarray, bx: np.ndarray,
                 kp: np.ndarray) -> None:
    """Writes (in place) the targets of instance ``ins[k]`` at pixel ``(y[k], x[k])`` of ``reg`` (6, S, S):
    distances to the pixel-edge box ``bx`` (l, t, r, b) and the offset to the keypoint ``kp`` (dx, dy)."""
    gx, gy = x.astype(np.float32), y.astype(np.float32)
    b = bx[ins]
    reg[0][y, x] = gx - b[:, 0]
    reg[1][y, x] = gy - b[:, 1]
    reg[2][y, x] = b[:, 2] - gx
    reg[3][y, x] = b[:, 3] - gy
    reg[4][y, x] = kp[ins, 0] - gx
    reg[5][y, x] = kp[ins, 1] - gy


def _peak_box_targets(reg: np.ndarray, m: np.ndarray, own: np.ndarray, kp: np.ndarray, bx: np.ndarray,
                      cand: np.ndarray, area: np.ndarray, radius: int) -> None:
    """Box/offset targets (in place) on the pixels of the ``(2 radius + 1)^2`` window around every candidate
    instance's peak pixel (rounded keypoint) that belong to no trained mask: inference reads the box at the
    peak and its 3x3 neighbours (cnn.decode), and on a sliver or a thin, partly hidden seed most of those lie
    outside the mask, so without targets there they predict a whole-seed box. Where windows overlap the
    smaller instance wins; ``m`` and ``own`` (instance per pixel) are updated."""
    size = m.shape[0]
    ids = np.flatnonzero(cand)
    if len(ids) == 0:
        return
    ids = ids[np.argsort(-area[ids], kind="stable")]  # largest first: the smallest is written last
    c = np.round(kp[ids]).astype(np.int64)
    d = np.arange(-radius, radius + 1)
    dy, dx = (a.ravel() for a in np.meshgrid(d, d, indexing="ij"))
    ins = np.repeat(ids, len(dx))
    x = (c[:, 0:1] + dx[None]).ravel()
    y = (c[:, 1:2] + dy[None]).ravel()
    ok = (x >= 0) & (x < size) & (y >= 0) & (y < size)
    ins, x, y = ins[ok], x[ok], y[ok]
    ok = ~m[y, x]
    ins, x, y = ins[ok], x[ok], y[ok]
    if len(ins) == 0:
        return
    pix = y * size + x
    _, last = np.unique(pix[::-1], return_index=True)
    sel = len(pix) - 1 - last  # last occurrence of every pixel = the smallest instance there
    ins, x, y = ins[sel], x[sel], y[sel]
    _box_targets(reg, y, x, ins, bx, kp)
    m[y, x] = True
    own[y, x] = ins


def losses(out, heat, reg, mask, ignore=None, iou_weight: float = 0.0,  # noqa: ANN001, ANN201 - torch tensors
           center_weight: float = 0.0):
    """``(total, focal, box L1, offset L1, box 1-GIoU)``.

    CenterNet's penalty-reduced focal loss (``ignore`` pixels skipped), masked L1 of the four box
    edges and the keypoint offset, plus ``iou_weight`` x (1 - GIoU) of the box the edges describe:
    on a 5 px seed a 1 px edge error costs half the IoU, which the L1 loss does not know.
    ``center_weight > 0``: a mask pixel's box/offset terms weigh ``1 + center_weight x heat`` (the
    Gaussian heat target), so the peak and its 3x3 neighbours, which inference reads, count most.
    """
    import torch

    if center_weight > 0:
        mask = mask * (1.0 + center_weight * heat)

    p = torch.sigmoid(out[:, 0]).clamp(1e-4, 1 - 1e-4)
    pos = (heat >= 0.999).float()
    npos = pos.sum().clamp(min=1.0)
    neg = 1 - pos if ignore is None else (1 - pos) * (1 - ignore)
    lp = -(torch.log(p) * (1 - p) ** 2 * pos).sum()
    ln = -(torch.log(1 - p) * p**2 * (1 - heat) ** 4 * neg).sum()
    focal = (lp + ln) / npos
    msum = mask.sum().clamp(min=1.0)
    m = mask.unsqueeze(1)
    box = (torch.abs(out[:, 1:5] - reg[:, :4]) * m).sum() / msum / 4
    off = (torch.abs(out[:, 5:7] - reg[:, 4:6]) * m).sum() / msum / 2
    pe = out[:, 1:5].clamp(min=0.0)
    te = reg[:, :4].clamp(min=0.0)
    iw = torch.minimum(pe[:, 0], te[:, 0]) + torch.minimum(pe[:, 2], te[:, 2])
    ih = torch.minimum(pe[:, 1], te[:, 1]) + torch.minimum(pe[:, 3], te[:, 3])
    inter = iw.clamp(min=0) * ih.clamp(min=0)
    ap = (pe[:, 0] + pe[:, 2]) * (pe[:, 1] + pe[:, 3])
    at = (te[:, 0] + te[:, 2]) * (te[:, 1] + te[:, 3])
    union = (ap + at - inter).clamp(min=1e-6)
    enc = ((torch.maximum(pe[:, 0], te[:, 0]) + torch.maximum(pe[:, 2], te[:, 2]))
           * (torch.maximum(pe[:, 1], te[:, 1]) + torch.maximum(pe[:, 3], te[:, 3]))).clamp(min=1e-6)
    giou = inter / union - (enc - union) / enc
    iou_l = ((1 - giou) * mask).sum() / msum
    return focal + box + off + iou_weight * iou_l, focal, box, off, iou_l

# ------------------------------------------------------------------------------------------------
# training loop, checkpoints, export
# ------------------------------------------------------------------------------------------------


@dataclass
class CnnTrainConfig:
    steps: int = 5000
    batch: int = 12
    crop: int = 96
    lr: float = 2e-3
    seed: int = 0
    #: channels at full / half resolution (session 4: 8 / 16, 2.2x fewer multiply-adds than 12 / 24)
    c1: int = 8
    c2: int = 16
    #: GT instances below this many visible pixels are background; from it up to heat_min_area
    #: they are ignored by the heatmap loss (slivers: CropSpec)
    min_area: int = 4
    heat_min_area: float = 10.0
    heat_sigma: float = 1.0
    seed_fraction: float = 0.75
    #: weight of the box (1 - GIoU) loss next to the L1 edge loss (0 = L1 only, sessions <= 3)
    iou_weight: float = 1.0
    #: box/offset loss weight of a mask pixel = 1 + box_center_weight x heat target (0 = uniform, session 4)
    box_center_weight: float = 0.0
    #: fraction of the crops taken from arm-scan datasets (datasets with arm.yaml) when both kinds are given
    #: (None = every image alike, session 4)
    arm_fraction: float | None = None
    #: fraction of crops rescaled by U(scale_lo, scale_hi) (larger seeds of close-up arm scans)
    scale_prob: float = 0.5
    scale_lo: float = 0.8
    scale_hi: float = 1.7
    #: session 7, opt-in (CropSpec): box targets on the peak window of every instance (radius px), extra box weight
    #: of sliver pixels, background weight of the heatmap on slivers (0 / 0 / 0 = session 4)
    peak_box_radius: int = 0
    sliver_box_weight: float = 0.0
    sliver_neg_weight: float = 0.0
    #: session 9, opt-in (CropSpec): photometric augmentation, gamma/gain jitter and added noise (grey levels)
    gamma_jitter: float = 0.0
    noise_max: float = 0.0
    #: start from the weights of this fast_cnn ONNX file (fine-tuning; its channels replace c1/c2) instead of a
    #: random initialisation
    init_weights: str | None = None
    #: evaluate the held-out loss every this many steps (and write the checkpoint)
    val_every: int = 250
    val_crops: int = 96
    threads: int = 1
    extra: dict = field(default_factory=dict)


def _state_to_numpy(net, opt, step: int) -> tuple[dict, dict]:  # noqa: ANN001
    t = {f"model.{k}": v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}
    if opt is not None:
        for i, st in opt.state_dict()["state"].items():
            for k, v in st.items():
                t[f"opt.{i}.{k}"] = np.asarray(v.detach().cpu().numpy() if hasattr(v, "numpy") else v, np.float32)
    return t, {"step": str(step)}


def save_checkpoint(path: Path, net, opt, step: int, cfg: CnnTrainConfig, history: list) -> None:  # noqa: ANN001
    """Model + Adam state + step + history as one safetensors file (atomic)."""
    from dataclasses import asdict

    from safetensors.numpy import save

    from seedmap.io.atomic import atomic_write_bytes

    t, meta = _state_to_numpy(net, opt, step)
    meta.update({"seedmap_kind": "fast_cnn_checkpoint", "config": json.dumps(asdict(cfg)),
                 "history": json.dumps(history)})
    atomic_write_bytes(Path(path), save({k: np.ascontiguousarray(v) for k, v in t.items()}, metadata=meta))


def load_checkpoint(path: Path, net, opt) -> tuple[int, list]:  # noqa: ANN001
    """Restore ``net`` (and ``opt``) from :func:`save_checkpoint`; returns ``(step, history)``."""
    import torch

    from seedmap.io.tensors import read_safetensors

    t, meta = read_safetensors(path, "checkpoint")
    if meta.get("seedmap_kind") != "fast_cnn_checkpoint":
        raise InputError("not a fast-cnn training checkpoint", path)
    net.load_state_dict({k[6:]: torch.from_numpy(v) for k, v in t.items() if k.startswith("model.")})
    if opt is not None:
        sd = opt.state_dict()
        for key, v in t.items():
            if key.startswith("opt."):
                _, i, name = key.split(".", 2)
                val = torch.from_numpy(v)
                sd["state"].setdefault(int(i), {})[name] = val.reshape(()) if name == "step" else val
        opt.load_state_dict(sd)
    return int(meta.get("step", 0)), json.loads(meta.get("history", "[]"))


def onnx_weights(path: str | Path) -> dict[str, np.ndarray]:
    """The parameters of a fast_cnn ONNX file (:func:`export_onnx`) by their torch names, e.g. ``stem.weight``."""
    import onnx
    from onnx import numpy_helper

    from seedmap.detect.cnn import load_session

    load_session(path)  # a one-line InputError unless it is a readable fast_cnn model
    return {i.name: numpy_helper.to_array(i).copy() for i in onnx.load(str(path)).graph.initializer}


def export_onnx(net, path: Path, info: dict | None = None) -> Path:  # noqa: ANN001
    """Write the network as ONNX (dynamic batch/height/width) with ``info`` as metadata (atomic)."""
    import io

    import onnx
    import torch

    from seedmap.io.atomic import atomic_write_bytes

    net = net.eval()
    x = torch.zeros(1, 3, 64, 64)
    buf = io.BytesIO()
    with torch.no_grad():
        torch.onnx.export(net, (x,), buf, input_names=["image"], output_names=["out"], opset_version=17,
                          dynamic_axes={"image": {0: "n", 2: "h", 3: "w"}, "out": {0: "n", 2: "h", 3: "w"}},
                          dynamo=False)
    model = onnx.load_from_string(buf.getvalue())
    meta = {"seedmap_kind": "fast_cnn", "outputs": "heat_logit,l,t,r,b,dx,dy", "info": json.dumps(info or {})}
    for k, v in meta.items():
        e = model.metadata_props.add()
        e.key, e.value = k, v
    atomic_write_bytes(Path(path), model.SerializeToString())
    return Path(path)


def train_cnn(train_sets: list[str | Path], out: str | Path, val_sets: list[str | Path] | None = None,
              cfg: CnnTrainConfig | None = None, resume: bool = False, progress: bool = True) -> dict:
    """Train :class:`SeedNet` on simulated ranges; write ``out/fast_cnn.onnx`` + checkpoint + metrics.

    Held-out split: ``val_sets`` when given, else the last frame of every training set (its left
    and right image). ``resume`` continues from ``out/checkpoint.safetensors``. Returns the
    metrics dict (also written to ``out/train_metrics.json``).
    """
    import torch

    from seedmap.io.atomic import atomic_write_text

    cfg = cfg or CnnTrainConfig()
    out = Path(out)
    torch.set_num_threads(max(1, int(cfg.threads)))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    from seedmap.io.seedmap_dataset import SeedmapDataset

    if val_sets:
        tr = load_training_images(train_sets, None, 1, progress)
        va = load_training_images(val_sets, None, 1, progress)
    else:
        fr_tr, fr_va = {}, {}
        for d in train_sets:
            n = len(SeedmapDataset(d))
            if n < 2:
                raise InputError("needs at least 2 frames for a held-out split (or pass --val)", d)
            fr_tr[str(d)] = range(n - 1)
            fr_va[str(d)] = [n - 1]
        tr = load_training_images(train_sets, fr_tr, 1, progress)
        va = load_training_images(train_sets, fr_va, 1, progress)
    spec = CropSpec(cfg.heat_min_area, cfg.min_area, cfg.heat_sigma, cfg.scale_prob, (cfg.scale_lo, cfg.scale_hi),
                    cfg.peak_box_radius, cfg.sliver_box_weight, cfg.sliver_neg_weight, cfg.gamma_jitter, cfg.noise_max)
    vrng = np.random.default_rng(cfg.seed + 1)
    w_tr, w_va = image_weights(tr, cfg.arm_fraction), image_weights(va, cfg.arm_fraction)
    vbatch = [torch.from_numpy(np.ascontiguousarray(a))
              for a in crop_batch(va, cfg.val_crops, cfg.crop, vrng, cfg.seed_fraction, augment=False, spec=spec,
                                  weights=w_va)]

    ck = out / "checkpoint.safetensors"
    if resume:
        if not ck.is_file():
            raise InputError("no checkpoint to resume from", ck)
        from seedmap.io.tensors import read_safetensors

        old = json.loads(read_safetensors(ck, "checkpoint")[1].get("config", "{}"))
        # the architecture comes from the checkpoint, not from the command line
        cfg.c1, cfg.c2 = int(old.get("c1", cfg.c1)), int(old.get("c2", cfg.c2))
    init = None
    if cfg.init_weights and not resume:
        init = onnx_weights(cfg.init_weights)
        if "stem.weight" not in init or "down.weight" not in init:
            raise InputError("has no SeedNet parameters (stem/down) to start from", cfg.init_weights)
        cfg.c1, cfg.c2 = int(init["stem.weight"].shape[0]), int(init["down.weight"].shape[0])
    net = build_net(cfg.c1, cfg.c2)
    if init is not None:
        sd = net.state_dict()
        missing = sorted(set(sd) - set(init))
        if missing:
            raise InputError(f"lacks parameters {', '.join(missing[:3])}", cfg.init_weights)
        net.load_state_dict({k: torch.from_numpy(init[k]) for k in sd})
    # created only once the inputs and --init weights have been read: a bad input leaves no empty folder behind
    out.mkdir(parents=True, exist_ok=True)
    opt = torch.optim.Adam(net.parameters(), cfg.lr)
    step, history = 0, []
    if resume:
        step, history = load_checkpoint(ck, net, opt)
        rng = np.random.default_rng([cfg.seed, step])

    def set_lr(s: int) -> None:
        # cosine decay to 3 % of lr over cfg.steps (a function of the step, so resume continues it)
        f = 0.5 * (1 + np.cos(np.pi * min(s, cfg.steps) / cfg.steps)) * 0.97 + 0.03
        for gr in opt.param_groups:
            gr["lr"] = cfg.lr * f

    t_cpu0 = time.process_time()
    t_wall0 = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.steps, initial=step, desc="train fast-cnn", unit="step")
    run = []

    def validate() -> float:
        net.eval()
        with torch.no_grad():
            v = losses(net(vbatch[0]), *vbatch[1:], iou_weight=cfg.iou_weight, center_weight=cfg.box_center_weight)
        net.train()
        return [float(a) for a in v]

    prev_cpu = sum(h.get("cpu_s", 0.0) for h in history[-1:]) if history else 0.0
    while step < cfg.steps:
        x, *tg = (torch.from_numpy(np.ascontiguousarray(a))
                  for a in crop_batch(tr, cfg.batch, cfg.crop, rng, cfg.seed_fraction, spec=spec, weights=w_tr))
        set_lr(step)
        loss, *_ = losses(net(x), *tg, iou_weight=cfg.iou_weight, center_weight=cfg.box_center_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        run.append(float(loss.detach()))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{np.mean(run[-50:]):.3f}")
        if step % cfg.val_every == 0 or step == cfg.steps:
            v = validate()
            history.append({"step": step, "train_loss": float(np.mean(run[-cfg.val_every:])), "val_loss": v[0],
                            "val_focal": v[1], "val_box_l1_px": v[2], "val_offset_l1_px": v[3], "val_box_1_giou": v[4],
                            "cpu_s": prev_cpu + time.process_time() - t_cpu0})
            save_checkpoint(ck, net, opt, step, cfg, history)
    if bar is not None:
        bar.close()
    from dataclasses import asdict

    info = {"train_sets": [str(d) for d in train_sets], "val_sets": [str(d) for d in (val_sets or [])],
            "config": asdict(cfg), "steps": step,
            "train_images": len(tr), "val_images": len(va),
            "cpu_s": prev_cpu + time.process_time() - t_cpu0,
            "wall_s_this_run": time.perf_counter() - t_wall0,
            "final": history[-1] if history else None}
    export_onnx(net, out / "fast_cnn.onnx", info)
    metrics = {**info, "history": history}
    atomic_write_text(out / "train_metrics.json", json.dumps(metrics, indent=1))
    return metrics
