"""Numerical checks of the continuity theorem (paper Thm 4.3, docs/design.md §5) on a mesh.

The bank is filled with N(0, 1) values so that jumps are O(1). Two points ``2 EPS`` apart across
a line are continuous when they differ by less than ``SMOOTH``, or when the difference shrinks in
proportion to the distance (thin triangles have steep but continuous fields); a jump is a change
above ``JUMP`` that persists when the distance shrinks.
"""

from __future__ import annotations

import numpy as np
import torch

from dfc.field import FeatureField
from dfc.geometry.mesh import Mesh

from ._meshes import bezier, bezier_normal

EPS = 1e-10
SMOOTH = 1e-4
JUMP = 1e-2


def random_field(mesh: Mesh, seed: int = 0) -> FeatureField:
    field = FeatureField(mesh, dim=5)
    with torch.no_grad():
        field.bank.normal_(generator=torch.Generator().manual_seed(seed))
    return field


def evaluate(field: FeatureField, xy: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return field.features(torch.as_tensor(xy, dtype=torch.float64)).double().numpy()


def across(field: FeatureField, p: np.ndarray, n: np.ndarray, eps: float = EPS) -> np.ndarray:
    """|F(p + eps n) - F(p - eps n)| (M,) for points p (M, 2) and unit normals n (M, 2)."""
    return np.linalg.norm(evaluate(field, p + eps * n) - evaluate(field, p - eps * n), axis=1)


def interior_edges(mesh: Mesh) -> np.ndarray:
    """Edges (M, 2) shared by two triangles."""
    t = mesh.triangles
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 2]


