"""Fit the shipped count calibration (``seedmap/recon/calibrations/DETECTOR.json``) from ``bench_recon.py --eval``
results, or score a calibration on them (the model: :mod:`seedmap.recon.calibrate`, docs/method/counting.md).

Each ``results/recon_eval_bench/NAME/pSEED.json`` of a ``--modes seeds`` run holds the multiview count's GT-free
features (``count_features``) and the GT countable seeds; a panicle that appears in several folders is used once.
``seedmap train count-calibration`` fits the same model from ``seedmap reconstruct`` folders (hand counts or GT).

Fit::

    python benchmarks/bench_count_calibration.py --detector fast --dirs RESULT_DIRS \
        --out seedmap/recon/calibrations/fast.json --summary benchmarks/results/count_calibration_fit.json

Score a calibration on panicles rendered after it was fitted (``--skip 100``: the benchmark's first panicle is in
the fit)::

    python benchmarks/bench_count_calibration.py --dirs RESULT_DIRS --score seedmap/recon/calibrations/fast.json \
        --skip 100 --summary benchmarks/results/count_calibration_heldout.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: the panicles the counter's settings were tuned on (``--split-tuning`` fits on these and scores the rest)
TUNING = {95, 96, 97, 98, 99, 111, 112, 113, 114, 115, 310, 311, 312, 313, 314, 315}


def load_rows(dirs: list[Path], skip: set[int] = frozenset()) -> list[dict]:
    """One row per panicle (first occurrence, none of ``skip``): panicle, folder, features, GT countable count."""
    from seedmap.recon.calibrate import CountFeatures

    rows, seen = [], set()
    for d in dirs:
        for p in sorted(d.glob("p*.json"), key=lambda q: int(q.stem[1:])):
            r = json.loads(p.read_text())
            s = r["panicle"]
            if s in seen or s in skip:
                continue
            m = r["modes"]["seeds"]
            if "count_features" not in m:
                raise SystemExit(f"{p}: no count_features (re-run bench_recon.py --eval ... --recount on it)")
            f = m["count_features"]
            seen.add(s)
            rows.append({"panicle": s, "dir": d.name, "truth": r["gt_countable"],
                         "features": CountFeatures(f["count"], f["views"], f["detections"], f["seed_diam_mm"])})
    return rows


def _errors(cal, rows: list[dict]) -> np.ndarray:
    return np.array([(cal.estimate(r["features"]) - r["truth"]) / r["truth"] * 100.0 for r in rows])


def _raw(rows: list[dict]) -> np.ndarray:
    return np.array([(r["features"].count - r["truth"]) / r["truth"] * 100.0 for r in rows])


def _stats(e: np.ndarray) -> dict:
    return {"mape_pct": float(np.mean(np.abs(e))), "signed_pct": float(np.mean(e)), "std_pct": float(np.std(e)),
            "max_abs_pct": float(np.max(np.abs(e))), "n": int(len(e))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dirs", type=Path, nargs="+", required=True, help="bench_recon.py --eval results folders")
    ap.add_argument("--detector", default="fast")
    ap.add_argument("--features", default="obs_fraction,seed_diam_mm")
    ap.add_argument("--out", type=Path, help="calibration file to write")
    ap.add_argument("--score", type=Path, help="score this calibration file on the folders instead of fitting")
    ap.add_argument("--split-tuning", action="store_true", help="also fit on the tuning panicles, score the rest")
    ap.add_argument("--summary", type=Path, help="write the numbers as JSON")
    ap.add_argument("--skip", type=int, nargs="*", default=[], help="leave these panicles out (e.g. 100 when "
                                                                     "scoring: it is in the shipped fit)")
    a = ap.parse_args()
    from seedmap.recon.calibrate import count_domain, fit_count_calibration, load_count_calibration, \
        save_count_calibration
    from seedmap.recon.config import ReconConfig

    rows = load_rows(a.dirs, set(a.skip))
    raw = _raw(rows)
    out: dict = {"dirs": [str(d) for d in a.dirs], "panicles": [r["panicle"] for r in rows], "raw": _stats(raw)}
    if a.score is not None:
        cal = load_count_calibration(a.score)
        e = _errors(cal, rows)
        out.update(calibration=str(a.score), calibrated=_stats(e),
                   per_panicle={r["panicle"]: {"raw_pct": round(float(x), 2), "calibrated_pct": round(float(y), 2)}
                                for r, x, y in zip(rows, raw, e)})
    else:
        names = tuple(f for f in a.features.split(",") if f)
        dom = count_domain(ReconConfig(detector=a.detector))
        fit = (lambda rs: fit_count_calibration([r["features"] for r in rs], [r["truth"] for r in rs], dom,
                                                [f"{r['dir']}/p{r['panicle']}" for r in rs], names,
                                                truth_name="GT countable seeds (>= 12 px in the left and right "
                                                           "image of >= 2 views)"))
        cal = fit(rows)
        out.update(features=list(names), intercept=cal.intercept, coef=cal.coef, fit=cal.fit,
                   calibrated=_stats(_errors(cal, rows)))
        if a.split_tuning:
            tune = [r for r in rows if r["panicle"] in TUNING]
            rest = [r for r in rows if r["panicle"] not in TUNING]
            ct = fit(tune)
            out["tuning_to_rest"] = {"raw": _stats(_raw(rest)), "calibrated": _stats(_errors(ct, rest)),
                                     "coef": ct.coef, "intercept": ct.intercept}
        if a.out is not None:
            save_count_calibration(cal, a.out)
    print(json.dumps({k: v for k, v in out.items() if k not in ("per_panicle", "panicles", "dirs")}, indent=1))
    if a.summary is not None:
        a.summary.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
