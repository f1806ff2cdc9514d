"""Where triangle meshes cut through each other, found with Mitsuba's ray tracer.

Two triangles ``f`` and ``g`` of different meshes that cross meet along a segment whose ends are where an edge of
one passes through the other. Mesh edges are traced as rays from one end to the other (all hits, in order); each
hit of edge ``e`` on a triangle ``g`` of another mesh is an end of the segment ``f ∩ g`` for each face ``f`` of
``e``. A pair of triangles with exactly two such ends gives one intersection segment. Only edges inside another
mesh's bounding box, and that may show (``Occlusion.may_show``), are traced. Not found: a mesh cutting through
itself, and a mesh cut by an analytic shape (they meet along a conic, not a segment).
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
    (equal keys: the same crossing point) and the shape of the first triangle (I,) int64
    """
    empty = (np.zeros((0, 2, 3)), np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    if len(parts) < 2:
        return empty
    boxes = np.array([[p.vertices.min(axis=0), p.vertices.max(axis=0)] for p in parts])  # (M, 2, 3)
    first = np.array([p.offset for p in parts])
    last = np.array([p.offset + len(p.faces) for p in parts])
    scene, point, vector = occlusion.scene, occlusion.mi.Point3f, occlusion.mi.Vector3f
    ray = occlusion.mi.Ray3f()
    rec_part, rec_edge, rec_hit, rec_t = [], [], [], []
    for k, part in enumerate(parts):
        a, b = part.vertices[part.edges[:, 0]], part.vertices[part.edges[:, 1]]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        others = np.delete(boxes, k, axis=0)
        inside = np.zeros(len(a), dtype=bool)
        for box in others:
            inside |= np.all((hi >= box[0]) & (lo <= box[1]), axis=1)
        length = np.linalg.norm(b - a, axis=1)
        (keep,) = np.nonzero(inside & (length > 0))
        keep = keep[occlusion.may_show(a[keep], b[keep])]
        d = (b[keep] - a[keep]) / length[keep, None]
        origin = a[keep] + d * (_END_REL * length[keep, None])
        span = (1 - 2 * _END_REL) * length[keep]
        nudge = 1e-6 * span + 1e-7 * np.abs(origin).max(axis=1, initial=0.0)  # past a hit, beyond float32 rounding
        own_lo, own_hi = part.offset, part.offset + len(part.faces)
        occlusion.rays += len(keep)
        # flat lists of floats: nested lists would make the garbage collector crawl over millions of them
        for e, ox, oy, oz, dx, dy, dz, t_max, step in zip(keep.tolist(), *origin.T.tolist(), *d.T.tolist(),
                                                           span.tolist(), nudge.tolist()):
            ray.o, ray.d, ray.maxt = point(ox, oy, oz), vector(dx, dy, dz), t_max
            if not scene.ray_test(ray):
                continue
            travelled = 0.0
            for _ in range(_MAX_HITS):
                hit = scene.ray_intersect_preliminary(ray)
                if not hit.is_valid():
                    break
                travelled += hit.t
                gid = occlusion.hit_id(hit)
                if not own_lo <= gid < own_hi:
                    rec_part.append(k)
                    rec_edge.append(e)
                    rec_hit.append(gid)
                    rec_t.append(travelled)
                travelled += step
                if travelled >= t_max:
                    break
                ray.o = point(ox + dx * travelled, oy + dy * travelled, oz + dz * travelled)
                ray.maxt = t_max - travelled
                occlusion.rays += 1
    if not rec_edge:
        return empty
    part_of, edge, hit, t = (np.array(x) for x in (rec_part, rec_edge, rec_hit, rec_t))
    (on_mesh,) = np.nonzero(np.any((hit[:, None] >= first) & (hit[:, None] < last), axis=1))
    part_of, edge, hit, t = part_of[on_mesh], edge[on_mesh], hit[on_mesh], t[on_mesh]
    point_xyz = np.empty((len(edge), 3))
    faces = np.empty((len(edge), 2), np.int64)
    for k, part in enumerate(parts):
        (sel,) = np.nonzero(part_of == k)
        a, b = part.vertices[part.edges[edge[sel], 0]], part.vertices[part.edges[edge[sel], 1]]
        length = np.linalg.norm(b - a, axis=1)
        point_xyz[sel] = a + (b - a) * ((t[sel] + _END_REL * length) / length)[:, None]
        own = part.edge_faces[edge[sel]]
        faces[sel] = np.where(own >= 0, own + part.offset, -1)
    # one record per (face of the edge, hit triangle): the crossing is an end of that pair's segment
    rec = np.repeat(np.arange(len(edge)), 2)
    face = faces.ravel()
    rec, face = rec[face >= 0], face[face >= 0]
    other = hit[rec]
    lo, hi = np.minimum(face, other), np.maximum(face, other)
    order = np.lexsort((rec, hi, lo))
    lo, hi, rec = lo[order], hi[order], rec[order]
    head = np.flatnonzero(np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])])
    count = np.diff(np.r_[head, len(lo)])
    pair = head[count == 2]
    pair = pair[rec[pair] != rec[pair + 1]]
    ends = np.stack([point_xyz[rec[pair]], point_xyz[rec[pair + 1]]], axis=1)
    owners = np.stack([lo[pair], hi[pair]], axis=1)
    keys = np.stack([rec[pair], rec[pair + 1]], axis=1)
    shape = np.array([p.shape for p in parts])[part_of[rec[pair]]]
    return ends, owners, keys, shape
