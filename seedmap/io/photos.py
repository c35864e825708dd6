"""Single images (photos, scans) as detector input: one image file, or every image of a folder.

``seedmap detect PATH`` reads PATH this way when no stereo loader recognises it (:func:`is_photo_input`). Images
keep their names relative to PATH (a folder; its image files sorted by name, not recursive) or their file name
(one file). :func:`read_photo` converts what a camera or scanner writes to the detectors' 8-bit RGB: grayscale is
replicated to three channels, 16-bit is scaled to 8 bits (12-bit camera data in a 16-bit file too), an alpha channel
is dropped and the EXIF orientation applied (as image viewers and labelling tools show the photo).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from seedmap.errors import InputError
from seedmap.io.common import IMAGE_SUFFIXES, list_images, to_rgb
from seedmap.io.images import imdecode_quiet
from seedmap.io.registry import detect_format

#: file suffixes read as images (the stereo loaders' list plus WebP)
PHOTO_SUFFIXES = (*IMAGE_SUFFIXES, ".webp")
#: a 16-bit image whose pixels all lie at or below this holds 12-bit data (scaled by 2^-4, not 2^-8)
TWELVE_BIT_MAX = 4095


def list_photos(folder: str | Path) -> list[Path]:
    """The image files directly in ``folder`` (not in subfolders), sorted by name (``img2`` before ``img10``)."""
    return list_images(Path(folder), PHOTO_SUFFIXES)


def is_photo_input(path: str | Path, fmt: str | None = None) -> bool:
    """True when ``path`` is an image file, or a folder holding image files that no dataset loader recognises
    (``fmt``: a dataset format the user forced, never images)."""
    p = Path(path)
    if fmt is not None or not p.exists() or detect_format(p) is not None:
        return False
    if p.is_file():
        return p.suffix.lower() in PHOTO_SUFFIXES
    return p.is_dir() and bool(list_photos(p))


def read_photo(path: str | Path) -> np.ndarray:
    """An image file as ``H x W x 3`` RGB uint8 (conversions in the module docstring; one-line error otherwise)."""
    p = Path(path)
    try:
        data = np.fromfile(p, dtype=np.uint8)
    except OSError as e:
        raise InputError(f"image not readable ({e.strerror or e})", p) from None
    if data.size == 0:
        raise InputError("image file is empty (0 bytes)", p)
    img = imdecode_quiet(data, cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH)
    if img is None or img.size == 0:
        raise InputError("not a readable image (corrupt, unknown format, or over 2^30 pixels); re-export it "
                         "as PNG or JPEG", p)
    if img.dtype == np.uint16:
        img = (img >> (4 if int(img.max()) <= TWELVE_BIT_MAX else 8)).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{img.dtype} image; convert it to 8- or 16-bit integer pixels", p)
    try:
        return to_rgb(img)
    except ValueError as e:
        raise InputError(f"unsupported image layout ({e})", p) from None


class PhotoSet:
    """The images of ``path``: one image file, or every image directly in a folder (sorted by name).

    ``names[i]`` is the image's path relative to ``path`` (a folder) or its file name (one file); ``image(i)``
    reads it (:func:`read_photo`)."""

    name = "images"

    def __init__(self, path: str | Path) -> None:
        self.root = Path(path)
        if self.root.is_file():
            if self.root.suffix.lower() not in PHOTO_SUFFIXES:
                raise InputError(f"not an image file (known: {', '.join(PHOTO_SUFFIXES)})", self.root)
            self.files = [self.root]
            self.names = [self.root.name]
        elif self.root.is_dir():
            self.files = list_photos(self.root)
            if not self.files:
                raise InputError(f"no image files ({', '.join(PHOTO_SUFFIXES)}) in this folder", self.root)
            self.names = [f.relative_to(self.root).as_posix() for f in self.files]
        else:
            raise InputError("image or folder not found", self.root)

    def __len__(self) -> int:
        return len(self.files)

    def image(self, i: int) -> np.ndarray:
        return read_photo(self.files[i])
