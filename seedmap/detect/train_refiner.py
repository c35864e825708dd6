"""Training and validation of the fast CNN's refiner (``seedmap train cnn-refiner``; torch on CPU).

Training targets (:func:`peak_targets`): a peak belongs to the GT instance under its pixel (else under its keypoint);
it is a seed when that instance is detectable (>= the detectable-seed size, as ``seedmap eval detect`` counts) and
the peak is the instance's strongest -- second peaks and slivers are negatives; every peak on an instance learns
that instance's box.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seedmap.detect.cnn import CnnDetector
from seedmap.detect.cnn_refine import PATCH_R, SCALE_PX, file_sha256, peak_features
from seedmap.detect.config import CnnConfig, min_visible_seed_px
from seedmap.detect.labels import SeedmapSource, open_labelled
from seedmap.detect.mlp import KIND, Mlp
from seedmap.errors import InputError
from seedmap.eval.detect_metrics import evaluate_detections, prf
from seedmap.io.atomic import atomic_write_bytes
from seedmap.io.seedmap_dataset import Instances, SeedmapDataset
from seedmap.progress import track


def peak_targets(x: np.ndarray, y: np.ndarray, raw: np.ndarray, labels: np.ndarray, inst, min_gt_area: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(is_seed (N,) bool, GT box edges (N, 4) / 5 px (NaN where no instance), has_box (N,) bool)`` of the
    peaks, from the GT label image and its instance table (``seedmap.io.seedmap_dataset.Instances``)."""
    n = len(x)
    lut = np.full(int(max(labels.max(initial=0), inst.label.max(initial=0))) + 1, -1, np.int64)
    lut[inst.label.astype(np.int64)] = np.arange(len(inst))
    h, w = labels.shape
    xi = np.clip(np.asarray(x, np.int64), 0, w - 1)
    yi = np.clip(np.asarray(y, np.int64), 0, h - 1)
    a = lut[labels[yi, xi]]
    kx = np.clip(np.round(x + raw[:, 5]).astype(np.int64), 0, w - 1)
    ky = np.clip(np.round(y + raw[:, 6]).astype(np.int64), 0, h - 1)
    a = np.where(a >= 0, a, lut[labels[ky, kx]])
    has = a >= 0
    box = np.full((n, 4), np.nan, np.float32)
    bx = inst.boxes[a[has]]
    box[has] = np.c_[x[has] - bx[:, 0], y[has] - bx[:, 1], bx[:, 2] - x[has], bx[:, 3] - y[has]] / SCALE_PX
    seed = has & (inst.area[np.maximum(a, 0)] >= min_gt_area)
    # one seed per instance: its strongest peak; the others are second peaks (negatives)
    order = np.argsort(-raw[:, 0], kind="stable")
    first = np.zeros(len(inst) + 1, bool)
    for k in order[seed[order]]:
        if first[a[k]]:
            seed[k] = False
        else:
            first[a[k]] = True
    return seed, box, has


