"""Seeds in photos: detection out of the box on simulated grain photos, and after a fine-tune on 10 of them.

Runs the product's own commands as a user would (subprocesses): ``seedmap detect FOLDER`` with the default
settings (automatic seed scale, the photo network), ``seedmap train fast-cnn LABELS.json`` on ``--finetune-n``
labelled photos of the held-out set, then ``seedmap detect`` with the fine-tuned weights on the rest of it. Scores
are box F1 (IoU >= 0.5, greedy one-to-one, every labelled seed counts) pooled over the photos, also per background,
light and layout; false positives per megapixel on photos without seeds. Sets come from ``seedmap simulate photos``:

    seedmap simulate photos --out data/ph_heldout --count 60 --seed 300 --split heldout
    seedmap simulate photos --out data/ph_seen --count 30 --seed 400
    seedmap simulate photos --out data/ph_setup_500 --count 30 --seed 500 --split heldout --set setup=true  # 500-503
    .venv/bin/python benchmarks/bench_photos.py --heldout data/ph_heldout --seen data/ph_seen \
        --setup data/ph_setup_500 --setup data/ph_setup_501 --out benchmarks/results/photos.json

Fine-tunes run on the mixed held-out set (many setups in ten photos) and on each ``--setup`` set (one user's setup:
ten photos of it train, the other twenty are scored).

``--compare-domain field`` also scores the field network on the same photos (what the photos got before);
``--compare-set KEY=VALUE`` the shipped network with that setting (e.g. ``cnn.scale=folder``) on every set.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seedmap.eval.detect_metrics import match_boxes  # noqa: E402


def seedmap(*args: str) -> tuple[float, float]:
    """Run ``seedmap ARGS``; return (wall s, CPU s of the child)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "seedmap.cli", *args], check=True, cwd=ROOT,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.perf_counter() - t0, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def boxes_by_name(coco: dict, min_score: float = 0.0) -> dict[str, np.ndarray]:
    """``{file_name: (N, 4) x0, y0, x1, y1}`` of a COCO dict (annotations with ``score`` below ``min_score`` dropped)."""
    names = {im["id"]: im["file_name"] for im in coco["images"]}
    out: dict[str, list] = {n: [] for n in names.values()}
    for a in coco["annotations"]:
        if a.get("score", 1.0) >= min_score:
            x, y, w, h = a["bbox"]
            out[names[a["image_id"]]].append([x, y, x + w, y + h])
    return {k: np.asarray(v, np.float64).reshape(-1, 4) for k, v in out.items()}


def score(gt_coco: dict, det_coco: dict, names: list[str]) -> dict:
    """Pooled P/R/F1 over ``names`` and the breakdown per condition; FP per megapixel on seedless photos."""
    gt, det = boxes_by_name(gt_coco), boxes_by_name(det_coco)
    info = {im["file_name"]: im for im in gt_coco["images"]}
    tot = np.zeros(3)
    groups: dict[str, np.ndarray] = defaultdict(lambda: np.zeros(3))
    fp_empty, mpx_empty = 0, 0.0
    for n in names:
        g, d = gt[n], det.get(n, np.zeros((0, 4)))
        md, _, _ = match_boxes(d, g, 0.5)
        c = np.array([len(md), len(d), len(g)], float)
        tot += c
        cond = info[n].get("conditions", {})
        for key in ("background", "light", "layout"):
            if key in cond:
                groups[f"{key}={cond[key]}"] += c
        if len(g) == 0:
            fp_empty += len(d)
            mpx_empty += info[n]["width"] * info[n]["height"] / 1e6

    def prf(c: np.ndarray) -> dict:
        p, r = c[0] / max(c[1], 1), c[0] / max(c[2], 1)
        return {"precision": round(p, 4), "recall": round(r, 4), "f1": round(2 * p * r / max(p + r, 1e-12), 4),
                "tp": int(c[0]), "n_det": int(c[1]), "n_gt": int(c[2])}

    return {**prf(tot), "images": len(names), "fp_per_mpx_seedless": round(fp_empty / mpx_empty, 2) if mpx_empty else None,
            "by_condition": {k: prf(v) for k, v in sorted(groups.items())}}


def detect_and_score(folder: Path, gt: dict, names: list[str], work: Path, tag: str, *extra: str) -> dict:
    """``seedmap detect`` on ``folder`` (with ``extra`` options), scored against ``gt``; adds ms per image."""
    out = work / f"det_{tag}"
    wall, cpu = seedmap("detect", str(folder), "--out", str(out), *extra)
    det = json.loads((out / "detections_coco.json").read_text())
    meta = json.loads((out / "meta.json").read_text())
    s = score(gt, det, names)
    s.update({"ms_per_image": round(meta.get("ms_per_image", float("nan")), 1), "wall_s": round(wall, 1),
              "cpu_s": round(cpu, 1), "options": list(extra)})
    return s


