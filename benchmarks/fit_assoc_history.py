"""Fit the stereo score of ``association.stereo_history=true`` (session 9), reproducibly.

What it does, per rendered range (``gt`` oracle keypoints, which carry ground-truth seed ids): run
the matcher of the session-8 evaluation (``stereo_prior=sgbm``, ``prior_score=mlp``,
``temporal_score=mlp``) frame after frame exactly as ``seedmap eval associate`` does (stereo of
frame t, then the temporal matches t-1 -> t); for every frame t > 0 the previous frame's stereo
matches, the temporal matches and the previous right image's cues form the
:class:`~seedmap.associate.semantic.StereoHistory` of t, and the candidates and cues are those
:func:`~seedmap.associate.semantic.history_cue_candidates` gives the ``stereo_history`` matcher
(one code path), labelled 1 when both keypoints carry the same seed id. (The history at fit time
comes from the session-7 stereo network; with the option on it comes from the new one.)

It also writes the *anatomy* of the session-7 ``mlp`` stereo path on every range: where the
gated true stereo pairs are lost - (a) outside the candidate window (``mlp_gate_sigma`` of the SGBM
prior), (b) below ``mlp_min_logit``, (c) assigned but within ``mlp_margin`` of a competitor, (d)
one of its keypoints given to another partner by the assignment - and, of the lost ones, how many
have a history (the left keypoint tracked to a stereo pair of t-1) and how many of those
histories point at the true partner.

Then a network (two small ReLU hidden layers, torch, one thread, every random choice from
``--seed``) is fitted by ``fit_assoc_score.fit`` (``kind="stereo_history"``). ``--cv`` also fits
leave-one-range-out models, with and without the history cues (the baseline: the 17 cues of the
session-7 network on the same candidates), and scores each held-out range at a grid of
``history_min_logit`` x ``history_margin``; the chosen setting maximises the *worst* fold's gated
recall among those where every fold keeps precision >= ``--min-precision`` (held-out ranges vary
more than the CV mean suggests).

Usage (session 9; ~1 min CPU per range to collect, cached in ``--cache``)::

    nice -n 10 .venv/bin/python benchmarks/fit_assoc_history.py data/slam_r1 data/assoc_s11 data/assoc_s16 \\
        data/assoc_s17 data/assoc_s18 data/assoc_s19 data/assoc_s20 data/assoc_s21 \\
        --out seedmap/associate/weights/stereo_history_s9.json --cv \\
        --report benchmarks/results/fit_assoc_history_s9.json

Never fit on the evaluation ranges (seeds 13, 14, 15, 25, 26, 27, 28).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from fit_assoc_score import (  # noqa: E402
    fit_and_report,
    fit_arg_parser,
    gated_true_pairs,
    gt_matcher,
    leave_one_out,
    load_cache,
    same_seed,
    save_cache,
)

from seedmap.associate.semantic import (  # noqa: E402
    CUE_NAMES,
    HISTORY_CUE_NAMES,
    StereoHistory,
    assign_capped,
    candidate_positions,
    history_cue_candidates,
    history_prior,
    score_model,
    second_best,
    stereo_cue_candidates,
)

#: anatomy counters (gated true stereo pairs)
ANATOMY = ("gated", "matched", "wrong_pairs", "a_outside_window", "b_below_logit", "c_margin", "d_taken",
           "lost_with_history", "lost_history_true", "lost_history_true_in_window")


def _mlp_anatomy(ia, ib, x, y, n: int, m: int, gated: int, cfg) -> dict:
    """Where the session-7 ``mlp`` path (model ``cfg.score_model``) loses the gated true pairs of one
    frame: its candidates ``(ia, ib)``, cue rows ``x``, labels ``y``; same steps as
    :func:`~seedmap.associate.semantic.assign_logits`. Returns counts and the lost true candidates'
    left indices (for the history columns)."""
    t = score_model(cfg.score_model).logits(x)
    ml, mg = cfg.mlp_min_logit, cfg.mlp_margin
    top = float(max(t.max(), ml)) + 1.0 if len(t) else ml + 1.0
    cost = top - t
    out = assign_capped(n, m, ia, ib, cost, top - ml + 1e-9)
    pos = candidate_positions(ia, ib, m, out.idx_a, out.idx_b) if len(out) else np.zeros(0, np.int64)
    alt = second_best(ia, ib, cost, out, n, m)
    keep = cost[pos] + mg < alt
    ok = np.zeros(len(ia), bool)
    ok[pos[keep]] = True
    asg = np.zeros(len(ia), bool)
    asg[pos] = True
    lost = y & ~ok
    return {"gated": gated, "matched": int((ok & y).sum()), "wrong_pairs": int((ok & ~y).sum()),
            "a_outside_window": gated - int(y.sum()), "b_below_logit": int((lost & ~asg & (t < ml)).sum()),
            "c_margin": int((lost & asg).sum()), "d_taken": int((lost & ~asg & (t >= ml)).sum())}


def collect(dataset: Path, cache: Path | None, progress: bool = True) -> tuple[list[dict], dict]:
    """Labelled history candidates of every frame of ``dataset`` (dicts ``ia, ib, X, y, n, m,
    gated``) and the anatomy of the session-7 path (summed over frames)."""
    cached = load_cache(cache, f"history_{dataset.name}.npz")
    if cached is not None:
        return cached
    from seedmap.eval.associate_metrics import stereo_gate

    cfg, ds, matcher = gt_matcher(dataset, ["association.stereo_prior=sgbm", "association.prior_score=mlp",
                                            "association.temporal_score=mlp"])
    matcher.keep_inputs = True
    sg = stereo_gate(ds.calib.width, cfg.gates)
    w = ds.calib.width
    acfg = cfg.association
    out, anatomy = [], {k: 0 for k in ANATOMY}
    prev, prev_cues = None, None
    for i in range(len(ds)):
        f = matcher.features(ds[i])
        _, disp, cues = matcher.last_stereo_inputs
        hist, hp = None, prev
        if prev is not None:
            tm = matcher.match_temporal(prev, f)
            if prev_cues is not None:
                hist = StereoHistory(prev.kp_left, prev.kp_right, prev.stereo, tm, prev_cues.right)
        prev = f
        prev_cues = cues
        if disp is None or cues is None:
            continue
        idl, idr = f.seed_ids_left, f.seed_ids_right
        ta, tb = gated_true_pairs(idl, idr, f.kp_left, f.kp_right, sg)
        gated = len(ta)
        # anatomy of the session-7 path on its own candidates
        ja, jb, x7 = stereo_cue_candidates(f.kp_left, f.kp_right, w, cfg.gates, acfg, disp, cues)
        y7 = same_seed(idl, idr, ja, jb)
        an = _mlp_anatomy(ja, jb, x7, y7, len(f.kp_left), len(f.kp_right), gated, acfg)
        mr = len(f.kp_right)
        matched = set((f.stereo.idx_a.astype(np.int64) * mr + f.stereo.idx_b).tolist())
        lost = np.array([k not in matched for k in (ta * mr + tb).tolist()], bool)
        ia, ib, x = history_cue_candidates(f.kp_left, f.kp_right, w, cfg.gates, acfg, disp, cues, hist)
        y = same_seed(idl, idr, ia, ib)
        if hist is not None:
            pr = history_prior(f.kp_left, hist, disp, w, acfg.field_k)[0][ta[lost]]
            has = pr >= 0
            htrue = has & (hp.seed_ids_right[np.maximum(pr, 0)] == idl[ta[lost]])
            found = set((ia[y].astype(np.int64) * mr + ib[y]).tolist())
            inwin = np.array([k in found for k in (ta[lost] * mr + tb[lost]).tolist()], bool)
            an["lost_with_history"] = int(has.sum())
            an["lost_history_true"] = int(htrue.sum())
            an["lost_history_true_in_window"] = int((htrue & inwin).sum())
        out.append(dict(ia=ia, ib=ib, X=x.astype(np.float32), y=y, n=len(f.kp_left), m=len(f.kp_right), gated=gated))
        for k, v in an.items():
            anatomy[k] = anatomy.get(k, 0) + v
        if progress:
            print(f"  {dataset.name} frame {i}: {len(ia)} candidates, {int(y.sum())} true, {gated} gated true pairs",
                  flush=True)
    save_cache(cache, f"history_{dataset.name}.npz", out, anatomy)
    return out, anatomy


def choose(cv: dict, min_precision: float) -> tuple[str | None, dict]:
    """The grid setting (key ``"min_logit/margin"``) that maximises the worst fold's gated recall
    among those where every fold keeps precision >= ``min_precision``; with each setting's worst
    fold (precision, gated recall)."""
    settings = next(iter(cv.values())).keys()
    worst = {k: {"precision": min(cv[h][k]["precision"] for h in cv),
                 "recall_gated": min(cv[h][k]["recall_gated"] for h in cv)} for k in settings}
    ok = [k for k in settings if worst[k]["precision"] >= min_precision]
    best = max(ok, key=lambda k: worst[k]["recall_gated"]) if ok else None
    return best, worst


def main(argv: list[str] | None = None) -> None:
    ap = fit_arg_parser(__doc__.splitlines()[0], CUE_NAMES + HISTORY_CUE_NAMES, 40,
                        Path("benchmarks/results/fit_assoc_history.json"))
    ap.add_argument("--min-precision", type=float, default=0.993, help="every CV fold's precision at least this")
    ap.add_argument("--no-baseline", action="store_true", help="skip the CV of the 17-cue baseline")
    a = ap.parse_args(argv)
    t0, c0 = time.time(), time.process_time()
    feats = tuple(x for x in a.features.split(",") if x)
    hidden = tuple(int(x) for x in a.hidden.split(",") if x)
    data, anatomy = {}, {}
    for r in a.ranges:
        data[r.name], anatomy[r.name] = collect(r, a.cache)
        an = anatomy[r.name]
        g = max(an["gated"], 1)
        print(f"{r.name} mlp-path anatomy (gated true pairs): " + ", ".join(f"{k} {an[k]} ({an[k] / g:.4f})"
                                                                           for k in an), flush=True)
    settings = {f"{t}/{mg}": (t, mg) for t in (0.0, 0.5, 1.0, 1.5, 2.0) for mg in (0.5, 1.0, 1.5)}
    report: dict = {"ranges": [str(r) for r in a.ranges], "features": list(feats), "hidden": list(hidden),
                    "epochs": a.epochs, "seed": a.seed, "min_precision": a.min_precision, "mlp_anatomy": anatomy}
    variants = {"history": feats}
    if not a.no_baseline:
        variants["baseline_17"] = CUE_NAMES
    if a.cv and len(data) > 1:
        for name, fs in variants.items():
            cv = {}
            for held, row in leave_one_out(data, fs, hidden, a.epochs, a.seed, "stereo_history", settings):
                cv[held] = row
                v = row["1.0/1.0"]
                print(f"{name}: held out {held}: at 1.0/1.0 P {v['precision']:.4f} R {v['recall_gated']:.4f}",
                      flush=True)
            best, worst = choose(cv, a.min_precision)
            report[f"leave_one_out_{name}"] = cv
            report[f"worst_fold_{name}"] = worst
            report[f"chosen_{name}"] = best
            print(f"{name}: chosen {best}: worst fold {worst.get(best)}; at 1.0/1.0: {worst['1.0/1.0']}", flush=True)
    fit_and_report(a, data, feats, hidden, "stereo_history", settings, report, t0, c0)


if __name__ == "__main__":
    main()
