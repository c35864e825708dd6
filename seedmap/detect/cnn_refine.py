"""A learned second stage for the ``fast`` CNN: every heatmap peak is rescored and its box corrected (session 12).

Why: the CNN's errors on the row ranges are mostly boxes and second peaks, not missed seeds. On validation
det_s36 (session 7 buckets) 1,333 false positives sat on a seed that no detection matched (box IoU < 0.5),
1,693 on slivers below the detectable size whose box was too large to be ignored, and 885 were second peaks on
one seed. A peak's own logit cannot tell these apart: it does not see the neighbouring peak nor, with 8/16
channels, enough of the seed's outline.

Per peak (the shipped network at the candidate threshold ``cnn.refine_candidates``, below its own 0.45), a small
MLP (:class:`seedmap.detect.refine.Refiner`, kind ``cnn_refiner``) reads

* the RGB patch of (2 ``patch_r`` + 1)^2 pixels around the peak pixel (/ 255),
* the network's raw predictions there: heat logit, box edges (/ 5 px), keypoint offset (px),
* the strongest other peak within 8 px whose logit is higher: its offset (/ 5 px), logit difference and box size
  (/ 5 px; zeros and a 0 flag when there is none), and the number of peaks within 4 and 8 px,

and predicts a new seed logit and residuals (/ 5 px) added to the four box edges. The keypoint (peak + offset)
is unchanged. Training targets (:func:`peak_targets`, simulated datasets): a peak belongs to the GT instance
under its pixel (else under its keypoint); it is a seed when that instance is detectable (>= the
detectable-seed size, as ``seedmap eval detect`` counts) and the peak is the instance's strongest -- second
peaks and slivers are negatives; every peak on an instance (slivers included: a matching box makes it count
neither way) learns that instance's box.

A refiner is trained on the peaks of one network: its file records the network's SHA-256, and a refiner
asked to work on another network is refused (``cnn.refiner=auto`` uses the shipped refiner with the shipped
field network only). ``seedmap train cnn-refiner`` trains one.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from seedmap.detect.refine import Refiner, patches
from seedmap.errors import ConfigError, InputError

#: default half size of the patch (13 x 13 px)
PATCH_R = 6
#: box edges and neighbour offsets are divided by this (px) to keep the inputs O(1)
SCALE_PX = 5.0
#: radius (px) of the neighbour context
NEIGHBOUR_PX = 8.0
#: neighbours looked at per peak (the densest 8-px discs hold fewer)
NEIGHBOUR_K = 12
#: feature columns after the patch: raw predictions (7) and neighbour context (8)
N_EXTRA = 15
KIND = "cnn_refiner"


def default_cnn_refiner_path() -> Path:
    """The shipped refiner of the shipped field network (``fast_cnn.onnx``)."""
    return Path(__file__).with_name("weights") / "fast_cnn_refiner.onnx"


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def peak_features(img: np.ndarray, x: np.ndarray, y: np.ndarray, raw: np.ndarray, r: int = PATCH_R) -> np.ndarray:
    """``(N, 3 (2r+1)^2 + 15)`` float32 features of the peaks at pixels ``x``, ``y`` (N,) of the RGB ``img``
    with the network's ``raw`` (N, 7) predictions (module docstring)."""
    n = len(x)
    if n == 0:
        return np.zeros((0, 3 * (2 * r + 1) ** 2 + N_EXTRA), np.float32)
    h, w = img.shape[:2]
    patch = patches(img, np.clip(np.asarray(x, np.int64), 0, w - 1), np.clip(np.asarray(y, np.int64), 0, h - 1), r)
    rw = np.asarray(raw, np.float32).copy()
    rw[:, 1:5] /= SCALE_PX
    # neighbour context: the strongest other peak within NEIGHBOUR_PX whose logit is higher
    xy = np.c_[np.asarray(x, np.float64), np.asarray(y, np.float64)]
    k = min(NEIGHBOUR_K + 1, n)
    d, j = cKDTree(xy).query(xy, k=k, distance_upper_bound=NEIGHBOUR_PX)
    d, j = d.reshape(n, k), j.reshape(n, k)
    ok = (j < n) & (j != np.arange(n)[:, None])
    lg = np.append(rw[:, 0], -np.inf)
    lj = np.where(ok, lg[np.minimum(j, n)], -np.inf)
    higher = ok & (lj > rw[:, :1])
    best = np.argmax(np.where(higher, lj, -np.inf), axis=1)
    has = higher[np.arange(n), best]
    b = j[np.arange(n), best]
    b = np.where(has, b, 0)
    nb = np.zeros((n, 8), np.float32)
    nb[:, 0] = has
    nb[:, 1:3] = np.where(has[:, None], (xy[b] - xy) / SCALE_PX, 0.0)
    nb[:, 3] = np.where(has, rw[b, 0] - rw[:, 0], 0.0)
    nb[:, 4] = np.where(has, rw[b, 1] + rw[b, 3], 0.0)
    nb[:, 5] = np.where(has, rw[b, 2] + rw[b, 4], 0.0)
    nb[:, 6] = (ok & (d <= 4.0)).sum(axis=1)
    nb[:, 7] = ok.sum(axis=1)
    return np.concatenate([patch, rw, nb], axis=1)


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


