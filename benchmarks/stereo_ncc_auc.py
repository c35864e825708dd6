"""Does appearance tell a true left/right pair of seed keypoints from a wrong one? (issue #6)

On simulated arm scans (``DATA_DIR/pSEED``): the reconstruction's ``fast`` detections of every ``--every``-th
view, the multiview counter's stereo candidates (``_stereo_candidates``: same row within ``--dv`` px, disparity
in the counter's depth range), each candidate labelled true when its left and right keypoints sit on the same
GT seed (``gt/masks``). Reports the AUC (probability that a random true candidate scores above a random wrong
one) of the normalised cross-correlation of ``context_descriptors`` for several patch settings, and of the
negative row difference for comparison. Writes JSON (``--out``).

``python benchmarks/stereo_ncc_auc.py --panicles 96 --out benchmarks/results/stereo_ncc_auc.json``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from count_reach import keypoint_seed_ids  # benchmarks/ is on sys.path when run as a script

#: (name, colour?, half-width: px or "xS" = S x the view's median detection size, grid)
SETTINGS = [("grey 23 px", False, 11.0, 23), ("grey 31 px", False, 15.0, 31), ("grey 51 px, 11x11", False, 25.0, 11),
            ("colour 61 px, 11x11", True, 30.0, 11), ("colour 6 sizes, 15x15 (opt-in default)", True, "x6", 15)]


def auc(score: np.ndarray, true: np.ndarray) -> float:
    from scipy.stats import mannwhitneyu

    return float(mannwhitneyu(score[true], score[~true]).statistic / (true.sum() * (~true).sum()))


def main() -> None:
    import cv2

    from seedmap.detect import make_detector
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.recon.config import CountConfig, ReconConfig
    from seedmap.recon.count import _stereo_candidates, context_descriptors

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--panicles", type=int, nargs="+", required=True)
    ap.add_argument("--data-dir", type=Path, default=Path("data/recon_s7"))
    ap.add_argument("--every", type=int, default=6, help="use every N-th view")
    ap.add_argument("--dv", type=float, default=4.0, help="row tolerance of the candidates (px; the fast profile's)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/stereo_ncc_auc.json"))
    a = ap.parse_args()
    cc = CountConfig()
    res: dict = {"panicles": a.panicles, "every": a.every, "dv_px": a.dv, "per_panicle": {}}
    for s in a.panicles:
        root = a.data_dir / f"p{s}"
        ds = SeedmapDataset(root)
        calib = ds.calib
        det = make_detector("fast", dataset=ds, overrides=list(ReconConfig(detector="fast").detector_overrides))
        d_lo, d_hi = calib.fx * calib.baseline / cc.mv_max_depth, calib.fx * calib.baseline / cc.mv_min_depth
        true_all, dv_all, ncc_all = [], [], {n: [] for n, *_ in SETTINGS}
        for k in range(0, len(ds), a.every):
            fr = ds[k]
            sd = det.detect_stereo(fr)
            L, R = sd.left.keypoints, sd.right.keypoints
            sl, sr = keypoint_seed_ids(root, "left", k, L), keypoint_seed_ids(root, "right", k, R)
            c = _stereo_candidates(L, R, d_lo, d_hi, a.dv)
            true_all.append((sl[c[:, 0]] == sr[c[:, 1]]) & (sl[c[:, 0]] >= 0))
            dv_all.append(np.abs(L[c[:, 0], 1] - R[c[:, 1], 1]))
            med = float(np.median(0.5 * (sd.left.ellipses[:, 2] + sd.left.ellipses[:, 3])))
            for name, colour, r, grid in SETTINGS:
                il, ir = (fr.left, fr.right) if colour else (cv2.cvtColor(fr.left, cv2.COLOR_RGB2GRAY),
                                                             cv2.cvtColor(fr.right, cv2.COLOR_RGB2GRAY))
                rad = float(r[1:]) * med if isinstance(r, str) else r
                dl, dr = context_descriptors(il, L, rad, grid), context_descriptors(ir, R, rad, grid)
                ncc_all[name].append(np.einsum("ij,ij->i", dl[c[:, 0]], dr[c[:, 1]]))
        t = np.concatenate(true_all)
        row = {"candidates": int(len(t)), "true": int(t.sum()), "auc_row_difference": auc(-np.concatenate(dv_all), t)}
        for name in ncc_all:
            x = np.concatenate(ncc_all[name])
            row[f"auc_ncc {name}"] = auc(x, t)
            row[f"ncc_median_true {name}"] = float(np.median(x[t]))
            row[f"ncc_median_wrong {name}"] = float(np.median(x[~t]))
        res["per_panicle"][s] = row
        print(f"p{s}: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
                                    if not k.startswith("ncc_median")), flush=True)
    from seedmap.io.atomic import atomic_write_text

    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(a.out, json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
