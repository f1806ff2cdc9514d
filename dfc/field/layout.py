"""Parameter-bank layout of the discontinuity-aware feature field (docs/design.md §5).

The layout is a deterministic function of the mesh alone: a ``.dfield`` file stores the bank as-is
and the decoder rebuilds this layout from the decoded mesh.

Discontinuities at a vertex
    The *discontinuous half-edges* leaving vertex ``v`` are ``mesh.disc_edges`` and the chords
    ``mesh.curve_endpoints`` (a curved piece counts as an edge along its chord), taken in both
    directions, duplicates removed. They are sorted counter-clockwise in (x, y) by
    ``atan2(dy, dx)`` in ``(-π, π]`` (ties by the far vertex index). With ``k ≥ 1`` of them,
    sector ``j`` runs counter-clockwise from half-edge ``j`` to half-edge ``(j + 1) mod k`` (one
    half-edge: one sector of 2π).

Bank rows (per time slice), in this order
    1. for every vertex ``v = 0 .. V-1`` in turn: one row if ``k_v = 0``; otherwise ``2 k_v`` rows,
       sector ``j`` owning rows ``2j`` (feature at its start half-edge, the clockwise bound) and
       ``2j + 1`` (feature at its end half-edge, the counter-clockwise bound);
    2. one curve feature per curved piece, in the order of ``mesh.curved_triangles``.

Per triangle corner ``(t, i)`` at vertex ``v`` with next corner ``n`` (counter-clockwise), the
corner's wedge runs from ``v → n`` to ``v → prev``; it lies in exactly one sector, found from the
wedge bisector. ``alpha`` is the angle from that sector's start half-edge to ``v → n`` (exactly 0
when ``v → n`` is the start half-edge), ``beta`` the corner angle and ``theta`` the sector angle,
so a query ``x`` in the triangle sits at angle ``min(alpha + clamp(∠(v→n, x−v), 0, beta), theta)``
from the sector start — the clamps replace trusting ``atan2`` next to an edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from ..geometry.mesh import Mesh
from ..geometry.plane import cross

__all__ = ["Layout", "build_layout"]

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Layout:
    """Where every triangle corner and every curved triangle finds its features in the bank.

    n_features : rows of the bank per time slice
    n_vertex_features : rows 0 .. n_vertex_features-1 belong to vertices, the rest to curves
    vertex_offset : (V,) int64, first bank row of each vertex
    vertex_sectors : (V,) int64, sectors per vertex (0: one isotropic feature)
    corner_start, corner_end : (T, 3) int64, bank rows of the corner's sector at its start / end
        half-edge (equal for a vertex without discontinuities)
    corner_sector : (T, 3) int64, sector index of the corner at its vertex (0 without discontinuities)
    corner_alpha : (T, 3) float64, radians from the sector start to the edge ``v → next``
    corner_beta : (T, 3) float64, the corner angle in radians, in (0, π)
    corner_theta : (T, 3) float64, the sector angle in radians (``inf`` without discontinuities)
    triangle_curve : (T,) int64, curved piece held by each triangle, -1 for none
    curve_apex : (C,) int64, corner (0, 1, 2) of the curved triangle that is not on the piece
    curve_sliver_rows : (C, 3) int64, bank rows the three corners use in the sliver: at the two
        endpoints the chord-edge feature of the sector across the chord, at the apex the curve feature
    """

    n_features: int
    n_vertex_features: int
    vertex_offset: np.ndarray
    vertex_sectors: np.ndarray
    corner_start: np.ndarray
    corner_end: np.ndarray
    corner_sector: np.ndarray
    corner_alpha: np.ndarray
    corner_beta: np.ndarray
    corner_theta: np.ndarray
    triangle_curve: np.ndarray
    curve_apex: np.ndarray
    curve_sliver_rows: np.ndarray


def _angle(v: np.ndarray) -> np.ndarray:
    """Direction angles of vectors (..., 2) -> (...) float64 in (-π, π]."""
    return np.arctan2(v[..., 1], v[..., 0])


def _half_edges(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Discontinuous half-edges (from, to), (H,) int64 each, duplicates removed."""
    pairs = np.concatenate([np.asarray(mesh.disc_edges, np.int64).reshape(-1, 2),
                            np.asarray(mesh.curve_endpoints, np.int64).reshape(-1, 2)])
    if np.any(pairs[:, 0] == pairs[:, 1]):
        raise MeshError("field layout: a discontinuous edge or chord joins a vertex to itself")
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    return np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])


