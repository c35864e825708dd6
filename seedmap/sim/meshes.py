"""Small mesh builders (numpy only): seed ellipsoids, cylinders, leaf ribbons, vertex normals.

Meshes are ``(vertices (V, 3) float, triangles (T, 3) int)`` pairs in metres.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=1)
def unit_icosphere() -> tuple[np.ndarray, np.ndarray]:
    """Icosahedron subdivided once, projected on the unit sphere: 42 vertices, 80 triangles."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                  [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    verts = list(v / np.linalg.norm(v, axis=1, keepdims=True))
    mid: dict[tuple[int, int], int] = {}

    def midpoint(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in mid:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            mid[key] = len(verts) - 1
        return mid[key]

    faces = []
    for a, b, c in f:
        ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
        faces += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
    return np.array(verts, float), np.array(faces, np.int64)


def ellipsoids(centers: np.ndarray, axes: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Many low-poly ellipsoids in one mesh; seed ``k`` owns triangles ``[80 k, 80 k + 80)``.

    ``axes`` (N, 3, 3): columns are each ellipsoid's local axes; ``radii`` (N, 3) semi-axes (m).
    """
    uv, uf = unit_icosphere()
    n = len(centers)
    local = uv[None, :, :] * radii[:, None, :]  # (N, 42, 3)
    V = np.einsum("nij,nvj->nvi", axes, local) + centers[:, None, :]
    F = uf[None, :, :] + (np.arange(n) * len(uv))[:, None, None]
    return V.reshape(-1, 3), F.reshape(-1, 3)


def cylinder(p0: np.ndarray, p1: np.ndarray, r0: float, r1: float, sides: int = 8,
             caps: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Open (or capped) tapered cylinder from ``p0`` (radius ``r0``) to ``p1`` (radius ``r1``)."""
    p0 = np.asarray(p0, float)
    p1 = np.asarray(p1, float)
    a = p1 - p0
    a = a / max(np.linalg.norm(a), 1e-12)
    tmp = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(a, tmp)
    u /= np.linalg.norm(u)
    w = np.cross(a, u)
    ang = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w
    V = np.vstack([p0 + r0 * ring, p1 + r1 * ring])
    i = np.arange(sides)
    j = (i + 1) % sides
    F = np.vstack([np.stack([i, j, i + sides], 1), np.stack([j, j + sides, i + sides], 1)])
    if caps:
        V = np.vstack([V, p0, p1])
        c0, c1 = 2 * sides, 2 * sides + 1
        F = np.vstack([F, np.stack([np.full(sides, c0), j, i], 1), np.stack([np.full(sides, c1), i + sides,
                                                                             j + sides], 1)])
    return V, F


def polyline_tube(points: np.ndarray, radii: np.ndarray, sides: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """A tube along a polyline (one ring per point); used for stalks."""
    verts, faces = [], []
    off = 0
    for k in range(len(points) - 1):
        v, f = cylinder(points[k], points[k + 1], radii[k], radii[k + 1], sides)
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    return np.vstack(verts), np.vstack(faces)


def ribbon_topology(n_seg: int) -> tuple[np.ndarray, np.ndarray]:
    """Triangles and (s, w) texture coordinates of a leaf ribbon with 3 vertices across.

    Vertex ``3 k + j`` is segment ``k`` (0..n_seg), across position ``j`` (0 = edge, 1 = midrib, 2 = edge).
    """
    F = []
    for k in range(n_seg):
        for j in range(2):
            a, b = 3 * k + j, 3 * k + j + 1
            c, d = a + 3, b + 3
            F += [[a, b, c], [b, d, c]]
    s = np.repeat(np.linspace(0, 1, n_seg + 1), 3)
    w = np.tile([0.0, 0.5, 1.0], n_seg + 1)
    return np.array(F, np.int64), np.stack([s, w], 1)


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit length; zero vectors stay zero)."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.zeros_like(V)
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.maximum(norm, 1e-20)
