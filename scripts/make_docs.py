#!/usr/bin/env python3
"""Write the results pages ``docs/results/*.md`` from the benchmark JSON files in ``benchmarks/results/``.

It also writes the results table of ``README.md`` (between its two marker comments). Every number on those
pages comes from a JSON file a benchmark wrote, and every page names the command that
wrote it (the table in ``benchmarks/README.md``), so the pages cannot drift from the runs. A page whose JSON is
absent (e.g. ``paper.json`` before the paper benchmark was run) is skipped and left out of the index.

    python scripts/make_docs.py [--out docs/results] [--no-readme]

Standard library only; ``tests/test_docs_generated.py`` checks that the committed pages are what this writes.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from docs_format import GENERATED, ROOT, commands, fixed, load, method_label, num, pct, table  # noqa: E402
from docs_learned import glance_learned, page_learned  # noqa: E402
from docs_pages import (page_batch, page_demo, page_detect, page_io, page_paper, page_phenotype,  # noqa: E402
                        page_photos, page_recon, page_sim, page_slam, page_sweep)

PAGES: dict[str, Callable[[dict[str, str]], tuple[str, str] | None]] = {
    "demo.md": page_demo,
    "paper.md": page_paper,
    "sweep.md": page_sweep,
    "phenotype.md": page_phenotype,
    "detect.md": page_detect,
    "learned.md": page_learned,
    "photos.md": page_photos,
    "slam.md": page_slam,
    "recon.md": page_recon,
    "sim.md": page_sim,
    "io.md": page_io,
    "batch.md": page_batch,
}


def _row_named(rows: list[dict], start: str) -> dict | None:
    return next((r for r in rows if r.get("detector", "").startswith(start)), None)


def glance() -> str:
    """The README's one results table, each row from a benchmark JSON (rows whose JSON is absent are left out)."""
    rows = []
    if d := load("demo.json"):
        rows.append([f"SLAM, `make demo` ({num(d['range_length_m'])} m range)",
                     f"{d['frames_tracked']}/{d['frames']} frames; {pct(d['mdm_fraction'], 0)} of the range mapped, "
                     f"{pct(d['gt_mdm_fraction'], 0)} GT-validated; ATE {num(1000 * d['ate_rmse_m'], 2)} mm "
                     f"({pct(d.get('ate_fraction_of_distance'), 2)} of the distance)", "[demo](docs/results/demo.md)"])
    if d := load("paper.json"):
        recs = [r for r in d["records"] if r["scenario"] == "paper"]
        parts = []
        for m in dict.fromkeys(r["method"] for r in recs):
            v = [r["gt_mdm_fraction"] for r in recs if r["method"] == m and r.get("status") == "ok"
                 and r.get("gt_mdm_fraction") is not None]
            if v:
                parts.append(f"{method_label(m)} {pct(sum(v) / len(v), 0)}")
        ranges = len({r["range_name"] for r in recs})
        rows.append([f"SLAM, the paper's {ranges} ranges", "mean GT-validated fraction mapped: " + ", ".join(parts),
                     "[paper](docs/results/paper.md)"])
    if d := load("sweep.json"):
        summ = d["summary"]["conditions"]
        worst = {m: [f"{c} {v['fails_first']}" for c, per in summ.items() for mm, v in per["methods"].items()
                     if mm == m and v["fails_first"] not in ("never in range", "n/a")]
                 for m in dict.fromkeys(m for per in summ.values() for m in per["methods"])}
        txt = "; ".join(f"{method_label(m)}: {', '.join(v) if v else 'never'}" for m, v in worst.items())
        cfg = d.get("config") or {}
        rows.append([f"SLAM under field conditions ({', '.join(summ)}), {num(cfg.get('length'))} m ranges, "
                     f"{len(cfg.get('seeds', []))} world seeds", "fails first at (mean GT-validated fraction "
                     f"< 50 %): {txt}", "[sweep](docs/results/sweep.md)"])
    if (d := load("phenotype.json")) and (ho := d["summary"].get("held-out")):
        rows.append([f"phenotype table, `{d.get('detector', '?')}`, {len(ho['ranges'])} held-out ranges",
                     f"panicles: precision {fixed(ho['precision'])}, recall {fixed(ho['recall'])}; median error of "
                     f"height {num(100 * ho['height_err_median_m'], 2)} cm, length {pct(ho['length_rel_err_median'])}, "
                     f"width {pct(ho['width_rel_err_median'])}; seed-count MAPE {pct(ho['seeds_mape'])} "
                     f"({pct(ho['visible_fraction'], 0)} of the seeds visible)",
                     "[phenotype](docs/results/phenotype.md)"])
    if d := load("detect_accuracy.json"):
        f1s, kps, tot = [], [], {"tp": 0, "n_det": 0, "n_gt": 0}
        for v in d["datasets"].values():
            for r in v["by_threshold"].values():
                f1s.append(r["f1"])
                kps.append(r["kp_median_px"])
                for k in tot:
                    tot[k] += r[k]
        p, r = tot["tp"] / tot["n_det"], tot["tp"] / tot["n_gt"]
        rows.append([f"seed detection, `fast`, {len(d['datasets'])} held-out ranges",
                     f"F1 {2 * p * r / (p + r):.3f} pooled ({min(f1s):.3f}–{max(f1s):.3f} per range); keypoint "
                     f"error median {min(kps):.2f}–{max(kps):.2f} px", "[detect](docs/results/detect.md)"])
    if row := glance_learned():
        rows.append(row)
    if d := load("photos.json"):
        h, ft = d["sets"].get("heldout", {}).get("default"), d.get("finetune")
        if h:
            txt = (f"F1 {num(h['f1'])} out of the box on {h['images']} photos of backgrounds, lights and varieties "
                   "never trained on")
            st = d.get("setups") or []
            if ft:
                txt += (f"; {num(ft['after']['f1'])} after `seedmap train fast-cnn` on {len(ft['train_images'])} of "
                        f"them ({num(ft['wall_s'] / 60, 2)} min)")
            if st:
                txt += (f"; on {len(st)} unseen one-setup sets {min(x['before']['f1'] for x in st):.2f}–"
                        f"{max(x['before']['f1'] for x in st):.2f} out of the box, "
                        f"{min(x['after']['f1'] for x in st):.3f}–{max(x['after']['f1'] for x in st):.3f} after "
                        f"`seedmap train fast-cnn` on {len(st[0]['train_images'])} of their photos")
            rows.append(["seed detection in simulated grain photos", txt, "[photos](docs/results/photos.md)"])
    if d := load("bench_detect.json"):
        one = _row_named(d["rows"], "fast (1 onnxruntime thread, gated tiles)")
        pair = _row_named(d["rows"], "fast stereo frame (left and right concurrently")
        if one and pair:
            rows.append(["detection speed, `fast`",
                         f"{num(one['cpu_ms_1thread'])} ms CPU per {one['width']}×{one['height']} image on one core; "
                         f"a stereo pair in {num(pair['ms_per_stereo_frame'])} ms on two cores",
                         "[detect](docs/results/detect.md)"])
    if d := load("bench_slam.json"):
        r = next((r for r in d["association"] if r["refine"] == "field" and r["keypoints_left"] == 1000), None)
        if r:
            rows.append(["association speed (default)",
                         f"{num(1000 * (r['stereo_cpu_s'] + r['temporal_cpu_s']), 2)} ms CPU per frame (stereo + "
                         "temporal) at 1,000 seeds per image", "[slam](docs/results/slam.md)"])
        paper = [st for st in d.get("stages", []) if st["dataset"].startswith("paper")
                 and st.get("seeds_vs_orbslam3_ratio") is not None]
        if paper:
            def span(vals: list[float]) -> str:
                lo, hi = num(min(vals)), num(max(vals))
                return lo if lo == hi else f"{lo}–{hi}"

            walls = {m: [next(r for r in st["rows"] if r["method"] == m)["wall_ms_per_frame"] for st in paper]
                     for m in ("seeds (fast), prefetch", "ORB-SLAM3, prefetch")}
            rows.append(["SLAM speed, whole pipeline (decode to back-end), paper ranges",
                         f"{span(walls['seeds (fast), prefetch'])} ms per frame on two cores against ORB-SLAM3's "
                         f"{span(walls['ORB-SLAM3, prefetch'])} in the same run "
                         f"({span([st['seeds_vs_orbslam3_ratio'] for st in paper])}× slower)",
                         "[slam](docs/results/slam.md)"])
    e, o = load("bench_recon_eval.json"), load("bench_recon_eval_oracle.json")
    if e or o:
        txt = []

        def reg(modes: dict, m: str) -> str:
            return (f"{num(modes[m]['pose_trans_mm_mean']['mean'], 3)} mm / "
                    f"{num(modes[m]['pose_rot_deg_mean']['mean'], 2)}°")

        if e and "seeds" in e["modes"]:
            txt.append(f"seed-centre ICP with `fast`: {reg(e['modes'], 'seeds')}")
        if o and {"seeds", "full"} <= set(o["modes"]):
            txt.append(f"with the ORACLE detector {reg(o['modes'], 'seeds')} vs full-cloud ICP {reg(o['modes'], 'full')}")
        rows.append(["arm-scan registration, pose error", "; ".join(txt), "[recon](docs/results/recon.md)"])
    if (d := load("count_calibration_heldout.json")) and "calibrated" in d:
        rows.append([f"seed count, `fast`, {d['raw']['n']} panicles rendered after the fit",
                     f"calibrated MAPE {num(d['calibrated']['mape_pct'])} % (raw count {num(d['raw']['mape_pct'])} %)",
                     "[recon](docs/results/recon.md)"])
    if d := load("bench_sim.json"):
        cpu = [r["cpu_s_per_pair_median"] for r in d["ranges"]]
        rows.append(["simulator", f"{min(cpu):.2f}–{max(cpu):.2f} s CPU per stereo pair on "
                     f"{' and '.join(num(r['range_length_m']) for r in d['ranges'])} m ranges",
                     "[sim](docs/results/sim.md)"])
    return table(["what", "result", "page"], rows)


