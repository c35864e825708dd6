"""A DBoW2 ORB vocabulary trained on images, written in the text format ORB-SLAM3 loads.

ORB-SLAM3 needs a bag-of-words vocabulary (``ORBvoc.txt``) to start. This module builds one the way DBoW2's
``TemplatedVocabulary::create`` does: ORB descriptors of the training images, a hierarchical k-means tree
(branching ``k``, depth ``L``) with k-means++ seeding and binary majority-bit centroids, words at the leaves,
TF-IDF word weights (``log(N images / images containing the word)``), written as ``loadFromTextFile`` reads it.
How and why: ``docs/method/orbslam3.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from seedmap.errors import InputError

#: ORB-SLAM3's extractor settings (its stereo examples): features per image, pyramid scale and levels, FAST
#: threshold (ORB-SLAM3 retries a cell at ``minThFAST`` = 7, which OpenCV's ORB cannot), border and patch size.
ORB_FEATURES = 2000
ORB_SCALE = 1.2
ORB_LEVELS = 8
ORB_FAST = 20
ORB_EDGE = 19
ORB_PATCH = 31
#: DBoW2 enum values written into the header: TF_IDF weighting, L1-norm scoring (ORB-SLAM3's choice).
WEIGHTING_TF_IDF = 0
SCORING_L1 = 0
DESC_BYTES = 32
#: Upper bound of k-means iterations per node (DBoW2 iterates until assignments stop changing).
MAX_KMEANS_ITER = 100


def orb_extractor(n_features: int = ORB_FEATURES) -> cv2.ORB:
    """OpenCV ORB with ORB-SLAM3's extractor settings."""
    return cv2.ORB_create(nfeatures=int(n_features), scaleFactor=ORB_SCALE, nlevels=ORB_LEVELS,
                          edgeThreshold=ORB_EDGE, fastThreshold=ORB_FAST, patchSize=ORB_PATCH)


def orb_descriptors(gray: np.ndarray, n_features: int = ORB_FEATURES) -> np.ndarray:
    """``(N, 32)`` uint8 ORB descriptors of one grayscale image (``(0, 32)`` when it has none)."""
    _, d = orb_extractor(n_features).detectAndCompute(gray, None)
    return np.zeros((0, DESC_BYTES), np.uint8) if d is None else np.ascontiguousarray(d, np.uint8)


