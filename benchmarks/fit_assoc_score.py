"""Fit the stereo candidate score of ``association.prior_score="mlp"`` (session 7), reproducibly.

What it does, per rendered range (``gt`` oracle keypoints, which carry ground-truth seed ids):
run the session-6 matcher (``stereo_prior=sgbm``, ``prior_score=learned``) frame after frame (it
drives the SGBM search range exactly as ``seedmap eval associate`` does) and keep, per frame, the
dense disparity and :class:`~seedmap.associate.semantic.StereoCues`; the candidates and their cues
are those :func:`~seedmap.associate.semantic.stereo_cue_candidates` gives the ``mlp`` matcher (one
code path), labelled 1 when both keypoints carry the same seed id. A network with two small ReLU
hidden layers is fitted on the labelled candidates (torch, Adam, binary cross-entropy, one thread,
every random choice from ``--seed``) and written as JSON for
:class:`~seedmap.associate.semantic.ScoreModel`. ``--cv`` also fits leave-one-range-out models and
reports each held-out range's stereo precision / recall over gated pairs at a grid of
``mlp_min_logit`` values (the assignment and ambiguity test of the matcher), which is how the
threshold is chosen without looking at the evaluation ranges.

Usage (session 7; ~1 min CPU per range to collect, cached in ``--cache``)::

    .venv/bin/python benchmarks/fit_assoc_score.py data/slam_r1 data/assoc_s11 data/assoc_s16 data/assoc_s17 \\
        --out seedmap/associate/weights/stereo_score_s7.json --cv

Never fit on the evaluation ranges (seeds 13, 14, 15).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seedmap.associate.semantic import (  # noqa: E402
    CUE_NAMES,
    HISTORY_CUE_NAMES,
    TEMPORAL_CUE_NAMES,
    ScoreModel,
    SeedMatcher,
    assign_logits,
    candidate_positions,
    stereo_cue_candidates,
)


def collect(dataset: Path, cache: Path | None, progress: bool = True) -> list[dict]:
    """Labelled candidates of every frame of ``dataset``: dicts with ``ia, ib, X, y, n, m, gated``
    (``gated``: the frame's ground-truth pairs that pass the stereo gates, the recall denominator)."""
    cached = load_cache(cache, f"{dataset.name}.npz")
    if cached is not None:
        return cached[0]
    from seedmap.eval.associate_metrics import stereo_gate

    cfg, ds, matcher = gt_matcher(dataset, ["association.stereo_prior=sgbm", "association.prior_score=learned"])
    mcfg = cfg.association.model_copy(update={"prior_score": "mlp"})
    matcher.keep_inputs = True
    sg = stereo_gate(ds.calib.width, cfg.gates)
    out = []
    for i in range(len(ds)):
        f = matcher.features(ds[i])
        _, disp, cues = matcher.last_stereo_inputs
        if disp is None or cues is None:
            continue
        ia, ib, x = stereo_cue_candidates(f.kp_left, f.kp_right, ds.calib.width, cfg.gates, mcfg, disp, cues)
        idl, idr = f.seed_ids_left, f.seed_ids_right
        y = same_seed(idl, idr, ia, ib)
        gated = len(gated_true_pairs(idl, idr, f.kp_left, f.kp_right, sg)[0])
        out.append(dict(ia=ia, ib=ib, X=x.astype(np.float32), y=y, n=len(f.kp_left), m=len(f.kp_right), gated=gated))
        if progress:
            print(f"  {dataset.name} frame {i}: {len(ia)} candidates, {int(y.sum())} true", flush=True)
    save_cache(cache, f"{dataset.name}.npz", out)
    return out


# ----------------------------------------------------------------------------------------------
# shared by the three candidate-score fit scripts (this one, fit_assoc_temporal.py, fit_assoc_history.py)
# ----------------------------------------------------------------------------------------------


def load_cache(cache: Path | None, name: str) -> tuple[list[dict], dict | None] | None:
    """The labelled candidates cached as ``cache/name`` (its ``frames`` and, when stored, its
    ``anatomy`` counts; None without them); None when there is no such file."""
    if cache is None or not (cache / name).is_file():
        return None
    z = np.load(cache / name, allow_pickle=True)
    return list(z["frames"]), (json.loads(str(z["anatomy"])) if "anatomy" in z.files else None)


def save_cache(cache: Path | None, name: str, frames: list[dict], anatomy: dict | None = None) -> None:
    """Write what :func:`load_cache` reads (nothing without a ``cache`` folder)."""
    if cache is None:
        return
    cache.mkdir(parents=True, exist_ok=True)
    extra = {} if anatomy is None else {"anatomy": json.dumps(anatomy)}
    np.savez_compressed(cache / name, frames=np.array(frames, dtype=object), **extra)


def gt_matcher(dataset: Path, overrides: list[str]):
    """``(cfg, ds, matcher)``: the ``SlamConfig`` with ``overrides``, the opened ``dataset`` and a
    :class:`SeedMatcher` on its ``gt`` oracle keypoints (which carry ground-truth seed ids), as
    ``seedmap eval associate`` builds them."""
    from seedmap.config import load_config
    from seedmap.io import open_dataset
    from seedmap.slam.config import SlamConfig
    from seedmap.slam.pipeline import _detector_for

    cfg = load_config(SlamConfig, None, overrides)
    ds = open_dataset(dataset)
    det = _detector_for("gt", dataset, cfg.detect)
    return cfg, ds, SeedMatcher(ds.calib, detector=det, cfg=cfg.association, gates=cfg.gates)


def same_seed(ids_a: np.ndarray, ids_b: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """Labels of the candidates ``(ia, ib)``: both keypoints carry the same ground-truth seed id."""
    return (ids_a[ia] == ids_b[ib]) & (ids_a[ia] >= 0)


def gated_true_pairs(ids_a: np.ndarray, ids_b: np.ndarray, ka: np.ndarray, kb: np.ndarray, gate
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(pa, pb)`` of the keypoints ``ka``/``kb`` with the same ground-truth seed id
    that pass ``gate(ka, kb) -> bool`` (``seedmap.eval.associate_metrics``): the recall denominator."""
    common, pa, pb = np.intersect1d(ids_a[ids_a >= 0], ids_b[ids_b >= 0], return_indices=True)
    pa, pb = np.flatnonzero(ids_a >= 0)[pa], np.flatnonzero(ids_b >= 0)[pb]
    ok = gate(ka[pa], kb[pb]) if len(common) else np.zeros(0, bool)
    return pa[ok], pb[ok]


def leave_one_out(data: dict[str, list[dict]], features: tuple[str, ...], hidden: tuple[int, ...], epochs: int,
                  seed: int, kind: str, settings: dict[str, tuple[float, float]]):
    """Per range of ``data`` (name -> labelled frames): ``(name, {setting: score})`` of the model
    fitted on all other ranges, at every ``settings`` (name -> (min_logit, margin))."""
    for held in data:
        train = [f for n, fr in data.items() if n != held for f in fr]
        mdl = fit(train, features, hidden, epochs, seed, kind=kind)
        yield held, {k: score(data[held], mdl, t, mg) for k, (t, mg) in settings.items()}


def cv_table(data: dict[str, list[dict]], features: tuple[str, ...], hidden: tuple[int, ...], a: argparse.Namespace,
             kind: str, settings: dict[str, tuple[float, float]]) -> dict:
    """:func:`leave_one_out` (epochs and seed from ``a``) as ``{held-out range: {setting: score}}``,
    printing each fold's precision / gated recall at every setting."""
    cv = {}
    for held, row in leave_one_out(data, features, hidden, a.epochs, a.seed, kind, settings):
        cv[held] = row
        print(f"held out {held}: " + ", ".join(f"t>={t}: P {v['precision']:.4f} R {v['recall_gated']:.4f}"
                                              for t, v in row.items()), flush=True)
    return cv


def fit_and_report(a: argparse.Namespace, data: dict[str, list[dict]], features: tuple[str, ...],
                   hidden: tuple[int, ...], kind: str, settings: dict[str, tuple[float, float]], report: dict,
                   t0: float, c0: float) -> None:
    """The end of every fit script: the model fitted on all ranges of ``data`` (written to
    ``a.out``) and ``report`` with its in-sample scores at ``settings`` and the run's CPU / wall
    seconds since ``c0`` / ``t0`` (written to ``a.report``)."""
    model = fit([f for fr in data.values() for f in fr], features, hidden, a.epochs, a.seed, kind=kind)
    model.info["ranges"] = [r.name for r in a.ranges]
    report["in_sample"] = {n: {k: score(fr, model, t, mg) for k, (t, mg) in settings.items()}
                           for n, fr in data.items()}
    model.save(a.out)
    report["cpu_s"] = round(time.process_time() - c0, 1)
    report["wall_s"] = round(time.time() - t0, 1)
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(a.report, json.dumps(report, indent=1) + "\n")
    print(f"model {a.out}, report {a.report} ({report['cpu_s']} s CPU)")


def fit(frames: list[dict], features: tuple[str, ...], hidden: tuple[int, ...], epochs: int, seed: int,
        lr: float = 3e-3, weight_decay: float = 1e-5, batch: int = 4096, kind: str = "stereo") -> ScoreModel:
    """Fit the network on labelled candidates (deterministic for a given ``seed``, one CPU thread).
    ``kind``: "stereo" (columns of ``CUE_NAMES``), "temporal" (``TEMPORAL_CUE_NAMES``, used by
    benchmarks/fit_assoc_temporal.py) or "stereo_history" (``CUE_NAMES + HISTORY_CUE_NAMES``,
    benchmarks/fit_assoc_history.py)."""
    import torch

    torch.set_num_threads(1)
    torch.manual_seed(seed)
    names = {"temporal": TEMPORAL_CUE_NAMES, "stereo_history": CUE_NAMES + HISTORY_CUE_NAMES}.get(kind, CUE_NAMES)
    cols = [names.index(c) for c in features]
    x = np.concatenate([f["X"][:, cols] for f in frames]).astype(np.float64)
    y = np.concatenate([f["y"] for f in frames]).astype(np.float32)
    mean, std = x.mean(0), x.std(0) + 1e-6
    xt = torch.tensor((x - mean) / std, dtype=torch.float32)
    yt = torch.tensor(y)
    sizes = (len(cols), *hidden, 1)
    mods: list = []
    for k in range(len(sizes) - 1):
        mods.append(torch.nn.Linear(sizes[k], sizes[k + 1]))
        if k + 2 < len(sizes):
            mods.append(torch.nn.ReLU())
    net = torch.nn.Sequential(*mods)
    opt = torch.optim.Adam(net.parameters(), lr, weight_decay=weight_decay)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        perm = torch.randperm(len(xt), generator=gen)
        for k in range(0, len(xt), batch):
            idx = perm[k:k + batch]
            loss = torch.nn.functional.binary_cross_entropy_with_logits(net(xt[idx])[:, 0], yt[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        full = float(torch.nn.functional.binary_cross_entropy_with_logits(net(xt)[:, 0], yt))
    layers = [(m.weight.detach().double().numpy(), m.bias.detach().double().numpy())
              for m in net if isinstance(m, torch.nn.Linear)]
    info = {"hidden": list(hidden), "epochs": epochs, "seed": seed, "lr": lr, "weight_decay": weight_decay,
            "candidates": int(len(y)), "positives": int(y.sum()), "train_log_loss": round(full, 5)}
    return ScoreModel(tuple(features), mean, std, layers, info, kind)


def score(frames: list[dict], model: ScoreModel, min_logit: float, margin: float) -> dict:
    """Stereo precision / recall over gated pairs of the matcher's assignment with ``model``."""
    correct = kept = gated = 0
    for f in frames:
        t = model.logits(f["X"].astype(np.float64))
        m = assign_logits(f["ia"], f["ib"], t, f["n"], f["m"], min_logit, margin)
        pos = candidate_positions(f["ia"], f["ib"], f["m"], m.idx_a, m.idx_b)
        correct += int(f["y"][pos].sum())
        kept += len(m)
        gated += f["gated"]
    return {"precision": correct / max(kept, 1), "recall_gated": correct / max(gated, 1), "wrong": kept - correct}


def fit_arg_parser(description: str, cues: tuple[str, ...] | list[str], epochs: int, report: Path
                   ) -> argparse.ArgumentParser:
    """The command line of the candidate-score fit scripts (this one, ``fit_assoc_temporal.py`` and
    ``fit_assoc_history.py``)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("ranges", nargs="+", type=Path, help="rendered ranges to fit on (seedmap layout with gt/)")
    ap.add_argument("--out", type=Path, required=True, help="model JSON")
    ap.add_argument("--cache", type=Path, default=Path("data/assoc_fit_cache"), help="candidate cache folder")
    ap.add_argument("--features", default=",".join(cues), help="comma-separated subset of the cues")
    ap.add_argument("--hidden", default="32,16")
    ap.add_argument("--epochs", type=int, default=epochs)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--margin", type=float, default=1.0)
    ap.add_argument("--cv", action="store_true", help="also leave-one-range-out scores")
    ap.add_argument("--report", type=Path, default=report, help="JSON report")
    return ap


def main(argv: list[str] | None = None) -> None:
    ap = fit_arg_parser(__doc__.splitlines()[0], CUE_NAMES, 40, Path("benchmarks/results/fit_assoc_score.json"))
    a = ap.parse_args(argv)
    t0, c0 = time.time(), time.process_time()
    feats = tuple(x for x in a.features.split(",") if x)
    hidden = tuple(int(x) for x in a.hidden.split(",") if x)
    data = {r.name: collect(r, a.cache) for r in a.ranges}
    settings = {str(t): (t, a.margin) for t in (0.0, 0.5, 1.0, 1.5, 2.0)}
    report: dict = {"ranges": [str(r) for r in a.ranges], "features": list(feats), "hidden": list(hidden),
                    "epochs": a.epochs, "seed": a.seed, "margin": a.margin}
    if a.cv and len(data) > 1:
        report["leave_one_out"] = cv_table(data, feats, hidden, a, "stereo", settings)
    fit_and_report(a, data, feats, hidden, "stereo", settings, report, t0, c0)


if __name__ == "__main__":
    main()
