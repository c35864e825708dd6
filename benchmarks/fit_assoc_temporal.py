"""Fit the temporal candidate score of ``association.temporal_score="mlp"`` (session 8), reproducibly.

What it does, per rendered range (``gt`` oracle keypoints, which carry ground-truth seed ids):
run the matcher of the session-7 evaluation (``stereo_prior=sgbm``, ``prior_score=mlp``) frame
after frame with ``temporal_score=mlp`` (so it keeps each frame's
:class:`~seedmap.associate.semantic.TemporalInputs`); for every consecutive pair of frames the
candidates and cues are those :meth:`SeedMatcher.temporal_candidates` gives the matcher (one code
path), labelled 1 when both keypoints carry the same seed id. The constant-velocity prediction is
driven by the ``field`` temporal matching, as in ``seedmap eval associate`` without the network.
The network (two small ReLU hidden layers, torch, one thread, every random choice from ``--seed``)
is fitted by ``fit_assoc_score.fit`` and written as JSON for
:class:`~seedmap.associate.semantic.ScoreModel` (``kind="temporal"``). ``--cv`` also fits
leave-one-range-out models and reports each held-out range's temporal precision / recall over
gated pairs at a grid of ``temporal_mlp_min_logit`` values.

It also writes the *anatomy* of the ``field`` temporal path on every range (where the gated true
pairs are lost: outside the field window, the assignment's cost cap, a conflict in the assignment,
the ambiguity (ratio) test, the NCC check at 0.3) and the share of gated true pairs inside the
network's wider window.

Usage (session 8; ~1 min CPU per range to collect, cached in ``--cache``)::

    nice -n 10 .venv/bin/python benchmarks/fit_assoc_temporal.py data/slam_r1 data/assoc_s11 data/assoc_s16 \\
        data/assoc_s17 data/assoc_s18 data/assoc_s19 data/assoc_s20 data/assoc_s21 \\
        --out seedmap/associate/weights/temporal_score_s8.json --cv

Never fit on the evaluation ranges (seeds 13, 14, 15, 25, 26).
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
    cv_table,
    fit_and_report,
    fit_arg_parser,
    gated_true_pairs,
    gt_matcher,
    load_cache,
    same_seed,
    save_cache,
)

from seedmap.associate.semantic import (  # noqa: E402
    TEMPORAL_CUE_NAMES,
    SeedMatcher,
    _assign_in_prior,
    _field_candidates,
    _temporal_search,
    assign_capped,
    field_estimate,
    full_res_scale,
    match_temporal_keypoints,
    pair_cost,
)

#: the anatomy's stages, in order (each counts the gated true pairs still alive after it)
STAGES = ("gated", "in_field_window", "under_cost_cap", "assigned", "ratio_test", "ncc_0.3")


def _anatomy(matcher: SeedMatcher, prev, cur, pred_uv, width: int, true_a: np.ndarray, true_b: np.ndarray,
             window_pairs: set) -> dict:
    """Gated true pairs ``(true_a, true_b)`` alive after each stage of the ``field`` temporal path."""
    from seedmap.associate.disparity import patch_ncc

    cfg, g = matcher.cfg, matcher.gates.scaled(width)
    ka, kb = prev.kp_left, cur.kp_left
    s = full_res_scale(width)
    gate, lo, hi, extent = _temporal_search(ka, kb, width, g, cfg, *pred_uv)
    sigma = np.asarray(cfg.field_temporal_sigma_px, np.float64) / s
    pred = field_estimate(ka, kb, gate, lo, hi, sigma, cfg, s, extent)
    ia, ib, res = _field_candidates(ka, kb, pred, sigma, gate, cfg.field_gate_sigma)
    n, m = len(ka), len(kb)
    sums = (matcher._cached_sums(ka), matcher._cached_sums(kb))
    cost = pair_cost(ka * s, kb * s, sums[0], sums[1], cfg, ia, ib) + cfg.field_weight * res * res
    cap = cfg.max_cost + cfg.field_weight * cfg.field_gate_sigma ** 2
    key = lambda a, b: a.astype(np.int64) * m + b  # noqa: E731
    tk = key(true_a, true_b)
    cand = dict(zip(key(ia, ib).tolist(), cost.tolist()))
    in_win = np.array([k in cand for k in tk.tolist()], bool)
    under = np.array([k in cand and cand[k] <= cap for k in tk.tolist()], bool)
    assigned = assign_capped(n, m, ia, ib, cost, cap)
    ak = set(key(assigned.idx_a, assigned.idx_b).tolist())
    final = _assign_in_prior(ka * s, kb * s, sums[0], sums[1], ia, ib, res, n, m, cfg, cfg.field_ratio)
    fk = set(key(final.idx_a, final.idx_b).tolist())
    in_assigned = np.array([k in ak for k in tk.tolist()], bool)
    in_final = np.array([k in fk for k in tk.tolist()], bool)
    ta, tb = matcher._cached_temporal_inputs(ka), matcher._cached_temporal_inputs(kb)
    mid = matcher._patch_size()
    ncc = patch_ncc(ta.cues.patches[mid], tb.cues.patches[mid], true_a, true_b)
    return {"gated": len(tk), "in_field_window": int(in_win.sum()), "under_cost_cap": int(under.sum()),
            "assigned": int(in_assigned.sum()), "ratio_test": int(in_final.sum()),
            "ncc_0.3": int((in_final & (ncc >= 0.3)).sum()),
            "in_mlp_window": int(sum(k in window_pairs for k in tk.tolist()))}


def collect(dataset: Path, cache: Path | None, progress: bool = True) -> tuple[list[dict], dict]:
    """Labelled temporal candidates of every consecutive frame pair of ``dataset`` (dicts with
    ``ia, ib, X, y, n, m, gated``) and the range's anatomy counts (summed over frame pairs)."""
    cached = load_cache(cache, f"temporal_{dataset.name}.npz")
    if cached is not None:
        return cached
    from seedmap.eval.associate_metrics import temporal_gate

    cfg, ds, matcher = gt_matcher(dataset, ["association.stereo_prior=sgbm", "association.prior_score=mlp",
                                            "association.temporal_score=mlp"])
    tg = temporal_gate(ds.calib.width, cfg.gates)
    w = ds.calib.width
    out, anatomy = [], {k: 0 for k in (*STAGES, "in_mlp_window")}
    prev = None
    for i in range(len(ds)):
        f = matcher.features(ds[i])
        if prev is not None:
            pred_uv = matcher._prediction()
            cand = matcher.temporal_candidates(prev, f)
            ia, ib, x = cand
            ida, idb = prev.seed_ids_left, f.seed_ids_left
            y = same_seed(ida, idb, ia, ib)
            ta, tb = gated_true_pairs(ida, idb, prev.kp_left, f.kp_left, tg)
            out.append(dict(ia=ia, ib=ib, X=x.astype(np.float32), y=y, n=len(prev.kp_left), m=len(f.kp_left),
                            gated=len(ta)))
            win = set((ia.astype(np.int64) * len(f.kp_left) + ib).tolist())
            a = _anatomy(matcher, prev, f, pred_uv, w, ta, tb, win)
            for k, v in a.items():
                anatomy[k] += v
            # drive the constant-velocity prediction with the field matching (what eval associate does)
            m = match_temporal_keypoints(prev.kp_left, f.kp_left, w, matcher.gates, matcher.cfg, *pred_uv,
                                         sums=(matcher._cached_sums(prev.kp_left), matcher._cached_sums(f.kp_left)))
            matcher._update_shift(prev.kp_left, f.kp_left, m)
            if progress:
                print(f"  {dataset.name} frames {i - 1}-{i}: {len(ia)} candidates, {int(y.sum())} true, "
                      f"{len(ta)} gated true pairs", flush=True)
        prev = f
    save_cache(cache, f"temporal_{dataset.name}.npz", out, anatomy)
    return out, anatomy


