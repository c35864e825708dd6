"""Panicle reconstruction benchmark.

Speed (default): seconds per view of SGBM, full-cloud ICP and seed-centre ICP, measured in one run on one
simulated arm scan; ICP costs are also given as ratios to SGBM. Writes JSON (``--out``, default
``benchmarks/results/bench_recon.json``). ``python benchmarks/bench_recon.py [--dataset DIR | --views N --seed S]``
-- without ``--dataset`` a scan is simulated into a temporary folder first (not timed).

Accuracy (``--eval 100 101 ... 110``): simulates the missing scans (``--eval-views``, default 24) into
``DATA_DIR/pSEED``, reconstructs each in the registration modes of ``--modes`` (fk, full, seeds) with each detector
of ``--detectors`` (default gt), counts seeds with both count methods -- ``multiview`` (the default counter, with the
detector's profile and the count calibration, as the pipeline runs it) and ``density`` (the paper's) -- and the naive
2D baseline (detections / detections per seed of the first panicle, which calibrates it and is left out of the
means), and writes per-panicle JSON and ``summary.json`` into ``results/recon_eval_bench/DETECTOR[_TAG]/``. The 2D
detections (with the SGBM disparity at the left keypoints) are cached per panicle in ``cache/pSEED_kps_HASH.npz``,
HASH over the detector config and weights and the SGBM config; ``--recount`` re-runs only the counting on cached
reconstructions, ``--count-set key=value`` overrides the multiview CountConfig, ``--detector-set key=value`` the
detector config. The evaluation protocol and the measured numbers: docs/method/counting.md.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np


COUNT_METHODS = ("density", "multiview")


DEFAULT_DATA_DIR = Path("data/recon_eval")
KPS_CACHE_VERSION = 2  # per-view keypoints + SGBM disparity at the left keypoints


def _recon_config(det: str, detector_set: tuple[str, ...] = ()):  # noqa: ANN202 - ReconConfig
    """The pipeline's config for detector ``det`` with ``detector_set`` appended to its detector overrides."""
    from seedmap.recon.config import ReconConfig

    cfg = ReconConfig(detector=det)
    cfg.detector_overrides = list(cfg.detector_overrides) + list(detector_set)
    return cfg


def _kps_cache_path(cache: Path, s: int, det: str, detector_set: tuple[str, ...] = ()) -> Path:
    """Cache file of a panicle's 2D detections, keyed by a hash of everything that makes them: the
    detector name and resolved config, its weights file (learned detectors), the SGBM/cloud config
    (the keypoint disparities) and the cache format -- a retrained detector gets a fresh cache."""
    import hashlib

    from seedmap.detect.config import resolve_config

    cfg = _recon_config(det, detector_set)
    dcfg = resolve_config(None, cfg.detector_overrides)
    h = hashlib.sha1(json.dumps([KPS_CACHE_VERSION, det, dcfg.model_dump(),
                                 cfg.sgbm.model_dump(), cfg.cloud.model_dump()], sort_keys=True,
                                default=str).encode())
    if det == "fast":
        from seedmap.detect.cnn import cnn_weights_path

        w = cnn_weights_path(dcfg.cnn)
        if w.is_file():
            h.update(w.read_bytes())
    return cache / f"p{s}_kps_{h.hexdigest()[:10]}.npz"


def _save_kps(path: Path, kps: list) -> None:
    """Per-view StereoKeypoints (None = skipped view) -> npz."""
    arrs: dict = {"n_views": len(kps)}
    for i, k in enumerate(kps):
        arrs[f"skipped_{i}"] = k is None
        if k is not None:
            arrs[f"left_{i}"], arrs[f"right_{i}"], arrs[f"size_{i}"] = k.left, k.right, k.left_size
            arrs[f"disp_{i}"] = k.left_disp if k.left_disp is not None else np.full(len(k.left), np.nan)
    np.savez_compressed(path, **arrs)


