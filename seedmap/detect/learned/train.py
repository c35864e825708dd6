"""Training of the Faster R-CNN detector and the pix2pix segmenter (CPU or GPU).

Both loops share the same machinery: a held-out split (a separate ``val`` source, or the last
``val_fraction`` of the images — the last frames of a sequence, so no near-duplicate neighbour of a
training frame is used for validation), deterministic per-step randomness
(``numpy.random.default_rng([seed, step])``, so a resumed run continues exactly), periodic
safetensors checkpoints with the optimiser state (``--resume``), a progress bar and a JSON
lines metrics log (``<kind>_metrics.jsonl``: step, split, losses, seconds per iteration, validation
metrics). The final weights (``<kind>.safetensors``) carry their architecture config; the segmenter
is also exported to ONNX (``segmenter.onnx``) for onnxruntime inference.
"""

from __future__ import annotations

import json
import time
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn

from seedmap import outputs
from seedmap.config import ConfigModel, config_to_yaml
from seedmap.detect.labels import LabelledImage
from seedmap.detect.learned.crops import CROP_PAD, crop_to_full, extract_crops
from seedmap.detect.learned.models import (
    DetectorArch,
    PatchDiscriminator,
    SegmenterArch,
    UNetGenerator,
    build_frcnn,
    set_input_scale,
)
from seedmap.detect.learned.weights import (
    load_into,
    optimizer_tensors,
    read_weights,
    restore_optimizer,
    save_weights,
)
from seedmap.errors import InputError
from seedmap.io.atomic import atomic_write_text
from seedmap.progress import Progress


#: detector: AdamW weight decay
DET_WEIGHT_DECAY = 1e-4
#: detector: validation crops
DET_VAL_CROPS = 8
#: detector: box score counted in the validation metrics
DET_VAL_SCORE = 0.5
#: segmenter: weight of the L1 term against the GAN term (pix2pix)
SEG_L1_WEIGHT = 100.0
#: segmenter: box jitter (fraction of the box size) imitating detector errors
SEG_BOX_JITTER = 0.15
#: segmenter: GT instances with fewer visible pixels are not trained on
SEG_MIN_AREA_PX = 6
#: segmenter: validation crops
SEG_VAL_CROPS = 256


class DetectorTrainConfig(ConfigModel):
    """How ``seedmap train detector`` trains the Faster R-CNN."""

    #: random seed of the initialisation and the batches
    seed: int = 0
    #: optimiser steps
    steps: int = 20000
    #: crops per step
    batch_size: int = 2
    #: AdamW learning rate
    lr: float = 1e-4
    #: training crops (px at the source resolution); the detector sees them upscaled by arch.upscale
    crop: int = 256
    #: proposals per image sampled for the box head's loss (torchvision's default 512; a quarter positive)
    box_batch: int = 512
    #: simulated datasets: seeds with fewer visible pixels are no training targets (10: the detectable seed at
    #: 1434 px width, what the scorer counts; slivers behind other seeds are half of all instances)
    min_gt_area: int = 3
    #: proposals whose best IoU with a seed lies in [box_bg_iou, 0.5) are left out of the box head's loss (0.5: none,
    #: torchvision's default); a tiny seed's box 1 px off is not background
    box_bg_iou: float = 0.5
    #: region proposals per image before / after the RPN's NMS while training (inference: the architecture's)
    rpn_pre_nms: int = 6000
    rpn_post_nms: int = 4000
    #: held-out share of the images when no --val source is given (the last ones)
    val_fraction: float = 0.2
    #: validate and write a resumable checkpoint every this many steps (and at the last)
    checkpoint_every: int = 500
    #: log the losses every this many steps
    log_every: int = 10
    #: torch threads (0 = torch's default)
    threads: int = 0
    arch: DetectorArch = DetectorArch()