@dataclass
class CnnRefiner:
    """A trained second stage: the MLP (:class:`Refiner` of kind ``cnn_refiner``), run in onnxruntime when loaded
    from its ``.onnx`` export (one thread, no BLAS threads spinning) or in numpy from the ``.safetensors``."""

    mlp: Refiner
    path: Path
    session: object | None = None  # onnxruntime.InferenceSession

    @property
    def cnn_sha256(self) -> str:
        return str((self.mlp.info or {}).get("cnn_sha256", ""))

    @classmethod
    def load(cls, path: str | Path) -> CnnRefiner:
        p = Path(path)
        if p.suffix.lower() == ".onnx":
            sess, patch_r, info, dims = _load_onnx(p)
            mlp = Refiner([], patch_r, info, KIND)
            n_in, n_out = dims
        else:
            mlp = Refiner.load(p, kind=KIND)
            sess = None
            n_in, n_out = mlp.layers[0][0].shape[0], mlp.layers[-1][0].shape[1]
        if n_in != 3 * (2 * mlp.patch_r + 1) ** 2 + N_EXTRA or n_out != 5:
            raise InputError(f"cnn_refiner input/output sizes {n_in}/{n_out} do not match its patch radius "
                             f"{mlp.patch_r}", p)
        return cls(mlp, p, sess)

    def check_network(self, cnn_path: str | Path) -> None:
        """Refuse to refine the peaks of a network other than the one this refiner was trained on."""
        if self.cnn_sha256 and file_sha256(cnn_path) != self.cnn_sha256:
            raise ConfigError(f"cnn.refiner {self.path} was trained on the peaks of another network "
                              f"(SHA-256 {self.cnn_sha256[:12]}...), not of {cnn_path}; train one for it with "
                              "`seedmap train cnn-refiner`, or set cnn.refiner=none")

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``(N, 5)``: the four box-edge residuals (/ 5 px) and the seed logit."""
        if self.session is None:
            return self.mlp.forward(x)
        return self.session.run(None, {"features": np.ascontiguousarray(x, np.float32)})[0]

    def refine(self, img: np.ndarray, x: np.ndarray, y: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """The peaks' ``raw`` (N, 7) with the seed logit replaced and the box edges corrected."""
        if len(x) == 0:
            return raw
        o = self.forward(peak_features(img, x, y, raw, self.mlp.patch_r))
        out = np.asarray(raw, np.float64).copy()
        out[:, 0] = o[:, 4]
        out[:, 1:5] += o[:, :4] * SCALE_PX
        return out


def _load_onnx(p: Path) -> tuple[object, int, dict, tuple[int, int]]:
    import json

    from seedmap.detect.cnn import load_session

    sess = load_session(p, threads=1, kind=KIND)
    meta = sess.get_modelmeta().custom_metadata_map
    n_in = sess.get_inputs()[0].shape[1]
    n_out = sess.get_outputs()[0].shape[1]
    return sess, int(meta.get("patch_r", PATCH_R)), json.loads(meta.get("info", "{}")), (int(n_in), int(n_out))


