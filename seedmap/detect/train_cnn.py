"""Training of the ``fast`` detector's small CNN (torch on CPU) and its export to ONNX.

The network (:mod:`seedmap.detect.cnn_net`) is CenterNet-style and fully convolutional: for every full-resolution
pixel it predicts a seed-centre logit, the four distances (px) from that pixel to the seed's box edges (left, top,
right, bottom; GT convention x0/y0 inclusive, x1/y1 exclusive) and the sub-pixel offset (px) from the pixel to the
seed's keypoint.

Targets come from a simulated dataset's ground truth (``gt/masks`` + ``gt/instances``) or from a user's COCO
labels (boxes, with or without masks: :mod:`seedmap.detect.cnn_targets`), made per crop by :func:`crop_batch`
(:class:`CropSpec`):

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
  images, where a network trained without it fired twice on a third of the seeds); for ``off_scale_prob`` of the
  crops a rescale far off the network's seed size (0.3-0.5x or 2.2-3.2x) with every seed background.

Training recipes of the shipped networks and the runs that were measured: docs/method/detection.md.

Inference does not need torch: :func:`export_onnx` writes an ONNX graph that
:mod:`seedmap.detect.cnn` runs in onnxruntime. Weights/checkpoints are safetensors.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seedmap.detect.autoscale import SCORE_SIZE
from seedmap.detect.cnn import network_scale_cue, network_score_size
from seedmap.detect.cnn_net import build_net, net_channels
from seedmap.detect.cnn_targets import TrainImage, coco_image_targets, image_targets, is_coco_file, pad_to
from seedmap.detect.labels import CocoSource
from seedmap.errors import InputError
from seedmap.progress import Progress, track

# ------------------------------------------------------------------------------------------------
# training data
# ------------------------------------------------------------------------------------------------


def is_arm_scan(dataset: str | Path) -> bool:
    """True for a simulated arm scan (``seedmap simulate panicle``: close-up panicle views, seeds ~2x the
    area of the field images' seeds, flash-saturated), recognised by its ``arm.yaml``."""
    return (Path(dataset) / "arm.yaml").is_file()


def load_training_images(datasets: list[str | Path], frames: dict | None = None, min_area: int = 1,
                         progress: bool = False, images_root: str | Path | None = None,
                         coco_scale: float = 1.0, image_scales: dict | None = None) -> list[TrainImage]:
    """Every (frame, camera) image of the simulated ``datasets`` with its targets (``arm`` set for arm scans); a
    ``.json`` entry is a COCO label file, its images under ``images_root`` (default: beside it), every image one
    item (:func:`seedmap.detect.cnn_targets.labelled_targets`) resized by ``image_scales[(str(file), index)]``, else
    ``coco_scale``. ``frames``: ``{str(dataset): indices}``."""
    from seedmap.io.images import read_rgb
    from seedmap.io.seedmap_dataset import SeedmapDataset

    def sim_item(ds: SeedmapDataset, arm: bool, i: int, cam: str) -> TrainImage:
        ti = image_targets(read_rgb(ds.image_path(i, cam)), ds.gt_label_image(i, cam), ds.gt_instances(i, cam),
                           min_area)
        ti.arm = arm
        return ti

    items = []
    for d in datasets:
        if is_coco_file(d):
            src = CocoSource(d, images_root)
            items += [(coco_image_targets, src, k, (image_scales or {}).get((str(d), k), coco_scale))
                      for k in (frames or {}).get(str(d), range(len(src)))]
            continue
        ds = SeedmapDataset(d)
        if not ds.has_gt:
            raise InputError("dataset has no ground truth (gt/instances/) to train on", d)
        fr = (frames or {}).get(str(d), range(len(ds)))
        arm = is_arm_scan(ds.root)
        items += [(sim_item, ds, arm, i, cam) for i in fr for cam in ("left", "right")]
    return [it[0](*it[1:]) for it in track(items, "cnn targets", "img", enabled=progress)]


def training_set_size(dataset: str | Path, images_root: str | Path | None = None) -> int:
    """Frames of a simulated dataset, or images of a COCO label file (``.json``)."""
    from seedmap.io.seedmap_dataset import SeedmapDataset

    return len(CocoSource(dataset, images_root)) if is_coco_file(dataset) else len(SeedmapDataset(dataset))


def image_weights(images: list[TrainImage], arm_fraction: float | None, replay_fraction: float = 0.0
                  ) -> np.ndarray | None:
    """Sampling probabilities of the images so that ``arm_fraction`` of the crops come from arm scans and
    ``replay_fraction`` from rehearsal images (a kind absent, or None / 0: every image alike; None = all alike)."""
    rep = np.array([im.replay for im in images], bool)
    w = None
    if arm_fraction is not None:
        arm = np.array([im.arm for im in images], bool) & ~rep
        if arm.any() and (~arm & ~rep).any():
            w = np.where(arm, arm_fraction / arm.sum(), (1.0 - arm_fraction) / (~arm & ~rep).sum()) * ~rep
    if replay_fraction <= 0 or not rep.any() or rep.all():
        return w
    own = (np.where(rep, 0.0, 1.0 / (~rep).sum()) if w is None else w / w.sum())
    return own * (1.0 - replay_fraction) + np.where(rep, replay_fraction / rep.sum(), 0.0)


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
    #: fraction of the crops shown far off the network's seed size, by a factor drawn uniformly from one of
    #: ``off_scale_range`` (seeds much smaller or much larger), with every seed in them background: the network
    #: learns to fire on seeds of its own size only, which the ``score`` seed-size cue reads
    off_scale_prob: float = 0.0
    off_scale_range: tuple[tuple[float, float], tuple[float, float]] = ((0.3, 0.5), (2.2, 3.2))


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
        s, off = 1.0, False
        if augment and sp.off_scale_prob > 0 and rng.random() < sp.off_scale_prob:
            s, off = float(rng.uniform(*sp.off_scale_range[int(rng.integers(2))])), True
        elif augment and sp.scale_prob > 0 and rng.random() < sp.scale_prob:
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
        wgt = m.astype(np.float32)
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
        if off:  # seeds far off the network's size: background
            heat[:], reg[:], ign[:], wgt[:], m[:] = 0.0, 0.0, 0.0, 0.0, False
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
        X[k] = rgb.transpose(2, 0, 1)
        H[k] = heat
        R[k] = reg
        M[k] = wgt
        IG[k] = ign
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


def losses(out, heat, reg, mask, ignore=None, iou_weight: float = 0.0):  # noqa: ANN001, ANN201 - torch tensors
    """``(total, focal, box L1, offset L1, box 1-GIoU)``.

    CenterNet's penalty-reduced focal loss (``ignore`` pixels skipped), masked L1 of the four box
    edges and the keypoint offset, plus ``iou_weight`` x (1 - GIoU) of the box the edges describe:
    on a 5 px seed a 1 px edge error costs half the IoU, which the L1 loss does not know.
    """
    import torch

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
    #: channels at full / half / quarter resolution (8 / 16 / 0: the shipped field and arm networks; c3 = 0: no
    #: quarter-resolution context stage)
    c1: int = 8
    c2: int = 16
    c3: int = 0
    #: training from scratch: the seed size (px) the network operates at, labelled images resized to it (None: the
    #: field network's); a fine-tune keeps its starting network's
    seed_px: float | None = None
    #: GT instances below this many visible pixels are background; from it up to heat_min_area
    #: they are ignored by the heatmap loss (slivers: CropSpec)
    min_area: int = 4
    heat_min_area: float = 10.0
    heat_sigma: float = 1.0
    seed_fraction: float = 0.75
    #: weight of the box (1 - GIoU) loss next to the L1 edge loss (0 = L1 only)
    iou_weight: float = 1.0
    #: fraction of the crops taken from arm-scan datasets (datasets with arm.yaml) when both kinds are given
    #: (None = every image alike)
    arm_fraction: float | None = None
    #: fraction of crops rescaled by U(scale_lo, scale_hi) (larger seeds of close-up arm scans)
    scale_prob: float = 0.5
    scale_lo: float = 0.8
    scale_hi: float = 1.7
    #: fraction of crops shown at 0.3-0.5x or 2.2-3.2x with their seeds as background (CropSpec.off_scale_prob)
    off_scale: float = 0.0
    #: fraction of the crops from rehearsal photos (seedmap.detect.replay) when training on COCO labels (0 = none)
    replay: float = 0.0
    #: start from the weights of this fast_cnn ONNX file (fine-tuning; its channels replace c1/c2) instead of a
    #: random initialisation
    init_weights: str | None = None
    #: evaluate the held-out loss every this many steps (and write the checkpoint)
    val_every: int = 250
    val_crops: int = 96
    #: COCO labels without held-out files: this fraction of the labelled images (at least one) is held out
    val_fraction: float = 0.2
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

    from seedmap.detect.runtime import load_session

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
              cfg: CnnTrainConfig | None = None, resume: bool = False, progress: bool = True,
              images_root: str | Path | None = None) -> dict:
    """Train :class:`SeedNet` on simulated ranges or COCO label files (``.json``, images under ``images_root``);
    write ``out/fast_cnn.onnx`` + checkpoint + metrics.

    Held-out split: ``val_sets`` when given, else the last frame of every simulated training set (its left and
    right image) and a seeded ``cfg.val_fraction`` of a COCO file's labelled images
    (:mod:`seedmap.detect.train_validate`). COCO images are resized so that their labels' median seed size becomes
    the seed size of the starting network (``cfg.init_weights``' ``seed_px``, else the shipped field network's); the
    exported network records ``seed_px`` (what it expects in its input) and ``images_seed_px`` (the labels' size in
    the user's images). ``resume`` continues from ``out/checkpoint.safetensors``. Returns the metrics dict (also
    written to ``out/train_metrics.json``), with the held-out box F1 of the trained and the starting network.
    """
    import torch

    from seedmap.io.atomic import atomic_write_text

    cfg = cfg or CnnTrainConfig()
    out = Path(out)
    torch.set_num_threads(max(1, int(cfg.threads)))
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    from seedmap.detect.config import TRAINED_SEED_PX
    from seedmap.detect.train_validate import calibrate_seed_px, heldout_report, network_seed_px, plan_training

    init_path = cfg.init_weights if cfg.init_weights else None
    net_seed_px = (float(cfg.seed_px) if cfg.seed_px and not init_path
                   else network_seed_px(init_path, TRAINED_SEED_PX["field"]))
    plan = plan_training(list(train_sets), list(val_sets or []), images_root, cfg.val_fraction, cfg.seed,
                         net_seed_px)
    tr = load_training_images(train_sets, plan.train, 1, progress, images_root, plan.scale, plan.image_scales)
    va = load_training_images(val_sets or train_sets, plan.val, 1, progress, images_root, plan.scale,
                              plan.image_scales)
    n_replay = 0
    if cfg.replay > 0 and any(is_coco_file(d) for d in train_sets):
        from seedmap.detect.replay import replay_images

        rep = replay_images(cfg.seed, net_seed_px, progress)
        tr, n_replay = tr + rep, len(rep)
    tr, va = [pad_to(im, cfg.crop) for im in tr], [pad_to(im, cfg.crop) for im in va]
    spec = CropSpec(cfg.heat_min_area, cfg.min_area, cfg.heat_sigma, cfg.scale_prob, (cfg.scale_lo, cfg.scale_hi),
                    cfg.off_scale)
    vrng = np.random.default_rng(cfg.seed + 1)
    w_tr, w_va = image_weights(tr, cfg.arm_fraction, cfg.replay), image_weights(va, cfg.arm_fraction)
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
        cfg.c1, cfg.c2, cfg.c3 = int(old.get("c1", cfg.c1)), int(old.get("c2", cfg.c2)), int(old.get("c3", 0))
    init = None
    if cfg.init_weights and not resume:
        init = onnx_weights(cfg.init_weights)
        if "stem.weight" not in init or "down.weight" not in init:
            raise InputError("has no SeedNet parameters (stem/down) to start from", cfg.init_weights)
        cfg.c1, cfg.c2, cfg.c3 = net_channels(init)
    net = build_net(cfg.c1, cfg.c2, cfg.c3)
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
    bar = Progress(cfg.steps, "train fast-cnn", "step", enabled=progress, initial=step)
    run = []

    def validate() -> float:
        net.eval()
        with torch.no_grad():
            v = losses(net(vbatch[0]), *vbatch[1:], iou_weight=cfg.iou_weight)
        net.train()
        return [float(a) for a in v]

    prev_cpu = sum(h.get("cpu_s", 0.0) for h in history[-1:]) if history else 0.0
    initial_val_loss = validate()[0] if step == 0 else None
    while step < cfg.steps:
        x, *tg = (torch.from_numpy(np.ascontiguousarray(a))
                  for a in crop_batch(tr, cfg.batch, cfg.crop, rng, cfg.seed_fraction, spec=spec, weights=w_tr))
        set_lr(step)
        loss, *_ = losses(net(x), *tg, iou_weight=cfg.iou_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        run.append(float(loss.detach()))
        bar.advance()
        bar.note(f"loss={np.mean(run[-50:]):.3f}")
        if step % cfg.val_every == 0 or step == cfg.steps:
            v = validate()
            history.append({"step": step, "train_loss": float(np.mean(run[-cfg.val_every:])), "val_loss": v[0],
                            "val_focal": v[1], "val_box_l1_px": v[2], "val_offset_l1_px": v[3], "val_box_1_giou": v[4],
                            "cpu_s": prev_cpu + time.process_time() - t_cpu0})
            save_checkpoint(ck, net, opt, step, cfg, history)
    bar.close()
    from dataclasses import asdict

    info = {"train_sets": [str(d) for d in train_sets], "val_sets": [str(d) for d in (val_sets or [])],
            "config": asdict(cfg), "steps": step,
            "train_images": len(tr) - n_replay, "replay_images": n_replay, "val_images": len(va),
            "initial_val_loss": initial_val_loss,
            "cpu_s": prev_cpu + time.process_time() - t_cpu0,
            "wall_s_this_run": time.perf_counter() - t_wall0,
            "final": history[-1] if history else None}
    if not init_path and cfg.off_scale > 0:  # it fires on seeds of its own size only: read the size off the scores
        info["scale_cue"], info["score_size"] = "score", SCORE_SIZE
    if init_path:  # a fine-tuned network reads its seed size off the ladder as its starting network does
        from seedmap.detect.runtime import network_info

        init_info = network_info(init_path)
        info["scale_cue"] = network_scale_cue(init_path, init_info)
        if info["scale_cue"] == "score":
            info["score_size"] = network_score_size(init_path, init_info)
    if plan.images_seed_px is not None:
        # the network expects seeds of seed_px in its input; the user's images show them at images_seed_px (one
        # size: the network runs at that fixed scale) or at several (it estimates each image's scale)
        info["seed_px"] = net_seed_px
        info["labels_seed_px"] = plan.images_seed_px
        if plan.fixed_scale:
            info["images_seed_px"] = plan.images_seed_px
            info["labels_scale"] = plan.scale
    onnx_path = export_onnx(net, out / "fast_cnn.onnx", info)
    if not init_path and info.get("scale_cue") == "score" and "seed_px" in info:
        # from scratch: declare the seed size at which its estimates centre on the held-out labels
        cal = calibrate_seed_px(onnx_path, plan.heldout, cfg.threads)
        if cal is not None:
            info["trained_seed_px"], info["seed_px"], info["seed_px_calibration"] = net_seed_px, cal["seed_px"], cal
            onnx_path = export_onnx(net, out / "fast_cnn.onnx", info)
    metrics = {**info, **heldout_report(onnx_path, init_path, plan, cfg.threads, progress), "history": history}
    atomic_write_text(out / "train_metrics.json", json.dumps(metrics, indent=1))
    return metrics