class SegmenterTrainConfig(ConfigModel):
    """How ``seedmap train segmenter`` trains pix2pix (the ONNX export is written beside the weights)."""

    #: random seed of the initialisation and the batches
    seed: int = 0
    #: optimiser steps
    steps: int = 5000
    #: crops per step
    batch_size: int = 64
    #: Adam learning rate
    lr: float = 2e-4
    #: held-out share of the images when no --val source is given (the last ones)
    val_fraction: float = 0.2
    #: validate and write a resumable checkpoint every this many steps (and at the last)
    checkpoint_every: int = 250
    #: log the losses every this many steps
    log_every: int = 10
    #: torch threads (0 = torch's default)
    threads: int = 0
    arch: SegmenterArch = SegmenterArch()


def split_indices(n: int, val_fraction: float) -> tuple[list[int], list[int]]:
    """Training / held-out indices: the last ``val_fraction`` of the images are held out."""
    if n < 2 or val_fraction <= 0:
        return list(range(n)), []
    nv = min(max(1, int(round(n * val_fraction))), n - 1)
    return list(range(n - nv)), list(range(n - nv, n))


class _Cache:
    """A few decoded images in memory (PNG decoding of 1.5 MP costs ~20 ms)."""

    def __init__(self, source, size: int = 12) -> None:
        self.source = source
        self.size = size
        self.d: OrderedDict[int, LabelledImage] = OrderedDict()

    def __call__(self, i: int) -> LabelledImage:
        if i in self.d:
            self.d.move_to_end(i)
            return self.d[i]
        li = self.source[i]
        self.d[i] = li
        if len(self.d) > self.size:
            self.d.popitem(last=False)
        return li


