"""The panicle reconstruction pipeline: arm scan dataset -> registered cloud, seed count, metrics.

``prepare_scan`` does the per-view work once (SGBM, clouds, detections, 3D seed centres);
``reconstruct`` registers the views in one mode, merges the cloud and counts seeds;
``write_results`` writes the results folder (config.yaml, metrics.json, cloud.ply, seeds.csv,
observations.csv, detections.csv, calib.yaml, poses_tum.txt, poses_fk_tum.txt, report.md).
"""

from __future__ import annotations

import io
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from seedmap import outputs
from seedmap.config import dump_config
from seedmap.detect import detector_label
from seedmap.errors import InputError
from seedmap.geometry import transform_points
from seedmap.io.atomic import atomic_write_text
from seedmap.io.text import read_table, read_text
from seedmap.progress import Progress
from seedmap.recon.config import ReconConfig
from seedmap.recon.calibrate import CalibratedCount, calibrate_count, count_features
from seedmap.recon.count import SeedCount, StereoKeypoints, count_density, count_multiview
from seedmap.recon.register import (FULL_VOXEL, NORMAL_RADIUS, RegistrationResult, ViewGeometry, estimate_normals,
                                    register_views, voxel_down)
from seedmap.recon.stereo import (
    SeedObservations,
    ViewCloud,
    compute_disparity,
    detection_label_image,
    disparity_to_cloud,
    seed_centres,
)
from seedmap.records import StereoCalib
from seedmap.viz.rerun_log import check_rrd_path

JOINTS_FILE = "joints.csv"
ARM_FILE = "arm.yaml"
#: views with fewer valid 3D points are skipped
MIN_VIEW_POINTS = 500


def scan_files(root: str | Path, cfg: ReconConfig | None = None) -> tuple[Path, Path]:
    """The joints and arm files of a scan: the config's, else ``joints.csv`` / ``arm.yaml`` in the dataset folder
    (next to the file for a bag)."""
    root = Path(root)
    base = root if root.is_dir() else root.parent
    joints = Path(cfg.joints) if cfg is not None and cfg.joints else base / JOINTS_FILE
    arm = Path(cfg.arm) if cfg is not None and cfg.arm else base / ARM_FILE
    return joints, arm


def load_fk_poses(root: Path, n_frames: int, joints_path: Path | None = None,
                  arm_path: Path | None = None) -> np.ndarray:
    """Nominal camera poses from ``joints.csv`` (measured joints) and ``arm.yaml`` (DH, base, hand-eye);
    by default both in ``root``."""
    from seedmap.sim.arm import fk_camera_poses, read_joints_csv

    root = Path(root)
    joints_path = Path(joints_path) if joints_path is not None else root / JOINTS_FILE
    views, q = read_joints_csv(joints_path)
    arm_path = Path(arm_path) if arm_path is not None else root / ARM_FILE
    if not arm_path.is_file():
        raise InputError("arm description not found (needed with joints.csv for FK poses)", arm_path)
    try:
        arm = yaml.safe_load(read_text(arm_path, "arm description"))
    except yaml.YAMLError:
        raise InputError("arm description is not valid YAML", arm_path) from None
    if not isinstance(arm, dict):
        raise InputError("arm description must be a YAML mapping", arm_path)
    if len(q) == n_frames and not np.array_equal(views, np.arange(n_frames)):
        # the right number of rows, but not views 0..N-1 in order (was 'has 6 rows for views 0..5, but the
        # dataset has 6 frames', which names no problem)
        k = int(np.flatnonzero(views != np.arange(n_frames))[0])
        raise InputError(f"joints file rows must be views 0..{n_frames - 1} in order, one row each; line {k + 2} "
                         f"has view {views[k]} (expected {k})", joints_path)
    if len(q) != n_frames:
        raise InputError(f"joints file has {len(q)} rows for views {views.min()}..{views.max()}, "
                         f"but the dataset has {n_frames} frames", joints_path)
    try:
        return fk_camera_poses(q, arm)
    except InputError as e:
        raise InputError(str(e), arm_path) from None


@dataclass
class PreparedView:
    cloud: ViewCloud  # voxel-downsampled, left camera frame, with detection indices
    seeds: SeedObservations
    geometry: ViewGeometry
    n_detections: int
    keypoints: StereoKeypoints | None = None  # the view's 2D detections (count method ``multiview``)


