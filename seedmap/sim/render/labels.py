"""Ground-truth instance labels of a rendered image: label mask, boxes, projected centres, visibility."""

from __future__ import annotations

import numpy as np

from seedmap.geometry import invert
from seedmap.io.seedmap_dataset import Instances
from seedmap.records import StereoCalib
from seedmap.sim.render.scene import _FrameScene

def _instances(fs: _FrameScene, seed_img: np.ndarray, centers_now: np.ndarray, T_wc: np.ndarray,
               calib: StereoCalib) -> tuple[np.ndarray, Instances]:
    world = fs.world
    H, W = seed_img.shape
    flat = seed_img.reshape(-1)
    has = flat >= 0
    labels = np.zeros(H * W, np.uint16)
    if not has.any():
        return labels.reshape(H, W), Instances.empty()
    pix = np.nonzero(has)[0]
    ids, inv, area = np.unique(flat[pix], return_inverse=True, return_counts=True)
    if len(ids) > 65535:
        raise RuntimeError("more than 65535 visible seeds in one image")
    K = len(ids)
    labels[pix] = (inv + 1).astype(np.uint16)
    rows, cols = np.divmod(pix, W)
    x0 = np.full(K, W, np.int64)
    y0 = np.full(K, H, np.int64)
    x1 = np.zeros(K, np.int64)
    y1 = np.zeros(K, np.int64)
    np.minimum.at(x0, inv, cols)
    np.minimum.at(y0, inv, rows)
    np.maximum.at(x1, inv, cols + 1)
    np.maximum.at(y1, inv, rows + 1)
    c_world = centers_now[ids]
    Tcw = invert(T_wc)
    pc = c_world @ Tcw[:3, :3].T + Tcw[:3, 3]
    # rounded to the 1/1000 px the dataset stores, so the pixel test below agrees with what is read back
    u = np.round(calib.fx * pc[:, 0] / pc[:, 2] + calib.cx, 3)
    v = np.round(calib.fy * pc[:, 1] / pc[:, 2] + calib.cy, 3)
    # center_visible: the ray from the optical centre towards the 3D centre meets this seed first
    o = T_wc[:3, 3]
    dv = (c_world - o).astype(np.float32)
    dist = np.linalg.norm(dv, axis=1)
    hc = fs.trace(o.astype(np.float32)[None, :], (dv / dist[:, None]).astype(np.float32))
    ray_ok = (hc.seed == ids) & (hc.t <= dist + 1e-5)
    # ... and the pixel that contains the projected centre shows this seed (a seed can be hit by the
    # exact centre ray while the pixel-centre ray, up to half a pixel away, meets a neighbour)
    cu = np.floor(u + 0.5).astype(np.int64)
    cr = np.floor(v + 0.5).astype(np.int64)
    inside = (cu >= 0) & (cu < W) & (cr >= 0) & (cr < H)
    pix_ok = np.zeros(K, bool)
    pix_ok[inside] = seed_img[cr[inside], cu[inside]] == ids[inside]
    visible = ray_ok & pix_ok
    inst = Instances(
        label=np.arange(1, K + 1, dtype=np.uint16), seed_id=world.seeds.seed_id[ids].astype(np.int64),
        panicle_id=world.seeds.panicle_id[ids].astype(np.int64), boxes=np.column_stack([x0, y0, x1, y1]),
        center_uv=np.column_stack([u, v]), area=area.astype(np.int64), center_visible=visible)
    return labels.reshape(H, W), inst