def onnx_bytes(mlp: Refiner) -> bytes:
    """The MLP as an ONNX graph (MatMul + Add, ReLU between; input ``features`` (N, D), output ``out`` (N, 5)) with
    its kind, patch radius and info as metadata. Needs the ``onnx`` package (the learned extra)."""
    import json

    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes, inits = [], []
    cur = "features"
    for k, (w, b) in enumerate(mlp.layers):
        inits += [numpy_helper.from_array(np.asarray(w, np.float32), f"w{k}"),
                  numpy_helper.from_array(np.asarray(b, np.float32), f"b{k}")]
        last = k == len(mlp.layers) - 1
        nodes += [helper.make_node("MatMul", [cur, f"w{k}"], [f"m{k}"]),
                  helper.make_node("Add", [f"m{k}", f"b{k}"], ["out" if last else f"a{k}"])]
        if not last:
            nodes.append(helper.make_node("Relu", [f"a{k}"], [f"h{k}"]))
            cur = f"h{k}"
    d_in, d_out = mlp.layers[0][0].shape[0], mlp.layers[-1][0].shape[1]
    graph = helper.make_graph(nodes, "cnn_refiner",
                              [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["n", d_in])],
                              [helper.make_tensor_value_info("out", TensorProto.FLOAT, ["n", d_out])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    for k, v in {"seedmap_kind": KIND, "patch_r": str(mlp.patch_r), "info": json.dumps(mlp.info or {})}.items():
        e = model.metadata_props.add()
        e.key, e.value = k, v
    onnx.checker.check_model(model)
    return model.SerializeToString()


def training_data(datasets: list[str | Path], detector, patch_r: int = PATCH_R,  # noqa: ANN001 - CnnDetector
                  progress: bool = False, min_gt_area: float | None = None, images_root: str | Path | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(features, GT box edges / 5 px, is_seed, has_box)`` of the ``detector``'s peaks (at its threshold) on
    every labelled image of ``datasets``: simulated dataset folders (left and right images, GT masks) or COCO
    ``.json`` files with instance masks (polygon or RLE; images under ``images_root``, default beside the file). A
    seed has >= ``min_gt_area`` visible pixels (None: the detectable-seed size at the image width, as
    ``seedmap eval detect``)."""
    from seedmap.detect.config import min_visible_seed_px
    from seedmap.detect.labels import SeedmapSource, open_labelled
    from seedmap.io.seedmap_dataset import Instances

    sources = [SeedmapSource(p, min_area_px=1) if Path(p).is_dir() else open_labelled(p, images_root)
               for p in datasets]
    items = [(src, p, k) for src, p in zip(sources, datasets) for k in range(len(src))]
    it = items
    if progress:
        from tqdm import tqdm

        it = tqdm(items, desc="cnn-refiner samples", unit="img")
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
    """How ``seedmap train cnn-refiner`` trains (defaults: the shipped refiner, session 12)."""

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
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.config import CnnConfig

    cfg = cfg or CnnRefinerTrainConfig()
    det = CnnDetector(CnnConfig(threshold=cfg.candidates, refiner="none"), weights=weights)
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
    from seedmap.io.atomic import atomic_write_bytes

    Path(out).parent.mkdir(parents=True, exist_ok=True)
    mlp.save(out)
    onnx_path = Path(out).with_suffix(".onnx")
    atomic_write_bytes(onnx_path, onnx_bytes(mlp))
    return onnx_path


def _fit(x: np.ndarray, box: np.ndarray, seed: np.ndarray, cfg: CnnRefinerTrainConfig, n_patch: int,
         has: np.ndarray, progress: bool) -> Refiner:
    """The MLP on standardised features (``x`` is scaled in place); the box term weighs 20 x the mean smooth-L1 in
    units of 5 px, i.e. the sum over the four edges in pixels (beta 0.5 px)."""
    from seedmap.detect.refine import train_refiner

    return train_refiner(x, box, seed, steps=cfg.steps, hidden=cfg.hidden, lr=cfg.lr, batch=cfg.batch, seed=cfg.seed,
                         box_cols=slice(n_patch + 1, n_patch + 5), has_box=has, standardize=True, cosine=True,
                         beta=0.1, box_weight=20.0, kind=KIND, progress=progress)


def validate(datasets: list[str | Path], refiner: str | Path, thresholds: list[float],
             weights: str | Path | None = None, progress: bool = True) -> dict:
    """Box F1 (``seedmap eval detect``'s rule) of the network with the refiner at each refined-score threshold, and
    of the plain network at its own 0.45, per dataset and pooled (summed counts)."""
    from seedmap.detect.cnn import CnnDetector
    from seedmap.detect.config import CnnConfig, min_visible_seed_px
    from seedmap.eval.detect_metrics import evaluate_detections, prf
    from seedmap.io.seedmap_dataset import SeedmapDataset

    runs = {"plain": CnnDetector(CnnConfig(refiner="none"), weights=weights),
            "refined": CnnDetector(CnnConfig(refiner=str(refiner), refine_threshold=min(thresholds)), weights=weights)}
    res: dict = {"thresholds": list(thresholds), "datasets": {}, "pooled": {}}
    tot: dict = {}
    for p in datasets:
        ds = SeedmapDataset(p)
        mga = min_visible_seed_px(ds.calib.width)
        frames = range(len(ds))
        if progress:
            from tqdm import tqdm

            frames = tqdm(frames, desc=f"validate {Path(p).name}", unit="frame")
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