@dataclass
class PreparedScan:
    """Per-view results that do not depend on the registration mode."""

    root: Path
    calib: StereoCalib
    T_fk: np.ndarray
    views: list[PreparedView | None]
    skipped: list[dict]
    timestamps: np.ndarray
    seconds_sgbm: np.ndarray
    seconds_detect: np.ndarray
    oracle: bool


def _downsample_view(vc: ViewCloud, voxel: float) -> ViewCloud:
    """Open3D voxel averaging of points and colours; detection index of the nearest original point."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    if len(vc) == 0:
        return vc
    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(vc.xyz))
    p.colors = o3d.utility.Vector3dVector(vc.rgb.astype(np.float64) / 255.0)
    d = p.voxel_down_sample(voxel)
    xyz = np.asarray(d.points)
    rgb = np.clip(np.asarray(d.colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    _, nn = cKDTree(vc.xyz).query(xyz)
    return ViewCloud(xyz, rgb, vc.det[nn])


def prepare_scan(root: str | Path, cfg: ReconConfig, progress: bool = True) -> PreparedScan:
    """SGBM, clouds, detections and 3D seed centres of every view of an arm scan dataset."""
    from seedmap.detect import make_detector

    root = Path(root)
    ds = cfg.dataset.open(root)  # seedmap layout or any format seedmap reads (rectified at load)
    if len(ds) == 0:
        raise InputError("dataset has no stereo pairs", root)
    T_fk = load_fk_poses(root, len(ds), *scan_files(root, cfg))
    det = make_detector(cfg.detector, dataset=ds, overrides=list(cfg.detector_overrides))
    oracle = bool(getattr(det, "is_oracle", False))
    views: list[PreparedView | None] = []
    skipped: list[dict] = []
    t_sgbm = np.zeros(len(ds))
    t_det = np.zeros(len(ds))
    it = range(len(ds))
    bar = Progress(len(ds), "views (SGBM + seeds)", "view", enabled=progress)
    for i in it:
        frame = ds[i]
        t0 = time.perf_counter()
        disp = compute_disparity(frame.left, frame.right, ds.calib, cfg.sgbm, cfg.cloud)
        t_sgbm[i] = time.perf_counter() - t0
        t0 = time.perf_counter()
        sdet = det.detect_stereo(frame)
        t_det[i] = time.perf_counter() - t0
        labels = detection_label_image(disp.shape, sdet.left)
        vc = disparity_to_cloud(disp, frame.left, ds.calib, cfg.cloud, labels)
        bar.advance()
        if len(vc) < MIN_VIEW_POINTS:
            skipped.append({"view": i, "reason": f"only {len(vc)} valid 3D points (min {MIN_VIEW_POINTS})"})
            views.append(None)
            continue
        vc = _downsample_view(vc, cfg.cloud.voxel_size)
        so = seed_centres(disp, sdet.left, ds.calib, cfg.cloud)
        reg_xyz = voxel_down(vc.xyz, FULL_VOXEL)
        # seed ICP uses the measured front-surface points of the seeds: seen from neighbouring views
        # they are nearly the same points, while the radius push-back adds view-dependent errors
        geo = ViewGeometry(reg_xyz, estimate_normals(reg_xyz, NORMAL_RADIUS), so.surface_xyz)
        views.append(PreparedView(vc, so, geo, len(sdet.left),
                                  StereoKeypoints.from_detections(sdet.left, sdet.right, disp)))
    bar.close()
    if all(v is None for v in views):
        raise InputError("no view has valid disparity in the configured depth range "
                         f"({cfg.cloud.min_depth}-{cfg.cloud.max_depth} m)", root)
    return PreparedScan(root, ds.calib, T_fk, views, skipped, ds.timestamps.copy(), t_sgbm, t_det, oracle)


@dataclass
class Reconstruction:
    mode: str
    poses: np.ndarray
    T_fk: np.ndarray
    timestamps: np.ndarray
    registration: RegistrationResult
    cloud_xyz: np.ndarray
    cloud_rgb: np.ndarray
    cloud_label: np.ndarray  # counted seed index per point, -1 = none
    obs_xyz: np.ndarray  # world seed observations
    obs_view: np.ndarray
    obs_diam: np.ndarray
    obs_seed_id: np.ndarray
    count: SeedCount
    quality: dict
    skipped: list[dict]
    oracle: bool
    seconds: dict = field(default_factory=dict)
    keypoints: list[StereoKeypoints | None] | None = None  # per view 2D detections (multiview counting)
    calib: StereoCalib | None = None
    calibrated: CalibratedCount | None = None  # the count calibration's estimate (seedmap.recon.calibrate)
    detector: str = ""  # the detector's name


def reconstruct(prep: PreparedScan, cfg: ReconConfig, progress: bool = False) -> Reconstruction:
    """Register, merge and count in the mode ``cfg.registration.mode``."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    from seedmap.recon.quality import cross_view_seed_distance, quality_scores

    geoms = [v.geometry if v is not None else None for v in prep.views]
    t0 = time.perf_counter()
    reg = register_views(geoms, prep.T_fk, cfg.registration)
    t_reg = time.perf_counter() - t0
    # seed observations in the world
    ox, ov, od, oid, odet = [], [], [], [], []
    for k, v in enumerate(prep.views):
        if v is None or len(v.seeds) == 0:
            continue
        ox.append(transform_points(reg.poses[k], v.seeds.xyz))
        ov.append(np.full(len(v.seeds), k))
        od.append(v.seeds.diameter)
        oid.append(v.seeds.seed_id)
        odet.append(v.seeds.det)
    cat = (lambda a, shape: np.concatenate(a) if a else np.zeros(shape))
    obs_xyz, obs_view = cat(ox, (0, 3)), cat(ov, (0,)).astype(np.int64)
    obs_diam, obs_id, obs_det = cat(od, (0,)), cat(oid, (0,)).astype(np.int64), cat(odet, (0,)).astype(np.int64)
    kps = [v.keypoints if v is not None else None for v in prep.views]
    t0 = time.perf_counter()
    if cfg.count.method == "multiview":
        cnt = multiview_count_observations(kps, reg.poses, prep.calib, cfg, obs_view, obs_det)
    else:
        cnt = count_density(obs_xyz, obs_view, obs_diam, cfg.count)
    t_count = time.perf_counter() - t0
    calibrated = calibrate_count(cfg, count_features(kps, cnt))
    # merged cloud; per-point label = counted seed of the detection the pixel belonged to
    px, pc, pl = [], [], []
    for k, v in enumerate(prep.views):
        if v is None:
            continue
        lab = np.full(len(v.cloud), -1, np.int64)
        sel = obs_view == k
        if sel.any():
            lut = np.full(int(max(v.cloud.det.max(initial=-1), obs_det[sel].max())) + 2, -1, np.int64)
            lut[obs_det[sel]] = cnt.assignment[sel]
            has = v.cloud.det >= 0
            lab[has] = lut[np.minimum(v.cloud.det[has], len(lut) - 1)]
        px.append(transform_points(reg.poses[k], v.cloud.xyz))
        pc.append(v.cloud.rgb)
        pl.append(lab)
    all_xyz, all_rgb, all_lab = np.concatenate(px), np.concatenate(pc), np.concatenate(pl)
    p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(all_xyz))
    p.colors = o3d.utility.Vector3dVector(all_rgb.astype(np.float64) / 255.0)
    d = p.voxel_down_sample(cfg.cloud.voxel_size)
    cxyz = np.asarray(d.points)
    crgb = np.clip(np.asarray(d.colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    _, nn = cKDTree(all_xyz).query(cxyz)
    clab = all_lab[nn]
    q = quality_scores(cxyz, cnt, seed=cfg.seed)
    q["cross_view_seed_mm"] = cross_view_seed_distance(
        [v.geometry.seeds_xyz if v is not None else None for v in prep.views], reg.poses) * 1000.0
    return Reconstruction(
        mode=cfg.registration.mode, poses=reg.poses, T_fk=prep.T_fk, timestamps=prep.timestamps, registration=reg,
        cloud_xyz=cxyz, cloud_rgb=crgb, cloud_label=clab, obs_xyz=obs_xyz, obs_view=obs_view, obs_diam=obs_diam,
        obs_seed_id=obs_id, count=cnt, quality=q, skipped=prep.skipped, oracle=prep.oracle,
        keypoints=kps, calib=prep.calib, calibrated=calibrated, detector=cfg.detector,
        seconds={"registration_total": t_reg, "count": t_count,
                 "sgbm_per_view": float(np.mean(prep.seconds_sgbm)),
                 "icp_per_view": float(np.mean(reg.seconds[1:])) if len(reg.seconds) > 1 else 0.0})


def multiview_count_observations(kps: list[StereoKeypoints | None], poses: np.ndarray, calib: StereoCalib,
                                 cfg: ReconConfig, obs_view: np.ndarray, obs_det: np.ndarray) -> SeedCount:
    """Count method ``multiview`` on the views' 2D detections; the returned ``assignment`` is given
    per stereo seed observation (``obs_view``, ``obs_det`` = view and left detection index), like the
    density counter's (it labels the merged cloud and observations.csv)."""
    cnt = count_multiview(kps, poses, calib, cfg.count.for_detector(cfg.detector), depth_range=depth_range(cfg))
    offset = np.concatenate([[0], np.cumsum([len(k.left) if k is not None else 0 for k in kps])]).astype(np.int64)
    obs_view = np.asarray(obs_view, np.int64)
    obs_det = np.asarray(obs_det, np.int64)
    cnt.assignment = cnt.assignment[offset[obs_view] + obs_det] if len(obs_view) else np.zeros(0, np.int64)
    return cnt


def detections_csv_text(kps: list[StereoKeypoints | None]) -> str:
    """All 2D detections of a reconstruction: view, side (0 = left, 1 = right), u, v (px), size (px;
    mean full ellipse axis, left only, else 0), SGBM disparity at the keypoint (px; left only, nan =
    none) -- what ``seedmap count`` needs for ``multiview``."""
    rows = []
    for k, kp in enumerate(kps):
        if kp is None:
            continue
        ld = kp.left_disp if kp.left_disp is not None else np.full(len(kp.left), np.nan)
        rows.append(np.column_stack([np.full(len(kp.left), k), np.zeros(len(kp.left)), kp.left, kp.left_size, ld]))
        rows.append(np.column_stack([np.full(len(kp.right), k), np.ones(len(kp.right)), kp.right,
                                     np.zeros(len(kp.right)), np.full(len(kp.right), np.nan)]))
    a = np.concatenate(rows) if rows else np.zeros((0, 6))
    return _csv("view,side,u,v,size_px,sgbm_disp_px", a, "%.10g")


def read_detections(results: str | Path, n_views: int) -> list[StereoKeypoints | None]:
    """``detections.csv`` of a results folder -> per-view :class:`StereoKeypoints` (None = no row)."""
    p = Path(results) / "detections.csv"
    if not p.is_file():
        raise InputError("detections.csv not found (count method 'multiview' needs the 2D detections; "
                         "re-run `seedmap reconstruct`)", p)
    a = read_table(p, "detections.csv", finite=False)  # no SGBM disparity: NaN
    if a.size and a.shape[1] < 5:
        raise InputError(f"detections.csv needs 5 columns, found {a.shape[1]}", p)
    ncol = a.shape[1] if a.size else 5
    a = a.reshape(-1, ncol)
    view = a[:, 0].astype(np.int64)
    if len(view) and (view.min() < 0 or view.max() >= n_views):
        raise InputError(f"detections.csv refers to view {view.max()}, the poses have {n_views}", p)
    out: list[StereoKeypoints | None] = []
    for k in range(n_views):
        sel = view == k
        if not sel.any():
            out.append(None)
            continue
        left, right = sel & (a[:, 1] == 0), sel & (a[:, 1] == 1)
        # column 6 (SGBM disparity at the left keypoint) is absent in files of older versions
        out.append(StereoKeypoints(a[left, 2:4], a[right, 2:4], a[left, 4], a[left, 5] if ncol >= 6 else None))
    return out


# ------------------------------------------------------------------------------------------------
# writing
# ------------------------------------------------------------------------------------------------


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray, label: np.ndarray) -> None:
    """Binary PLY with colours and an extra per-point ``seed_label`` (int32, -1 = none)."""
    from seedmap.io.pointcloud import write_labelled_ply

    write_labelled_ply(path, xyz, {"seed_label": label}, rgb=rgb)


def _csv(header: str, rows: np.ndarray, fmt: str) -> str:
    buf = io.StringIO()
    buf.write(header + "\n")
    if len(rows):
        np.savetxt(buf, rows, fmt=fmt, delimiter=",")
    return buf.getvalue()


def seeds_csv_text(cnt: SeedCount) -> str:
    rows = np.column_stack([np.arange(cnt.count), cnt.xyz, cnt.diameter, cnt.n_views, cnt.spread]) \
        if cnt.count else np.zeros((0, 7))
    return _csv("seed,x,y,z,diameter_m,n_views,spread_m", rows, "%.6g")


def write_results(rec: Reconstruction, out: Path, cfg: ReconConfig, metrics: dict, overwrite: bool = False,
                  inputs: Sequence[str | Path | None] = ()) -> Path:
    """Write the results folder atomically (a seedmap ``reconstruct`` output, never one of ``inputs``)."""
    from seedmap.io.trajectory import write_tum
    from seedmap.records import Trajectory

    with outputs.output_dir(Path(out), "reconstruct", inputs, overwrite) as tmp:
        dump_config(cfg, tmp / "config.yaml")
        write_ply(tmp / "cloud.ply", rec.cloud_xyz, rec.cloud_rgb, rec.cloud_label)
        atomic_write_text(tmp / "seeds.csv", seeds_csv_text(rec.count))
        obs = np.column_stack([rec.obs_view, rec.obs_xyz, rec.obs_diam, rec.obs_seed_id, rec.count.assignment]) \
            if len(rec.obs_xyz) else np.zeros((0, 7))
        atomic_write_text(tmp / "observations.csv",
                          _csv("view,x,y,z,diameter_m,gt_seed_id,seed", obs, "%.7g"))
        if rec.keypoints is not None:
            atomic_write_text(tmp / "detections.csv", detections_csv_text(rec.keypoints))
        if rec.calib is not None:
            from seedmap.io.calibration import save_calib_yaml

            save_calib_yaml(rec.calib, tmp / "calib.yaml")
        write_tum(tmp / "poses_tum.txt", Trajectory(rec.timestamps, rec.poses))
        write_tum(tmp / "poses_fk_tum.txt", Trajectory(rec.timestamps, rec.T_fk))
        atomic_write_text(tmp / "metrics.json", json.dumps(metrics, indent=2, default=_jsonable))
        atomic_write_text(tmp / "report.md", report_markdown(rec, metrics))
        from seedmap.viz.run_hooks import recon_html_report

        recon_html_report(tmp, rec, metrics, metrics.get("dataset"))
    return Path(out)


def _jsonable(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def report_markdown(rec: Reconstruction, metrics: dict) -> str:
    lines = [f"# Panicle reconstruction ({rec.mode})", ""]
    if rec.oracle:
        lines += ["**Detections come from the ground-truth ORACLE (`gt` detector) -- simulation only.**", ""]
    lines += [f"- detector: {detector_label(rec.detector, rec.oracle)}",
              f"- views: {len(rec.poses)} ({len(rec.skipped)} skipped)",
              f"- cloud points: {len(rec.cloud_xyz)}",
              f"- seed count: **{rec.count.count}** (from {len(rec.obs_xyz)} per-view detections)",
              calibrated_count_line(rec.calibrated),
              f"- GT-free quality (lower is better): cross-view seed distance "
              f"{rec.quality['cross_view_seed_mm']:.3f} mm (the recommended score), seed spread "
              f"{rec.quality['seed_spread_mm']:.3f} mm, surface thickness {rec.quality['surface_thickness_mm']:.3f} mm",
              ""]
    gt = metrics.get("gt")
    if gt:
        lines += ["## Against ground truth", "", "| metric | value |", "|---|---|"]
        for k, v in gt.items():
            if isinstance(v, (int, float)):
                lines.append(f"| {k} | {v:.4g} |")
        lines.append("")
    for s in rec.skipped:
        lines.append(f"- skipped view {s['view']}: {s['reason']}")
    return "\n".join(lines) + "\n"


def base_metrics(rec: Reconstruction) -> dict:
    """GT-free metrics of a reconstruction."""
    reg = rec.registration
    return {
        "mode": rec.mode,
        "oracle_detector": rec.oracle,
        "views": len(rec.poses),
        "skipped_views": rec.skipped,
        "registered_views": int(reg.accepted.sum()),
        "registration_notes": reg.notes,
        **(rec.calibrated.as_dict() if rec.calibrated is not None else {"seed_count": rec.count.count}),
        "detections_total": int(len(rec.obs_xyz)),
        "cloud_points": int(len(rec.cloud_xyz)),
        "quality": rec.quality,
        "seconds": rec.seconds,
    }


def gt_visible_seeds(root: Path, min_area_px: int, min_views: int = 1) -> np.ndarray:
    """GT ids of the seeds a perfect detector could count: centre visible with at least
    ``min_area_px`` visible pixels in the LEFT image of at least ``min_views`` views."""
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(root)
    ids = []
    for i in range(len(ds)):
        inst = ds.gt_instances(i, "left")
        ids.append(inst.seed_id[inst.center_visible & (inst.area >= min_area_px)])
    if not ids:
        return np.zeros(0, np.int64)
    u, c = np.unique(np.concatenate(ids), return_counts=True)
    return u[c >= min_views]


def gt_countable_seeds(root: Path, min_area_px: int, min_views: int = 2) -> np.ndarray:
    """GT ids of the seeds a 3D counter can count: at least ``min_area_px`` visible pixels in BOTH
    the left and the right image (stereo depth needs both) of at least ``min_views`` views (one view
    cannot tell a duplicate from a new seed; the counter needs ``count.min_observations`` = 2)."""
    from seedmap.io.seedmap_dataset import SeedmapDataset

    ds = SeedmapDataset(root)
    ids = []
    for i in range(len(ds)):
        left, right = ds.gt_instances(i, "left"), ds.gt_instances(i, "right")
        ids.append(np.intersect1d(left.seed_id[left.area >= min_area_px], right.seed_id[right.area >= min_area_px]))
    if not ids:
        return np.zeros(0, np.int64)
    u, c = np.unique(np.concatenate(ids), return_counts=True)
    return u[c >= min_views]


def gt_metrics(rec: Reconstruction, root: Path, min_area_px: int) -> dict | None:
    """Pose, cloud and count errors against the simulator's ground truth (None without GT)."""
    if not (Path(root) / "gt").is_dir():  # users' scans (any format) have none
        return None
    from seedmap.eval.recon_metrics import evaluate_reconstruction
    from seedmap.sim.panicle_scan import gt_rest_poses, gt_surface_points

    ref = gt_rest_poses(root)
    surf = gt_surface_points(root)
    if ref is None or surf is None:
        return None
    vis = gt_visible_seeds(root, min_area_px)
    out = evaluate_reconstruction(rec.poses, rec.cloud_xyz, rec.count.count, ref, surf, len(vis), fk_poses=rec.T_fk)
    out["gt_visible_seeds_definition"] = f"centre visible and >= {min_area_px} px in >= 1 left view"
    countable = len(gt_countable_seeds(root, min_area_px))
    out["count_gt_countable"] = countable
    out["count_countable_ape_pct"] = float(abs(rec.count.count - countable) / max(countable, 1) * 100.0)
    out["gt_countable_seeds_definition"] = f">= {min_area_px} px in the left AND right image of >= 2 views"
    if rec.calibrated is not None and rec.calibrated.estimate is not None:
        e = rec.calibrated.estimate
        out["count_calibrated"] = e
        out["count_calibrated_countable_err_pct"] = float((e - countable) / max(countable, 1) * 100.0)
        out["count_calibrated_countable_ape_pct"] = abs(out["count_calibrated_countable_err_pct"])
    return out


def run_reconstruct(dataset: str | Path, out: str | Path, cfg: ReconConfig, overwrite: bool = False,
                    progress: bool = True, rerun: Path | None = None,
                    inputs: Sequence[str | Path | None] = ()) -> tuple[Path, dict]:
    """``seedmap reconstruct``: prepare, register (``cfg.registration.mode``), count, evaluate, write.

    ``rerun``: also record per-view clouds, camera poses, merged cloud and seed centres to this ``.rrd``.
    ``inputs``: more files the command read (``--config``); ``out`` and ``rerun`` are never one of them."""
    out = Path(out)
    ins = [dataset, *inputs, *scan_files(dataset, cfg), *outputs.dataset_option_files(getattr(cfg, "dataset", None))]
    outputs.check_output_dir(out, "reconstruct", ins, overwrite)
    if rerun is not None:  # the recording is written after the results: refuse a bad path before any work
        check_rrd_path(rerun, [*ins, out], overwrite)
    prep = prepare_scan(dataset, cfg, progress=progress)
    rec = reconstruct(prep, cfg)
    metrics = base_metrics(rec)
    metrics["dataset"] = str(Path(dataset))
    gt = gt_metrics(rec, Path(dataset), _min_area(cfg))
    if gt is not None:
        metrics["gt"] = gt
    write_results(rec, out, cfg, metrics, overwrite=overwrite, inputs=ins)
    from seedmap.viz.run_hooks import recon_rerun

    recon_rerun(rerun, prep, rec)
    return out, metrics


def _min_area(cfg: ReconConfig) -> int:
    """The oracle's min-area override (keeps the GT-visible definition consistent with the detector)."""
    for o in cfg.detector_overrides:
        if o.replace(" ", "").startswith("gt.min_area_px="):
            return int(float(o.split("=", 1)[1]))
    return 3


def read_observations(results: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``observations.csv`` of a results folder -> (world centres, views, diameters)."""
    p = Path(results) / "observations.csv"
    if not Path(results).is_dir():
        raise InputError("results folder not found", results)
    if not p.is_file():
        raise InputError("observations.csv not found (is this a `seedmap reconstruct` results folder?)", p)
    a = read_table(p, "observations.csv", finite=False)
    if a.size == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0)
    if a.shape[1] < 5:
        raise InputError(f"observations.csv needs >= 5 columns, found {a.shape[1]}", p)
    return a[:, 1:4], a[:, 0].astype(np.int64), a[:, 4]


def calibrated_count_line(c: CalibratedCount | None) -> str:
    """One report line on the count calibration."""
    if c is None:
        return "- calibrated count: none"
    if c.estimate is None:
        return f"- calibrated count: none ({c.reason})"
    return (f"- calibrated count: **{c.estimate:.0f}** (count calibration `{Path(c.source).name}`, {c.fitted}; "
            f"features: obs_fraction {c.features.obs_fraction:.3f}, seed diameter {c.features.seed_diam_mm:.2f} mm)")


def recount(results: str | Path, cfg: ReconConfig) -> SeedCount:
    """``seedmap count``: count the stored detections again with ``cfg.count``: method ``multiview``
    from ``detections.csv``, ``calib.yaml`` and ``poses_tum.txt`` (the assignment is per left detection of
    detections.csv, view order); ``density`` de-duplicates the per-view seed observations of ``observations.csv``."""
    return recount_calibrated(results, cfg)[0]


def recount_calibrated(results: str | Path, cfg: ReconConfig) -> tuple[SeedCount, CalibratedCount]:
    """:func:`recount` and the count calibration (``cfg.count.calibration``) applied to it."""
    cnt, kps = _recount(results, cfg)
    return cnt, calibrate_count(cfg, count_features(kps, cnt))


def depth_range(cfg: ReconConfig) -> tuple[float, float]:
    """The depth range (m) the counter looks for seeds in: the clouds' range."""
    return cfg.cloud.min_depth, cfg.cloud.max_depth


def _recount(results: str | Path, cfg: ReconConfig) -> tuple[SeedCount, list[StereoKeypoints | None]]:
    xyz, view, diam = read_observations(results)
    if cfg.count.method == "density":
        return count_density(xyz, view, diam, cfg.count), []
    from seedmap.io.seedmap_dataset import read_calib_yaml
    from seedmap.io.trajectory import read_tum

    p = Path(results) / "poses_tum.txt"
    if not p.is_file():
        raise InputError("poses_tum.txt not found (count method 'multiview' needs the camera poses)", p)
    poses = read_tum(p).poses
    c = Path(results) / "calib.yaml"
    if not c.is_file():
        raise InputError("calib.yaml not found (count method 'multiview' needs the calibration)", c)
    calib = read_calib_yaml(c)
    kps = read_detections(results, len(poses))
    return count_multiview(kps, poses, calib, cfg.count.for_detector(cfg.detector), depth_range=depth_range(cfg)), kps