def jumps(field: FeatureField, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Change across points p (M, 2) along unit normals n (M, 2) that does not vanish with the distance (M,)."""
    d = across(field, p, n)
    steep = d >= SMOOTH
    if steep.any():
        d[steep] = np.where(across(field, p[steep], n[steep], EPS * 1e-3) > 0.5 * d[steep], d[steep], 0.0)
    return d


def edge_set(pairs: np.ndarray) -> set:
    return {tuple(sorted(map(int, p))) for p in np.asarray(pairs).reshape(-1, 2)}


def check_edges(field: FeatureField, s=(0.3, 0.65)) -> None:
    """Every interior edge: a jump iff it is discontinuous (chords of curved pieces are continuous)."""
    mesh = field.mesh
    edges = interior_edges(mesh)
    disc = edge_set(mesh.disc_edges)
    chords = edge_set(mesh.curve_endpoints)
    is_disc = np.array([tuple(e) in disc for e in edges.tolist()], bool)
    for si in s:
        a, b = mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]]
        p = a + si * (b - a)
        n = np.stack([-(b - a)[:, 1], (b - a)[:, 0]], 1)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        d = jumps(field, p, n)
        assert np.all(d[~is_disc] < SMOOTH), (
            f"jump {d[~is_disc].max():.3g} across a continuous edge "
            f"{edges[~is_disc][np.argmax(d[~is_disc])]} (chord: {tuple(edges[~is_disc][np.argmax(d[~is_disc])]) in chords})")
        assert np.all(d[is_disc] > JUMP), f"no jump ({d[is_disc].min():.3g}) across a discontinuous edge"


def check_curves(field: FeatureField, ts=(0.2, 0.5, 0.8)) -> None:
    """Every curved piece: a jump at interior points."""
    for cp in field.mesh.curve_control_points:
        t = np.asarray(ts)
        d = jumps(field, bezier(cp, t), bezier_normal(cp, t))
        assert np.all(d > JUMP), f"no jump ({d.min():.3g}) across a curved piece"


def check_interiors(field: FeatureField, n: int = 2000, seed: int = 0) -> None:
    """Random nearby pairs inside the domain differ by O(EPS)."""
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = field.mesh.domain
    p = rng.uniform([x0, y0], [x1, y1], (n, 2))
    dirs = rng.normal(size=(n, 2))
    d = jumps(field, p, dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
    assert np.all(d < SMOOTH), f"F changes by {d.max():.3g} between points {2 * EPS:.0e} apart"


def jumps_around(field: FeatureField, vertices: np.ndarray, radius: np.ndarray, samples: int = 1024,
                 rounds: int = 30, extra: np.ndarray | None = None) -> np.ndarray:
    """Number of persistent jumps of F on a circle around each vertex (K,) -> (K,) int.

    extra : optional (K, m) angles sampled besides the ``samples`` uniform ones (so that two discontinuities
    closer than the uniform spacing still have a sample between them)."""
    mesh = field.mesh
    c = mesh.vertices[vertices]
    ang = np.broadcast_to(np.linspace(0, 2 * np.pi, samples + 1), (len(vertices), samples + 1))
    if extra is not None:
        ang = np.sort(np.concatenate([ang, np.mod(extra, 2 * np.pi)], axis=1), axis=1)
    pts = c[:, None] + radius[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], -1)
    f = evaluate(field, pts.reshape(-1, 2)).reshape(len(vertices), ang.shape[1], -1)
    d = np.linalg.norm(np.diff(f, axis=1), axis=2)
    k, j = np.nonzero(d > JUMP)
    lo, hi = ang[k, j], ang[k, j + 1]
    flo, fhi = f[k, j], f[k, j + 1]

    def at(kk, a):
        return evaluate(field, c[kk] + radius[kk, None] * np.stack([np.cos(a), np.sin(a)], -1))

    for _ in range(rounds):
        mid = 0.5 * (lo + hi)
        fm = at(k, mid)
        left = np.linalg.norm(fm - flo, axis=1) >= np.linalg.norm(fhi - fm, axis=1)
        hi, fhi = np.where(left, mid, hi), np.where(left[:, None], fm, fhi)
        lo, flo = np.where(left, lo, mid), np.where(left[:, None], flo, fm)
    persistent = np.linalg.norm(fhi - flo, axis=1) > JUMP
    return np.bincount(k[persistent], minlength=len(vertices))


def _bisectors(mesh, vertices: np.ndarray) -> np.ndarray:
    """(K, m) angles halfway between consecutive incident discontinuity directions (edges; curves by their
    chords and end tangents) around each vertex, padded by repetition."""
    v = mesh.vertices
    cp = np.asarray(mesh.curve_control_points, np.float64).reshape(-1, 4, 2)
    ends = mesh.curve_endpoints
    rays = [(a, v[b]) for a, b in mesh.disc_edges] + [(b, v[a]) for a, b in mesh.disc_edges]
    rays += [(ends[i, 0], p) for i in range(len(ends)) for p in (v[ends[i, 1]], cp[i, 1], cp[i, 2])]
    rays += [(ends[i, 1], p) for i in range(len(ends)) for p in (v[ends[i, 0]], cp[i, 2], cp[i, 1])]
    out = []
    for vertex in vertices:
        d = np.array([p - v[vertex] for a, p in rays if a == vertex and np.any(p != v[vertex])]).reshape(-1, 2)
        a = np.sort(np.arctan2(d[:, 1], d[:, 0]))
        out.append(0.5 * (a + np.roll(a, -1) + np.where(np.arange(len(a)) == len(a) - 1, 2 * np.pi, 0.0)))
    width = max(1, max(len(o) for o in out))
    return np.array([np.resize(o, width) if len(o) else np.zeros(width) for o in out])


def check_vertex_circles(field: FeatureField) -> None:
    """Around every interior vertex, F jumps exactly once per incident discontinuous edge and per
    incident curved piece (junctions, open tips, chains), and nowhere else (not across chords)."""
    mesh = field.mesh
    x0, y0, x1, y1 = mesh.domain
    v = mesh.vertices
    inner = np.flatnonzero((v[:, 0] > x0) & (v[:, 0] < x1) & (v[:, 1] > y0) & (v[:, 1] < y1))
    # Radius: a small fraction of the distance from the vertex to the opposite side of every incident triangle.
    t = mesh.triangles
    radius = np.full(len(v), np.inf)
    for i in range(3):
        a, b, c = v[t[:, i]], v[t[:, (i + 1) % 3]], v[t[:, (i + 2) % 3]]
        e = c - b
        h = np.abs(e[:, 0] * (a - b)[:, 1] - e[:, 1] * (a - b)[:, 0]) / np.linalg.norm(e, axis=1)
        np.minimum.at(radius, t[:, i], h)
    expected = np.zeros(len(v), np.int64)
    for e in edge_set(mesh.disc_edges):
        expected[list(e)] += 1
    np.add.at(expected, mesh.curve_endpoints.reshape(-1), 1)
    got = jumps_around(field, inner, 0.04 * radius[inner], extra=_bisectors(mesh, inner))
    bad = np.flatnonzero(got != expected[inner])
    assert len(bad) == 0, (f"vertex {inner[bad[0]]}: {got[bad[0]]} jumps around it, expected "
                           f"{expected[inner[bad[0]]]}")


def check_all(field: FeatureField) -> None:
    check_edges(field)
    check_curves(field)
    check_interiors(field)
    check_vertex_circles(field)
