"""The results pages (scripts/make_docs.py): one function per page, each from its benchmark JSON."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from docs_format import fixed, load, mean_std, method_label, num, pct, source, table

PUBLISHED_AS = {"orbslam3": "ORB-SLAM2 (beside orbslam3)"}


def page_paper(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("paper.json")
    if d is None:
        return None
    recs = d["records"]
    parts = [f"Commit `{d.get('commit', '?')}`, {d.get('date', '?')}, {d.get('machine', 'machine not recorded')}.\n",
             f"```bash\n{d.get('command', cmds.get('paper.json', ''))}\n```\n",
             *[f"Added by commit `{x.get('commit', '?')}`, {x.get('date', '?')}:\n\n```bash\n{x['command']}\n```\n"
               for x in d.get("added", [])],
             "Per range: fraction of the range mapped (maximum distance mapped over the range length) / the same "
             "with the map validated against ground truth (position error within max(5 % of distance, 5 cm)). "
             "`published` is the paper's Table 1 (ORB-SLAM2, beside `orbslam3`: its Table 2).\n"]
    for sc in dict.fromkeys(r["scenario"] for r in recs):
        rs = [r for r in recs if r["scenario"] == sc]
        methods = list(dict.fromkeys(r["method"] for r in rs))
        names = list(dict.fromkeys(r["range_name"] for r in rs))
        by = {(r["range_name"], r["method"]): r for r in rs}
        has_pub = any(r.get("published_mdm_m") is not None or r.get("published_failed") for r in rs)

        def cell(r: dict | None) -> str:
            if r is None:
                return ""
            if r.get("status") != "ok":
                return r.get("status", "n/a")
            return f"{pct(r.get('mdm_fraction'), 0)} / {pct(r.get('gt_mdm_fraction'), 0)}"

        rows = []
        for n in names:
            length = next((r.get("range_length_m") for r in rs if r["range_name"] == n and r.get("range_length_m")),
                          None)
            row = [f"{n} ({length:.2f} m)" if length else n] + [cell(by.get((n, m))) for m in methods]
            if has_pub:
                pubs = [f"{PUBLISHED_AS.get(m, method_label(m))}: "
                        f"{'failed' if r.get('published_failed') else num(r.get('published_mdm_m'))}"
                        for m in methods if (r := by.get((n, m))) and (r.get("published_mdm_m") is not None
                                                                     or r.get("published_failed"))]
                row.append("; ".join(pubs))
            rows.append(row)
        header = ["range"] + [method_label(m) for m in methods] + (["published MDM (m)"] if has_pub else [])
        parts.append(f"## {sc}\n\n" + table(header, rows))

        def mean(m: str, key: str) -> float | None:
            v = [r[key] for r in rs if r["method"] == m and r.get("status") == "ok" and r.get(key) is not None]
            return sum(v) / len(v) if v else None

        summ = [[method_label(m), pct(mean(m, "mdm_fraction")), pct(mean(m, "gt_mdm_fraction")),
                 num(None if (a := mean(m, "ate_rmse_m")) is None else 1000 * a),
                 num(None if (t := mean(m, "ms_per_frame")) is None else round(t)),
                 str(sum(1 for r in rs if r["method"] == m and r.get("status") == "ok"))] for m in methods]
        parts.append("\n" + table(["method", "mean fraction mapped", "GT-validated", "ATE (mm)", "ms / frame",
                                   "ranges run"], summ))
        notes = sorted({f"{r['method']} on {r['range_name']}: {r['note']}" for r in rs
                        if r.get("status") != "ok" and r.get("note")})
        if notes:
            parts.append("\nNotes: " + "; ".join(notes) + "\n")
        runs = [f"{r['method']} on {r['range_name']}: {r['note']}" for r in rs if r.get("status") == "ok"
                and r.get("note")]
        if runs:  # peers: the vocabulary used and the longest tracked segment
            parts.append("\nRuns: " + "; ".join(runs) + "\n")
    return "Paper benchmark (Table 1)", "\n".join(parts)


def _sweep_cell(p: dict, fail_below: float) -> str:
    if p.get("gt") is None:
        return "n/a" if p.get("na") else ("error" if p.get("errors") else "–")
    lo, hi = f"{100 * p['gt_min']:.0f}", f"{100 * p['gt_max']:.0f}"
    band = "" if lo == hi else f" ({lo}–{hi})"
    digits = 1 if round(100 * p["gt"]) == round(100 * fail_below) else 0  # which side of the line it lies on
    text = f"{100 * p['gt']:.{digits}f} %{band}" + (f" [{p['errors']} error]" if p.get("errors") else "")
    return f"**{text}**" if p["gt"] < fail_below else text


def _first_set(per: dict) -> tuple[list[str], str | None]:
    """The methods that fail at the smallest strength of one condition, and the ``level`` of that strength."""
    at = {}
    for m, v in per.items():
        s = next((p["strength"] for p in v["points"] if p["level"] == v["fails_first"]), None)
        if s is not None:
            at[m] = (s, v["fails_first"])
    if not at:
        return [], None
    s0 = min(s for s, _ in at.values())
    return [m for m, (s, _) in at.items() if s == s0], next(lev for s, lev in at.values() if s == s0)


def _first_to_fail(per: dict) -> str:
    """The methods that fail first under one condition, with the level (``none`` when every method holds)."""
    ms, lev = _first_set(per)
    return ", ".join(method_label(m) for m in ms) + f" ({lev})" if ms else "none"


def _seeds_first(conds: dict, methods: Sequence[str]) -> str:
    """Where seeds with a real (not ORACLE) detector are among the first to fail, said plainly."""
    out = []
    for m in (m for m in methods if m.startswith("seeds+") and not m.endswith("+gt")):
        where = [f"{c} ({lev})" for c, per in conds.items() for ms, lev in [_first_set(per["methods"])] if m in ms]
        out.append(f"{method_label(m)} is among the first to fail under: " + (", ".join(where) if where else
                                                                             "no condition of this sweep") + ".")
    return "\n" + " ".join(out) + "\n" if out else ""


def _sweep_detectors(methods: Sequence[str]) -> str:
    """Which seed detectors the sweep ran, and why ``frcnn-pix2pix`` is not among them when it is not."""
    dets = [m.split("+", 1)[1] for m in methods if m.startswith("seeds+")]
    named = [f"`{d}`" + (" (ORACLE: the ground-truth seed positions, the best any detector can give)"
                         if d == "gt" else "") for d in dets]
    text = "Seeds ran with the detector" + ("s " + ", ".join(named[:-1]) + " and " + named[-1] if len(named) > 1
                                            else " " + "".join(named)) + "."
    if not any(d.startswith("frcnn-pix2pix") for d in dets):
        text += (" The paper's detector is not in this sweep: `frcnn-pix2pix-lite` shipped after it ran, and "
                 "`frcnn-pix2pix` runs only with the user's own weights.")
    return text + " Plots: drawn by the sweep from the same summary, copied by `scripts/sweep_json.py`.\n"


def page_sweep(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("sweep.json")
    if d is None:
        return None
    summ, cfg = d["summary"], d.get("config") or {}
    conds = list(summ["conditions"])
    methods = list(dict.fromkeys(m for c in conds for m in summ["conditions"][c]["methods"]))
    seeds = ", ".join(str(s) for s in cfg.get("seeds", []))
    parts = [source("sweep.json", cmds),
             f"Commit `{d.get('commit', '?')}`, {d.get('date', '?')}, {d.get('machine', 'machine not recorded')}. "
             f"Simulated {num(cfg.get('length'))} m ranges, world seeds {seeds}; one condition at a time "
             "(`--set conditions.<c>=<strength>`, 1 = the typical field value of "
             "[docs/method/conditions.md](../method/conditions.md)), and the calm < breeze < windy < rough ladder. "
             f"A method fails at a strength when its mean GT-validated fraction of the range mapped drops below "
             f"{100 * summ['fail_below']:.0f} %.\n",
             _sweep_detectors(methods),
             "## Where each method fails first\n",
             table(["method"] + conds, [[method_label(m)] + [summ["conditions"][c]["methods"].get(m, {}).get(
                 "fails_first", "–") for c in conds] for m in methods]
                   + [["**first to fail**"] + [_first_to_fail(summ["conditions"][c]["methods"]) for c in conds]]),
             _seeds_first(summ["conditions"], methods)]
    for c in conds:
        per = summ["conditions"][c]["methods"]
        levels = [p["level"] for p in next(iter(per.values()))["points"]]
        rows = [[method_label(m)] + [_sweep_cell(p, summ["fail_below"]) for p in v["points"]] for m, v in per.items()]
        rows += [[f"{method_label(m)}: ATE (mm)"] + [num(None if p.get("ate_m") is None else 1000 * p["ate_m"])
                                                   for p in v["points"]]
                 for m, v in per.items() if any(p.get("ate_m") is not None for p in v["points"])]
        parts += [f"\n## {c}\n", f"![{c}: GT-validated fraction mapped vs strength per method](sweep/{c}.png)\n",
                  "GT-validated fraction of the range mapped: mean (min–max) over the world "
                  "seeds, in bold where the method fails; ATE over the tracked part, mean over the seeds that ran.\n",
                  table([f"{c} strength" if c != "ladder" else "rung"] + levels, rows)]
    notes = sorted({f"{r['method']}: {r['note']}" for r in d["records"] if r.get("status") not in ("ok", None)
                    and r.get("note")})
    if notes:
        parts.append("\nNotes: " + "; ".join(notes) + "\n")
    vocab = sorted({r["note"].split(";")[0] for r in d["records"] if r.get("status") == "ok"
                    and r.get("note", "").startswith("vocabulary")})
    if vocab:
        parts.append("\norbslam3 " + "; ".join(vocab) + ".\n")
    return "Robustness sweep (field conditions)", "\n".join(parts)


#: the phenotype page's per-range columns: (JSON key, header, formatter)
_PHENO_COLS = (("precision", "precision", fixed), ("recall", "recall", fixed),
               ("height_err_median_m", "height (cm)", lambda v: num(None if v is None else 100 * v, 2)),
               ("length_rel_err_median", "length", pct), ("width_rel_err_median", "width", pct),
               ("seeds_mape", "seeds MAPE", pct), ("landmarks_mape_visible", "landmarks vs visible", pct),
               ("visible_fraction", "visible fraction", lambda v: fixed(v, 2)))


def page_phenotype(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("phenotype.json")
    if d is None:
        return None
    cal = ", ".join(sorted({str(r.get("calibration")) for r in d.get("ranges", [])})) or "?"
    parts = [source("phenotype.json", cmds),
             f"Commit `{d.get('commit', '?')}`, {d.get('date', '?')}, {d.get('machine', 'machine not recorded')}. "
             f"`seedmap slam DATA --detector {d.get('detector', '?')}` on each simulated range, then `seedmap "
             f"phenotype --data DATA` and `seedmap eval phenotype` (seed-count calibration `{cal}`; method: "
             "[docs/method/phenotype.md](../method/phenotype.md)). Medians of absolute errors over the matched "
             "panicles; seed-count MAPE against the true number of seeds on the panicle, the landmark count against "
             "its visible seeds; visible fraction: visible over true seeds of the matched panicles. `tuning` ranges "
             "were used to set the table's rules and calibration, `held-out` ones never.\n"]
    ho = (d.get("summary") or {}).get("held-out")
    if ho:
        labels = dict((k, h) for k, h, _ in _PHENO_COLS)
        fmts = dict((k, f) for k, _, f in _PHENO_COLS)
        rows = [[labels[k], fmts[k](ho.get(k)), ("≥ " if t["kind"] == "min" else "≤ ") + fmts[k](t["bound"]),
                 "yes" if t["met"] else "**no**"] for k, t in ho["targets"].items()]
        rows.append(["visible fraction", fmts["visible_fraction"](ho.get("visible_fraction")), "(stated)", ""])
        parts += [f"## Held-out ranges ({', '.join(ho['ranges'])}), pooled\n",
                  f"{ho['matched']} matched panicles of {ho['panicles_est']} in the tables and "
                  f"{ho['panicles_gt_expected']} expected (GT panicles with at least 20 visible seeds).\n",
                  table(["score", "held-out", "target", "met"], rows)]

    def row(name: str, split: str, r: dict, extra: list[str]) -> list[str]:
        return [name, split, f"{r['panicles_est']} / {r['panicles_gt_expected']}",
                *[f(r.get(k)) for k, _, f in _PHENO_COLS], *extra]

    rows = [row(r["name"], r["split"], r, [fixed(r.get("phenotype_s"), 2), num(r.get("phenotype_vs_slam_ratio"), 2)])
            for r in d["ranges"]]
    for split in ("held-out", "tuning"):
        if (p := (d.get("summary") or {}).get(split)) and len(p["ranges"]) > 1:
            rows.append(row(f"**all {split}, pooled**", "", p, ["", ""]))
    parts += ["\n## Per range\n",
              "Panicles: in the table / expected. Phenotype step: `seedmap phenotype --data` in-process (the seeds "
              "detected again in every frame that sees a panicle whole, the table, CSV files, thumbnails, "
              "phenotype.html), wall seconds on a shared machine and its ratio to the SLAM run's own time on the "
              "range; `seedmap slam` counts on the seeds it already detected.\n",
              table(["range", "split", "panicles", *[h for _, h, _ in _PHENO_COLS], "phenotype step (s)",
                     "/ SLAM time"], rows)]
    return "Phenotype table (panicles from the seed map)", "\n".join(parts)


def _detect_accuracy(d: dict, cmds: dict[str, str]) -> str:
    rows, tot = [], {"tp": 0, "n_det": 0, "n_gt": 0}
    for name, v in d["datasets"].items():
        for thr, r in v["by_threshold"].items():
            rows.append([f"`{name}`", thr, num(r["precision"]), num(r["recall"]), f"**{num(r['f1'])}**",
                         num(r["kp_median_px"], 2), num(r["kp_p90_px"], 2), num(v.get("images"))])
            for k in tot:
                tot[k] += r[k]
    p, r = tot["tp"] / max(tot["n_det"], 1), tot["tp"] / max(tot["n_gt"], 1)
    rows.append(["**all, pooled**", "", num(p), num(r), f"**{num(2 * p * r / max(p + r, 1e-12))}**", "", "", ""])
    return "\n".join([
        "\n## Accuracy\n", source("detect_accuracy.json", cmds),
        "The default `fast` detector on simulated ranges never used for training or tuning: a detection is "
        "correct at box IoU ≥ 0.5 (one-to-one), ground-truth slivers below the detectable size are ignored; the "
        "keypoint error is the ellipse centre's distance to the true seed centre.\n",
        table(["dataset", "threshold", "precision", "recall", "F1", "keypoint error, median (px)", "p90 (px)",
               "images"], rows)])


def page_detect(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("bench_detect.json")
    if d is None:
        return None
    rows = [[r["detector"], f"{r['width']}×{r['height']}", num(r.get("ms_per_stereo_frame", r.get("ms"))),
             num(r.get("cpu_ms_1thread", r.get("cpu_ms_per_stereo_frame"))),
             num(r.get("fps_1core_from_cpu_time")), num(r.get("ratio_vs_blur_cpu")), num(r.get("detections"))]
            for r in d["rows"]]
    body = [source("bench_detect.json", cmds),
            f"{d.get('cpus', '?')} CPUs, load average {num(d.get('load_avg_1m'), 2)} at the start. "
            f"{d.get('note', '')}\n",
            "Speed per image (per stereo frame where the row says so); `fast-cnn` is the `fast` detector "
            "(CNN + refiner) unless a `[override]` is named.\n",
            table(["detector", "image", "wall ms", "CPU ms", "images/s per core", "CPU / blur",
                   "detections"], rows)]
    il = d.get("interleaved")
    if il:
        body.append(f"\nTimed round-robin ({il.get('rounds')} rounds, {il.get('image')}), CPU ms per image:\n")
        irows = [[mode, name, num(v.get("cpu_ms")), num(v.get("ratio_vs_shipped"))]
                 for mode, nets in il.get("networks", {}).items() for name, v in nets.items()]
        body.append(table(["mode", "network", "CPU ms", "ratio to shipped"], irows))
    acc = load("detect_accuracy.json")
    if acc is not None:
        body.append(_detect_accuracy(acc, cmds))
    return "Seed detection", "\n".join(body)


def page_slam(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("bench_slam.json")
    if d is None:
        return None
    label = {"none": "paper cost (`refine=none`)", "field": "field matcher (default)"}
    arows = [[label.get(r["refine"], r["refine"]), num(r["keypoints_left"]), num(1000 * r["stereo_cpu_s"]),
              num(1000 * r["temporal_cpu_s"]), num(r["association_frames_per_s"]),
              num(r["association_cpu_vs_sift_cpu_ratio"]), num(r["stereo_precision_synthetic"])]
             for r in d["association"]]
    prows = [[label.get(r["refine"], r["refine"]), num(r["keypoints_per_image"]), f"{r['frames_ok']}/{r['frames']}",
              num(r["ms_per_frame"]), num(r["cpu_ms_per_frame"]), num(r["ms_per_frame_vs_sift_ratio"])]
             for r in d.get("pipeline", [])]
    w, h = d.get("image", ["?", "?"])
    body = [source("bench_slam.json", cmds),
            f"Synthetic panicles drawn as blobs at {w}×{h}. Baseline in the same run: SIFT + brute-force kNN "
            f"on the same stereo pair, {num(d['baseline_sift_bf_stereo_cpu_s'])} s CPU.\n",
            "**Association** (stereo + temporal, per frame)\n",
            table(["association", "keypoints / image", "stereo CPU ms", "temporal CPU ms", "frames/s",
                   "CPU / SIFT", "stereo precision (synthetic)"], arows)]
    if prows:
        body += ["\n**Association + motion + iSAM2 back-end, per frame**\n",
                 table(["association", "keypoints / image", "frames tracked", "wall ms", "CPU ms", "wall / SIFT"],
                       prows)]
    for st in d.get("stages", []):
        la = st.get("load_average")
        busy = f", load average {num(la[0], 2)} → {num(la[1], 2)}" if la else ""
        cpu = f" of {d['cpu_model']}" if d.get("cpu_model") else ""
        body += [f"\n**Whole pipeline per stage on `{st['dataset']}`** (wall ms per frame, {st['cpu_count']} cores{cpu}{busy}; "
                 "with the prefetch thread decode and detection overlap the rest, so the stages add up to more than "
                 f"the wall time; ORB-SLAM3: {st['orbslam3']})\n", _stage_table(st)]
        if st.get("sequential_seeds_vs_orbslam3_ratio") is not None:
            body.append(f"\nSeeds / ORB-SLAM3, wall per frame: {num(st['seeds_vs_orbslam3_ratio'])} with the decode "
                        f"prefetch for both, {num(st['sequential_seeds_vs_orbslam3_ratio'])} with neither.\n")
    if ln := load("bench_slam_length.json"):
        lrows = [[num(r["length_m"]), f"`{r['online']}`", f"{r['frames_tracked']}/{r['frames']}",
                  num(r["cpu_ms_first_10pct"]), num(r["cpu_ms_last_10pct"]), num(r["last_vs_first_ratio"]),
                  _tenths(r),
                  num(r["final_batch_cpu_s"]), num(r["rss_growth_mb_per_m"]), num(r.get("online_position_rmse_mm")),
                  num(r["position_rmse_mm"]), num(r.get("smoother_variables_max"))]
                 for r in ln["rows"]]
        body += ["\n## Cost along a row\n", source("bench_slam_length.json", cmds),
                 "Synthetic seed geometry (no renderer); CPU of association + motion + back-end per frame, first and "
                 "last 10 % of the frames; `online = none` (motion estimate only) is the baseline of the same run; "
                 "the lowest and highest mean CPU of the 2nd to 10th tenth of the frames (the first is the ramp-up "
                 "while the view fills with landmarks); position RMSE of the online (per-frame) and the final (batch) "
                 "trajectory; the most variables the fixed-lag smoother held at once.\n",
                 table(["row (m)", "online", "frames tracked", "CPU ms first 10 %", "CPU ms last 10 %", "last / first",
                        "CPU ms, tenths 2–10",
                        "final batch (s CPU)", "memory growth (MB / m)", "online RMSE (mm)", "final RMSE (mm)",
                        "smoother variables"], lrows)]
    return "Semantic association and SLAM back-end speed", "\n".join(body)


def _tenths(r: dict) -> str:
    """Lowest–highest mean CPU ms of the 2nd to 10th tenth of a ``bench_slam_length.json`` row."""
    t = r.get("cpu_ms_tenths")
    return f"{num(min(t[1:]))}–{num(max(t[1:]))}" if t else "n/a"


_STAGE_COLS = ("decode", "detection", "stereo", "temporal", "motion", "backend")


def _stage_table(st: dict) -> str:
    """One row per method of a ``bench_slam.json`` ``stages`` entry, wall ratio to the ORB + BF front-end."""
    base = next((r["wall_ms_per_frame"] for r in st["rows"] if r["method"] == "ORB + BF"), None)
    rows = []
    for r in st["rows"]:
        sm = r["stages_ms"]
        cells = [num(sm.get(c)) if c in sm else "–" for c in _STAGE_COLS]
        if "tracking" in sm:
            cells[2] = f"tracking {num(sm['tracking'])}"
        tracked = "n/a" if r.get("frames_tracked") is None else f"{r['frames_tracked']}/{r['frames']}"
        rows.append([r["method"], tracked, *cells, num(r["final_ms_per_frame"]), num(r["wall_ms_per_frame"]),
                     num(r["cpu_ms_per_frame"]), num(r["wall_ms_per_frame"] / base) if base else "n/a",
                     num(None if r.get("ate_rmse_m") is None else 1000 * r["ate_rmse_m"])])
    return table(["method", "frames tracked", *_STAGE_COLS, "final opt.", "wall", "CPU", "wall / ORB + BF",
                  "ATE (mm)"], rows)


_RECON_METRICS = [("pose_trans_mm_mean", "pose error (mm)"), ("pose_rot_deg_mean", "rotation error (°)"),
                  ("cloud_dist_mm_median", "cloud error, median (mm)"), ("cloud_dist_mm_p90", "cloud error, p90 (mm)"),
                  ("icp_s_per_view", "ICP s / view")]


def _recon_eval(d: dict, title: str) -> str:
    pan = d.get("panicles", [])
    out = [f"**{title}**: detector `{d.get('detector')}`{' (ORACLE: reads the ground truth)' if d.get('detector') == 'gt' else ''}, "
           f"means ± standard deviations over {len(pan)} panicles ({pan[0]}–{pan[-1]}; the command's first panicle "
           "tunes the naive 2D baseline and is not among them).\n"
           if pan else f"**{title}**\n"]
    modes = d.get("modes", {})
    rows = [[f"`{m}`"] + [mean_std(v.get(k)) for k, _ in _RECON_METRICS] for m, v in modes.items()]
    out.append(table(["registration"] + [t for _, t in _RECON_METRICS], rows))
    crow = []
    for m, v in modes.items():
        for key, label in (("count_multiview", "raw count"), ("count_multiview_calibrated", "calibrated count")):
            c = v.get(key)
            if c:
                crow.append([f"`{m}`", label, f"{num(c.get('mape_vs_countable'))} %",
                             f"{num(c.get('mean_signed_pct_vs_countable'))} %", f"{num(c.get('mape_vs_visible'))} %"])
    if crow:
        out.append("\nSeed count error against the ground truth's countable seeds (and its visible ones):\n")
        out.append(table(["registration", "count", "MAPE", "mean signed", "MAPE vs visible"], crow))
    return "\n".join(out)


def _calibration(d: dict, title: str) -> str:
    rows = [["raw count", num(d["raw"]["mape_pct"]), num(d["raw"]["signed_pct"]), num(d["raw"]["max_abs_pct"]),
             num(d["raw"]["n"])]]
    if "calibrated" in d:
        c = d["calibrated"]
        rows.append(["calibrated count", num(c["mape_pct"]), num(c["signed_pct"]), num(c["max_abs_pct"]), num(c["n"])])
    text = [f"**{title}**\n", table(["", "MAPE (%)", "mean signed (%)", "max \\|error\\| (%)", "panicles"], rows)]
    fit = d.get("fit")
    if fit:
        text.append(f"\nFeatures {', '.join(f'`{f}`' for f in d.get('features', []))}; leave-one-out MAPE "
                    f"{num(fit.get('loo_mape_pct'))} % (mean signed {num(fit.get('loo_signed_pct'))} %).\n")
    return "\n".join(text)


def page_recon(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("bench_recon.json")
    if d is None:
        return None
    body = [source("bench_recon.json", cmds),
            f"Speed on one arm scan ({d.get('dataset')}, "
            f"{'×'.join(map(str, d.get('image_size', [])))} px):\n",
            table(["step", "s / view", "relative to SGBM", "points / view"], [
                ["SGBM stereo", num(d["sgbm_s_per_view"]), "1", ""],
                ["full-cloud ICP", num(d["full_icp_s_per_view"]), num(d["full_icp_over_sgbm"]),
                 num(d["points_per_view_full_icp"])],
                ["seed-centre ICP", num(d["seed_icp_s_per_view"]), num(d["seed_icp_over_sgbm"]),
                 num(d["points_per_view_seed_icp"])]])]
    for name, title in (("bench_recon_eval.json", "Accuracy with the default detector"),
                        ("bench_recon_eval_oracle.json", "Registration modes compared")):
        e = load(name)
        if e is not None:
            body += ["", f"## {title}\n", source(name, cmds), _recon_eval(e, title)]
    for name, title in (("count_calibration_fit.json", "Count calibration: the shipped fit"),
                        ("count_calibration_heldout.json", "Count calibration on panicles rendered after the fit")):
        c = load(name)
        if c is not None:
            body += ["", f"## {title}\n", source(name, cmds), _calibration(c, title)]
    return "Panicle reconstruction and seed count", "\n".join(body)


def page_sim(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("bench_sim.json")
    if d is None:
        return None
    rows = [[num(r["range_length_m"]), num(r["seeds_in_world"]), num(r["cpu_s_per_pair_median"]),
             num(r["cpu_s_per_pair_rendered_and_written"]), num(r["start_cpu_s_per_pair_median"]),
             num(r["ratio_cpu_pair_vs_bare_cast"]), num(r["world_build_cpu_s"]), num(r["peak_rss_mb_so_far"])]
            for r in d["ranges"]]
    w, h = d.get("image_size", ["?", "?"])
    body = [source("bench_sim.json", cmds),
            f"Stereo pairs at {w}×{h} (camera scale {d.get('scale')}), {d.get('cpu_count')} CPUs, open3d "
            f"{d.get('open3d')}. Render cost does not depend on the range length: long / short = "
            f"{num(d.get('ratio_long_vs_short_cpu'))}.\n",
            table(["range (m)", "seeds", "CPU s / pair (mid-range)", "rendered and written", "CPU s / pair (start)",
                   "CPU / bare cast", "world build CPU s", "peak RSS (MB)"], rows)]
    return "Simulator speed", "\n".join(body)


def page_io(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("bench_io.json")
    if d is None:
        return None
    rows = []
    for part, v in d.items():
        items = v.items() if isinstance(v, dict) else [("", v)]
        for k, x in items:
            shown = "×".join(map(str, x)) if isinstance(x, list) else num(x)
            rows.append([f"`{part}`", f"`{k}`" if k else "", shown])
    return "Loader speed", "\n".join([
        source("bench_io.json", cmds),
        "`rectify_overhead`: time per frame of an unrectified image folder (decode + remap) over decoding the same "
        "two PNGs; `bag_random_over_stream`: random access into a ROS 1 bag over one streaming pass.\n",
        table(["loader", "measure", "value"], rows)])


def page_batch(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("bench_batch.json")
    if d is None:
        return None
    w = d["workers"]
    body = [source("bench_batch.json", cmds),
            f"{d['ranges']} tiny ranges of {d['frames_per_range']} frames on {d['cpu_count']} CPUs; results "
            f"identical from both runs: {num(d['same_results'])}.\n",
            table(["workers", "wall s", "CPU s", "cores used"], [
                ["1", num(d["wall_s_1_worker"]), num(d["cpu_s_1_worker"]), num(d["cores_used_1_worker"])],
                [str(w), num(d[f"wall_s_{w}_workers"]), num(d[f"cpu_s_{w}_workers"]),
                 num(d[f"cores_used_{w}_workers"])]]),
            f"\nSpeed-up {num(d['speedup'])}×.\n"]
    return "Field batch speed-up", "\n".join(body)


def page_demo(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("demo.json")
    if d is None:
        return None
    ms = d.get("ms_per_frame", {})
    rows = [["frames tracked / in the range", f"{d['frames_tracked']} / {d['frames']}"],
            ["maximum distance mapped", f"{num(d['mdm_m'])} m ({pct(d['mdm_fraction'])} of {num(d['range_length_m'])} m)"],
            ["GT-validated maximum distance mapped", f"{num(d['gt_mdm_m'])} m ({pct(d['gt_mdm_fraction'])})"],
            ["ATE RMSE (aligned)", f"{num(1000 * d['ate_rmse_m'])} mm ({pct(d.get('ate_fraction_of_distance'), 2)} of "
                                   "the distance)"],
            ["RPE translation RMSE", f"{num(1000 * d['rpe_trans_rmse_m'])} mm"],
            ["landmarks", num(d.get("landmarks"))],
            ["matcher / detector / back-end", f"`{d.get('matcher')}` / `{d.get('detector')}` / `{d.get('backend')}`"]]
    trows = [[f"`{k}`", num(v)] for k, v in ms.items()]
    return "The demo", "\n".join([
        source("demo.json", cmds), table(["metric", "value"], rows), "\n**Time per frame (ms, mean)**\n",
        table(["stage", "ms"], trows)])


def _photo_row(name: str, r: dict) -> list[str]:
    return [name, num(r["precision"]), num(r["recall"]), f"**{num(r['f1'])}**", num(r.get("n_gt")),
            num(r.get("fp_per_mpx_seedless")), num(r.get("ms_per_image"))]


def _autoscale(a: dict) -> str:
    """Per network and rescale factor: estimates within 15 %, relative error median / max, seconds per estimate."""
    groups: dict = {}
    for r in a["rows"]:
        groups.setdefault((r["domain"], r["factor"]), []).append(r)
    rows = []
    for (dom, f), rs in sorted(groups.items()):
        err = [abs(r["rel_err"]) for r in rs if r.get("rel_err") is not None]
        srt = sorted(err)
        med = srt[len(srt) // 2] if srt else None
        rows.append([dom, f"{f:g}×", num(sum(r["true_seed_px"] for r in rs) / len(rs), 3),
                     f"{sum(e <= 0.15 for e in err)}/{len(rs)}", num(med, 2), num(max(err) if err else None, 2),
                     num(sorted(r["estimate_s"] for r in rs)[len(rs) // 2], 2)])
    big = a.get("big_image") or {}
    tail = (f"\nOne {big.get('width')}×{big.get('height')} image: {num(big.get('estimate_s'), 2)} s per estimate.\n"
            if big else "")
    curves = a.get("scale_curve") or {}
    if curves:
        rel = next(iter(curves.values()))["rel"]
        tail += ("\nBox F1 of the photo network on photos at their own size, run with the input scale at r × the one "
                 "that brings the true seed size to the network's, at the scale `cnn.scale=auto` picks (the ladder "
                 "level where the network scores highest) and at the seed-size estimate's:\n\n"
                 + table(["photos", "images", *[f"r {x:.2f}" for x in rel], "auto", "estimate"],
                         [[Path(k.rpartition(":")[0] if k.endswith((":photo", ":arm", ":field")) else k).parent.name,
                           str(c["images"]), *[num(f) for f in c["f1_rel"]], f"**{num(c['f1_auto'])}**",
                           num(c["f1_estimate"])] for k, c in curves.items()]))
    return ("Each image of the sets below resized by the factor (its true seed size scales with it); the estimate "
            "(`cnn.scale=auto`) against the median box side of its labelled seeds. Missing estimates count as "
            "failures.\n\n" + table(["network", "rescale", "true seed size, mean (px)", "within ±15 %",
                                       "|error| median", "|error| max", "s per estimate"], rows) + tail)

def page_photos(cmds: dict[str, str]) -> tuple[str, str] | None:
    d = load("photos.json")
    if d is None:
        return None
    head = ["set / network", "precision", "recall", "F1", "seeds", "false det. per MPx (seedless photos)",
            "ms per image"]
    rows = []
    for tag, r in d["sets"].items():
        for k, v in r.items():
            if isinstance(v, dict):
                rows.append(_photo_row(f"{tag}: {'shipped defaults' if k == 'default' else k}", v))
    body = [source("photos.json", cmds),
            "Simulated grain photos (`seedmap simulate photos`, docs/method/photos.md): `heldout` = backgrounds, "
            "lights and varieties never used for training; `seen` = training conditions, photos never trained on. "
            "`seedmap detect FOLDER` with its defaults (automatic seed scale, photo network); box IoU ≥ 0.5, "
            "one-to-one, every labelled seed counts. The renderer is kinder than the field: these are not real "
            "photos.\n", table(head, rows)]
    st = d.get("setups") or []
    if st:
        body += [f"\n### One setup: out of the box, and after a fine-tune on {len(st[0]['train_images'])} of its photos\n",
                 "Each set is one user's setup (`seedmap simulate photos --split heldout --set setup=true`): one "
                 "held-out background, light and seed lot. `seedmap train fast-cnn` with its defaults on the first "
                 f"{len(st[0]['train_images'])} labelled photos, `seedmap detect --weights` on the others.\n",
                 table(["setup (background, light, varieties)", "photos tested", "F1 out of the box",
                        *[f"F1 out of the box, {o}" for o in (st[0].get("before_set") or {})], "F1 after",
                        "precision after", "recall after", "fine-tune wall s", "CPU s"],
                       [[", ".join([x["setup"]["bg"], x["setup"]["light"], "+".join(x["setup"]["varieties"])])
                         if x.get("setup") else x["folder"], num(x["test_images"]), num(x["before"]["f1"]),
                         *[num(v["f1"]) for v in (x.get("before_set") or {}).values()],
                         num(x["after"]["f1"]), num(x["after"]["precision"]), num(x["after"]["recall"]),
                         num(x["wall_s"]), num(x["cpu_s"])] for x in st])]
    ft = d.get("finetune")
    if ft:
        body += [f"\n### Fine-tune on {len(ft['train_images'])} photos of the mixed held-out set\n",
                 f"`seedmap train fast-cnn` with its defaults on {len(ft['train_images'])} labelled photos of the "
                 f"held-out set ({ft.get('steps')} steps, {num(ft['wall_s'])} s wall, {num(ft['cpu_s'])} s CPU), "
                 f"then `seedmap detect --weights` on the other {ft['test_images']}:\n",
                 table(head, [_photo_row("before (shipped)", ft["before"]), _photo_row("after fine-tune", ft["after"])])]
    h = d["sets"].get("heldout", {}).get("default", {}).get("by_condition")
    if h:
        body += ["\n### Held-out set by condition (shipped defaults)\n",
                 table(["condition", "precision", "recall", "F1", "seeds"],
                       [[k, num(v["precision"]), num(v["recall"]), num(v["f1"]), num(v["n_gt"])]
                        for k, v in h.items()])]
    a = load("autoscale.json")
    if a is not None:
        body += ["\n## Automatic seed scale\n", source("autoscale.json", cmds), _autoscale(a)]
    return "Seeds in photos", "\n".join(body)
