"""Small hand-built curved meshes for the field tests (pythoncdt directly, no dfc.geometry.triangulate).

Curved pieces are placed inside a triangle ``(a, b, c)``: a quadratic or cubic from ``a`` to ``b``
inside the tangent triangle ``(a, X, b)`` with ``X`` inside ``(a, b, c)``, so the piece is a graph
over its chord that bulges towards the apex ``c``.
"""

from __future__ import annotations

import numpy as np
import pythoncdt as cdt

from dfc.geometry.mesh import Mesh

UNIT = (0.0, 0.0, 1.0, 1.0)


def cdt_triangles(points: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Constrained Delaunay triangles (T, 3) int64, counter-clockwise, of points (V, 2) with edges (E, 2)."""
    t = cdt.Triangulation(cdt.VertexInsertionOrder.AS_PROVIDED, cdt.IntersectingConstraintEdges.NOT_ALLOWED, 0.0)
    t.insert_vertices(np.ascontiguousarray(points, np.float64))
    if len(edges):
        t.insert_edges(np.ascontiguousarray(edges, np.uint32))
    t.erase_super_triangle()
    tris = t.triangles_array()["vertices"].astype(np.int64)
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    cw = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] < 0
    tris[cw] = tris[cw][:, ::-1]
    return tris


def bezier(cp: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cubic Bézier cp (4, 2) at t (M,) -> (M, 2)."""
    t = np.asarray(t, np.float64)[:, None]
    s = 1.0 - t
    return s**3 * cp[0] + 3 * s * s * t * cp[1] + 3 * s * t * t * cp[2] + t**3 * cp[3]


def bezier_normal(cp: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Unit normals (M, 2) of cp (4, 2) at t (M,)."""
    t = np.asarray(t, np.float64)[:, None]
    s = 1.0 - t
    d = 3 * (s * s * (cp[1] - cp[0]) + 2 * s * t * (cp[2] - cp[1]) + t * t * (cp[3] - cp[2]))
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def piece_in_triangle(a, b, c, rng: np.random.Generator, degree: int, flatness: float | None = None) -> np.ndarray:
    """Cubic control points (4, 2) of a piece from a to b inside triangle (a, b, c) bulging towards c.

    flatness : height of the control apex as a fraction of the room under the triangle (random when None).
    """
    a, b, c = (np.asarray(p, np.float64) for p in (a, b, c))
    chord = b - a
    ux = chord / chord.dot(chord)
    vx = np.array([-chord[1], chord[0]]) / chord.dot(chord)
    uc, vc = (c - a).dot(ux), (c - a).dot(vx)
    u = rng.uniform(0.2, 0.8)
    room = vc * min(u / uc if uc > 0 else np.inf, (1 - u) / (1 - uc) if uc < 1 else np.inf)
    rho = rng.uniform(0.1, 0.9) if flatness is None else flatness
    x = a + u * chord + rho * room * np.array([-chord[1], chord[0]])
    if degree == 2:
        return np.array([a, a + 2 / 3 * (x - a), b + 2 / 3 * (x - b), b])
    s1, s2 = rng.uniform(0.2, 1.0, size=2)
    return np.array([a, a + s1 * (x - a), b + s2 * (x - b), b])


def make_mesh(points, triangles, disc_edges, curved, domain=UNIT) -> Mesh:
    """Mesh from arrays; curved is a list of (triangle, endpoint_a, endpoint_b, control points (4, 2), degree)."""
    c = len(curved)
    return Mesh(
        domain=domain,
        vertices=np.asarray(points, np.float64),
        triangles=np.asarray(triangles, np.int64),
        disc_edges=np.asarray(disc_edges, np.int64).reshape(-1, 2),
        curved_triangles=np.array([k[0] for k in curved], np.int64),
        curve_endpoints=np.array([[k[1], k[2]] for k in curved], np.int64).reshape(c, 2),
        curve_control_points=np.array([k[3] for k in curved], np.float64).reshape(c, 4, 2),
        curve_degree=np.array([k[4] for k in curved], np.int8),
        disc_edge_piece=np.full(len(disc_edges), -1, np.int64),
        curve_piece=np.full(c, -1, np.int64),
    )


def mesh_edges(triangles: np.ndarray) -> np.ndarray:
    """Unique undirected edges (M, 2) int64, sorted pairs."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def random_mesh(seed: int, n_points: int = 24, disc_fraction: float = 0.35, n_curves: int = 5) -> Mesh:
    """Delaunay mesh of random points in the unit square, a random subset of edges discontinuous
    (junctions of any valence, open tips) and random curved pieces on other edges."""
    rng = np.random.default_rng(seed)
    pts = np.concatenate([[[0, 0], [1, 0], [1, 1], [0, 1]], rng.uniform(0.05, 0.95, (n_points, 2))])
    tris = cdt_triangles(pts, np.zeros((0, 2)))
    edges = mesh_edges(tris)
    disc = edges[rng.random(len(edges)) < disc_fraction]
    taken = {tuple(e) for e in disc}
    curved, used = [], set()
    for t in rng.permutation(len(tris)):
        if len(curved) == n_curves:
            break
        i = int(rng.integers(3))
        a, b, c = tris[t, i], tris[t, (i + 1) % 3], tris[t, (i + 2) % 3]
        key = (min(a, b), max(a, b))
        if key in taken or t in used:
            continue
        if rng.random() < 0.5:
            a, b = b, a
        taken.add(key)
        used.add(t)
        deg = int(rng.integers(2, 4))
        curved.append((t, a, b, piece_in_triangle(pts[a], pts[b], pts[c], rng, deg), deg))
    return make_mesh(pts, tris, disc, curved)


def needle_mesh() -> Mesh:
    """The unit square with one short discontinuous edge (1e-6 long) in the middle, so that the triangles on it
    are needles ~4e5 times as long as that edge, each listed from its far corner (as dfc.triangulate may list
    them) — the mesh a tiny line piece left by the clean-up gives (property-test seed 205)."""
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1],
                    [0.5429338042388561, 0.42156448725157014], [0.5429342603539355, 0.4215635981485822]])
    tris = cdt_triangles(pts, np.array([[4, 5]]))
    opposite = np.linalg.norm(pts[np.roll(tris, -1, 1)] - pts[np.roll(tris, -2, 1)], axis=2)
    first = np.argmin(opposite, axis=1)[:, None]  # the corner facing the shortest edge comes first
    return make_mesh(pts, np.take_along_axis(tris, (first + np.arange(3)) % 3, axis=1), [[4, 5]], [])


