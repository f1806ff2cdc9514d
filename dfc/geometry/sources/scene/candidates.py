"""The curves of a Mitsuba scene that may show in its render, in world space, before visibility.

* Meshes (every shape Mitsuba loads as triangles, ``to_world`` applied): their feature edges (``edges``), and with
  ``add_intersections`` where meshes cut through each other (``intersections``).
* Spheres: the contour seen from the eye; disks: the rim; cylinders: both rims and the two silhouette rulings
  (``conics``). Any other shape type is refused.

Segments carry end point ids (equal ids: the same point, so that chains follow the mesh) and a unit ``nudge``
that moves their points off their own surfaces for the ray test (``visibility``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ....errors import InputError
from ....io.mitsuba import Camera, import_mitsuba, ordered_shapes
from . import conics
from .edges import BOUNDARY, INTERSECTION, SILHOUETTE, edge_table, feature_kinds, off_surface, weld
from .intersections import MeshPart, intersection_segments

__all__ = ["Candidates", "SUPPORTED"]

SUPPORTED = "meshes (obj, ply, serialized, cube, rectangle, ...), spheres, disks and cylinders"


class Candidates:
    """Candidate curves of a scene seen from ``camera``.

    Segments: ``a``, ``b`` (S, 3) float64 ends; ``nudge`` (S, 3) float64 unit off-surface directions; ``ids``
    (S, 2) int64 end point ids; ``kind`` (S,) uint8 (``edges`` kind bits); ``shape`` (S,) int64.
    Arcs: ``arcs`` (``conics.Ellipses``). Per shape: ``labels``, ``is_mesh`` (bool), ``offsets`` (n + 1,) int64 its
    first global primitive id. ``point_shape`` (P,) int64 the shape of each point id; ``triangles`` and ``edges``
    count the meshes' triangles and edges.
    """

    def __init__(self, scene, camera: Camera, path: str | Path, *, crease_angle: float, creases: bool):
        shapes = ordered_shapes(scene)
        self.eye = camera.eye
        self.labels = [_label(s, i) for i, s in enumerate(shapes)]
        self.is_mesh = np.array([s.is_mesh() for s in shapes], dtype=bool)
        counts = [s.face_count() if m else 1 for s, m in zip(shapes, self.is_mesh)]
        self.offsets = np.r_[0, np.cumsum(counts)].astype(np.int64)
        self.triangles = int(sum(c for c, m in zip(counts, self.is_mesh) if m))
        self.edges = 0
        self.parts: list[MeshPart] = []
        self._seg: list[tuple] = []
        self._point_shape: list[np.ndarray] = []
        arcs = []
        for i, s in enumerate(shapes):
            kind = s.class_name()
            if s.is_mesh():
                self._add_mesh(i, s, crease_angle, creases)
            elif kind == "Sphere":
                to_world = _to_world(s)
                radius = float(np.linalg.norm(to_world[:3, 0]))
                arcs.append(conics.sphere_contours(to_world[:3, 3], radius, self.eye, i, SILHOUETTE))
            elif kind == "Disk":
                arcs.append(conics.disk_rim(_to_world(s), i, BOUNDARY))
            elif kind == "Cylinder":
                to_world = _to_world(s)
                rims, lines, outward = conics.cylinder_outline(to_world, self.eye, i, BOUNDARY, SILHOUETTE)
                arcs.append(rims)
                k = len(lines)
                self._add_segments(lines[:, 0], lines[:, 1], outward, self._new_ids(2 * k, i).reshape(k, 2),
                                   np.full(k, SILHOUETTE, np.uint8), i)
            else:
                raise InputError(f"{path}: {self.labels[i]} is a {kind}; dfc curves handles {SUPPORTED}")
        self.arcs = conics.Ellipses.concat(arcs)
        self.n_intersections = 0
        self._finish()

    def _finish(self) -> None:
        """Concatenate the segments added so far into the arrays ``a``, ``b``, ``nudge``, ``ids``, ``kind``,
        ``shape`` and ``point_shape``."""
        empty = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2), np.int64),
                 np.zeros(0, np.uint8), np.zeros(0, np.int64))
        parts = self._seg or [empty]
        self.a, self.b, self.nudge, self.ids, self.kind, self.shape = (
            np.concatenate([p[j] for p in parts]) for j in range(6))
        self._seg = [(self.a, self.b, self.nudge, self.ids, self.kind, self.shape)]
        self.point_shape = np.concatenate(self._point_shape) if self._point_shape else np.zeros(0, np.int64)

    def _new_ids(self, n: int, shape) -> np.ndarray:
        """``n`` fresh point ids belonging to ``shape`` (an int, or (n,) ints)."""
        first = sum(len(p) for p in self._point_shape)
        self._point_shape.append(np.broadcast_to(np.asarray(shape, dtype=np.int64), (n,)).copy())
        return first + np.arange(n, dtype=np.int64)

    def _add_segments(self, a, b, nudge, ids, kind, shape) -> None:
        self._seg.append((a, b, nudge, ids, kind, np.broadcast_to(np.asarray(shape, np.int64), (len(a),)).copy()))

    def _add_mesh(self, i: int, shape, crease_angle: float, creases: bool) -> None:
        vertices = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        faces = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        vertices, faces = weld(vertices, faces)
        table = edge_table(faces)
        self.edges += len(table.edges)
        self.parts.append(MeshPart(i, int(self.offsets[i]), vertices, faces, table.edges, table.faces))
        bits = feature_kinds(vertices, table, self.eye, crease_angle=crease_angle, creases=creases)
        (sel,) = np.nonzero(bits)
        ends = table.edges[sel]
        a, b = vertices[ends[:, 0]], vertices[ends[:, 1]]
        opposite = table.opposite[sel]
        c2 = np.where(opposite[:, 1:] >= 0, vertices[np.maximum(opposite[:, 1], 0)], np.nan)
        across = (bits[sel] & (SILHOUETTE | BOUNDARY)) != 0
        nudge = off_surface(a, b, vertices[opposite[:, 0]], c2, self.eye, across)
        ids = self._new_ids(len(vertices), i)
        self._add_segments(a, b, nudge, ids[ends], bits[sel], i)

    def add_intersections(self, occlusion) -> None:
        """Add the segments where meshes cut through each other (traced with ``occlusion``'s scene)."""
        ends, owners, keys, shape = intersection_segments(occlusion, self.parts)
        if not len(ends):
            return
        unique, inverse = np.unique(keys, return_inverse=True)
        key_shape = np.zeros(len(unique), np.int64)
        key_shape[inverse.reshape(-1, 2)[:, 0]] = shape
        key_shape[inverse.reshape(-1, 2)[:, 1]] = shape
        ids = self._new_ids(len(unique), key_shape)[inverse.reshape(-1, 2)]
        normals = [self._face_normal(owners[:, k]) for k in range(2)]
        nudge = normals[0] + normals[1]
        norm = np.linalg.norm(nudge, axis=1)
        nudge /= np.where(norm > 0, norm, 1.0)[:, None]
        self._add_segments(ends[:, 0], ends[:, 1], nudge, ids, np.full(len(ends), INTERSECTION, np.uint8), shape)
        self.n_intersections = len(ends)
        self._finish()

    def _face_normal(self, gid: np.ndarray) -> np.ndarray:
        """Unit normals (N, 3) of mesh triangles by global primitive id, turned towards the eye."""
        offsets = np.array([p.offset for p in self.parts])
        which = np.searchsorted(offsets, gid, side="right") - 1
        out = np.zeros((len(gid), 3))
        for k, part in enumerate(self.parts):
            (sel,) = np.nonzero(which == k)
            tri = part.vertices[part.faces[gid[sel] - part.offset]]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n *= np.sign(np.einsum("ij,ij->i", n, self.eye - tri[:, 0]))[:, None]
            out[sel] = n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        return out


def _to_world(shape) -> np.ndarray:
    """The (4, 4) ``to_world`` matrix of an analytic shape."""
    mi = import_mitsuba()
    return np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64)


def _label(shape, index: int) -> str:
    name = shape.id()
    kind = shape.class_name().lower()
    return f"{kind} {name!r}" if name else f"shape {index} ({kind})"