def _pack(desc: np.ndarray) -> np.ndarray:
    """``(N, 32)`` uint8 -> ``(N, 4)`` uint64 (for XOR + popcount)."""
    return np.ascontiguousarray(desc, np.uint8).view(np.uint64).reshape(-1, DESC_BYTES // 8)


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between packed descriptors ``a (N, 4)`` and ``b (M, 4)``: ``(N, M)`` int."""
    return np.bitwise_count(a[:, None, :] ^ b[None, :, :]).sum(axis=2, dtype=np.int64)


def majority(bits: np.ndarray) -> np.ndarray:
    """DBoW2's binary mean of unpacked ``(N, 256)`` bits: a bit is set when at least ``ceil(N / 2)`` have it."""
    n = len(bits)
    return np.packbits(bits.sum(axis=0) >= (n // 2 + n % 2))


@dataclass
class Vocabulary:
    """A DBoW2 tree: node 0 is the root; per node its parent, descriptor (32 bytes) and weight; leaves are words."""

    k: int
    L: int
    parent: np.ndarray  # (n_nodes,) int, -1 at the root
    desc: np.ndarray  # (n_nodes, 32) uint8 (zeros at the root)
    weight: np.ndarray  # (n_nodes,) float, 0 on inner nodes
    scoring: int = SCORING_L1
    weighting: int = WEIGHTING_TF_IDF

    def __len__(self) -> int:
        return len(self.parent)

    @property
    def is_leaf(self) -> np.ndarray:
        """True for nodes without children (the words); the root is never a word."""
        has_child = np.zeros(len(self), bool)
        has_child[self.parent[1:]] = True
        leaf = ~has_child
        leaf[0] = False
        return leaf

    @property
    def n_words(self) -> int:
        return int(self.is_leaf.sum())

    def words_of(self, desc: np.ndarray) -> np.ndarray:
        """Node id of the word each ``(N, 32)`` descriptor falls into (DBoW2's descent: nearest child per level)."""
        order = np.argsort(self.parent[1:], kind="stable") + 1
        starts = np.searchsorted(self.parent[order], np.arange(len(self)))
        ends = np.searchsorted(self.parent[order], np.arange(len(self)), side="right")
        width = max(1, int((ends - starts).max()))
        kids = np.full((len(self), width), -1, np.int64)
        for j in range(width):  # children of every node, in creation order, padded with -1
            sel = starts + j < ends
            kids[sel, j] = order[starts[sel] + j]
        packed = _pack(self.desc)
        q = _pack(desc)
        node = np.zeros(len(q), np.int64)
        for _ in range(self.L + 1):
            c = kids[node]
            active = c[:, 0] >= 0
            if not active.any():
                break
            ca, qa = c[active], q[active]
            d = np.bitwise_count(qa[:, None, :] ^ packed[np.maximum(ca, 0)]).sum(axis=2, dtype=np.int64)
            d[ca < 0] = np.iinfo(np.int64).max
            node[active] = ca[np.arange(len(ca)), np.argmin(d, axis=1)]
        return node


def _kmeanspp(packed: np.ndarray, k: int, rng: np.random.Generator) -> list[int]:
    """DBoW2's k-means++ seeding: the next centre drawn with probability proportional to the distance."""
    centres = [int(rng.integers(len(packed)))]
    dmin = hamming(packed, packed[centres[0]][None])[:, 0].astype(np.float64)
    while len(centres) < k:
        total = dmin.sum()
        if total <= 0:
            break  # every remaining descriptor equals a centre
        i = int(np.searchsorted(np.cumsum(dmin), rng.random() * total, side="right"))
        i = min(i, len(packed) - 1)
        centres.append(i)
        dmin = np.minimum(dmin, hamming(packed, packed[i][None])[:, 0])
    return centres


def _kmeans(packed: np.ndarray, bits: np.ndarray, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Binary k-means of one node: ``(centroids (c, 32) uint8, label per descriptor)``; empty clusters dropped."""
    cent = np.ascontiguousarray(np.packbits(bits[_kmeanspp(packed, k, rng)], axis=1))
    labels = np.argmin(hamming(packed, _pack(cent)), axis=1)
    for _ in range(MAX_KMEANS_ITER):
        used = np.unique(labels)
        labels = np.searchsorted(used, labels)  # clusters 0..c-1, none empty
        cent = np.stack([majority(bits[labels == c]) for c in range(len(used))])
        new = np.argmin(hamming(packed, _pack(cent)), axis=1)
        if np.array_equal(new, labels):
            return cent, labels
        labels = new
    used = np.unique(labels)
    return cent[used], np.searchsorted(used, labels)


def build_tree(desc: np.ndarray, k: int = 10, L: int = 5, seed: int = 0,
               progress: Callable[[int], None] | None = None) -> Vocabulary:
    """The hierarchical k-means tree of ``(N, 32)`` descriptors (no weights yet), as DBoW2's ``HKmeansStep``.

    A node with at most ``k`` descriptors gets one child per descriptor; recursion stops at depth ``L`` or at a
    child holding one descriptor. ``progress(n)`` is called with the number of descriptors placed at leaves."""
    if not 2 <= k <= 20 or not 1 <= L <= 10:
        raise ValueError(f"vocabulary shape k={k}, L={L} outside DBoW2's limits (k 2..20, L 1..10)")
    rng = np.random.default_rng(seed)
    desc = np.ascontiguousarray(desc, np.uint8)
    packed, bits = _pack(desc), np.unpackbits(desc, axis=1)
    parent, node_desc = [-1], [np.zeros(DESC_BYTES, np.uint8)]
    stack = [(0, np.arange(len(desc)), 1)]
    while stack:
        pid, idx, level = stack.pop()
        if len(idx) <= k:
            cent, labels = desc[idx], np.arange(len(idx))
        else:
            cent, labels = _kmeans(packed[idx], bits[idx], k, rng)
        children = []
        for c in range(len(cent)):
            parent.append(pid)
            node_desc.append(cent[c])
            children.append(len(parent) - 1)
        for c, nid in reversed(list(enumerate(children))):
            sub = idx[labels == c]
            if level < L and len(sub) > 1:
                stack.append((nid, sub, level + 1))
            elif progress is not None:
                progress(len(sub))
    return Vocabulary(k, L, np.asarray(parent, np.int64), np.stack(node_desc),
                      np.zeros(len(parent), np.float64))


def set_tfidf_weights(voc: Vocabulary, per_image: Sequence[np.ndarray]) -> None:
    """DBoW2 TF-IDF: each word's weight is ``log(images / images with the word)`` (0 for a word never seen)."""
    n_images = len(per_image)
    seen = np.zeros(len(voc), np.int64)
    for d in per_image:
        if len(d):
            seen[np.unique(voc.words_of(d))] += 1
    w = np.zeros(len(voc), np.float64)
    ok = voc.is_leaf & (seen > 0)
    w[ok] = np.log(n_images / seen[ok])
    voc.weight = w


def vocabulary_text(voc: Vocabulary) -> str:
    """DBoW2's text format: ``k L scoring weighting``, then per node after the root
    ``parent is_leaf d0 .. d31 weight`` (no newline after the last line: DBoW2 would read one more, empty node)."""
    leaf = voc.is_leaf
    lines = [f"{voc.k} {voc.L}  {voc.scoring} {voc.weighting}"]
    for i in range(1, len(voc)):
        d = " ".join(str(int(b)) for b in voc.desc[i])
        lines.append(f"{int(voc.parent[i])} {int(leaf[i])} {d} {voc.weight[i]:.6g}")
    return "\n".join(lines)


def check_vocabulary_header(path: str | Path) -> tuple[int, int]:
    """``(k, L)`` of a DBoW2 text vocabulary; one-line :class:`InputError` when the first line is not DBoW2's
    (ORB-SLAM3 would end the process on it)."""
    p = Path(path)
    if not p.is_file():
        raise InputError("ORB vocabulary not found", p)
    with open(p, "rb") as f:
        head = f.readline(200).decode("ascii", "replace").split()
    try:
        k, L, n1, n2 = (int(x) for x in head)
    except ValueError:
        raise InputError("not a DBoW2 text vocabulary (first line must be 'k L scoring weighting'; "
                         "a binary or gzipped ORBvoc needs unpacking to ORBvoc.txt)", p) from None
    if not (0 <= k <= 20 and 1 <= L <= 10 and 0 <= n1 <= 5 and 0 <= n2 <= 3):
        raise InputError(f"DBoW2 vocabulary header '{' '.join(head)}' out of range", p)
    return k, L


def read_vocabulary(path: str | Path) -> Vocabulary:
    """Parse a DBoW2 text vocabulary back (as ``loadFromTextFile`` does; blank lines are skipped)."""
    k, L = check_vocabulary_header(path)
    lines = Path(path).read_text().splitlines()
    n1, n2 = (int(x) for x in lines[0].split()[2:4])
    rows = [ln.split() for ln in lines[1:] if ln.strip()]
    if any(len(r) != DESC_BYTES + 3 for r in rows):
        raise InputError(f"a node line does not hold parent, leaf flag, {DESC_BYTES} bytes and a weight", path)
    parent = np.asarray([-1] + [int(r[0]) for r in rows], np.int64)
    desc = np.zeros((len(rows) + 1, DESC_BYTES), np.uint8)
    if rows:
        desc[1:] = np.asarray([[int(x) for x in r[2:2 + DESC_BYTES]] for r in rows], np.uint8)
    weight = np.asarray([0.0] + [float(r[-1]) for r in rows], np.float64)
    voc = Vocabulary(k, L, parent, desc, weight, n1, n2)
    flags = np.asarray([0] + [int(r[1]) for r in rows], bool)
    if np.any(parent[1:] >= np.arange(1, len(parent))) or not np.array_equal(flags, voc.is_leaf):
        raise InputError("node lines are not a tree (a parent after its child, or a leaf flag that disagrees)",
                         path)
    return voc


def train_vocabulary(per_image: Sequence[np.ndarray], k: int = 10, L: int = 5, seed: int = 0,
                     progress: Callable[[int], None] | None = None) -> Vocabulary:
    """Tree + TF-IDF weights from the descriptors of each training image."""
    nonempty = [d for d in per_image if len(d)]
    if not nonempty:
        raise InputError("the training images have no ORB features", "IMAGES")
    voc = build_tree(np.concatenate(nonempty), k, L, seed, progress)
    set_tfidf_weights(voc, per_image)
    return voc


def levels_for(n_desc: int, k: int = 10, per_word: int = 20) -> int:
    """Depth that gives about ``per_word`` training descriptors per word (1..6)."""
    return int(min(6, max(1, math.ceil(math.log(max(n_desc / per_word, 2), k)))))


def training_images(paths: Sequence[str | Path]) -> list[tuple[str, Callable[[], np.ndarray]]]:
    """``(name, load_gray)`` per training image: an image file, a folder of images, or a dataset folder (its
    rectified left images, as ORB-SLAM3 sees them). One-line :class:`InputError` for anything else."""
    from seedmap.io import detect_format, open_dataset
    from seedmap.io.common import IMAGE_SUFFIXES, list_images, read_image_rgb

    def gray_file(p: Path) -> Callable[[], np.ndarray]:
        return lambda: cv2.cvtColor(read_image_rgb(p)[0], cv2.COLOR_RGB2GRAY)

    def gray_frame(ds, i: int) -> Callable[[], np.ndarray]:
        return lambda: cv2.cvtColor(ds[i].left, cv2.COLOR_RGB2GRAY)

    out: list[tuple[str, Callable[[], np.ndarray]]] = []
    for raw in paths:
        p = Path(raw)
        if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES:
            out.append((str(p), gray_file(p)))
        elif p.is_dir() and detect_format(p) is not None:
            ds = open_dataset(p)
            out += [(f"{p}#{i}", gray_frame(ds, i)) for i in range(len(ds))]
        elif p.is_dir() and (imgs := list_images(p)):
            out += [(str(q), gray_file(q)) for q in imgs]
        elif not p.exists():
            raise InputError("not found", p)
        else:
            raise InputError("neither an image, a folder of images nor a dataset", p)
    return out