def training_data(datasets: list[str | Path], detector, patch_r: int = PATCH_R,  # noqa: ANN001 - CnnDetector
                  progress: bool = False, min_gt_area: float | None = None, images_root: str | Path | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(features, GT box edges / 5 px, is_seed, has_box)`` of the ``detector``'s peaks (at its threshold) on
    every labelled image of ``datasets``: simulated dataset folders (left and right images, GT masks) or COCO
    ``.json`` files with instance masks (polygon or RLE; images under ``images_root``, default beside the file). A
    seed has >= ``min_gt_area`` visible pixels (None: the detectable-seed size at the image width, as
    ``seedmap eval detect``)."""
    sources = [SeedmapSource(p, min_area_px=1) if Path(p).is_dir() else open_labelled(p, images_root)
               for p in datasets]
    items = [(src, p, k) for src, p in zip(sources, datasets) for k in range(len(src))]
    it = track(items, "cnn-refiner samples", "img", enabled=progress)
    fs, bs, ss, hs = [], [], [], []
    for src, p, k in it:
        li = src[k]
        n = len(li.boxes)
        area = np.bincount(li.labels.ravel(), minlength=n + 1)[1:n + 1]
        if n and not area.any():
            raise InputError(f"image {li.name}: instances without masks (the refiner learns from instance masks: "
                             "COCO polygon or RLE segmentations)", p)
        inst = Instances(label=np.arange(1, n + 1), seed_id=np.arange(n), panicle_id=np.zeros(n, np.int64),
                         boxes=np.asarray(li.boxes, np.float64), center_uv=np.zeros((n, 2)), area=area,
                         center_visible=np.ones(n, bool))
        pk = detector.peaks(li.image)
        fs.append(peak_features(li.image, pk.x, pk.y, pk.raw, patch_r).astype(np.float32))
        s, b, h = peak_targets(pk.x, pk.y, pk.raw, li.labels, inst,
                               min_gt_area if min_gt_area is not None else min_visible_seed_px(li.image.shape[1]))
        bs.append(b)
        ss.append(s)
        hs.append(h)
    x = np.empty((sum(len(f) for f in fs), fs[0].shape[1] if fs else 0), np.float32)
    k0 = 0
    while fs:  # one copy at a time: the features can be gigabytes
        f = fs.pop(0)
        x[k0:k0 + len(f)] = f
        k0 += len(f)
    return x, np.concatenate(bs), np.concatenate(ss), np.concatenate(hs)


@dataclass
class CnnRefinerTrainConfig:
    """How ``seedmap train cnn-refiner`` trains (the defaults trained the shipped refiner)."""

    #: the network's peak threshold that makes the candidates
    candidates: float = 0.25
    patch_r: int = PATCH_R
    hidden: tuple[int, ...] = (128, 64)
    steps: int = 30000
    batch: int = 512
    lr: float = 2e-3
    seed: int = 0
    #: visible pixels a GT seed needs to be a positive (None: the detectable-seed size at the dataset's width)
    min_gt_area: float | None = None


def train_cnn_refiner(datasets: list[str | Path], out: str | Path, cfg: CnnRefinerTrainConfig | None = None,
                      weights: str | Path | None = None, progress: bool = True,
                      images_root: str | Path | None = None) -> Path:
    """Train a refiner for the network ``weights`` (default: the shipped field network) on ``datasets`` (simulated
    folders or COCO files, :func:`training_data`); write its weights and config to ``out`` (``.safetensors``) and
    the inference graph beside it (same name, ``.onnx``), both atomically. Returns the ``.onnx`` path."""
    cfg = cfg or CnnRefinerTrainConfig()
    det = CnnDetector(CnnConfig(threshold=cfg.candidates, refiner="none"), weights=weights)
    if det.info.get("images_seed_px") and any(Path(d).suffix.lower() == ".json" for d in datasets):
        # the samples are taken at the labels' own resolution; this network sees the images resized
        raise InputError(f"was fine-tuned on labels of {float(det.info['images_seed_px']):.3g}-px seeds and runs on "
                         "resized images; a refiner is trained on simulated datasets at the network's own size only "
                         "(run the fine-tuned network without one: cnn.refiner=none)", det.path)
    t0 = time.process_time()
    x, box, seed, has = training_data(datasets, det, cfg.patch_r, progress, cfg.min_gt_area, images_root)
    if len(x) == 0:
        raise InputError("no CNN peaks in the training datasets", datasets[0])
    n_patch = 3 * (2 * cfg.patch_r + 1) ** 2
    seed_fraction, n = float(seed.mean()), len(x)
    mlp = _fit(x, box, seed, cfg, n_patch, has, progress)
    mlp.patch_r = cfg.patch_r
    mlp.info = {**(mlp.info or {}), "cnn_weights": Path(det.path).name, "cnn_sha256": file_sha256(det.path),
                "candidates": cfg.candidates, "hidden": list(cfg.hidden), "samples": n,
                "seed_fraction": seed_fraction, "datasets": [str(d) for d in datasets],
                "cpu_s": time.process_time() - t0, "config": {**cfg.__dict__, "hidden": list(cfg.hidden)}}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    mlp.save(out)
    onnx_path = Path(out).with_suffix(".onnx")
    atomic_write_bytes(onnx_path, mlp.onnx_bytes())
    return onnx_path


def _fit(x: np.ndarray, box: np.ndarray, seed: np.ndarray, cfg: CnnRefinerTrainConfig, n_patch: int,
         has: np.ndarray, progress: bool) -> Mlp:
    """The MLP on standardised features (``x`` is scaled in place); the box term weighs 20 x the mean smooth-L1 in
    units of 5 px, i.e. the sum over the four edges in pixels (beta 0.5 px)."""
    return train_mlp(x, box, seed, steps=cfg.steps, hidden=cfg.hidden, lr=cfg.lr, batch=cfg.batch, seed=cfg.seed,
                         box_cols=slice(n_patch + 1, n_patch + 5), has_box=has, standardize=True, cosine=True,
                         beta=0.1, box_weight=20.0, kind=KIND, progress=progress)


def validate(datasets: list[str | Path], refiner: str | Path, thresholds: list[float],
             weights: str | Path | None = None, progress: bool = True) -> dict:
    """Box F1 (``seedmap eval detect``'s rule) of the network with the refiner at each refined-score threshold, and
    of the plain network at its own 0.45, per dataset and pooled (summed counts)."""
    runs = {"plain": CnnDetector(CnnConfig(refiner="none"), weights=weights),
            "refined": CnnDetector(CnnConfig(refiner=str(refiner), refine_threshold=min(thresholds)), weights=weights)}
    res: dict = {"thresholds": list(thresholds), "datasets": {}, "pooled": {}}
    tot: dict = {}
    for p in datasets:
        ds = SeedmapDataset(p)
        mga = min_visible_seed_px(ds.calib.width)
        frames = track(range(len(ds)), f"validate {Path(p).name}", "frame", enabled=progress)
        dets: dict = {k: {} for k in runs}
        for i in frames:
            fr = ds[i]
            for k, det in runs.items():
                dets[k][(i, "left")], dets[k][(i, "right")] = det.detect(fr.left), det.detect(fr.right)
        per = {}
        for k, ts in (("plain", [0.0]), ("refined", thresholds)):
            for t in ts:
                m = evaluate_detections(ds, {f: d.subset(d.scores >= t) for f, d in dets[k].items()}, 0.5, "greedy",
                                        mga)
                key = "plain" if k == "plain" else f"refined@{t:g}"
                per[key] = {"precision": m.precision, "recall": m.recall, "f1": m.f1, "kp_median_px": m.kp_err_median_px}
                a = tot.setdefault(key, [0, 0, 0])
                a[0] += m.tp
                a[1] += m.n_det
                a[2] += m.n_gt
        res["datasets"][str(p)] = per
    for key, (tp, nd, ng) in tot.items():
        pr, rc, f1 = prf(tp, nd, ng)
        res["pooled"][key] = {"precision": pr, "recall": rc, "f1": f1}
    return res


def train_mlp(x: np.ndarray, y: np.ndarray, is_seed: np.ndarray, steps: int = 3000, hidden: tuple = (96, 64),
                  lr: float = 2e-3, batch: int = 512, seed: int = 0, box_cols: slice | None = None,
                  has_box: np.ndarray | None = None, standardize: bool = False, cosine: bool = False,
                  beta: float = 0.1, box_weight: float = 1.0, kind: str = KIND,
                  progress: bool = False) -> Mlp:
    """Fit the MLP (torch, CPU): BCE on ``is_seed`` + smooth-L1 (``beta``) of (output + the candidate's own box
    ``x[:, box_cols]``) against ``y`` on the rows of ``has_box`` (default: the seeds), weighted ``box_weight``.

    ``box_cols`` defaults to the four columns after a 1-channel patch. ``standardize``:
    inputs scaled to zero mean and unit variance for training (``x`` is modified in place to save memory) and the
    scaling folded into the first layer, so the saved MLP takes raw features. ``cosine``: the learning rate decays
    to 3 % over the steps."""
    import torch

    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    dims = [x.shape[1], *hidden, 5]
    mods: list = []
    for k in range(len(dims) - 1):
        mods.append(torch.nn.Linear(dims[k], dims[k + 1]))
        if k < len(dims) - 2:
            mods.append(torch.nn.ReLU())
    net = torch.nn.Sequential(*mods)
    opt = torch.optim.Adam(net.parameters(), lr)
    n_patch = x.shape[1] - 9
    box_cols = box_cols if box_cols is not None else slice(n_patch, n_patch + 4)
    x = np.ascontiguousarray(x, np.float32)
    rb = torch.from_numpy(x[:, box_cols].copy())  # the candidates' own boxes, unscaled
    mu = sd = None
    if standardize:
        # in blocks and in place: the features can be gigabytes (a float64 copy would double them)
        s1 = np.zeros(x.shape[1], np.float64)
        s2 = np.zeros(x.shape[1], np.float64)
        for k0 in range(0, len(x), 65536):
            blk = x[k0:k0 + 65536].astype(np.float64)
            s1 += blk.sum(axis=0)
            s2 += (blk * blk).sum(axis=0)
        mu = (s1 / len(x)).astype(np.float32)
        sd = (np.sqrt(np.maximum(s2 / len(x) - (s1 / len(x)) ** 2, 0.0)) + 1e-3).astype(np.float32)
        for k0 in range(0, len(x), 65536):
            x[k0:k0 + 65536] -= mu
            x[k0:k0 + 65536] /= sd
    X = torch.from_numpy(x)
    Y = torch.from_numpy(np.nan_to_num(np.ascontiguousarray(y, np.float32)))
    S = torch.from_numpy(np.asarray(is_seed, bool))
    B = torch.from_numpy(np.asarray(is_seed if has_box is None else has_box, bool))
    sched = (torch.optim.lr_scheduler.LambdaLR(opt, lambda k: 0.03 + 0.97 * 0.5 * (1 + np.cos(np.pi * k / steps)))
             if cosine else None)
    losses = []
    it = track(range(steps), "refiner", "step", enabled=progress)
    for _ in it:
        b = torch.randint(0, len(X), (min(batch, len(X)),), generator=g)
        o = net(X[b])
        loss = torch.nn.functional.binary_cross_entropy_with_logits(o[:, 4], S[b].float())
        m = B[b]
        if m.any():
            loss = loss + box_weight * torch.nn.functional.smooth_l1_loss(o[m, :4] + rb[b][m], Y[b][m], beta=beta)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if sched is not None:
            sched.step()
        losses.append(loss.item())
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    layers = [(m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy()) for m in lin]
    if standardize:  # (x - mu) / sd @ w + b  =  x @ (w / sd) + (b - (mu / sd) @ w)
        w0, b0 = layers[0]
        layers[0] = ((w0 / sd[:, None]).astype(np.float32), (b0 - (mu / sd) @ w0).astype(np.float32))
    r = int(round((np.sqrt(n_patch) - 1) / 2))
    return Mlp(layers, r, {"steps": steps, "samples": int(len(X)), "seed_fraction": float(S.float().mean()),
                               "loss_first_100": float(np.mean(losses[:100])),
                               "loss_last_100": float(np.mean(losses[-100:]))}, kind)
