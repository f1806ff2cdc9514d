"""Edges of triangle meshes and which of them are features seen from an eye point: silhouettes, boundaries and
creases.

A mesh is ``vertices (V, 3) float64`` and ``faces (F, 3) int64`` in world space. Vertices at the same position are
welded first (OBJ and PLY files split them along texture and normal seams), so that adjacency follows the surface.
An edge is the pair of welded vertex ids ``(a, b)``, ``a < b``, listed once with up to two adjacent faces (indices
into the original face list, which are Mitsuba's primitive indices).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SILHOUETTE", "BOUNDARY", "CREASE", "INTERSECTION", "KIND_NAMES", "EdgeTable", "edge_table",
           "feature_kinds", "off_surface", "weld"]

SILHOUETTE, BOUNDARY, CREASE, INTERSECTION = 1, 2, 4, 8
"""Kind bits of a candidate edge (an edge may carry several)."""
KIND_NAMES = {SILHOUETTE: "silhouette", BOUNDARY: "boundary", CREASE: "crease", INTERSECTION: "intersection"}


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical positions.

    vertices : (V, 3) float, faces : (F, 3) int
    returns the unique positions (U, 3) float64 and the faces re-indexed into them (F, 3) int64
    """
    unique, inverse = np.unique(np.asarray(vertices, dtype=np.float64), axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[np.asarray(faces, dtype=np.int64)]


@dataclass(frozen=True)
class EdgeTable:
    """Every edge of a (welded) mesh once.

    edges : (E, 2) int64 vertex ids, ``a < b``
    faces : (E, 2) int64 the first two adjacent faces, -1 where there is none
    opposite : (E, 2) int64 each adjacent face's third vertex, -1 where there is no face
    count : (E,) int64 how many faces share the edge (1 boundary, 2 manifold, more non-manifold)
    """

    edges: np.ndarray
    faces: np.ndarray
    opposite: np.ndarray
    count: np.ndarray


def edge_table(faces: np.ndarray) -> EdgeTable:
    """The edges of welded ``faces`` (F, 3) int64. Degenerate faces (a repeated vertex id) contribute none."""
    faces = np.asarray(faces, dtype=np.int64)
    keep = np.nonzero((faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0]))[0]
    f = faces[keep]
    start, end, third = f.ravel(), f[:, [1, 2, 0]].ravel(), f[:, [2, 0, 1]].ravel()
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    key = lo * (int(faces.max(initial=0)) + 1) + hi
    order = np.argsort(key)
    key, third = key[order], third[order]
    face = keep[order // 3]
    head = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.append(head, len(key)))
    second = np.where(count > 1, head + 1, head)
    lo, hi = lo[order[head]], hi[order[head]]
    two = count > 1
    adjacent = np.stack([face[head], np.where(two, face[second], -1)], axis=1)
    opposite = np.stack([third[head], np.where(two, third[second], -1)], axis=1)
    return EdgeTable(np.stack([lo, hi], axis=1), adjacent, opposite, count)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays (np.cross is several times slower on long arrays)."""
    return np.stack([u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1], u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                     u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]], axis=1)


def feature_kinds(vertices: np.ndarray, table: EdgeTable, eye: np.ndarray, *, crease_angle: float,
                  creases: bool = True) -> np.ndarray:
    """Kind bits (E,) uint8 of every edge seen from ``eye`` (3,).

    * silhouette: both adjacent faces lie on the same side of the plane through the eye and the edge, i.e. one
      faces the eye and the other faces away (a test that does not depend on the faces' winding);
    * boundary: one adjacent face, or more than two (non-manifold);
    * crease (with ``creases``): the faces' normals differ by at least ``crease_angle`` degrees, both taken as if
      the faces were wound consistently (``(a, b, c1)`` and ``(b, a, c2)``), whatever their stored winding.
    """
    v = np.asarray(vertices, dtype=np.float64)
    a, b = v[table.edges[:, 0]], v[table.edges[:, 1]]
    kind = np.where(table.count != 2, BOUNDARY, 0).astype(np.uint8)
    (two,) = np.nonzero(table.count == 2)
    a, b = a[two], b[two]
    c1, c2 = v[table.opposite[two, 0]], v[table.opposite[two, 1]]
    plane = _cross(a - eye, b - eye)
    side1 = np.einsum("ij,ij->i", plane, c1 - eye)
    side2 = np.einsum("ij,ij->i", plane, c2 - eye)
    kind[two[side1 * side2 >= 0]] |= SILHOUETTE
    if creases:
        n1 = _cross(b - a, c1 - a)
        n2 = _cross(a - b, c2 - b)
        cos = np.einsum("ij,ij->i", n1, n2)
        norm = np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1)
        kind[two[(norm > 0) & (cos <= np.cos(np.radians(crease_angle)) * norm)]] |= CREASE
    return kind


def off_surface(a: np.ndarray, b: np.ndarray, c1: np.ndarray, c2: np.ndarray, eye: np.ndarray,
                across: np.ndarray) -> np.ndarray:
    """Unit directions (E, 3) that move a point of edge ``a``–``b`` (E, 3) off its faces ``(a, b, c1)`` and
    ``(b, a, c2)`` (c2 NaN where there is no second face) without hiding it from ``eye``.

    ``across`` (E,) bool: the faces lie on one side of the plane through the eye and the edge (silhouettes,
    boundaries); the direction is that plane's normal pointing to the other side, so an eye ray to the moved point
    passes beside both faces. Otherwise (creases, intersection lines) it is the sum of the faces' normals turned
    towards the eye: the moved point and the eye are both in front of both faces. Zero where the edge points at
    the eye.
    """
    plane = _cross(a - eye, b - eye)
    side = np.sign(np.einsum("ij,ij->i", plane, c1 - eye))
    n1 = _cross(b - a, c1 - a)
    n2 = np.nan_to_num(_cross(a - b, c2 - b))
    n1 *= np.sign(np.einsum("ij,ij->i", n1, eye - a))[:, None]
    n2 *= np.sign(np.einsum("ij,ij->i", n2, eye - b))[:, None]
    n1 /= np.maximum(np.linalg.norm(n1, axis=1), 1e-300)[:, None]
    n2 /= np.maximum(np.linalg.norm(n2, axis=1), 1e-300)[:, None]
    direction = np.where(across[:, None], -side[:, None] * plane, n1 + n2)
    norm = np.linalg.norm(direction, axis=1)
    return direction / np.where(norm > 0, norm, 1.0)[:, None]
