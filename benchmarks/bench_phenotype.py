"""Phenotype table accuracy on simulated paper ranges: ``seedmap slam`` then ``seedmap eval phenotype`` per range.

For every range: ``seedmap slam DATA --detector fast`` (skipped when ``--reuse-slam DIR`` already holds the
result ``DIR/NAME``), then the phenotype step as ``seedmap phenotype`` runs it (table, CSVs, report; timed
in-process) and ``seedmap eval phenotype`` (detection precision and recall, median errors of height, length and
width, seed-count MAPE against the true seeds, landmark count against the visible seeds, visible fraction).
Ranges are preset names (``paper1`` ...: read from ``--data-dir/paperN-sSEED-default``, the cache of
``seedmap benchmark paper``, and simulated there when missing) or dataset folders with ground truth. The ranges
the table was tuned on (``--tuning``) are labelled ``tuning``, the others ``held-out``; the summary pools the
matched panicles of the held-out ranges.

    python benchmarks/bench_phenotype.py [--ranges paper1 ... paper6] [--data-dir data/benchmark]
        [--reuse-slam results/phenotype_slam] [--set calibration=fast-shape] [--out F.json]

With ``--reuse-slam`` a rerun after a change of the table or the count model costs only the phenotype and eval
steps (seconds per range); without it the SLAM results go to a temporary folder.
"""

from __future__ import annotations

import argparse
import importlib
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from provenance import stamp  # noqa: E402

#: the ranges of the default run: the held-out ones and those the table was tuned on
DEFAULT_RANGES = ("paper1", "paper2", "paper3", "paper4", "paper5", "paper6")
#: ranges the table's rules and calibrations were tuned on (docs/method/phenotype.md)
TUNING = ("paper1", "paper2", "paper3")
#: the accuracy targets on held-out ranges: (key of the summary, bound, "min" = at least / "max" = at most)
TARGETS = {"precision": (0.95, "min"), "recall": (0.95, "min"), "height_err_median_m": (0.02, "max"),
           "length_rel_err_median": (0.10, "max"), "width_rel_err_median": (0.10, "max"),
           "seeds_mape": (0.15, "max")}
#: per-range scores of ``seedmap eval phenotype`` copied into the JSON
SCORES = ("panicles_est", "panicles_gt", "panicles_gt_expected", "matched", "precision", "recall",
          "position_err_median_m", "height_err_median_m", "length_rel_err_median", "width_rel_err_median",
          "seeds_mape", "landmarks_mape_visible", "visible_fraction", "landmarks_per_visible_seed", "height_source",
          "calibration")


def resolve_range(name: str, data_dir: Path) -> tuple[str, Path]:
    """``(label, dataset folder)`` of a preset name (simulated into ``data_dir`` when missing) or a folder."""
    from seedmap.eval.benchmark.run import simulate_job
    from seedmap.eval.benchmark.spec import sim_cache_name
    from seedmap.sim.config import preset_dict

    p = Path(name)
    if p.is_dir():
        return p.resolve().name, p
    seed = int(preset_dict(name).get("seed", 0))  # an unknown preset raises one line
    out = data_dir / sim_cache_name(name, seed, ())
    if not out.is_dir():
        print(f"simulating {name} into {out}", flush=True)
    simulate_job(name, seed, (), str(out))
    return name, out


def slam(dataset: Path, out: Path, detector: str) -> float | None:
    """``seedmap slam DATASET --detector DETECTOR --out OUT`` (no report.html); wall seconds, None when reused."""
    from seedmap.slam.pipeline import run_slam

    if (out / "landmarks.csv").is_file() and (out / "trajectory.tum").is_file():
        return None
    t0 = time.perf_counter()
    run_slam(dataset, out, detector=detector, overwrite=out.exists(), progress=False, html_report=False,
             phenotype=False)
    return time.perf_counter() - t0


def phenotype_step(result: Path, data: Path, out: Path, cfg):  # noqa: ANN001, ANN201
    """``seedmap phenotype RESULT --data DATA --out OUT`` in-process (the seeds detected again in the frames that
    see a panicle whole); (wall, CPU) seconds and the images, their detections kept for the evaluation."""
    from seedmap.outputs import output_dir
    from seedmap.phenotype.run import phenotype_result, result_images, write_phenotype

    t0, c0 = time.perf_counter(), time.process_time()
    images = result_images(result, data)
    ph = phenotype_result(result, cfg, images)
    with output_dir(out, "phenotype", inputs=[result, data], overwrite=True) as tmp:
        write_phenotype(tmp, ph, images, title=f"seedmap phenotype: {result.name}")
    return time.perf_counter() - t0, time.process_time() - c0, images


def slam_seconds(result: Path) -> float | None:
    """The SLAM run's own time (frames x total ms per frame of its metrics.json), for the ratio."""
    try:
        m = json.loads((result / "metrics.json").read_text())
        return m["frames"] * m["ms_per_frame"]["total_per_frame"] / 1000.0
    except (OSError, KeyError, TypeError, ValueError):
        return None