def subset(folder: Path, gt: dict, names: list[str], dest: Path) -> Path:
    """A folder of links to ``names`` of ``folder`` with their labels (``labels.json``); returns it."""
    dest.mkdir(parents=True)
    keep = {im["id"] for im in gt["images"] if im["file_name"] in names}
    for n in names:
        os.symlink((folder / n).resolve(), dest / n)
    sub = {**gt, "images": [im for im in gt["images"] if im["id"] in keep],
           "annotations": [a for a in gt["annotations"] if a["image_id"] in keep]}
    (dest / "labels.json").write_text(json.dumps(sub))
    return dest


def finetune(folder: Path, n: int, extra: list[str], work: Path, tag: str, compare: list[str] = ()) -> dict:
    """``seedmap train fast-cnn`` on the first ``n`` photos with seeds of ``folder``; box F1 of ``seedmap detect``
    on the rest before (defaults; also with each ``compare`` override, ``before_set``) and after (the fine-tuned
    weights)."""
    gt = json.loads((folder / "labels.json").read_text())
    with_seeds = {an["image_id"] for an in gt["annotations"]}
    names = [im["file_name"] for im in gt["images"]]
    train = [im["file_name"] for im in gt["images"] if im["id"] in with_seeds][:n]
    rest = [k for k in names if k not in train]
    tr = subset(folder, gt, train, work / f"{tag}_train")
    te = subset(folder, gt, rest, work / f"{tag}_test")
    (te / "labels.json").unlink()
    before = detect_and_score(te, gt, rest, work, f"{tag}_before")
    before_set = {o: detect_and_score(te, gt, rest, work, f"{tag}_before_{k}", "--set", o) for k, o in enumerate(compare)}
    wall, cpu = seedmap("train", "fast-cnn", str(tr / "labels.json"), "--out", str(work / f"{tag}_ft"), *extra)
    tm = json.loads((work / f"{tag}_ft" / "train_metrics.json").read_text())
    after = detect_and_score(te, gt, rest, work, f"{tag}_after", "--weights", str(work / f"{tag}_ft" / "fast_cnn.onnx"))
    print("finetune", tag, round(wall), before["f1"], "->", after["f1"], flush=True)
    return {"folder": str(folder), "setup": gt.get("info", {}).get("setup"), "train_images": train,
            "test_images": len(rest), "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "steps": tm.get("steps"),
            "val_f1": tm.get("val_f1"), "before": before, "before_set": before_set, "after": after}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--heldout", type=Path, required=True, help="seedmap simulate photos --split heldout folder")
    ap.add_argument("--seen", type=Path, help="a --split train folder not used for training")
    ap.add_argument("--setup", type=Path, action="append", default=[],
                    help="a --split heldout --set setup=true folder (one user's setup): fine-tuned on its own")
    ap.add_argument("--finetune-n", type=int, default=10, help="labelled photos to fine-tune on")
    ap.add_argument("--finetune-args", default="", help="extra options of seedmap train fast-cnn")
    ap.add_argument("--compare-domain", action="append", default=[], help="also score cnn.domain=NAME")
    ap.add_argument("--compare-set", action="append", default=[],
                    help="also score the shipped network with this --set KEY=VALUE (held-out, seen and setup sets)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    res: dict = {"what": "box F1 (IoU >= 0.5) of seedmap detect on simulated grain photos, default settings",
                 "command": " ".join(sys.argv), "sets": {}}
    with tempfile.TemporaryDirectory(prefix="bench_photos_") as tmp:
        work = Path(tmp)
        for tag, folder in (("heldout", a.heldout), ("seen", a.seen)):
            if folder is None:
                continue
            gt = json.loads((folder / "labels.json").read_text())
            names = [im["file_name"] for im in gt["images"]]
            r = {"folder": str(folder), "default": detect_and_score(folder, gt, names, work, tag)}
            for dom in a.compare_domain:
                r[f"domain={dom}"] = detect_and_score(folder, gt, names, work, f"{tag}_{dom}", "--set",
                                                      f"cnn.domain={dom}")
            for k, o in enumerate(a.compare_set):
                r[o] = detect_and_score(folder, gt, names, work, f"{tag}_set{k}", "--set", o)
            res["sets"][tag] = r
            print(tag, {k: (v["f1"], v["precision"], v["recall"]) for k, v in r.items() if isinstance(v, dict)})
        # fine-tunes: on the mixed held-out set (many setups), and on each one-setup set (a user's case)
        extra = a.finetune_args.split()
        res["finetune"] = finetune(a.heldout, a.finetune_n, extra, work, "mixed")
        res["setups"] = [finetune(f, a.finetune_n, extra, work, f"setup{i}", a.compare_set) for i, f in enumerate(a.setup)]
        if res["setups"]:
            res["setups_mean"] = {k: round(float(np.mean([r[k]["f1"] for r in res["setups"]])), 4)
                                  for k in ("before", "after")}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
