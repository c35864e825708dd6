"""Files of a SLAM result folder (written into the temporary folder of ``seedmap.outputs.output_dir``)."""

from __future__ import annotations

import io
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from seedmap.detect.base import detector_label
from seedmap.io.atomic import atomic_write_text
from seedmap.io.trajectory import write_kitti, write_tum
from seedmap.records import Trajectory
from seedmap.viz.plotting import figure_text


def cluster_panicles(xyz: np.ndarray, eps_m: float, min_points: int) -> np.ndarray:
    """Panicle cluster id per landmark (Open3D DBSCAN; -1 = noise)."""
    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(xyz, float)))
    return np.asarray(pc.cluster_dbscan(eps=eps_m, min_points=min_points, print_progress=False), np.int64)


def write_landmarks(folder: Path, lm, clusters: np.ndarray) -> None:
    from seedmap.io.pointcloud import write_labelled_ply

    buf = io.StringIO()
    buf.write("landmark_id,seed_id,cluster_id,x,y,z,n_obs,in_graph\n")
    in_graph = lm.in_graph.astype(np.int64)
    for i in range(len(lm)):
        x, y, z = lm.xyz[i]
        buf.write(f"{lm.ids[i]},{lm.seed_ids[i]},{clusters[i]},{x:.6f},{y:.6f},{z:.6f},{lm.n_obs[i]},{in_graph[i]}\n")
    atomic_write_text(folder / "landmarks.csv", buf.getvalue())
    write_labelled_ply(folder / "landmarks.ply", lm.xyz,
                       {"seed_id": lm.seed_ids, "landmark_id": lm.ids, "cluster_id": clusters,
                        "in_graph": in_graph})


@figure_text()
def plot_topview(path: Path, est: Trajectory, gt: Trajectory | None, lm_xyz: np.ndarray, title: str) -> None:
    """Top view of the estimate (and GT) with the landmarks.

    With ground truth the world is the simulator's (x along the row, y towards the row, z up): x against y.
    Without it the world is the first camera's optical frame (x right, y down, z forward), so the ground plane is
    x against z (plotting y there would draw a front view)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    j = 1 if gt is not None and len(gt) else 2
    fig, ax = plt.subplots(figsize=(10, 4), dpi=110)
    if len(lm_xyz):
        ax.scatter(lm_xyz[:, 0], lm_xyz[:, j], s=0.5, c="tab:green", alpha=0.5, label="seed landmarks")
    if gt is not None and len(gt):
        ax.plot(gt.positions[:, 0], gt.positions[:, 1], "k--", lw=1.2, label="ground truth")
    if len(est):
        ax.plot(est.positions[:, 0], est.positions[:, j], "r-", lw=1.5, label="estimate")
        ax.plot(est.positions[-1, 0], est.positions[-1, j], "rx", ms=8)
    if j == 1:
        ax.set_xlabel("x along the row (m)")
        ax.set_ylabel("y towards the row (m)")
    else:
        ax.set_xlabel("x, first camera's right (m)")
        ax.set_ylabel("z, first camera's forward (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title, fontsize=9)
    if ax.get_legend_handles_labels()[0]:  # nothing plotted (no frame, no GT): no empty legend
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    from seedmap.io.atomic import atomic_write_bytes

    atomic_write_bytes(path, buf.getvalue())


def _fmt(v, unit: str = "", pct: bool = False) -> str:
    if v is None:
        return "–"
    if pct:
        return f"{100 * v:.1f} %"
    return f"{v:.4f}{unit}"


def report_markdown(m, dataset: str | Path) -> str:
    lines = [
        f"# SLAM result: {Path(dataset).name}",
        "",
        f"matcher `{m.matcher}`, detector `{detector_label(m.detector, m.oracle_detector) if m.detector else '–'}`, "
        f"back-end `{m.backend}`",
        "",
        "| metric | value |",
        "|---|---|",
        f"| frames processed / in dataset | {m.frames_tracked} / {m.frames} |",
        f"| maximum distance mapped (MDM) | {_fmt(m.mdm_m, ' m')} ({_fmt(m.mdm_fraction, pct=True)} of range) |",
        f"| GT-validated MDM | {_fmt(m.gt_mdm_m, ' m')} ({_fmt(m.gt_mdm_fraction, pct=True)}) |",
        f"| range length | {_fmt(m.range_length_m, ' m')} |",
        f"| ATE RMSE (SE(3)-aligned) | {_fmt(m.ate_rmse_m, ' m')} ({_fmt(m.ate_fraction_of_distance, pct=True)} of distance) |",
        f"| ATE RMSE (first-pose aligned) | {_fmt(m.ate_first_pose_rmse_m, ' m')} |",
        f"| ATE RMSE online (iSAM2 per frame) | {_fmt(m.ate_online_rmse_m, ' m')} |",
        f"| RPE translation RMSE (1 frame) | {_fmt(m.rpe_trans_rmse_m, ' m')} |",
        f"| landmarks | {m.landmarks} |",
        f"| lost at frame | {m.lost_frame if m.lost_frame is not None else 'never'} |",
        f"| lost reason | {m.lost_reason or '–'} |",
        "",
        "## Time per frame (ms, mean)",
        "",
        "| stage | ms |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v:.1f} |" for k, v in m.ms_per_frame.items()]
    lines += ["", "Files: trajectory.tum/.kitti (final), trajectory_online.tum, landmarks.csv/.ply, "
              "topview.png, matches_per_frame.csv, metrics.json, config.yaml.", ""]
    return "\n".join(lines)


def write_outputs(folder: Path, result, online: Trajectory, gt: Trajectory | None, lm, rows: list[dict],
                  cfg, dataset: str | Path) -> None:
    folder = Path(folder)
    m = result.metrics
    atomic_write_text(folder / "metrics.json", json.dumps(asdict(m), indent=2, default=float) + "\n")
    write_tum(folder / "trajectory.tum", result.trajectory)
    write_kitti(folder / "trajectory.kitti", result.trajectory)
    write_tum(folder / "trajectory_online.tum", online)
    clusters = cluster_panicles(lm.xyz, cfg.cluster.eps_m, cfg.cluster.min_points)
    write_landmarks(folder, lm, clusters)
    cols = list(rows[0].keys()) if rows else ["frame"]
    text = ",".join(cols) + "\n" + "".join(",".join(str(r[c]) for c in cols) + "\n" for r in rows)
    atomic_write_text(folder / "matches_per_frame.csv", text)
    title = (f"{Path(dataset).name}: {m.matcher} — MDM {m.mdm_m:.2f} m"
             + (f", ATE {m.ate_rmse_m * 100:.1f} cm" if m.ate_rmse_m is not None else ""))
    plot_topview(folder / "topview.png", result.trajectory, gt, lm.xyz, title)
    atomic_write_text(folder / "report.md", report_markdown(m, dataset))
