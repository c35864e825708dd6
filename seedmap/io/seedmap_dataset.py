"""seedmap's own dataset layout: the one writer and the one reader.

::

    DATASET/
      calib.yaml                    rectified stereo calibration (StereoCalib.to_dict) + format version
      times.txt                     one timestamp (s) per frame
      left/000000.png ...           8-bit RGB, rectified
      right/000000.png ...
      gt/                           (simulated data only)
        poses_tum.txt               T_world_cam of the left camera per frame (TUM)
        seeds.csv                   seed_id,panicle_id,x,y,z,rx,ry,rz  world rest pose, semi-axes (m)
        panicle_poses.csv           frame,panicle_id,tx,ty,tz,qx,qy,qz,qw: motion D with
                                    p_world(frame) = D * p_rest (wind sway; identity when still)
        masks/{left,right}/000000.png   uint16 instance labels (0 = no seed); the label -> seed id
                                    table is the instances CSV of the same frame and camera
        instances/{left,right}/000000.csv
                                    label,seed_id,panicle_id,x0,y0,x1,y1,u,v,area,center_visible
                                    box = inclusive-exclusive pixel bounds of the visible mask;
                                    (u, v) = projection of the seed's true 3D centre in that frame;
                                    center_visible = 1 when a ray to the 3D centre meets this seed first
                                    and the pixel containing (u, v) (rounded) shows this seed
        config.yaml                 the generator config that produced the dataset
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from seedmap.errors import ConfigError, InputError
from seedmap.io.atomic import atomic_write_text
from seedmap.io.calib_formats import check_principal_point
from seedmap.io.images import read_label_png, read_rgb, write_png
from seedmap.io.registry import detect_format, register_loader
from seedmap.io.text import read_table, read_text
from seedmap.io.timestamps import read_times_txt
from seedmap.io.trajectory import read_tum, write_tum
from seedmap.records import StereoCalib, StereoFrame, Trajectory

FORMAT_VERSION = 1
CAMERAS = ("left", "right")
INSTANCE_COLUMNS = ("label", "seed_id", "panicle_id", "x0", "y0", "x1", "y1", "u", "v", "area", "center_visible")

_INSTANCE_ROW_FMT = "%d,%d,%d,%d,%d,%d,%d,%.3f,%.3f,%d,%d\n"


def _read_instance_table(path: Path) -> np.ndarray:
    """The instances CSV as an ``N x 11`` float64 array (``0 x 11`` for a header-only frame).

    pandas' C parser (pandas comes with evo): a 15k-row frame reads in ~6 ms against ~32 ms with
    ``np.loadtxt``; the oracle detector reads two per frame."""
    import pandas as pd

    try:
        df = pd.read_csv(path, dtype=np.float64)
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        raise InputError(f"malformed instance table ({str(e).splitlines()[0]})", path) from None
    if tuple(df.columns) != INSTANCE_COLUMNS:
        raise InputError(f"instance table columns are {','.join(map(str, df.columns))}, "
                         f"expected {','.join(INSTANCE_COLUMNS)}", path)
    return df.to_numpy(np.float64).reshape(-1, len(INSTANCE_COLUMNS))


@dataclass
class SeedTable:
    """Ground-truth seeds at rest: ids, panicle ids, centres (world, m) and semi-axes (m)."""

    seed_id: np.ndarray
    panicle_id: np.ndarray
    xyz: np.ndarray
    radii: np.ndarray

    def __len__(self) -> int:
        return len(self.seed_id)


@dataclass
class Instances:
    """Ground-truth seed instances visible in one image (one row per mask label)."""

    label: np.ndarray  # (N,) uint16 value in the mask image
    seed_id: np.ndarray  # (N,) int64
    panicle_id: np.ndarray  # (N,) int64
    boxes: np.ndarray  # (N, 4) x0, y0, x1, y1 (inclusive-exclusive)
    center_uv: np.ndarray  # (N, 2) projection of the true 3D centre
    area: np.ndarray  # (N,) visible pixels
    center_visible: np.ndarray  # (N,) bool

    def __len__(self) -> int:
        return len(self.label)

    @staticmethod
    def empty() -> Instances:
        z = np.zeros(0)
        return Instances(z.astype(np.uint16), z.astype(np.int64), z.astype(np.int64), np.zeros((0, 4)),
                         np.zeros((0, 2)), z.astype(np.int64), z.astype(bool))


def frame_name(i: int) -> str:
    return f"{i:06d}.png"


# ----------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------


class DatasetWriter:
    """Writes the layout into ``root`` (normally a temporary folder from ``seedmap.outputs.output_dir``)."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        for cam in CAMERAS:
            (self.root / cam).mkdir(parents=True, exist_ok=True)

    def write_calib(self, calib: StereoCalib) -> None:
        d = {"seedmap_dataset": FORMAT_VERSION, **calib.to_dict()}
        atomic_write_text(self.root / "calib.yaml", yaml.safe_dump(d, sort_keys=False))

    def write_times(self, timestamps: np.ndarray) -> None:
        atomic_write_text(self.root / "times.txt", "".join(f"{t:.6f}\n" for t in timestamps))

    def write_frame(self, i: int, left: np.ndarray, right: np.ndarray) -> None:
        write_png(self.root / "left" / frame_name(i), left)
        write_png(self.root / "right" / frame_name(i), right)

    # ---- ground truth ----
    def write_gt_poses(self, traj: Trajectory) -> None:
        write_tum(self.root / "gt" / "poses_tum.txt", traj)

    def write_gt_seeds(self, seeds: SeedTable) -> None:
        buf = io.StringIO()
        buf.write("seed_id,panicle_id,x,y,z,rx,ry,rz\n")
        a = np.column_stack([seeds.xyz, seeds.radii])
        for sid, pid, row in zip(seeds.seed_id, seeds.panicle_id, a, strict=True):
            buf.write(f"{sid},{pid}," + ",".join(f"{v:.6f}" for v in row) + "\n")
        atomic_write_text(self.root / "gt" / "seeds.csv", buf.getvalue())

    def write_gt_panicle_poses(self, frames: np.ndarray, panicle_ids: np.ndarray, tum_rows: np.ndarray) -> None:
        """``tum_rows`` (N, 7) = ``tx ty tz qx qy qz qw`` of the sway motion D per (frame, panicle)."""
        buf = io.StringIO()
        buf.write("frame,panicle_id,tx,ty,tz,qx,qy,qz,qw\n")
        for f, p, r in zip(frames, panicle_ids, tum_rows, strict=True):
            buf.write(f"{int(f)},{int(p)}," + ",".join(f"{v:.9f}" for v in r) + "\n")
        atomic_write_text(self.root / "gt" / "panicle_poses.csv", buf.getvalue())

    def write_gt_instances(self, i: int, cam: str, labels: np.ndarray, inst: Instances) -> None:
        if labels.dtype != np.uint16:
            raise ValueError("instance label images are uint16")
        write_png(self.root / "gt" / "masks" / cam / frame_name(i), labels)
        # one %-format over all rows (a per-row f-string loop cost ~55 ms for a 15k-row frame; this ~38 ms)
        ints = np.column_stack([inst.label.astype(np.int64), inst.seed_id.astype(np.int64),
                                inst.panicle_id.astype(np.int64), np.trunc(inst.boxes).astype(np.int64)]).tolist()
        tail = np.column_stack([inst.area.astype(np.int64), inst.center_visible.astype(bool).astype(np.int64)]).tolist()
        flat = [x for a, uv, c in zip(ints, inst.center_uv.tolist(), tail) for x in (*a, *uv, *c)]
        text = ",".join(INSTANCE_COLUMNS) + "\n" + (_INSTANCE_ROW_FMT * len(inst)) % tuple(flat)
        atomic_write_text(self.root / "gt" / "instances" / cam / f"{i:06d}.csv", text)

    def write_gt_config(self, text: str) -> None:
        atomic_write_text(self.root / "gt" / "config.yaml", text)


