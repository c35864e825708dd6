"""Sensor and ISP model: gain, vignetting, blur, shot and read noise, gamma, 8-bit, optional JPEG."""

from __future__ import annotations

import numpy as np

from seedmap.records import StereoCalib
from seedmap.sim.config import FULL_WELL, PSF_SIGMA_PX, READ_NOISE, VIGNETTING, SimConfig

_GAMMA_LUT = np.round(255.0 * np.linspace(0, 1, 4096) ** (1 / 2.2)).astype(np.uint8)


def _develop(lin: np.ndarray, calib: StereoCalib, cfg: SimConfig, rng: np.random.Generator, gain: float,
             cache: dict) -> np.ndarray:
    """Sensor + ISP model: gain, vignetting, blur, noise, gamma, 8-bit (and optional JPEG). ``lin`` (H, W, 3)
    float32 is overwritten."""
    import cv2

    ic = cfg.imaging
    H, W = lin.shape[:2]
    key = ("vignette", calib)
    vig = cache.get(key)
    if vig is None:
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        rn2 = ((xx - calib.cx) ** 2 + (yy - calib.cy) ** 2) / (0.25 * (W * W + H * H))
        vig = cache[key] = (1 - VIGNETTING * rn2).astype(np.float32)[..., None]
    img = lin  # (the caller's buffer, scaled in place)
    img *= vig * np.float32(gain * FULL_WELL)  # electrons
    img = cv2.GaussianBlur(img, (0, 0), PSF_SIGMA_PX)
    np.maximum(img, 0, out=img)
    # shot + read noise as one Gaussian of the combined variance
    noise = rng.standard_normal(img.shape, np.float32)
    sd = img + np.float32(READ_NOISE ** 2)
    np.sqrt(sd, out=sd)
    noise *= sd
    img += noise
    img *= np.float32(4095.0 / FULL_WELL)
    np.clip(img, 0, 4095, out=img)
    # uint16 codes (the same truncation as an integer cast; a quarter of the memory traffic of intp)
    out = np.take(_GAMMA_LUT, img.astype(np.uint16), mode="clip")
    if ic.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(ic.jpeg_quality)])
        if ok:
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return out