def _to_tensor(img: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float().div_(255.0)


class _Run:
    """Output folder bookkeeping shared by both trainers."""

    def __init__(self, out: Path, kind: str, resume: bool, overwrite: bool,
                 inputs: Sequence[str | Path | None] = ()) -> None:
        self.out = Path(out)
        self.kind = kind
        outputs.check_resume_dir(self.out, "training", inputs, strict=False)  # never an input, a dataset, a result
        self.ckpt = self.out / f"{kind}_checkpoint.safetensors"
        self.final = self.out / f"{kind}.safetensors"
        self.log = self.out / f"{kind}_metrics.jsonl"
        if not resume and not overwrite and (self.ckpt.exists() or self.final.exists()):
            raise InputError(f"{kind} weights/checkpoint already exist here (pass --resume or --overwrite)",
                             self.out)
        if resume and not self.ckpt.exists():
            raise InputError(f"nothing to resume: {self.ckpt.name} not found", self.out)
        outputs.mark(self.out, "training")
        if not resume and self.log.exists():
            self.log.unlink()

    def truncate_log(self, step: int) -> None:
        if not self.log.exists():
            return
        keep = [ln for ln in self.log.read_text().splitlines() if ln.strip() and json.loads(ln)["step"] <= step]
        atomic_write_text(self.log, "".join(k + "\n" for k in keep))

    def write(self, rec: dict) -> None:
        with open(self.log, "a") as f:
            f.write(json.dumps(rec) + "\n")


# ================================================================================================
# detector
# ================================================================================================


def sample_detector_crop(li: LabelledImage, crop: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random ``crop x crop`` window (mostly around seeds) and the boxes inside it."""
    h, w = li.image.shape[:2]
    cw, ch = min(crop, w), min(crop, h)
    if len(li.boxes) and rng.random() < 0.85:
        b = li.boxes[rng.integers(len(li.boxes))]
        cx = (b[0] + b[2]) / 2 + rng.uniform(-0.4, 0.4) * cw
        cy = (b[1] + b[3]) / 2 + rng.uniform(-0.4, 0.4) * ch
        x0 = int(np.clip(round(cx - cw / 2), 0, w - cw))
        y0 = int(np.clip(round(cy - ch / 2), 0, h - ch))
    else:
        x0 = int(rng.integers(0, w - cw + 1))
        y0 = int(rng.integers(0, h - ch + 1))
    img = li.image[y0:y0 + ch, x0:x0 + cw]
    b = li.boxes - np.array([x0, y0, x0, y0], np.float64)
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    c = b.copy()
    c[:, [0, 2]] = np.clip(c[:, [0, 2]], 0, cw)
    c[:, [1, 3]] = np.clip(c[:, [1, 3]], 0, ch)
    carea = np.clip(c[:, 2] - c[:, 0], 0, None) * np.clip(c[:, 3] - c[:, 1], 0, None)
    keep = (carea >= 0.5 * np.maximum(area, 1e-9)) & (c[:, 2] - c[:, 0] >= 1) & (c[:, 3] - c[:, 1] >= 1)
    return img, c[keep]


def _augment(img: np.ndarray, boxes: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if rng.random() < 0.5:
        w = img.shape[1]
        img = img[:, ::-1]
        boxes = boxes.copy()
        boxes[:, [0, 2]] = w - boxes[:, [2, 0]]
    gain = rng.uniform(0.8, 1.2)
    img = np.clip(img.astype(np.float32) * gain, 0, 255).astype(np.uint8)
    return img, boxes


def detector_val_metrics(model: nn.Module, arch: DetectorArch, items: list[tuple[np.ndarray, np.ndarray]],
                         score_threshold: float) -> dict:
    """Loss and box F1 (IoU >= 0.5) on fixed held-out crops."""
    from seedmap.eval.detect_metrics import match_boxes

    tot_loss, tp, nd, ng = 0.0, 0, 0, 0
    with torch.no_grad():
        for img, boxes in items:
            set_input_scale(model, img.shape[0], img.shape[1], arch.upscale)
            x = [_to_tensor(img)]
            t = [{"boxes": torch.as_tensor(boxes, dtype=torch.float32).reshape(-1, 4),
                  "labels": torch.ones(len(boxes), dtype=torch.int64)}]
            model.train()
            tot_loss += float(sum(model(x, t).values()))
            model.eval()
            out = model(x)[0]
            keep = out["scores"].numpy() >= score_threshold
            db = out["boxes"].numpy()[keep]
            md, _, _ = match_boxes(db, boxes, 0.5)
            tp += len(md)
            nd += len(db)
            ng += len(boxes)
    p = tp / nd if nd else 0.0
    r = tp / ng if ng else 0.0
    return {"val_loss": tot_loss / max(len(items), 1), "val_precision": p, "val_recall": r,
            "val_f1": 2 * p * r / (p + r) if p + r > 0 else 0.0}


def _start_run(kind: str, cfg, source, val_source, out: Path, resume: bool, overwrite: bool,
               inputs: Sequence[str | Path | None] = ()):
    """Shared start of a training run: threads, run folder + config, train/validation split, torch seed."""
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    run = _Run(out, kind, resume, overwrite, inputs)
    atomic_write_text(run.out / f"{kind}_train_config.yaml", config_to_yaml(cfg))
    if val_source is None:
        tr_idx, va_idx = split_indices(len(source), cfg.val_fraction)
        val_source = source
    else:
        tr_idx, va_idx = list(range(len(source))), list(range(len(val_source)))
    if not tr_idx:
        raise InputError("no training images", getattr(source, "path", None))
    torch.manual_seed(cfg.seed)
    return run, tr_idx, va_idx, val_source


def train_detector(source, out: Path, cfg: DetectorTrainConfig | None = None, val_source=None,
                   resume: bool = False, overwrite: bool = False, progress: bool = True,
                   inputs: Sequence[str | Path | None] = ()) -> Path:
    """Train Faster R-CNN (VGG16 stride-8) on ``source`` (labelled images); returns the weights path."""
    cfg = cfg or DetectorTrainConfig()
    run, tr_idx, va_idx, val_source = _start_run("detector", cfg, source, val_source, out, resume, overwrite,
                                                      inputs)
    model = build_frcnn(cfg.arch)
    model.roi_heads.fg_bg_sampler.batch_size_per_image = cfg.box_batch
    from torchvision.models.detection._utils import Matcher

    model.roi_heads.proposal_matcher = Matcher(0.5, cfg.box_bg_iou, allow_low_quality_matches=False)
    model.rpn._pre_nms_top_n["training"] = cfg.rpn_pre_nms
    model.rpn._post_nms_top_n["training"] = cfg.rpn_post_nms
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=DET_WEIGHT_DECAY)
    start = 0
    if resume:
        t, meta = read_weights(run.ckpt, "detector")
        load_into(model, t, run.ckpt, "model.")
        restore_optimizer(opt, t, meta["optim"], "optim")
        start = int(json.loads(meta["info"])["step"])
        run.truncate_log(start)
    cache = _Cache(source)
    vcache = _Cache(val_source, 4)
    vrng = np.random.default_rng([cfg.seed, 10**9])
    val_items = []
    for k in range(DET_VAL_CROPS if va_idx else 0):
        li = vcache(va_idx[k % len(va_idx)])
        val_items.append(sample_detector_crop(li, cfg.crop, vrng))
    bar = Progress(cfg.steps, "train detector", "it", enabled=progress, initial=start)
    t_acc, n_acc = 0.0, 0
    last = {}
    for step in range(start + 1, cfg.steps + 1):
        rng = np.random.default_rng([cfg.seed, step])
        torch.manual_seed(cfg.seed * 1_000_003 + step)
        t0 = time.perf_counter()
        imgs, tgts = [], []
        for _ in range(cfg.batch_size):
            li = cache(tr_idx[int(rng.integers(len(tr_idx)))])
            img, boxes = _augment(*sample_detector_crop(li, cfg.crop, rng), rng)
            imgs.append(_to_tensor(img))
            tgts.append({"boxes": torch.as_tensor(boxes, dtype=torch.float32).reshape(-1, 4),
                         "labels": torch.ones(len(boxes), dtype=torch.int64)})
        set_input_scale(model, imgs[0].shape[1], imgs[0].shape[2], cfg.arch.upscale)
        model.train()
        losses = model(imgs, tgts)
        loss = sum(losses.values())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        dt = time.perf_counter() - t0
        t_acc += dt
        n_acc += 1
        last = {k: v.item() for k, v in losses.items()}
        bar.advance()
        bar.note(f"loss={loss.item():.3f}, s/it={dt:.2f}")
        if step % cfg.log_every == 0 or step == cfg.steps:
            run.write({"step": step, "split": "train", "loss": loss.item(), **last, "s_per_it": t_acc / n_acc})
            t_acc, n_acc = 0.0, 0
        if val_items and (step % cfg.checkpoint_every == 0 or step == cfg.steps):
            run.write({"step": step, "split": "val", **detector_val_metrics(model, cfg.arch, val_items,
                                                                            DET_VAL_SCORE)})
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            ot, ojson = optimizer_tensors(opt, "optim")
            mt = {f"model.{k}": v for k, v in model.state_dict().items()}
            save_weights(run.ckpt, "detector", cfg.arch.model_dump(), {**mt, **ot}, {"step": step},
                         {"optim": ojson})
    bar.close()
    save_weights(run.final, "detector", cfg.arch.model_dump(), model.state_dict(),
                 {"step": cfg.steps, "last_losses": last})
    return run.final


# ================================================================================================
# segmenter (pix2pix)
# ================================================================================================


def sample_segmenter_batch(li: LabelledImage, n: int, arch: SegmenterArch, rng: np.random.Generator,
                           jitter: float, min_area: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(crops, masks, windows, label_ids)`` of ``n`` random instances with jittered boxes."""
    ids = np.arange(1, len(li.boxes) + 1)
    b = li.boxes
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    ok = ids[area >= min_area]
    if len(ok) == 0:
        z = np.zeros((0, arch.crop_size, arch.crop_size), np.uint8)
        return np.zeros((0, arch.crop_size, arch.crop_size, 3), np.uint8), z, np.zeros((0, 3)), np.zeros(0, int)
    pick = rng.choice(ok, size=n, replace=len(ok) < n)
    bx = b[pick - 1].copy()
    wh = bx[:, 2:] - bx[:, :2]
    sh = rng.uniform(-jitter, jitter, (n, 2)) * wh
    sc = rng.uniform(1 - jitter, 1 + jitter, (n, 2))
    c = (bx[:, :2] + bx[:, 2:]) / 2 + sh
    half = wh * sc / 2
    jb = np.concatenate([c - half, c + half], axis=1)
    crops, wins, masks = extract_crops(li.image, jb, arch.crop_size, CROP_PAD, li.labels, pick)
    return crops, masks, wins, pick


def _seg_input(crops: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(crops).permute(0, 3, 1, 2).float().div_(127.5).sub_(1.0)


def _mask_target(masks: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(masks).float().unsqueeze(1).mul_(2.0).sub_(1.0)


def segmenter_val_metrics(gen: nn.Module, arch: SegmenterArch, batch: tuple) -> dict:
    """L1, mask IoU and the error of the fitted ellipse centre vs the GT mask's (full-image px)."""
    from seedmap.detect.ellipse import fit_ellipse_mask

    crops, masks, wins, _ = batch
    gen.eval()
    with torch.no_grad():
        pred = gen(_seg_input(crops))
    gen.train()
    tgt = _mask_target(masks)
    l1 = float((pred - tgt).abs().mean())
    pm = (pred[:, 0].numpy() > 0)
    gm = masks > 0
    inter = (pm & gm).sum(axis=(1, 2))
    union = (pm | gm).sum(axis=(1, 2))
    iou = float(np.mean(inter / np.maximum(union, 1)))
    errs = []
    for k in range(len(crops)):
        ep = fit_ellipse_mask(pm[k], "contour")
        eg = fit_ellipse_mask(gm[k], "contour")
        if ep is None or eg is None:
            continue
        a = crop_to_full(ep[:2], wins[k], arch.crop_size)
        g = crop_to_full(eg[:2], wins[k], arch.crop_size)
        errs.append(float(np.hypot(*(a - g))))
    return {"val_l1": l1, "val_mask_iou": iou,
            "val_centre_err_median_px": float(np.median(errs)) if errs else None,
            "val_empty_masks": int(len(crops) - len(errs))}


def export_segmenter_onnx(gen: nn.Module, arch: SegmenterArch, path: Path) -> Path:
    """ONNX export (dynamic batch) of the generator, for onnxruntime CPU inference."""
    from seedmap.detect.learned.export import export_segmenter_onnx as _export

    return _export(gen, arch, path)


def train_segmenter(source, out: Path, cfg: SegmenterTrainConfig | None = None, val_source=None,
                    resume: bool = False, overwrite: bool = False, progress: bool = True,
                    inputs: Sequence[str | Path | None] = ()) -> Path:
    """Train pix2pix (U-Net + PatchGAN, GAN + λ·L1) on box crops of GT instances."""
    cfg = cfg or SegmenterTrainConfig()
    run, tr_idx, va_idx, val_source = _start_run("segmenter", cfg, source, val_source, out, resume, overwrite,
                                                      inputs)
    arch = cfg.arch
    gen = UNetGenerator(arch.crop_size, arch.ngf)
    disc = PatchDiscriminator(arch.ndf)
    opt_g = torch.optim.Adam(gen.parameters(), lr=cfg.lr, betas=(0.5, 0.999))
    opt_d = torch.optim.Adam(disc.parameters(), lr=cfg.lr, betas=(0.5, 0.999))
    start = 0
    if resume:
        t, meta = read_weights(run.ckpt, "segmenter")
        load_into(gen, t, run.ckpt, "gen.")
        load_into(disc, t, run.ckpt, "disc.")
        restore_optimizer(opt_g, t, meta["optim_g"], "optg")
        restore_optimizer(opt_d, t, meta["optim_d"], "optd")
        start = int(json.loads(meta["info"])["step"])
        run.truncate_log(start)
    bce = nn.BCEWithLogitsLoss()
    cache = _Cache(source)
    val_batch = None
    if va_idx:
        vrng = np.random.default_rng([cfg.seed, 10**9])
        parts = [sample_segmenter_batch(val_source[va_idx[k % len(va_idx)]],
                                        max(1, SEG_VAL_CROPS // min(len(va_idx), 4)), arch, vrng, SEG_BOX_JITTER,
                                        SEG_MIN_AREA_PX) for k in range(min(len(va_idx), 4))]
        val_batch = tuple(np.concatenate([p[j] for p in parts]) for j in range(4))
    bar = Progress(cfg.steps, "train segmenter", "it", enabled=progress, initial=start)
    gen.train()
    disc.train()
    t_acc, n_acc = 0.0, 0
    for step in range(start + 1, cfg.steps + 1):
        rng = np.random.default_rng([cfg.seed, step])
        torch.manual_seed(cfg.seed * 1_000_003 + step)
        t0 = time.perf_counter()
        crops, masks = np.zeros((0,)), np.zeros((0,))
        for _ in range(8):  # an image without usable instances: draw another
            li = cache(tr_idx[int(rng.integers(len(tr_idx)))])
            crops, masks, _, _ = sample_segmenter_batch(li, cfg.batch_size, arch, rng, SEG_BOX_JITTER,
                                                        SEG_MIN_AREA_PX)
            if len(crops):
                break
        if not len(crops):
            raise InputError("training images hold no instances large enough for the segmenter")
        if rng.random() < 0.5:
            crops, masks = crops[:, :, ::-1].copy(), masks[:, :, ::-1].copy()
        x = _seg_input(crops)
        y = _mask_target(masks)
        fake = gen(x)
        # discriminator: real pairs -> 1, generated pairs -> 0
        opt_d.zero_grad(set_to_none=True)
        d_real = disc(x, y)
        d_fake = disc(x, fake.detach())
        loss_d = 0.5 * (bce(d_real, torch.ones_like(d_real)) + bce(d_fake, torch.zeros_like(d_fake)))
        loss_d.backward()
        opt_d.step()
        # generator: fool D + λ L1 to the GT mask
        opt_g.zero_grad(set_to_none=True)
        d_fake = disc(x, fake)
        loss_gan = bce(d_fake, torch.ones_like(d_fake))
        loss_l1 = (fake - y).abs().mean()
        loss_g = loss_gan + SEG_L1_WEIGHT * loss_l1
        loss_g.backward()
        opt_g.step()
        dt = time.perf_counter() - t0
        t_acc += dt
        n_acc += 1
        bar.advance()
        bar.note(f"l1={loss_l1.item():.3f}, d={loss_d.item():.3f}")
        if step % cfg.log_every == 0 or step == cfg.steps:
            run.write({"step": step, "split": "train", "loss_g": loss_g.item(), "loss_gan": loss_gan.item(),
                       "loss_l1": loss_l1.item(), "loss_d": loss_d.item(), "s_per_it": t_acc / n_acc})
            t_acc, n_acc = 0.0, 0
        if val_batch is not None and len(val_batch[0]) and (step % cfg.checkpoint_every == 0 or step == cfg.steps):
            run.write({"step": step, "split": "val", **segmenter_val_metrics(gen, arch, val_batch)})
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            og, gj = optimizer_tensors(opt_g, "optg")
            od, dj = optimizer_tensors(opt_d, "optd")
            t = {**{f"gen.{k}": v for k, v in gen.state_dict().items()},
                 **{f"disc.{k}": v for k, v in disc.state_dict().items()}, **og, **od}
            save_weights(run.ckpt, "segmenter", arch.model_dump(), t, {"step": step},
                         {"optim_g": gj, "optim_d": dj})
    bar.close()
    save_weights(run.final, "segmenter", arch.model_dump(), gen.state_dict(), {"step": cfg.steps})
    export_segmenter_onnx(gen, arch, run.out / "segmenter.onnx")  # onnxruntime inference
    return run.final

