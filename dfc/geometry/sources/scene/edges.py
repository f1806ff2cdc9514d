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
           "feature_kinds", "weld"]

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
    flipped : (E,) bool, the two faces run along the edge in the same direction (inconsistent winding)
    count : (E,) int64 how many faces share the edge (1 boundary, 2 manifold, more non-manifold)
    """

    edges: np.ndarray
    faces: np.ndarray
    opposite: np.ndarray
    flipped: np.ndarray
    count: np.ndarray


def edge_table(faces: np.ndarray) -> EdgeTable:
    """The edges of welded ``faces`` (F, 3) int64. Degenerate faces (a repeated vertex id) contribute none."""
    faces = np.asarray(faces, dtype=np.int64)
    keep = np.nonzero((faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0]))[0]
    f = faces[keep]
    start, end, third = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1), np.roll(f, -2, axis=1).reshape(-1)
    face = np.repeat(keep, 3)
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    order = np.lexsort((hi, lo))
    lo, hi, start, third, face = lo[order], hi[order], start[order], third[order], face[order]
    first = np.ones(len(lo), dtype=bool)
    first[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    head = np.nonzero(first)[0]
    count = np.diff(np.append(head, len(lo)))
    second = np.where(count > 1, head + 1, -1)
    pick = np.stack([head, second], axis=1)
    present = pick >= 0
    adjacent = np.where(present, face[pick], -1)
    opposite = np.where(present, third[pick], -1)
    forward = start[pick] == lo[pick]
    flipped = (count > 1) & (forward[:, 0] == forward[:, 1])
    return EdgeTable(np.stack([lo[head], hi[head]], axis=1), adjacent, opposite, flipped, count)


def feature_kinds(vertices: np.ndarray, table: EdgeTable, eye: np.ndarray, *, crease_angle: float,
                  creases: bool = True) -> np.ndarray:
    """Kind bits (E,) uint8 of every edge seen from ``eye`` (3,).

    * silhouette: both adjacent faces lie on the same side of the plane through the eye and the edge, i.e. one
      faces the eye and the other faces away (a test that does not depend on the faces' winding);
    * boundary: one adjacent face, or more than two (non-manifold);
    * crease (with ``creases``): the faces' normals, oriented consistently across the edge, differ by at least
      ``crease_angle`` degrees.
    """
    v = np.asarray(vertices, dtype=np.float64)
    a, b = v[table.edges[:, 0]], v[table.edges[:, 1]]
    kind = np.where(table.count != 2, BOUNDARY, 0).astype(np.uint8)
    (two,) = np.nonzero(table.count == 2)
    a, b = a[two], b[two]
    c1, c2 = v[table.opposite[two, 0]], v[table.opposite[two, 1]]
    plane = np.cross(a - eye, b - eye)
    side1 = np.einsum("ij,ij->i", plane, c1 - eye)
    side2 = np.einsum("ij,ij->i", plane, c2 - eye)
    kind[two[side1 * side2 >= 0]] |= SILHOUETTE
    if creases:
        # normals of (a, b, c1) and (b, a, c2): consistent when the faces run along the edge in opposite directions
        n1 = np.cross(b - a, c1 - a)
        n2 = np.cross(a - b, c2 - b) * np.where(table.flipped[two], -1.0, 1.0)[:, None]
        cos = np.einsum("ij,ij->i", n1, n2)
        norm = np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1)
        kind[two[(norm > 0) & (cos <= np.cos(np.radians(crease_angle)) * norm)]] |= CREASE
    return kind