def build_layout(mesh: Mesh) -> Layout:
    """Compute the bank layout of ``mesh`` (see the module docstring); numpy, vectorised.

    Raises ``MeshError`` when a curved piece's endpoints are not two corners of its triangle or a
    triangle holds more than one curved piece.
    """
    verts = np.asarray(mesh.vertices, np.float64)
    tris = np.asarray(mesh.triangles, np.int64)
    n_v = len(verts)

    # Discontinuous half-edges sorted by (from, angle, to): CSR per vertex.
    h_from, h_to = _half_edges(mesh)
    h_ang = _angle(verts[h_to] - verts[h_from])
    order = np.lexsort((h_to, h_ang, h_from))
    h_from, h_to, h_ang = h_from[order], h_to[order], h_ang[order]
    k = np.bincount(h_from, minlength=n_v).astype(np.int64)
    first = np.cumsum(k) - k
    rows = np.where(k == 0, 1, 2 * k)
    offset = np.cumsum(rows) - rows
    n_vertex_features = int(rows.sum())

    # Sector angle of every sector (indexed like the sorted half-edges: sector j of v is first[v] + j).
    j_of = np.arange(len(h_from)) - first[h_from]
    nxt = first[h_from] + (j_of + 1) % np.maximum(k[h_from], 1)
    sector_theta = np.where(k[h_from] == 1, TWO_PI, np.mod(h_ang[nxt] - h_ang, TWO_PI))

    sector, alpha, beta, theta = _corner_sectors(verts, tris, h_to, h_ang, k, first, sector_theta)
    start = np.where(k[tris] > 0, offset[tris] + 2 * sector, offset[tris])
    end = np.where(k[tris] > 0, start + 1, start)
    triangle_curve, apex, sliver_rows = _sliver_rows(mesh, k, offset, sector, n_vertex_features)
    return Layout(
        n_features=n_vertex_features + len(apex),
        n_vertex_features=n_vertex_features,
        vertex_offset=offset,
        vertex_sectors=k,
        corner_start=start,
        corner_end=end,
        corner_sector=sector,
        corner_alpha=alpha,
        corner_beta=beta,
        corner_theta=theta,
        triangle_curve=triangle_curve,
        curve_apex=apex,
        curve_sliver_rows=sliver_rows,
    )


def _corner_sectors(verts, tris, h_to, h_ang, k, first, sector_theta):
    """Per triangle corner (T, 3): the sector of its vertex it lies in, the angle alpha from that sector's first
    edge to the corner's next edge, the corner's angle beta, and the sector's angle theta (inf without one)."""
    v = tris
    # Corners: vertex, next and previous corner.
    n = np.roll(tris, -1, axis=1)
    p = np.roll(tris, 1, axis=1)
    e_n = verts[n] - verts[v]
    e_p = verts[p] - verts[v]
    ang_n = _angle(e_n)
    beta = np.arctan2(cross(e_n, e_p), np.sum(e_n * e_p, axis=-1))
    bisector = np.mod(ang_n + 0.5 * beta + np.pi, TWO_PI) - np.pi

    # Sector of each corner: the last half-edge at v with angle <= bisector (cyclically).
    kv = k[v]
    count = np.zeros_like(v)
    for j in range(int(k.max(initial=0))):
        idx = np.minimum(first[v] + j, max(len(h_to) - 1, 0))
        count += (j < kv) & (h_ang[idx] <= bisector)
    has = kv > 0
    sector = np.where(has, np.mod(count - 1, np.maximum(kv, 1)), 0)
    hs = np.where(has, first[v] + sector, 0)
    if len(h_to):
        theta = np.where(has, sector_theta[hs], np.inf)
        alpha = np.where(has, np.mod(ang_n - h_ang[hs], TWO_PI), 0.0)
        alpha = np.where(has & (h_to[hs] == n), 0.0, alpha)
    else:
        theta = np.full(v.shape, np.inf)
        alpha = np.zeros(v.shape)
    # Rounding can push alpha just past the sector end; put it back at the nearer bound.
    over = alpha > theta
    alpha = np.where(over, np.where(alpha - theta < TWO_PI - alpha, theta, 0.0), alpha)
    return sector, alpha, beta, theta


def _sliver_rows(mesh: Mesh, k, offset, sector, n_vertex_features: int):
    """Curved triangles: (triangle → curve index or -1 (T,), apex corner (C,), sliver rows (C, 3)) — at the endpoints
    the chord-edge feature of the sector across the chord, at the apex the curve's own feature row."""
    tris = np.asarray(mesh.triangles, np.int64)
    n_t = len(tris)
    # Curved triangles: which corners are the endpoints, and the sliver rows.
    ct = np.asarray(mesh.curved_triangles, np.int64).reshape(-1)
    ends = np.asarray(mesh.curve_endpoints, np.int64).reshape(-1, 2)
    n_c = len(ct)
    triangle_curve = np.full(n_t, -1, np.int64)
    if n_c:
        if np.unique(ct).size != n_c:
            raise MeshError("field layout: a triangle holds more than one curved piece")
        triangle_curve[ct] = np.arange(n_c)
    corners = tris[ct]                                           # (C, 3)
    is_a = corners == ends[:, :1]
    is_b = corners == ends[:, 1:]
    if np.any(is_a.sum(1) != 1) or np.any(is_b.sum(1) != 1):
        bad = int(np.flatnonzero((is_a.sum(1) != 1) | (is_b.sum(1) != 1))[0])
        raise MeshError(f"field layout: curved piece {bad} does not have its endpoints on two corners of its triangle")
    apex = np.argmax(~(is_a | is_b), axis=1)
    curve_rows = n_vertex_features + np.arange(n_c)
    sliver_rows = np.empty((n_c, 3), np.int64)
    rc = np.arange(n_c)
    for which in (is_a, is_b):
        ci = np.argmax(which, axis=1)                             # corner index of this endpoint
        e_vert = corners[rc, ci]
        nxt_vert = corners[rc, (ci + 1) % 3]
        o_vert = np.where(is_a[rc, ci], ends[:, 1], ends[:, 0])
        kk = k[e_vert]
        s_t = sector[ct, ci]
        # The chord is the start of T's sector when the other endpoint is the next corner,
        # then the far sector is the previous one (its end feature); otherwise the next one (its start).
        chord_first = nxt_vert == o_vert
        far = np.where(chord_first, np.mod(s_t - 1, kk), np.mod(s_t + 1, kk))
        sliver_rows[rc, ci] = offset[e_vert] + 2 * far + chord_first
    sliver_rows[rc, apex] = curve_rows

    return triangle_curve, apex, sliver_rows