def _detections_cache(root: Path, det: str, path: Path, detector_set: tuple[str, ...] = ()) -> tuple[list, object]:
    """Per-view 2D detections (StereoKeypoints with the SGBM disparity at the left keypoints) of a
    scan with detector ``det``, cached in ``path`` (detector and SGBM run only when it is missing),
    and the scan's calibration."""
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.recon.count import StereoKeypoints

    ds = SeedmapDataset(root)
    if not path.is_file():
        from seedmap.detect import make_detector
        from seedmap.progress import track
        from seedmap.recon.stereo import compute_disparity

        cfg = _recon_config(det, detector_set)
        d = make_detector(det, dataset=ds, overrides=list(cfg.detector_overrides))
        kps = []
        for i in track(range(len(ds)), f"{root.name} detections + SGBM", "view"):
            fr = ds[i]
            sd = d.detect_stereo(fr)
            disp = compute_disparity(fr.left, fr.right, ds.calib, cfg.sgbm, cfg.cloud)
            kps.append(StereoKeypoints.from_detections(sd.left, sd.right, disp))
        _save_kps(path, kps)
    with np.load(path) as z:
        kps = [None if bool(z[f"skipped_{i}"]) else
               StereoKeypoints(z[f"left_{i}"], z[f"right_{i}"], z[f"size_{i}"], z[f"disp_{i}"])
               for i in range(int(z["n_views"]))]
    return kps, ds.calib