def main(argv: list[str] | None = None) -> None:
    ap = fit_arg_parser(__doc__.splitlines()[0], TEMPORAL_CUE_NAMES, 30,
                        Path("benchmarks/results/fit_assoc_temporal.json"))
    a = ap.parse_args(argv)
    t0, c0 = time.time(), time.process_time()
    feats = tuple(x for x in a.features.split(",") if x)
    hidden = tuple(int(x) for x in a.hidden.split(",") if x)
    data, anatomy = {}, {}
    for r in a.ranges:
        data[r.name], anatomy[r.name] = collect(r, a.cache)
        an = anatomy[r.name]
        print(f"{r.name} field-path anatomy (gated true pairs alive): "
              + ", ".join(f"{k} {an[k]} ({an[k] / max(an['gated'], 1):.3f})" for k in an), flush=True)
    settings = {str(t): (t, a.margin) for t in (-1.0, 0.0, 0.5, 1.0, 1.5, 2.0)}
    report: dict = {"ranges": [str(r) for r in a.ranges], "features": list(feats), "hidden": list(hidden),
                    "epochs": a.epochs, "seed": a.seed, "margin": a.margin, "field_anatomy": anatomy}
    if a.cv and len(data) > 1:
        report["leave_one_out"] = cv_table(data, feats, hidden, a, "temporal", settings)
    fit_and_report(a, data, feats, hidden, "temporal", settings, report, t0, c0)


if __name__ == "__main__":
    main()