def tangent_mesh(pieces: list[np.ndarray], degrees: list[int], extra: np.ndarray, disc=np.zeros((0, 2))) -> Mesh:
    """Mesh of the unit square holding the given pieces (cubic cp (4, 2) each, endpoints shared by
    exact equality), each in its tangent triangle (a, X, b) built with constrained edges, plus extra points."""
    ends = np.concatenate([[p[0], p[3]] for p in pieces])
    apexes = []
    for p in pieces:
        d0, d1 = p[1] - p[0], p[3] - p[2]
        # X = p0 + s d0 = p3 - r d1
        s, _ = np.linalg.solve(np.stack([d0, d1], axis=1), p[3] - p[0])
        apexes.append(p[0] + s * d0)
    pts = np.concatenate([[[0, 0], [1, 0], [1, 1], [0, 1]], ends, np.array(apexes), extra])
    pts, inv = np.unique(pts, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n_pieces = len(pieces)
    e_idx = inv[4:4 + 2 * n_pieces].reshape(-1, 2)
    x_idx = inv[4 + 2 * n_pieces:4 + 3 * n_pieces]
    cons = np.concatenate([e_idx, np.stack([e_idx[:, 0], x_idx], 1), np.stack([x_idx, e_idx[:, 1]], 1),
                           np.asarray(disc, np.int64).reshape(-1, 2)])
    cons = np.unique(np.sort(cons, axis=1), axis=0)
    tris = cdt_triangles(pts, cons)
    lookup = {tuple(sorted(t)): k for k, t in enumerate(tris.tolist())}
    curved = []
    for k, p in enumerate(pieces):
        a, b, x = e_idx[k, 0], e_idx[k, 1], x_idx[k]
        curved.append((lookup[tuple(sorted((a, b, x)))], a, b, p, degrees[k]))
    return make_mesh(pts, tris, disc, curved)


def circle_mesh(extra_points: int = 12, seed: int = 0) -> Mesh:
    """A circle of four cubics (centre (0.5, 0.5), radius 0.25) in the unit square."""
    k = 0.5522847498 * 0.25
    c = np.array([0.5, 0.5])
    r = 0.25
    axes = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    quads = []
    for q in range(4):
        u0, u1 = axes[q], axes[(q + 1) % 4]
        quads.append(np.array([c + r * u0, c + r * u0 + k * u1, c + r * u1 + k * u0, c + r * u1]))
    rng = np.random.default_rng(seed)
    extra = rng.uniform(0.02, 0.98, (4 * extra_points, 2))
    extra = extra[np.abs(np.linalg.norm(extra - c, axis=1) - r) > 0.12][:extra_points]
    return tangent_mesh(quads, [3, 3, 3, 3], extra)


def s_mesh(extra_points: int = 12, seed: int = 1) -> Mesh:
    """An S of two pieces (a cubic and a quadratic) meeting at (0.5, 0.5), plus a line piece from the
    middle vertex (a junction of three discontinuities there)."""
    a, m, b = np.array([0.3, 0.3]), np.array([0.5, 0.5]), np.array([0.7, 0.7])
    p1 = np.array([a, [0.33, 0.42], [0.42, 0.5], m])
    q = np.array([0.6, 0.5])
    p2 = np.array([m, m + 2 / 3 * (q - m), b + 2 / 3 * (q - b), b])
    rng = np.random.default_rng(seed)
    extra = rng.uniform(0.02, 0.98, (6 * extra_points, 2))
    extra = extra[np.linalg.norm(extra[:, None] - np.array([a, m, b, [0.4, 0.45], q]), axis=2).min(1) > 0.15]
    extra = np.concatenate([extra[:extra_points], [[0.5, 0.95]]])
    mesh = tangent_mesh([p1, p2], [3, 2], extra)
    top = int(np.flatnonzero(np.all(mesh.vertices == [0.5, 0.95], axis=1))[0])
    mid = int(np.flatnonzero(np.all(mesh.vertices == m, axis=1))[0])
    disc = np.array([[mid, top]])
    tris = cdt_triangles(mesh.vertices, np.concatenate([_constraints(mesh), disc]))
    lookup = {tuple(sorted(t)): k for k, t in enumerate(tris.tolist())}
    ct = [lookup[tuple(sorted(mesh.triangles[t]))] for t in mesh.curved_triangles]
    curved = [(ct[k], *mesh.curve_endpoints[k], mesh.curve_control_points[k], mesh.curve_degree[k]) for k in range(2)]
    return make_mesh(mesh.vertices, tris, disc, curved)


def _constraints(mesh: Mesh) -> np.ndarray:
    """Edges of every curved triangle (keeps them in a rebuilt CDT)."""
    t = mesh.triangles[mesh.curved_triangles]
    return np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