def _count_diagnostics(obs: dict, root: Path, gt_ids: np.ndarray) -> dict:
    """Oracle checks that split the count error into its sources (gt detector only): ``ids_2views``
    = distinct true seeds among the observations seen from >= 2 views (what a perfect
    de-duplication of these observations would count), and each method run on the TRUE seed
    centres of the observations (in the reconstruction frame: the clusterer alone)."""
    from seedmap.eval.recon_metrics import pose_errors
    from seedmap.geometry import invert, transform_points
    from seedmap.io.seedmap_dataset import SeedmapDataset
    from seedmap.recon.config import CountConfig
    from seedmap.recon.count import count_density
    from seedmap.sim.panicle_scan import gt_rest_poses

    sid, view, poses = obs["seed_id"], obs["view"], obs["poses"]
    ok = sid >= 0
    key = np.unique(sid[ok] * (view.max() + 1) + view[ok])
    ids, nv = np.unique(key // (view.max() + 1), return_counts=True)
    out = {"ids_observed": int(len(ids)), "ids_2views": int(np.sum(nv >= 2)),
           "countable_observed_2views": int(len(np.intersect1d(ids[nv >= 2], gt_ids)))}
    seeds = SeedmapDataset(root).gt_seeds()
    pos = dict(zip(seeds.seed_id.tolist(), seeds.xyz))
    T = invert(pose_errors(poses, gt_rest_poses(root)).T_align)
    true_xyz = transform_points(T, np.array([pos[i] for i in sid[ok]]).reshape(-1, 3))
    out["count_density_true_positions"] = count_density(true_xyz, view[ok], obs["diam"][ok],
                                                        CountConfig(method="density")).count
    return out


def _calibrated(kps: list, cnt, count_cfg, det: str, detector_set: tuple[str, ...]):  # noqa: ANN001, ANN202
    """The count calibration (``count_cfg.calibration``, default auto; ``count_cfg`` before the detector's profile)
    applied to a multiview count, with the domain of the pipeline run these detections came from."""
    from seedmap.recon.calibrate import calibrate_count, count_features

    cfg = _recon_config(det, detector_set)
    cfg.count = count_cfg
    return calibrate_count(cfg, count_features(kps, cnt))


def _count_fields(obs: dict, gt_vis: int, countable: np.ndarray, root: Path, oracle: bool,
                  kps: list | None = None, calib=None, count_set: tuple[str, ...] = (), det: str = "gt",
                  detector_set: tuple[str, ...] = ()) -> dict:
    """Every count method on one reconstruction's observations (``multiview``: on the 2D
    detections ``kps`` with the registered poses, CountConfig overrides ``count_set`` key=value, then
    the profile of detector ``det`` as the pipeline applies it), against both references."""
    from seedmap.config import apply_overrides
    from seedmap.recon.config import CountConfig
    from seedmap.recon.count import count_density, count_multiview

    m: dict = {}
    for meth in COUNT_METHODS:
        c1 = time.process_time()
        if meth == "multiview":
            base_cfg = CountConfig(**apply_overrides({"method": meth}, count_set))
            mv_cfg = base_cfg.for_detector(det)
            cnt = count_multiview(kps, obs["poses"], calib, mv_cfg)
            n = cnt.count
            cal = _calibrated(kps, cnt, base_cfg, det, detector_set)
            m["count_features"] = cal.features.as_dict()
            m["count_calibration"] = cal.source
            m["count_calibration_note"] = cal.reason
            if cal.estimate is not None:
                e = cal.estimate
                m["count_multiview_calibrated"] = e
                m["count_multiview_calibrated_ape"] = abs(e - gt_vis) / max(gt_vis, 1) * 100
                m["count_multiview_calibrated_visible_err"] = (e - gt_vis) / max(gt_vis, 1) * 100
                m["count_multiview_calibrated_countable_err"] = (e - len(countable)) / max(len(countable), 1) * 100
                m["count_multiview_calibrated_cpu_s"] = 0.0
        else:
            n = count_density(obs["xyz"], obs["view"], obs["diam"], CountConfig(method=meth)).count
        m[f"count_{meth}_cpu_s"] = time.process_time() - c1
        m[f"count_{meth}"] = n
        m[f"count_{meth}_ape"] = abs(n - gt_vis) / max(gt_vis, 1) * 100
        m[f"count_{meth}_visible_err"] = (n - gt_vis) / max(gt_vis, 1) * 100
        m[f"count_{meth}_countable_err"] = (n - len(countable)) / max(len(countable), 1) * 100
    if oracle:
        m["diagnostics"] = _count_diagnostics(obs, root, countable)
    return m


def _summarize(rows: list[dict], modes: tuple[str, ...], det: str) -> dict:
    from seedmap.eval.recon_metrics import summarize_scan_rows

    tune, held = rows[0], rows[1:]
    summary = summarize_scan_rows(rows, list(modes), (tune["panicle"],))
    summary["detector"] = det
    for mode in modes:
        for meth in COUNT_METHODS + ("multiview_calibrated",):
            if not all(f"count_{meth}_ape" in r["modes"][mode] for r in rows):
                continue
            ape = [r["modes"][mode][f"count_{meth}_ape"] for r in held]
            err = [r["modes"][mode][f"count_{meth}_countable_err"] for r in held]
            verr = [r["modes"][mode].get(f"count_{meth}_visible_err", np.nan) for r in held]
            summary["modes"][mode][f"count_{meth}"] = {
                "mape_vs_visible": float(np.mean(ape)), "mape_vs_countable": float(np.mean(np.abs(err))),
                "mean_signed_pct_vs_countable": float(np.mean(err)),
                "mean_signed_pct_vs_visible": float(np.mean(verr)),
                "tuning_panicle_pct_vs_countable": round(tune["modes"][mode][f"count_{meth}_countable_err"], 1),
                "per_panicle_pct_vs_countable": {r["panicle"]: round(e, 1) for r, e in zip(held, err)},
                "per_panicle_pct_vs_visible": {r["panicle"]: round(e, 1) for r, e in zip(held, verr)},
                "count_cpu_s_mean": float(np.mean([r["modes"][mode][f"count_{meth}_cpu_s"] for r in held]))}
    # the naive 2D baseline: detections / (detections per seed on the tuning panicle)
    for ref in ("gt_visible", "gt_countable"):
        vps = tune["detections"] / max(tune[ref], 1)
        summary[f"naive_2d_vs_{ref.split('_')[1]}"] = {"views_per_seed": vps, "mape": float(np.mean(
            [abs(r["detections"] / vps - r[ref]) / r[ref] * 100 for r in held])), "mean_signed_pct": float(np.mean(
            [(r["detections"] / vps - r[ref]) / r[ref] * 100 for r in held]))}
    summary["prepare_cpu_s_per_panicle"] = float(np.mean([r["prepare_cpu_s"] for r in rows]))
    return summary


def run_eval(seeds: list[int], views: int = 24, detectors: tuple[str, ...] = ("gt",),
             modes: tuple[str, ...] = ("fk", "full", "seeds"), recount: bool = False,
             count_set: tuple[str, ...] = (), detector_set: tuple[str, ...] = (), tag: str = "",
             data_dir: Path = DEFAULT_DATA_DIR) -> dict:
    """Accuracy of fk / full / seeds registration and of seed counting on simulated scans, per detector.

    Count references (both reported): ``gt_visible`` = centre visible and >= 12 px in >= 1 left view;
    ``gt_countable`` = >= 12 px in the left AND right image of >= 2 views (what a 3D
    counter that needs stereo depth and a second view can count). Each reconstruction's seed
    observations are cached (``cache/pSEED_MODE.npz``); ``recount`` re-runs only the counting on them.
    ``detector_set``: detector config overrides appended to the pipeline's (e.g. ``cnn.weights=W.onnx``);
    ``tag``: results go to ``results/recon_eval_bench/DETECTOR_TAG`` (runs with other settings kept apart);
    ``data_dir``: where the scans are read from / simulated into (``DATA_DIR/pSEED``); a folder other than the
    default puts its name into the results folder (``DETECTOR_DATADIRNAME_TAG``), so caches of the same panicle
    number rendered differently never mix."""
    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import gt_countable_seeds, gt_metrics, gt_visible_seeds, prepare_scan, reconstruct
    from seedmap.sim.arm import ArmConfig
    from seedmap.sim.panicle_scan import PanicleScanConfig, simulate_panicle

    out_all: dict = {}
    for det in detectors:
        name = det if Path(data_dir) == DEFAULT_DATA_DIR else f"{det}_{Path(data_dir).name}"
        out = Path("results/recon_eval_bench") / (f"{name}_{tag}" if tag else name)
        (out / "cache").mkdir(parents=True, exist_ok=True)
        rows = []
        for s in seeds:
            root = Path(data_dir) / f"p{s}"
            if recount:
                row = json.loads((out / f"p{s}.json").read_text())
                for mode in row["modes"]:
                    with np.load(out / "cache" / f"p{s}_{mode}.npz") as z:
                        obs = {k: z[k] for k in z.files}
                    kps, calib = _detections_cache(root, det, _kps_cache_path(out / "cache", s, det, detector_set),
                                                   detector_set)
                    row["modes"][mode].update(_count_fields(obs, row["gt_visible"], gt_countable_seeds(root, 12),
                                                            root, row["oracle"] and mode == "seeds", kps, calib,
                                                            count_set, det, detector_set))
                (out / f"p{s}.json").write_text(json.dumps(row, indent=1))
                rows.append(row)
                continue
            if not root.exists():  # (data/recon_eval keeps the flash-saturated field gain, exposure=1.0)
                expo = 1.0 if Path(data_dir) == DEFAULT_DATA_DIR else "auto"
                simulate_panicle(PanicleScanConfig(seed=s, arm=ArmConfig(views=views), exposure=expo), root,
                                 progress=True)
            cfg = _recon_config(det, detector_set)
            c0, w0 = time.process_time(), time.perf_counter()
            prep = prepare_scan(root, cfg, progress=True)
            gt_vis = int(len(gt_visible_seeds(root, 12)))
            countable = gt_countable_seeds(root, 12)
            row = {"panicle": s, "detector": det, "oracle": prep.oracle, "gt_visible": gt_vis,
                   "gt_countable": int(len(countable)), "sgbm_s_per_view": float(np.mean(prep.seconds_sgbm)),
                   "detections": int(sum(v.n_detections for v in prep.views if v is not None)),
                   "observations": int(sum(len(v.seeds) for v in prep.views if v is not None)),
                   "prepare_cpu_s": time.process_time() - c0, "prepare_wall_s": time.perf_counter() - w0,
                   "modes": {}}
            for mode in modes:
                cfg.registration.mode = mode
                t0 = time.perf_counter()
                rec = reconstruct(prep, cfg)
                m = gt_metrics(rec, root, 12)
                m["quality"] = rec.quality
                m["icp_s_per_view"] = float(np.mean(rec.registration.seconds[1:]))
                m["reconstruct_s"] = time.perf_counter() - t0
                obs = {"xyz": rec.obs_xyz, "view": rec.obs_view, "diam": rec.obs_diam, "seed_id": rec.obs_seed_id,
                       "poses": rec.poses}
                np.savez_compressed(out / "cache" / f"p{s}_{mode}.npz", **obs)
                kp_path = _kps_cache_path(out / "cache", s, det, detector_set)
                if not kp_path.is_file():  # the prepared views hold them already (no second detector run)
                    _save_kps(kp_path, [v.keypoints if v is not None else None for v in prep.views])
                kps, calib = _detections_cache(root, det, kp_path, detector_set)
                m.update(_count_fields(obs, gt_vis, countable, root, rec.oracle and mode == "seeds", kps, calib,
                                       count_set, det, detector_set))
                row["modes"][mode] = m
            (out / f"p{s}.json").write_text(json.dumps(row, indent=1))
            rows.append(row)
        summary = _summarize(rows, modes if not recount else tuple(rows[0]["modes"]), det)
        summary["multiview_count_set"] = list(count_set)
        summary["detector_set"] = list(detector_set)
        (out / "summary.json").write_text(json.dumps(summary, indent=1))
        out_all[det] = summary
    return out_all


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--eval", type=int, nargs="+", default=None, help="accuracy evaluation on these scan seeds")
    ap.add_argument("--detectors", nargs="+", default=["gt"], help="--eval: detectors to evaluate (gt, fast, ...)")
    ap.add_argument("--modes", nargs="+", default=["fk", "full", "seeds"], help="--eval: registration modes")
    ap.add_argument("--recount", action="store_true", help="--eval: only re-run the counting on the cached "
                                                          "observations of an earlier --eval run")
    ap.add_argument("--count-set", nargs="*", default=[], help="--eval: CountConfig overrides (key=value) of "
                                                               "the multiview count, e.g. mv_relink_px=3")
    ap.add_argument("--detector-set", nargs="*", default=[], help="--eval: detector config overrides "
                                                                  "(key=value) added to the pipeline's")
    ap.add_argument("--tag", default="", help="--eval: write to results/recon_eval_bench/DETECTOR_TAG")
    ap.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR,
                    help="--eval: scans are read from / simulated into DATA_DIR/pSEED (data/recon_eval: "
                         "flash-saturated field gain; any other folder: auto exposure)")
    ap.add_argument("--dataset", type=Path, default=None, help="existing arm scan dataset")
    ap.add_argument("--views", type=int, default=12, help="views of the speed run's scan")
    ap.add_argument("--eval-views", type=int, default=24, help="--eval: views of the scans it simulates")
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results") / "bench_recon.json")
    args = ap.parse_args()
    if args.eval:
        print(json.dumps(run_eval(args.eval, views=args.eval_views, detectors=tuple(args.detectors),
                                  modes=tuple(args.modes), recount=args.recount, count_set=tuple(args.count_set),
                                  detector_set=tuple(args.detector_set), tag=args.tag, data_dir=args.data_dir),
                         indent=1))
        return

    from seedmap.recon.config import ReconConfig
    from seedmap.recon.pipeline import prepare_scan
    from seedmap.recon.register import register_views

    with tempfile.TemporaryDirectory() as tmp:
        root = args.dataset
        if root is None:
            from seedmap.sim.arm import ArmConfig
            from seedmap.sim.panicle_scan import PanicleScanConfig, simulate_panicle

            root = Path(tmp) / "scan"
            simulate_panicle(PanicleScanConfig(seed=args.seed, arm=ArmConfig(views=args.views)), root, progress=True)
        cfg = ReconConfig(detector="gt")  # (speeds of SGBM and ICP, not of a detector)
        t0 = time.perf_counter()
        prep = prepare_scan(root, cfg, progress=True)
        prep_s = time.perf_counter() - t0
        geoms = [v.geometry if v is not None else None for v in prep.views]
        res = {}
        for mode in ("full", "seeds"):
            cfg.registration.mode = mode
            t0 = time.perf_counter()
            reg = register_views(geoms, prep.T_fk, cfg.registration)
            res[mode] = {"icp_s_per_view": float(np.mean(reg.seconds[1:])),
                         "register_total_s": time.perf_counter() - t0}
        sgbm = float(np.mean(prep.seconds_sgbm))
        n_views = len(prep.views)
        geo0 = next(g for g in geoms if g is not None)
        out = {
            "dataset": str(args.dataset) if args.dataset else f"simulated seed {args.seed}, {args.views} views",
            "image_size": [prep.calib.width, prep.calib.height],
            "views": n_views,
            "sgbm_s_per_view": sgbm,
            "full_icp_s_per_view": res["full"]["icp_s_per_view"],
            "seed_icp_s_per_view": res["seeds"]["icp_s_per_view"],
            "full_icp_over_sgbm": res["full"]["icp_s_per_view"] / sgbm,
            "seed_icp_over_sgbm": res["seeds"]["icp_s_per_view"] / sgbm,
            "full_over_seed_icp": res["full"]["icp_s_per_view"] / max(res["seeds"]["icp_s_per_view"], 1e-9),
            "points_per_view_full_icp": int(len(geo0.cloud_xyz)),
            "points_per_view_seed_icp": int(len(geo0.seeds_xyz)),
            "prepare_total_s": prep_s,
            "machine": platform.processor() or platform.machine(),
        }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