README_BEGIN = "<!-- results table: generated by scripts/make_docs.py (make docs) -->"
README_END = "<!-- end of the generated results table -->"


def readme_with_glance(text: str) -> str:
    """``text`` (the README) with the block between the two markers replaced by :func:`glance`."""
    head, sep, rest = text.partition(README_BEGIN)
    _, sep2, tail = rest.partition(README_END)
    if not sep or not sep2:
        raise SystemExit(f"README.md lacks the markers {README_BEGIN!r} ... {README_END!r}")
    return f"{head}{README_BEGIN}\n{glance()}{README_END}{tail}"


def write(out: Path) -> list[Path]:
    """Write every page whose JSON exists, and the index, into ``out``; return the written paths."""
    out.mkdir(parents=True, exist_ok=True)
    cmds = commands()
    written, index = [], []
    for fname, make in PAGES.items():
        page = make(cmds)
        if page is None:
            continue
        title, body = page
        p = out / fname
        p.write_text(f"{GENERATED}\n\n# {title}\n\n{body.rstrip()}\n")
        written.append(p)
        index.append(f"- [{title}]({fname})")
    idx = out / "README.md"
    idx.write_text(f"{GENERATED}\n\n# Results\n\nEach page is generated from the benchmark JSON files in "
                   "[`benchmarks/results/`](../../benchmarks/results/) (how each was produced: "
                   "[`benchmarks/README.md`](../../benchmarks/README.md)).\n\n" + "\n".join(index) + "\n")
    return [idx] + written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results")
    ap.add_argument("--no-readme", action="store_true", help="leave README.md's results table alone")
    args = ap.parse_args()
    for p in write(args.out):
        print(p)
    if not args.no_readme:
        readme = ROOT / "README.md"
        readme.write_text(readme_with_glance(readme.read_text()))
        print(readme)


if __name__ == "__main__":
    main()