# ----------------------------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------------------------


def read_calib_yaml(path: Path) -> StereoCalib:
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found", path)
    try:
        d = yaml.safe_load(read_text(path, "calibration file"))
    except yaml.YAMLError:
        raise InputError("calibration is not valid YAML", path) from None
    if not isinstance(d, dict):
        raise InputError("calibration must be a YAML mapping", path)
    missing = [k for k in ("fx", "fy", "cx", "cy", "baseline_m", "image_width", "image_height") if k not in d]
    if missing:
        raise InputError(f"calibration lacks {', '.join(missing)}", path)
    try:
        return check_principal_point(StereoCalib.from_dict(d), path)
    except (TypeError, ValueError) as e:
        raise InputError(f"bad calibration value ({e})", path) from None
    except InputError:
        raise
    except Exception as e:  # ConfigError from StereoCalib validation
        raise InputError(str(e), path) from None


class SeedmapDataset:
    """Reader of the layout above. Frames load lazily; ground truth is available when ``gt/`` exists."""

    name = "seedmap"

    def __init__(self, root: str | Path, allow_fewer_times: bool = False) -> None:
        self.root = Path(root)
        if self.root.exists() and not (self.root / "calib.yaml").is_file():
            fmt = detect_format(self.root)
            if fmt not in (None, "seedmap"):  # real data given where simulated data with GT is needed
                raise InputError(f"this is a {fmt} dataset; this needs seedmap's own layout (calib.yaml, times.txt, "
                                 "left/, right/, and gt/ for the gt oracle detector and GT evaluations) as "
                                 "`seedmap simulate` writes it (on real images use --detector fast)", self.root)
        if not self.root.is_dir():
            raise InputError("dataset folder not found", self.root)
        self.calib = read_calib_yaml(self.root / "calib.yaml")
        times = self.root / "times.txt"
        if not times.is_file():
            raise InputError("times.txt not found", times)
        self.timestamps = read_times_txt(times)
        for cam in CAMERAS:
            if not (self.root / cam).is_dir():
                raise InputError(f"{cam}/ image folder not found", self.root / cam)
        self._check_frame_count(times, allow_fewer_times)

    def _check_frame_count(self, times: Path, allow_fewer: bool) -> None:
        """As many timestamps as frames: a frame without one would be dropped silently, a timestamp without
        a frame fails late. Gaps in the numbering are left to the frame reader (it names the missing file)."""
        n = len(self.timestamps)
        for cam in CAMERAS:
            m = sum(1 for p in (self.root / cam).glob("[0-9]*.png") if p.stem.isdigit())
            if m > n and not allow_fewer:
                raise InputError(f"has {n} timestamps but {cam}/ has {m} images (one line per frame; to use "
                                 f"only the first {n} frames pass --set dataset.allow_fewer_times=true)", times)
            if m < n and all(self.image_path(i, cam).is_file() for i in range(m)):
                raise InputError(f"has {n} timestamps but {cam}/ has only {m} images (one line per frame)", times)

    @staticmethod
    def is_dataset(path: Path) -> bool:
        p = Path(path)
        return (p / "calib.yaml").is_file() and (p / "left").is_dir() and (p / "times.txt").is_file()

    def __len__(self) -> int:
        return len(self.timestamps)

    def image_path(self, i: int, cam: str) -> Path:
        return self.root / cam / frame_name(i)

    def __getitem__(self, i: int) -> StereoFrame:
        if not 0 <= i < len(self):
            raise IndexError(i)
        for cam in CAMERAS:  # a user's own scan with JPEGs said only '000000.png: image file not found'
            p = self.image_path(i, cam)
            if not p.is_file() and (other := sorted(p.parent.glob(p.stem + ".*"))):
                raise InputError(f"image file not found: seedmap's layout names frames {cam}/NNNNNN.png and this "
                                 f"folder has {other[0].name} (convert the images to PNG)", p)
        left = read_rgb(self.image_path(i, "left"))
        right = read_rgb(self.image_path(i, "right"))
        if left.shape != right.shape:
            raise InputError(f"left {left.shape[:2]} and right {right.shape[:2]} image sizes differ",
                             self.image_path(i, "right"))
        if left.shape[:2] != (self.calib.height, self.calib.width):
            raise InputError(
                f"image is {left.shape[1]}x{left.shape[0]} but calib.yaml says "
                f"{self.calib.width}x{self.calib.height}", self.image_path(i, "left"))
        return StereoFrame(index=i, timestamp=float(self.timestamps[i]), left=left, right=right)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    # ---- ground truth ----
    @property
    def has_gt(self) -> bool:
        return (self.root / "gt" / "poses_tum.txt").is_file()

    def gt_trajectory(self) -> Trajectory | None:
        p = self.root / "gt" / "poses_tum.txt"
        return read_tum(p) if p.is_file() else None

    def gt_seeds(self) -> SeedTable:
        p = self.root / "gt" / "seeds.csv"
        if not p.is_file():
            raise InputError("ground-truth seeds.csv not found", p)
        a = read_table(p, "ground-truth seeds.csv").reshape(-1, 8)
        return SeedTable(a[:, 0].astype(np.int64), a[:, 1].astype(np.int64), a[:, 2:5], a[:, 5:8])

    def gt_panicle_poses(self) -> dict[int, dict[int, np.ndarray]]:
        """``{frame: {panicle_id: D (4x4)}}``; missing entries mean identity."""
        from seedmap.geometry import tum_to_pose

        p = self.root / "gt" / "panicle_poses.csv"
        out: dict[int, dict[int, np.ndarray]] = {}
        if not p.is_file():
            return out
        a = read_table(p, "ground-truth panicle_poses.csv")
        if a.size == 0:
            return out
        T = tum_to_pose(a[:, 2:9])
        for f, pid, Ti in zip(a[:, 0].astype(int), a[:, 1].astype(int), T, strict=True):
            out.setdefault(int(f), {})[int(pid)] = Ti
        return out

    def gt_instances(self, i: int, cam: str = "left") -> Instances:
        p = self.root / "gt" / "instances" / cam / f"{i:06d}.csv"
        if not p.is_file():
            raise InputError("ground-truth instance table not found", p)
        a = _read_instance_table(p)
        if a.size == 0:
            return Instances.empty()
        return Instances(
            label=a[:, 0].astype(np.uint16),
            seed_id=a[:, 1].astype(np.int64),
            panicle_id=a[:, 2].astype(np.int64),
            boxes=a[:, 3:7],
            center_uv=a[:, 7:9],
            area=a[:, 9].astype(np.int64),
            center_visible=a[:, 10].astype(bool),
        )

    def gt_label_image(self, i: int, cam: str = "left") -> np.ndarray:
        """The raw uint16 label image (0 = background); map labels with :meth:`gt_instances`."""
        return read_label_png(self.root / "gt" / "masks" / cam / frame_name(i))

    def gt_seed_id_image(self, i: int, cam: str = "left") -> np.ndarray:
        """``H x W`` int64 image of global seed ids, ``-1`` where no seed is visible."""
        labels = self.gt_label_image(i, cam)
        inst = self.gt_instances(i, cam)
        lut = np.full(int(labels.max()) + 1 if labels.size else 1, -1, np.int64)
        lut[inst.label.astype(np.int64)] = inst.seed_id
        return lut[labels]

    def gt_config_text(self) -> str | None:
        p = self.root / "gt" / "config.yaml"
        return read_text(p, "ground-truth config.yaml") if p.is_file() else None


def _is_seedmap(p: Path) -> bool:
    # a generic folder with calib.yaml + times.txt but other file names is left to the folder loader
    return SeedmapDataset.is_dataset(p) and (
        (p / "left" / frame_name(0)).is_file() or not any((p / "left").iterdir()))


def _open_seedmap(p: Path, allow_fewer_times: bool = False, **kw) -> SeedmapDataset:
    if kw:
        raise ConfigError(f"the seedmap dataset format takes only the option allow_fewer_times (got "
                          f"{', '.join(sorted(kw))})", p)
    return SeedmapDataset(p, allow_fewer_times=allow_fewer_times)


register_loader("seedmap", _is_seedmap, _open_seedmap, order=10)
