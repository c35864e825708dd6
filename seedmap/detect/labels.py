"""Labelled images for training: simulated seedmap datasets or the user's COCO annotations.

Both sources yield :class:`LabelledImage` (RGB image, GT boxes, an instance label image whose
value ``k + 1`` is the mask of box ``k``). The COCO reader understands ``bbox`` and
``segmentation`` as polygons, uncompressed RLE (``counts`` list) or compressed RLE (``counts``
string, the LEB128-like encoding of the COCO API) — decoded here, pycocotools is not needed.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seedmap.errors import InputError
from seedmap.io.text import read_text
from seedmap.io.images import read_rgb
from seedmap.io.photos import read_photo


@dataclass
class LabelledImage:
    image: np.ndarray  # H x W x 3 uint8 RGB
    boxes: np.ndarray  # (N, 4) x0, y0, x1, y1 (x1/y1 exclusive pixel bounds)
    labels: np.ndarray  # H x W int32; k + 1 = instance k, 0 = background
    name: str = ""


def rle_decode_counts(counts: list[int], h: int, w: int) -> np.ndarray:
    """Uncompressed COCO RLE (column-major runs starting with zeros) -> ``h x w`` uint8 mask."""
    flat = np.zeros(h * w, np.uint8)
    pos = 0
    val = 0
    for c in counts:
        c = int(c)
        if val:
            flat[pos:pos + c] = 1
        pos += c
        val ^= 1
    if pos != h * w:
        raise ValueError(f"RLE covers {pos} pixels, image has {h * w}")
    return flat.reshape(w, h).T.copy()


def rle_string_to_counts(s: str | bytes) -> list[int]:
    """Decode the COCO API's compressed RLE string into run lengths."""
    if isinstance(s, bytes):
        s = s.decode("ascii")
    counts: list[int] = []
    i = 0
    n = len(s)
    while i < n:
        x = 0
        k = 0
        more = True
        while more:
            c = ord(s[i]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            i += 1
            k += 1
            if not more and (c & 0x10):
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


def rle_counts_to_string(counts: list[int]) -> str:
    """Inverse of :func:`rle_string_to_counts` (used by the tests to build compressed RLE)."""
    out = []
    for i, c in enumerate(counts):
        x = int(c)
        if i > 2:
            x -= int(counts[i - 2])
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = not ((x == 0 and not (ch & 0x10)) or (x == -1 and (ch & 0x10)))
            if more:
                ch |= 0x20
            out.append(chr(ch + 48))
    return "".join(out)


def rle_window(counts: list[int], h: int, w: int) -> tuple[np.ndarray, int, int]:
    """Uncompressed COCO RLE -> ``(mask, y0, x0)``: the mask cut to the rows and columns its pixels span (decoded
    in that window only: a seed's mask in a 24-megapixel photo costs its own size, not the image's)."""
    c = np.asarray([int(v) for v in counts], np.int64)
    if c.sum() != h * w:
        raise ValueError(f"RLE covers {int(c.sum())} pixels, image has {h * w}")
    if (c < 0).any():
        raise ValueError("RLE has negative run lengths")
    ends = np.cumsum(c)
    starts = ends - c
    ones = (np.arange(len(c)) % 2 == 1) & (c > 0)
    if not ones.any():
        return np.zeros((0, 0), np.uint8), 0, 0
    s1, e1 = starts[ones], ends[ones]
    c0, c1 = int(s1.min() // h), int((e1.max() - 1) // h)
    flat = np.zeros((c1 - c0 + 1) * h, np.uint8)
    for a, b in zip(s1 - c0 * h, e1 - c0 * h):
        flat[a:b] = 1
    win = flat.reshape(c1 - c0 + 1, h).T
    rows = np.flatnonzero(win.any(axis=1))
    return np.ascontiguousarray(win[rows[0]:rows[-1] + 1]), int(rows[0]), c0


def segmentation_window(seg: object, h: int, w: int) -> tuple[np.ndarray, int, int]:
    """COCO ``segmentation`` (polygons or RLE) of an ``h x w`` image -> ``(mask, y0, x0)``: the uint8 mask within
    the window at row ``y0``, column ``x0`` that holds all its pixels (decoded there only)."""
    if isinstance(seg, dict) and "counts" in seg:
        sh = seg.get("size", [h, w])
        counts = seg["counts"]
        if isinstance(counts, (str, bytes)):
            counts = rle_string_to_counts(counts)
        return rle_window(counts, int(sh[0]), int(sh[1]))
    if isinstance(seg, list):
        pts = [np.asarray(q, np.float64).reshape(-1, 2) for q in seg]
        pts = [q for q in pts if len(q) >= 3]
        if not pts:
            return np.zeros((0, 0), np.uint8), 0, 0
        allp = np.concatenate(pts)
        x0, y0 = (int(v) for v in np.clip(np.floor(allp.min(axis=0)), 0, [w, h]))
        x1, y1 = (int(v) for v in np.clip(np.ceil(allp.max(axis=0)) + 1, 0, [w, h]))
        if x1 <= x0 or y1 <= y0:
            return np.zeros((0, 0), np.uint8), 0, 0
        shifted = [(q - [x0, y0]).ravel().tolist() for q in pts]
        return segmentation_mask(shifted, y1 - y0, x1 - x0), y0, x0
    raise ValueError("segmentation must be a polygon list or an RLE dict")


def segmentation_mask(seg: object, h: int, w: int) -> np.ndarray:
    """COCO ``segmentation`` (polygons or RLE) -> ``h x w`` uint8 mask."""
    if isinstance(seg, list):
        from matplotlib.path import Path as MplPath

        m = np.zeros((h, w), np.uint8)
        for poly in seg:
            p = np.asarray(poly, np.float64).reshape(-1, 2)
            if len(p) < 3:
                continue
            # COCO polygons use pixel-edge coordinates (pixel k spans [k, k+1)): a pixel is inside
            # when its centre (k + 0.5) is inside the polygon
            x0, y0 = np.clip(np.floor(p.min(axis=0)).astype(int), 0, [w, h])
            x1, y1 = np.clip(np.ceil(p.max(axis=0)).astype(int) + 1, 0, [w, h])
            if x1 <= x0 or y1 <= y0:
                continue
            yy, xx = np.mgrid[y0:y1, x0:x1]
            inside = MplPath(p).contains_points(np.c_[xx.ravel() + 0.5, yy.ravel() + 0.5])
            m[y0:y1, x0:x1] |= inside.reshape(yy.shape).astype(np.uint8)
        return m
    if isinstance(seg, dict) and "counts" in seg:
        sh = seg.get("size", [h, w])
        counts = seg["counts"]
        if isinstance(counts, (str, bytes)):
            counts = rle_string_to_counts(counts)
        return rle_decode_counts(counts, int(sh[0]), int(sh[1]))
    raise ValueError("segmentation must be a polygon list or an RLE dict")


def _check_coco_images(images, root: Path | None, p: Path, purpose: str = "train on") -> dict:
    """COCO ``images``: ids unique, files present under ``root`` (None: not checked) -> {id: (width, height) or
    None}.

    Checked before a training run starts, so a bad file is one line naming it and leaves no run folder
    (a missing image used to be found at the first batch, after the run folder was written)."""
    if not isinstance(images, list) or not images:
        raise InputError(f"COCO 'images' is empty (nothing to {purpose})", p)
    sizes: dict = {}
    for k, im in enumerate(images):
        if not isinstance(im, dict) or "id" not in im or "file_name" not in im:
            raise InputError(f"images[{k}] needs 'id' and 'file_name'", p)
        if im["id"] in sizes:
            raise InputError(f"image id {im['id']} appears twice", p)
        if root is not None and not (root / im["file_name"]).is_file():
            raise InputError(f"image {im['file_name']!r} (id {im['id']}) not found under {root} "
                             "(--images-root names the image folder)", p)
        wh = (im.get("width"), im.get("height"))
        sizes[im["id"]] = wh if all(isinstance(v, (int, float)) and v > 0 for v in wh) else None
    return sizes


def _check_coco_annotation(a, sizes: dict, cats: dict, p: Path) -> None:
    """One COCO annotation: its image and category exist, its ``bbox`` is [x, y, w, h] with w, h > 0 inside
    the image (1 px tolerance). A box outside the image crashed training in OpenCV (warpAffine on an empty
    crop); an unknown category was trained on silently."""
    if not isinstance(a, dict) or "image_id" not in a:
        raise InputError("an annotation has no 'image_id'", p)
    aid = a.get("id", "?")
    if a["image_id"] not in sizes:
        raise InputError(f"annotation {aid}: image_id {a['image_id']} is not in 'images'", p)
    if cats and "category_id" in a and a["category_id"] not in cats:
        raise InputError(f"annotation {aid}: category_id {a['category_id']} is not in 'categories'", p)
    if "bbox" in a:
        b = a["bbox"]
        try:
            x, y, bw, bh = (float(v) for v in b)
        except (TypeError, ValueError):
            raise InputError(f"annotation {aid}: bbox must be four numbers [x, y, width, height], got {b!r}",
                             p) from None
        if not np.all(np.isfinite([x, y, bw, bh])) or bw <= 0 or bh <= 0:
            raise InputError(f"annotation {aid}: bbox {b} needs finite numbers and width, height > 0 "
                             "([x, y, width, height])", p)
        wh = sizes[a["image_id"]]
        if wh is not None and (x < -1 or y < -1 or x + bw > wh[0] + 1 or y + bh > wh[1] + 1):
            raise InputError(f"annotation {aid}: bbox {b} ([x, y, width, height]) is outside the "
                             f"{wh[0]:g}x{wh[1]:g} image {a['image_id']}", p)
    elif not a.get("segmentation"):
        raise InputError(f"annotation {aid}: neither 'bbox' nor 'segmentation'", p)
    seg = a.get("segmentation")
    wh = sizes[a["image_id"]]
    if isinstance(seg, list) and seg and wh is not None:
        try:
            pts = np.concatenate([np.asarray(q, np.float64).reshape(-1, 2) for q in seg])
        except (TypeError, ValueError):
            raise InputError(f"annotation {aid}: segmentation polygons must be lists of x, y numbers", p) from None
        if len(pts) and (not np.all(np.isfinite(pts)) or pts.min() < -1 or pts[:, 0].max() > wh[0] + 1
                         or pts[:, 1].max() > wh[1] + 1):
            raise InputError(f"annotation {aid}: segmentation polygon is outside the {wh[0]:g}x{wh[1]:g} image "
                             f"{a['image_id']}", p)


def read_coco_json(p: Path) -> dict:
    """The parsed COCO file ``p``: a dict with ``images`` and ``annotations`` (else one-line InputError)."""
    if not p.is_file():
        raise InputError("COCO label file not found", p)
    try:
        d = json.loads(read_text(p, "COCO label file"))
    except json.JSONDecodeError as e:
        raise InputError(f"not valid JSON ({e.msg} at line {e.lineno})", p) from None
    if not isinstance(d, dict) or "images" not in d or "annotations" not in d:
        raise InputError("not a COCO file (needs 'images' and 'annotations')", p)
    return d

class CocoSource:
    """Images + instance masks from a COCO JSON file (one category or all categories as 'seed')."""

    def __init__(self, json_path: str | Path, images_root: str | Path | None = None,
                 category: str | None = None) -> None:
        p = Path(json_path)
        d = read_coco_json(p)
        self.path = p
        self.root = Path(images_root) if images_root else p.parent
        cats = {c["id"]: c.get("name", "") for c in d.get("categories", [])}
        keep_cat = None
        if category is not None:
            keep_cat = {i for i, n in cats.items() if n == category}
            if not keep_cat:
                raise InputError(f"no category named {category!r} (have: {', '.join(cats.values())})", p)
        self.images = d["images"]
        self.anns: dict[int, list[dict]] = {}
        sizes = _check_coco_images(self.images, self.root, p)
        for a in d["annotations"]:
            _check_coco_annotation(a, sizes, cats, p)
            if keep_cat is not None and a.get("category_id") not in keep_cat:
                continue
            self.anns.setdefault(a["image_id"], []).append(a)
        if not self.anns:
            raise InputError("no annotations" + (f" of category {category!r}" if category is not None else "")
                             + " (nothing to train on)", p)

    def __len__(self) -> int:
        return len(self.images)

    def labelled_indices(self) -> list[int]:
        """Indices of the images that have at least one annotation."""
        return [k for k, im in enumerate(self.images) if self.anns.get(im["id"])]

    def seed_sides(self, indices) -> np.ndarray:  # noqa: ANN001 - iterable of image indices
        """Geometric mean of the box sides (px) of every annotation of the images ``indices``: from ``bbox``, else
        from the segmentation's extent (polygon points, or the decoded RLE mask)."""
        out = []
        for k in indices:
            im = self.images[k]
            for a in self.anns.get(im["id"], []):
                if "bbox" in a:
                    _, _, bw, bh = (float(v) for v in a["bbox"])
                else:
                    seg = a["segmentation"]
                    if isinstance(seg, list):
                        pts = np.concatenate([np.asarray(q, np.float64).reshape(-1, 2) for q in seg])
                        bw, bh = np.ptp(pts[:, 0]), np.ptp(pts[:, 1])
                    else:
                        try:
                            sh = seg.get("size") or [im.get("height"), im.get("width")]
                            m, _, _ = segmentation_window(seg, int(sh[0]), int(sh[1]))
                        except (ValueError, TypeError, AttributeError) as e:
                            raise InputError(f"annotation {a.get('id')}: bad segmentation ({e})", self.path) from None
                        ys, xs = np.nonzero(m)
                        if not len(xs):
                            continue
                        bw, bh = np.ptp(xs) + 1, np.ptp(ys) + 1
                out.append(float(np.sqrt(max(bw, 0) * max(bh, 0))))
        return np.asarray(out, np.float64)

    def __getitem__(self, i: int) -> LabelledImage:
        im = self.images[i]
        img = read_photo(self.root / im["file_name"])  # as `seedmap detect` reads it (grayscale, 16-bit converted)
        h, w = img.shape[:2]
        labels = np.zeros((h, w), np.int32)
        boxes = []
        for a in self.anns.get(im["id"], []):
            seg = a.get("segmentation")
            if isinstance(seg, dict) and "size" in seg and [int(v) for v in seg["size"]] != [h, w]:
                raise InputError(f"annotation {a.get('id')}: mask size {tuple(seg['size'])} != image {h}x{w}",
                                 self.path)
            try:
                m, y0, x0 = segmentation_window(seg, h, w) if seg else (None, 0, 0)
            except (ValueError, TypeError, AttributeError) as e:
                raise InputError(f"annotation {a.get('id')}: bad segmentation ({e})", self.path) from None
            if "bbox" in a:
                x, y, bw, bh = (float(v) for v in a["bbox"])
                box = [x, y, x + bw, y + bh]
            elif m is not None and m.any():
                ys, xs = np.nonzero(m)
                box = [x0 + xs.min(), y0 + ys.min(), x0 + xs.max() + 1, y0 + ys.max() + 1]
            else:
                continue
            boxes.append(box)
            if m is not None and m.size:
                sub = labels[y0:y0 + m.shape[0], x0:x0 + m.shape[1]]
                sub[(m[:sub.shape[0], :sub.shape[1]] > 0) & (sub == 0)] = len(boxes)
        return LabelledImage(img, np.asarray(boxes, np.float64).reshape(-1, 4), labels, im["file_name"])


class SeedmapSource:
    """Every (frame, camera) image of a simulated seedmap dataset with its GT instances."""

    def __init__(self, root: str | Path, min_area_px: int = 3, frames: list[int] | None = None) -> None:
        from seedmap.io.seedmap_dataset import SeedmapDataset

        self.ds = SeedmapDataset(root)
        if not (Path(root) / "gt" / "instances").is_dir():
            raise InputError("dataset has no ground truth (gt/instances/) to train on", root)
        self.min_area = min_area_px
        fr = list(range(len(self.ds))) if frames is None else frames
        self.items = [(i, c) for i in fr for c in ("left", "right")]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, k: int) -> LabelledImage:
        i, cam = self.items[k]
        img = read_rgb(self.ds.image_path(i, cam))
        inst = self.ds.gt_instances(i, cam)
        raw = self.ds.gt_label_image(i, cam).astype(np.int64)
        keep = inst.area >= self.min_area
        lut = np.zeros(int(max(raw.max(), inst.label.max(initial=0))) + 1, np.int32)
        lut[inst.label[keep].astype(np.int64)] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
        return LabelledImage(img, inst.boxes[keep].astype(np.float64), lut[raw], f"{cam}/{i:06d}.png")


def open_labelled(path: str | Path, images_root: str | Path | None = None, frames: list[int] | None = None,
                  min_area_px: int = 3):
    """A seedmap dataset folder (GT instances of at least ``min_area_px`` visible pixels) or a COCO ``.json`` file
    -> a labelled-image source."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        return CocoSource(p, images_root)
    if not p.exists():
        raise InputError("training data not found", p)
    return SeedmapSource(p, min_area_px=min_area_px, frames=frames)


class ConcatSource:
    """Several labelled-image sources read as one, in order (their images one after the other)."""

    def __init__(self, sources: Sequence) -> None:
        self.sources = list(sources)
        self.path = getattr(self.sources[0], "path", None) if self.sources else None
        self.starts = np.cumsum([0] + [len(s) for s in self.sources])

    def __len__(self) -> int:
        return int(self.starts[-1])

    def __getitem__(self, k: int) -> LabelledImage:
        if not 0 <= k < len(self):
            raise IndexError(k)
        j = int(np.searchsorted(self.starts, k, side="right")) - 1
        return self.sources[j][k - int(self.starts[j])]


def open_labelled_many(paths: Sequence[str | Path], images_root: str | Path | None = None, min_area_px: int = 3):
    """:func:`open_labelled` of each path; one source as is, several as a :class:`ConcatSource`."""
    sources = [open_labelled(p, images_root, min_area_px=min_area_px) for p in paths]
    return sources[0] if len(sources) == 1 else ConcatSource(sources)


def read_coco_boxes(path: str | Path) -> list[dict]:
    """The labelled boxes of a COCO file, without reading its images (``seedmap eval detect``'s ground truth):
    ``[{"file_name", "width", "height", "boxes" (N, 4) x0, y0, x1, y1, "areas" (N,)}]`` in the order of ``images``.
    A box comes from ``bbox``, else from the segmentation's extent; ``areas`` from ``area``, else the box's area.
    Checked as for training (:class:`CocoSource`) except that the image files need not exist; no annotation at all
    is an error."""
    p = Path(path)
    d = read_coco_json(p)
    images = d["images"]
    sizes = _check_coco_images(images, None, p, "evaluate")
    cats = {c["id"]: c.get("name", "") for c in d.get("categories", []) if isinstance(c, dict) and "id" in c}
    anns = d["annotations"] if isinstance(d["annotations"], list) else []
    if not anns:
        raise InputError("no annotations (no labelled seed to evaluate against)", p)
    per: dict = {i: ([], []) for i in sizes}
    for a in anns:
        _check_coco_annotation(a, sizes, cats, p)
        if "bbox" in a:
            x, y, bw, bh = (float(v) for v in a["bbox"])
            box = [x, y, x + bw, y + bh]
        else:
            seg = a["segmentation"]
            try:
                if isinstance(seg, list):
                    pts = np.concatenate([np.asarray(q, np.float64).reshape(-1, 2) for q in seg])
                    box = [*pts.min(axis=0), *pts.max(axis=0)]
                else:
                    wh = sizes[a["image_id"]] or (0, 0)
                    sh = seg.get("size") or [wh[1], wh[0]]
                    m, y0, x0 = segmentation_window(seg, int(sh[0]), int(sh[1]))
                    ys, xs = np.nonzero(m)
                    if not len(xs):
                        continue
                    box = [x0 + xs.min(), y0 + ys.min(), x0 + xs.max() + 1, y0 + ys.max() + 1]
            except (ValueError, TypeError, AttributeError) as e:
                raise InputError(f"annotation {a.get('id', '?')}: bad segmentation ({e})", p) from None
        area = a.get("area")
        per[a["image_id"]][0].append(box)
        per[a["image_id"]][1].append(float(area) if isinstance(area, (int, float)) and area > 0
                                     else (box[2] - box[0]) * (box[3] - box[1]))
    out = []
    for im in images:
        b, ar = per[im["id"]]
        wh = sizes[im["id"]] or (None, None)
        out.append({"file_name": str(im["file_name"]), "width": wh[0], "height": wh[1],
                    "boxes": np.asarray(b, np.float64).reshape(-1, 4), "areas": np.asarray(ar, np.float64)})
    return out