def pooled(records: list[dict]) -> dict:
    """Scores over the matched panicles of several ranges pooled (precision and recall over their counts)."""
    per = [p for r in records for p in r["per_panicle"]]
    est = sum(r["panicles_est"] for r in records)
    expected = sum(r["panicles_gt_expected"] for r in records)
    found = sum(round((r["recall"] or 0.0) * r["panicles_gt_expected"]) for r in records)
    med = lambda k: float(np.median([abs(p[k]) for p in per])) if per else None  # noqa: E731
    mean = lambda k: float(np.mean([abs(p[k]) for p in per])) if per else None  # noqa: E731
    seeds = sum(p["seeds"] for p in per)
    out = {"ranges": [r["name"] for r in records], "panicles_est": est, "panicles_gt_expected": expected,
           "matched": len(per), "precision": len(per) / est if est else None,
           "recall": found / expected if expected else None,
           "height_err_median_m": med("height_err_m"), "length_rel_err_median": med("length_rel_err"),
           "width_rel_err_median": med("width_rel_err"), "seeds_mape": mean("seeds_rel_err"),
           "landmarks_mape_visible": mean("landmarks_rel_err_visible"),
           "visible_fraction": sum(p["seeds_visible"] for p in per) / seeds if seeds else None,
           "phenotype_s_mean": float(np.mean([r["phenotype_s"] for r in records])) if records else None}
    out["targets"] = {k: {"bound": b, "kind": kind, "met": (out[k] is not None
                                                             and (out[k] >= b if kind == "min" else out[k] <= b))}
                      for k, (b, kind) in TARGETS.items()}
    return out


def run(ranges: list[str], data_dir: Path, slam_dir: Path, detector: str, tuning: set[str],
        sets: list[str]) -> dict:
    """Every range through slam, the phenotype step and its evaluation; the JSON record."""
    from seedmap.config import load_config
    from seedmap.phenotype.config import PhenotypeConfig
    from seedmap.phenotype.evaluate import evaluate_phenotype

    cfg = load_config(PhenotypeConfig, None, sets)
    for mod in ("matplotlib.pyplot", "seedmap.phenotype.table", "seedmap.phenotype.report"):
        importlib.import_module(mod)  # before the timed phenotype step: its time is the work, not the imports

    records = []
    for name in ranges:
        label, data = resolve_range(name, data_dir)
        res = slam_dir / label
        slam_s = slam(data, res, detector)
        print(f"{label}: slam {'reused' if slam_s is None else f'{slam_s:.0f} s'}", flush=True)
        wall, cpu, images = phenotype_step(res, data, slam_dir / f"{label}_phenotype", cfg)
        m = evaluate_phenotype(res, data, cfg, images)
        base = slam_seconds(res)
        rec = {"name": label, "split": "tuning" if label in tuning else "held-out", "dataset": str(data),
               "slam": "reused" if slam_s is None else "run", "slam_s": base,
               "phenotype_s": wall, "phenotype_cpu_s": cpu,
               "phenotype_vs_slam_ratio": wall / base if base else None,
               **{k: m.get(k) for k in SCORES}, "per_panicle": m["per_panicle"]}
        records.append(rec)
        print(f"{label}: P {rec['precision']:.3f} R {rec['recall']:.3f} seeds MAPE {rec['seeds_mape']:.3f} "
              f"phenotype {wall:.2f} s", flush=True)
    held = [r for r in records if r["split"] == "held-out"]
    tune = [r for r in records if r["split"] == "tuning"]
    return {"detector": detector, "config": cfg.model_dump(), "ranges": records,
            "summary": {"held-out": pooled(held) if held else None, "tuning": pooled(tune) if tune else None}}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ranges", nargs="+", default=list(DEFAULT_RANGES),
                    help="presets (paperN) or simulated dataset folders with gt/")
    ap.add_argument("--data-dir", type=Path, default=Path("data/benchmark"),
                    help="where preset ranges are read from / simulated into (PRESET-sSEED-default)")
    ap.add_argument("--reuse-slam", type=Path, default=None,
                    help="keep the SLAM results in DIR/NAME and reuse the ones already there")
    ap.add_argument("--detector", default="fast", help="seed detector of the SLAM runs")
    ap.add_argument("--tuning", nargs="*", default=list(TUNING), help="ranges labelled tuning (others: held-out)")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="phenotype config key=value")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "phenotype.json")
    a = ap.parse_args(argv)
    from seedmap.errors import SeedmapError

    tmp = None
    if a.reuse_slam is None:
        tmp = Path(tempfile.mkdtemp(prefix="bench_phenotype_"))
    try:
        slam_dir = a.reuse_slam if a.reuse_slam is not None else tmp
        slam_dir.mkdir(parents=True, exist_ok=True)
        res = run(a.ranges, a.data_dir, slam_dir, a.detector, set(a.tuning), a.sets)
    except SeedmapError as e:
        raise SystemExit(f"error: {e}") from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    cmd = " ".join(["python", "benchmarks/bench_phenotype.py", *(argv if argv is not None else sys.argv[1:])])
    doc = {**stamp(cmd), **res}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(doc, indent=1, default=float) + "\n")
    s = res["summary"]["held-out"]
    if s:
        print(f"held-out ({', '.join(s['ranges'])}): P {s['precision']:.3f} R {s['recall']:.3f} "
              f"height {100 * s['height_err_median_m']:.2f} cm length {100 * s['length_rel_err_median']:.1f} % "
              f"width {100 * s['width_rel_err_median']:.1f} % seeds MAPE {100 * s['seeds_mape']:.1f} %")
    print(a.out)


if __name__ == "__main__":
    main()
