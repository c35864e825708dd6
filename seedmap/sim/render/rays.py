"""Rays and the array helpers the renderer shares: hit records, Open3D ray tensors, fast gathers and
scatters, camera ray directions."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from seedmap.records import StereoCalib
from seedmap.sim.world import World

ENV_CODE = -2  # ``_FrameScene.trace(only=...)`` code of the env BVH (stalks and leaves)


@dataclass
class _Hits:
    t: np.ndarray  # (N,) distance along the unit ray, inf = miss
    cls: np.ndarray  # (N,) uint8 surface class
    obj: np.ndarray  # (N,) int32: panicle index (seed/rachis), -1 otherwise
    prim: np.ndarray  # (N,) int64 triangle index within its mesh
    bary: np.ndarray  # (N, 2) barycentric (u, v) of the hit
    seed: np.ndarray  # (N,) int64 global seed id or -1


def _o3d():
    import open3d as o3d

    return o3d


def _xf(a: np.ndarray, M: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """``a @ M.T + t`` for many points ``a`` (N, 3) as float32 (OpenCV's transform: numpy's matmul of
    an (N, 3) by a 3 x 3 matrix is ~50x slower)."""
    import cv2

    a = np.ascontiguousarray(a, np.float32)
    if len(a) == 0:
        return a.reshape(0, 3)
    m = np.zeros((3, 4), np.float32)
    m[:, :3] = M
    if t is not None:
        m[:, 3] = t
    return cv2.transform(a.reshape(-1, 1, 3), m).reshape(-1, 3)


_O3D_THREADS = threading.local()


def _o3d_threads() -> int:
    """Threads of one Open3D query: 1 while the two cameras render in parallel threads (the cores are
    already busy; more threads only add scheduling overhead), else 0 = automatic."""
    return getattr(_O3D_THREADS, "n", 0)


def _take(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` along the first axis for valid ``idx`` (``np.take``: 2-3x faster than fancy indexing on
    (N, k) arrays; ``mode="clip"`` skips the bounds check, up to 3x faster again on wide rows)."""
    return np.take(a, idx, axis=0, mode="clip")


def _put_rows(out: np.ndarray, idx: np.ndarray, rows: np.ndarray) -> None:
    """``out[idx] = rows`` for a C-contiguous (N, k) ``out`` and distinct ``idx``: one ``np.put`` of
    k-float records (1.6x faster than fancy row assignment, which copies element by element)."""
    rec = np.dtype((np.void, out.dtype.itemsize * out.shape[1]))
    np.put(out.view(rec).reshape(-1), idx, np.ascontiguousarray(rows, out.dtype).view(rec).reshape(-1))


def _rays_tensor(o: np.ndarray, d: np.ndarray):
    o3d = _o3d()
    r = np.empty((len(d), 6), np.float32)
    r[:, :3] = o
    r[:, 3:] = d
    return o3d.core.Tensor.from_numpy(r)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of two (3, n) struct-of-arrays vectors."""
    out = a[0] * b[0]
    out += a[1] * b[1]
    out += a[2] * b[2]
    return out


def _normalize3(a: np.ndarray) -> np.ndarray:
    """Normalise (3, n) vectors in place (and return them)."""
    a *= 1.0 / np.maximum(np.sqrt(_dot3(a, a)), np.float32(1e-12))
    return a


def _rows(table: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``table[idx]`` as a (K, n) struct-of-arrays view (one contiguous row of ``table`` per item)."""
    return np.take(table, idx, axis=0, mode="clip").T


def _camera_dirs(world: World, calib: StereoCalib) -> tuple[np.ndarray, np.ndarray]:
    """Unit ray directions through all pixel centres in the camera frame (cached) and pixel (u, v)."""
    key = ("dirs", calib)
    got = world.cache.get(key)
    if got is None:
        H, W = calib.height, calib.width
        vv, uu = np.mgrid[0:H, 0:W]
        pix = np.stack([uu.reshape(-1), vv.reshape(-1)], 1).astype(np.float32)
        got = (_unit_dirs(calib, pix), pix)
        world.cache[key] = got
    return got


def _unit_dirs(calib: StereoCalib, pix: np.ndarray) -> np.ndarray:
    x = (pix[:, 0] - np.float32(calib.cx)) / np.float32(calib.fx)
    y = (pix[:, 1] - np.float32(calib.cy)) / np.float32(calib.fy)
    inv = 1.0 / np.sqrt(x * x + y * y + 1.0)
    return np.stack([x * inv, y * inv, inv], 1).astype(np.float32)


def _object_key(h: _Hits) -> np.ndarray:
    """One int32 per ray naming what it sees: the seed id, or a negative code of (class, object)."""
    return np.where(h.seed >= 0, h.seed.astype(np.int32), -(h.cls.astype(np.int32) * 1_000_000 + h.obj + 2))
