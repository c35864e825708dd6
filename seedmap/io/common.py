"""Pieces every dataloader shares: image decoding to RGB, timestamp files, frame assembly from a rig."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from seedmap.errors import InputError
from seedmap.io.calibration import RectifyMaps, StereoRig, check_image_size, rectify
from seedmap.io.images import imdecode_quiet
from seedmap.records import StereoCalib, StereoFrame

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


_REPORTED: set[str] = set()


class LoaderWarnings(list):
    """A loader's ``warnings`` list that also reports each entry on the ``seedmap.io`` logger as it is added.

    Recoverable oddities (grayscale converted, frames dropped, timestamps made up from fps, a baseline that
    looks like millimetres) change what a run means, so the user must see them: the CLI prints this logger
    as ``warning: <dataset>: <message>`` lines on stderr; library users get Python's default handling.
    """

    def __init__(self, where: str | Path) -> None:
        super().__init__()
        self.where = str(where)

    def append(self, msg: str) -> None:  # type: ignore[override]
        super().append(msg)
        import logging

        text = str(msg)
        text = text if text.startswith(self.where) else f"{self.where}: {text}"
        if text not in _REPORTED:  # a command that opens one dataset several times (benchmark methods) says it once
            _REPORTED.add(text)
            logging.getLogger("seedmap.io").warning(text)

    def extend(self, msgs) -> None:  # type: ignore[override]
        for m in msgs:
            self.append(m)

    def __reduce__(self):  # unpickles as a plain list (no second report)
        return (list, (list(self),))


def to_rgb(img: np.ndarray, bgr: bool = True) -> np.ndarray:
    """Any 8-bit decoded image -> ``H x W x 3`` RGB uint8 (grayscale is replicated to three channels)."""
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 1):
        return cv2.cvtColor(img.reshape(img.shape[0], img.shape[1]), cv2.COLOR_GRAY2RGB)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if bgr else cv2.COLOR_RGBA2RGB)
    if img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if bgr else np.ascontiguousarray(img)
    raise ValueError(f"{img.shape[2]}-channel image")


def decode_image_bytes(data: bytes | np.ndarray, where: str | Path) -> tuple[np.ndarray, bool]:
    """Decode PNG/JPEG/... bytes to RGB uint8; returns ``(rgb, was_grayscale)``.

    Grayscale images are converted to 3-channel RGB (the caller records a warning: seed detectors are
    built for colour). 16-bit images are refused - seedmap works on 8-bit images.
    """
    buf = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1)
    if buf.size == 0:
        raise InputError("image is empty (0 bytes)", where)
    img = imdecode_quiet(buf)
    if img is None or img.size == 0:
        raise InputError("not a readable image (corrupt or unknown format); re-export or remove it", where)
    if img.dtype != np.uint8:
        raise InputError(f"{img.dtype} image; seedmap expects 8-bit images (convert to 8-bit)", where)
    gray = img.ndim == 2 or img.shape[2] == 1
    try:
        return to_rgb(img), gray
    except ValueError as e:
        raise InputError(f"unsupported image layout ({e})", where) from None


def read_image_rgb(path: Path) -> tuple[np.ndarray, bool]:
    """Read an image file as RGB uint8 (grayscale replicated); ``(rgb, was_grayscale)``."""
    path = Path(path)
    if not path.is_file():
        raise InputError("image file not found", path)
    return decode_image_bytes(np.fromfile(path, dtype=np.uint8), path)


def natural_key(p: Path) -> tuple:
    """Sort key that orders ``img2.png`` before ``img10.png``."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name))


def list_images(folder: Path, suffixes: Sequence[str] = IMAGE_SUFFIXES) -> list[Path]:
    """The files directly in ``folder`` with one of ``suffixes``, sorted by name (``img2`` before ``img10``)."""
    return sorted((p for p in Path(folder).iterdir() if p.suffix.lower() in suffixes and p.is_file()),
                  key=natural_key)


def write_times_txt(path: Path, ts: Sequence[float]) -> None:
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(Path(path), "".join(f"{t:.9f}\n" for t in ts))


class RectifiedPairs:
    """Base of the file-based loaders: raw pair files + a rig -> rectified RGB :class:`StereoFrame`.

    Subclasses set ``self.rig`` (or ``self.calib`` for already-rectified data), ``self.timestamps`` and
    ``self._pairs`` (list of ``(left_path, right_path)``), then call :meth:`_setup_rectification`.
    ``warnings`` collects recoverable oddities (grayscale converted, frames dropped) for the user.
    """

    name = "pairs"
    calib: StereoCalib
    timestamps: np.ndarray
    rig: StereoRig
    maps: RectifyMaps | None
    warnings: list[str]

    def _setup_rectification(self, rig: StereoRig, alpha: float = 0.0) -> None:
        self.rig = rig
        self.calib, self.maps = rectify(rig, alpha=alpha)
        self.warnings.extend(rig.warnings)
        self._gray_warned = False

    def __len__(self) -> int:
        return len(self._pairs)

    def _read(self, p: Path) -> np.ndarray:
        img, gray = read_image_rgb(p)
        if gray and not self._gray_warned:
            self._gray_warned = True
            self.warnings.append(f"{p.parent}: grayscale images converted to 3-channel RGB "
                                 "(seed detectors expect colour)")
        return img

    def raw_pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The unrectified RGB pair ``i`` as stored on disk."""
        lp, rp = self._pairs[i]
        left, right = self._read(lp), self._read(rp)
        check_image_size(self.rig.left.size, left, lp, self.rig.source)
        check_image_size(self.rig.right.size, right, rp, self.rig.source)
        return left, right

    def __getitem__(self, i: int) -> StereoFrame:
        if not isinstance(i, (int, np.integer)):
            raise TypeError("frame index must be an integer")
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        left, right = self.raw_pair(int(i))
        if self.maps is not None:
            left, right = self.maps.apply(left, right)
        return StereoFrame(index=int(i), timestamp=float(self.timestamps[i]), left=left, right=right)

    def __iter__(self) -> Iterator[StereoFrame]:
        for i in range(len(self)):
            yield self[i]
