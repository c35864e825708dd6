"""How much of a panicle the detector lets any counter count (issue #6, session 11).

For every simulated arm scan ``DATA_DIR/pSEED``: run the reconstruction's detector (its ``detector_overrides``
plus ``--detector-set``) once at the lowest of ``--thresholds``, label every left and right keypoint with the GT
seed under it (``gt/masks`` + ``gt/instances``), and report per threshold

- ``reachable_pct``: countable seeds (>= ``--min-area`` px, default 12, in the left and right image of >= 2 views,
  as the count benchmark) with a keypoint in the left AND the right image of >= 2 views -- what a counter can count;
- ``dup_pct``: left keypoints that are a second (third...) keypoint on a seed of the same image;
- ``background_pct``: left keypoints on no seed.

With ``--errors SUMMARY.json`` (a ``bench_recon.py`` summary of the same panicles) it also gives the correlation
of the reachable share with the signed count error. Writes JSON (``--out``).

``python benchmarks/count_reach.py --panicles 95 96 97 98 99 111 112 113 114 115 310 311 312 313 314 315 --errors
benchmarks/results/bench_recon_eval_fast_s11_tuning.json benchmarks/results/bench_recon_eval_fast_s11_tuning_red.json --out benchmarks/results/count_reach_s11.json``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def keypoint_seed_ids(root: Path, side: str, view: int, uv: np.ndarray) -> np.ndarray:
    """GT seed id under every keypoint ``uv`` (N, 2) px of one image (-1 = background)."""
    import cv2
    import pandas as pd

    m = cv2.imread(str(root / "gt" / "masks" / side / f"{view:06d}.png"), cv2.IMREAD_UNCHANGED)
    ins = pd.read_csv(root / "gt" / "instances" / side / f"{view:06d}.csv")
    lut = np.full(int(max(m.max(), ins.label.max() if len(ins) else 0)) + 1, -1, np.int64)
    lut[ins.label.values] = ins.seed_id.values
    if len(uv) == 0:
        return np.zeros(0, np.int64)
    u = np.clip(np.round(uv[:, 0]).astype(int), 0, m.shape[1] - 1)
    v = np.clip(np.round(uv[:, 1]).astype(int), 0, m.shape[0] - 1)
    return lut[m[v, u]]


def reach(root: Path, thresholds: list[float], detector_set: list[str], min_area: int = 12) -> dict:
    from seedmap.detect import make_detector
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import gt_countable_seeds

    ds = SeedmapDataset(root)
    countable = set(np.asarray(gt_countable_seeds(root, min_area)).tolist())
    cfg = ReconConfig(detector="fast")
    over = list(cfg.detector_overrides) + list(detector_set) + [f"cnn.threshold={min(thresholds)}"]
    det = make_detector("fast", dataset=ds, overrides=over)
    acc = {t: {"views": {}, "n": 0, "dup": 0, "bg": 0} for t in thresholds}
    for k in range(len(ds)):
        sd = det.detect_stereo(ds[k])
        a0 = keypoint_seed_ids(root, "left", k, sd.left.keypoints)
        b0 = keypoint_seed_ids(root, "right", k, sd.right.keypoints)
        for t in thresholds:
            a, b = a0[sd.left.scores >= t], b0[sd.right.scores >= t]
            r = acc[t]
            for x in set(a[a >= 0].tolist()) & set(b[b >= 0].tolist()):
                r["views"][x] = r["views"].get(x, 0) + 1
            on = a[a >= 0]
            r["n"] += len(a)
            r["dup"] += len(on) - len(set(on.tolist()))
            r["bg"] += int(np.sum(a < 0))
    out = {}
    for t, r in acc.items():
        both = {x for x, c in r["views"].items() if c >= 2}
        out[str(t)] = {"reachable_pct": 100.0 * len(both & countable) / max(len(countable), 1),
                       "dup_pct": 100.0 * r["dup"] / max(r["n"], 1), "background_pct": 100.0 * r["bg"] / max(r["n"], 1),
                       "left_keypoints": r["n"], "countable": len(countable)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--panicles", type=int, nargs="+", required=True)
    ap.add_argument("--data-dir", type=Path, default=Path("data/recon_s7"))
    ap.add_argument("--thresholds", default="0.4", help="comma-separated CNN thresholds (default: the pipeline's 0.4)")
    ap.add_argument("--detector-set", nargs="*", default=[], help="detector overrides appended to the pipeline's")
    ap.add_argument("--min-area", type=int, default=12,
                    help="countable = >= this many visible px in the left and right image of >= 2 views (the count "
                         "benchmark's reference uses 12)")
    ap.add_argument("--errors", type=Path, nargs="*", default=[],
                    help="bench_recon.py summary JSONs with the signed count error per panicle")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/count_reach.json"))
    a = ap.parse_args()
    from tqdm import tqdm

    thr = [float(x) for x in a.thresholds.split(",")]
    rows = {s: reach(a.data_dir / f"p{s}", thr, a.detector_set, a.min_area) for s in tqdm(a.panicles, desc="panicles")}
    res: dict = {"data_dir": str(a.data_dir), "detector_set": a.detector_set, "min_area": a.min_area,
                 "per_panicle": rows}
    for t in map(str, thr):
        r = np.array([rows[s][t]["reachable_pct"] for s in a.panicles])
        res[f"threshold_{t}"] = {"reachable_pct_mean": float(r.mean()), "reachable_pct_std": float(r.std()),
                                 "dup_pct_mean": float(np.mean([rows[s][t]["dup_pct"] for s in a.panicles]))}
        if a.errors:
            per: dict[int, float] = {}
            for f in a.errors:
                m = json.loads(f.read_text())["modes"]["seeds"]["count_multiview"]
                per.update({int(k): v for k, v in m["per_panicle_pct_vs_countable"].items()})
            s_ok = [s for s in a.panicles if s in per]
            e = np.array([per[s] for s in s_ok])
            rr = np.array([rows[s][t]["reachable_pct"] for s in s_ok])
            res[f"threshold_{t}"].update({"panicles_with_error": s_ok, "corr_reachable_signed_error":
                                          float(np.corrcoef(rr, e)[0, 1]),
                                          "fit_error_vs_reachable": np.polyfit(rr, e, 1).tolist()})
        print(f"threshold {t}: {res[f'threshold_{t}']}")
    from seedmap.io.atomic import atomic_write_text

    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(a.out, json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
