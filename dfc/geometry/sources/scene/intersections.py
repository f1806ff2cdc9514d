"""Where triangle meshes cut through each other (or themselves), found with Mitsuba's ray tracer.

Two triangles ``f`` and ``g`` that cross meet along a segment whose ends are where an edge of one passes through
the other. Every mesh edge is traced as a ray from one end to the other (all hits, in order); each hit of edge
``e`` on triangle ``g`` is an end of the segment ``f ∩ g`` for each face ``f`` of ``e``. A pair of triangles with
exactly two such ends gives one intersection segment. Hits on triangles that share a vertex with the traced edge are
the mesh's own neighbourhood and are skipped. Only mesh–mesh crossings are found: a mesh cut by an analytic shape
meets it along a conic, not a segment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MeshPart", "intersection_segments"]

_END_REL = 1e-6
"""Edge rays start and stop this fraction of the edge's length inside its ends."""
_MAX_HITS = 64
"""At most this many crossings are followed along one edge."""


@dataclass(frozen=True)
class MeshPart:
    """One mesh of the scene: its shape index, global primitive id offset, welded vertices (V, 3) float64 and
    faces (F, 3) int64 (rows = Mitsuba's primitive indices), its edges (E, 2) int64 and their faces (E, 2) int64."""

    shape: int
    offset: int
    vertices: np.ndarray
    faces: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray


def intersection_segments(occlusion, parts: list[MeshPart]):
    """Intersection segments between the meshes ``parts`` (``occlusion`` gives the scene and hit ids).

    returns ends (I, 2, 3) float64, owners (I, 2) int64 (the two triangles' global ids), end keys (I, 2) int64
    (equal keys: the same crossing point, numbered from 0) and the shape of the first triangle (I,) int64
    """
    ray, scene = occlusion.mi.Ray3f, occlusion.scene
    rec_edge, rec_part, rec_hit, rec_t = [], [], [], []
    for k, part in enumerate(parts):
        a, b = part.vertices[part.edges[:, 0]], part.vertices[part.edges[:, 1]]
        length = np.linalg.norm(b - a, axis=1)
        keep = np.nonzero(length > 0)[0]
        d = (b[keep] - a[keep]) / length[keep, None]
        origin = a[keep] + d * (_END_REL * length[keep, None])
        span = (1 - 2 * _END_REL) * length[keep]
        nudge = 1e-6 * span + 1e-7 * np.abs(origin).max(axis=1)  # past a hit, beyond float32 rounding
        for e, (ox, oy, oz), (dx, dy, dz), t_max, step in zip(keep.tolist(), origin.tolist(), d.tolist(),
                                                                span.tolist(), nudge.tolist()):
            travelled = 0.0
            for _ in range(_MAX_HITS):
                r = ray((ox + dx * travelled, oy + dy * travelled, oz + dz * travelled), (dx, dy, dz))
                r.maxt = t_max - travelled  # (the constructor's third argument is the time)
                if not scene.ray_test(r):
                    break
                hit = scene.ray_intersect_preliminary(r)
                if not hit.is_valid():
                    break
                travelled += hit.t
                rec_edge.append(e)
                rec_part.append(k)
                rec_hit.append(occlusion.hit_id(hit))
                rec_t.append(travelled)
                travelled += step
                if travelled >= t_max:
                    break
    empty = (np.zeros((0, 2, 3)), np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    if not rec_edge:
        return empty
    edge, part_of, hit, t = (np.array(x) for x in (rec_edge, rec_part, rec_hit, rec_t))
    # the crossing points in float64, and whether the hit triangle is a real crossing partner
    offsets = np.array([p.offset for p in parts])
    sizes = np.array([len(p.faces) for p in parts])
    owner_part = np.searchsorted(offsets, hit, side="right") - 1
    is_mesh_hit = (owner_part >= 0) & (hit < offsets[np.maximum(owner_part, 0)] + sizes[np.maximum(owner_part, 0)])
    point = np.empty((len(edge), 3))
    edge_faces = np.empty((len(edge), 2), np.int64)
    shares = np.zeros(len(edge), bool)
    for k, part in enumerate(parts):
        (sel,) = np.nonzero(part_of == k)
        a, b = part.vertices[part.edges[edge[sel], 0]], part.vertices[part.edges[edge[sel], 1]]
        direction = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
        point[sel] = a + direction * (t[sel] + _END_REL * np.linalg.norm(b - a, axis=1))[:, None]
        edge_faces[sel] = np.where(part.edge_faces[edge[sel]] >= 0, part.edge_faces[edge[sel]] + part.offset, -1)
        own = sel[is_mesh_hit[sel] & (owner_part[sel] == k)]
        tri = part.faces[hit[own] - part.offset]
        ends = part.edges[edge[own]]
        shares[own] = (tri[:, :, None] == ends[:, None, :]).any(axis=(1, 2))
    valid = np.nonzero(is_mesh_hit & ~shares)[0]
    # one record per (face of the edge, hit triangle): the crossing is an end of that pair's segment
    rec = np.repeat(valid, 2)
    face = edge_faces[valid].ravel()
    rec, face = rec[face >= 0], face[face >= 0]
    other = hit[rec]
    lo, hi = np.minimum(face, other), np.maximum(face, other)
    order = np.lexsort((rec, hi, lo))
    lo, hi, rec, face = lo[order], hi[order], rec[order], face[order]
    head = np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])]
    start = np.nonzero(head)[0]
    count = np.diff(np.r_[start, len(lo)])
    pair = start[(count == 2)]
    pair = pair[rec[pair] != rec[pair + 1]]
    ends = np.stack([point[rec[pair]], point[rec[pair + 1]]], axis=1)
    owners = np.stack([lo[pair], hi[pair]], axis=1)
    keys = np.stack([rec[pair], rec[pair + 1]], axis=1)
    shape = np.array([p.shape for p in parts])[owner_part[rec[pair]]]
    return ends, owners, keys, shape
