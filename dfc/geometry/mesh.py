"""The curved constrained triangulation the feature field lives on (docs/design.md §4).

Plain arrays with fixed shapes; ``validate()`` checks every invariant the interpolation relies on.
Built by ``dfc.geometry.triangulate`` (module ``dfc.geometry.triangulate``); read back from ``.dfield`` files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from .plane import cross
from .tolerances import tol


@dataclass
class Mesh:
    """A triangulation of a rectangle with discontinuous straight edges and curved triangles.

    domain : (x0, y0, x1, y1) float, the rectangle the triangles cover exactly
    vertices : (V, 2) float64
    triangles : (T, 3) int64, counter-clockwise in (x, y): cross(b - a, c - a) > 0
    disc_edges : (E, 2) int64, vertex pairs of discontinuous straight edges (each a mesh edge)
    curved_triangles : (C,) int64, triangle holding each curved piece
    curve_endpoints : (C, 2) int64, the piece's endpoint vertices (two corners of that triangle);
        ``curve_control_points[c, 0]`` is at ``vertices[curve_endpoints[c, 0]]``, ``[c, 3]`` at ``[c, 1]``
    curve_control_points : (C, 4, 2) float64, cubic Bézier control points (quadratics degree-elevated)
    curve_degree : (C,) int8, 2 or 3 (the piece's true degree)
    disc_edge_piece : (E,) int64, index of the clean-up piece each straight edge came from (-1: unknown)
    curve_piece : (C,) int64, the same for curved pieces
    """

    domain: tuple[float, float, float, float]
    vertices: np.ndarray
    triangles: np.ndarray
    disc_edges: np.ndarray
    curved_triangles: np.ndarray
    curve_endpoints: np.ndarray
    curve_control_points: np.ndarray
    curve_degree: np.ndarray
    disc_edge_piece: np.ndarray
    curve_piece: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    @property
    def diagonal(self) -> float:
        """Length of the domain's diagonal, the unit of the relative tolerances."""
        x0, y0, x1, y1 = self.domain
        return float(np.hypot(x1 - x0, y1 - y0))

    @property
    def n_disc_vertices(self) -> int:
        """Number of vertices touched by a discontinuous edge or a curved piece's endpoint."""
        return len(np.unique(np.concatenate([self.disc_edges.ravel(), self.curve_endpoints.ravel()])))

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Unique undirected edges and how many triangles use each.

        returns edges (K, 2) int64 with ``edges[:, 0] < edges[:, 1]``, sorted; counts (K,) int64
        """
        e = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        return np.unique(e, axis=0, return_counts=True)

    def validate(self) -> None:
        """Raise ``MeshError`` with a precise message if any invariant of docs/design.md §4 is broken.

        Checks array shapes and dtypes, index ranges, counter-clockwise non-degenerate triangles that
        tile the domain exactly and conform (every interior edge shared by exactly two triangles, in
        opposite directions; every other edge on the domain border), discontinuous edges that are
        distinct mesh edges, and curved pieces that lie in their own triangle with their endpoints as
        two of its corners, are graphs over their chords, and share no chord with a discontinuous edge,
        another curve or a triangle with another curve. Tolerances come from ``dfc.geometry.tolerances.tol``.
        """
        self._check_arrays()
        v, t = self.vertices, self.triangles
        x0, y0, x1, y1 = self.domain
        diag = self.diagonal
        eps = tol.touch_rel * diag

        outside = (v[:, 0] < x0 - eps) | (v[:, 0] > x1 + eps) | (v[:, 1] < y0 - eps) | (v[:, 1] > y1 + eps)
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            raise MeshError(f"mesh: vertex {i} at {_xy(v[i])} is outside the domain {self.domain}")
        unused = np.ones(len(v), dtype=bool)
        unused[t.ravel()] = False
        if unused.any():
            i = int(np.flatnonzero(unused)[0])
            raise MeshError(f"mesh: vertex {i} at {_xy(v[i])} belongs to no triangle")

        p = v[t]  # (T, 3, 2)
        area2 = cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        longest = np.sqrt((np.diff(p[:, [0, 1, 2, 0]], axis=1) ** 2).sum(axis=2).max(axis=1))
        bad = area2 <= tol.degenerate_rel * diag * longest
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            kind = "clockwise" if area2[i] < 0 else "degenerate"
            raise MeshError(f"mesh: triangle {i} {t[i].tolist()} at {_pts(p[i])} is {kind} (doubled area {area2[i]:.3g})")
        self._check_conforming()
        total, domain_area = 0.5 * float(area2.sum()), (x1 - x0) * (y1 - y0)
        if abs(total - domain_area) > tol.area_rel * domain_area:
            raise MeshError(f"mesh: triangle areas sum to {total!r}, the domain's area is {domain_area!r}")
        edge_key = self._check_disc_edges()
        self._check_curves(edge_key, eps)

    def _check_arrays(self) -> None:
        n_v, n_t = len(self.vertices), len(self.triangles)
        n_e, n_c = len(self.disc_edges), len(self.curved_triangles)
        floats = {"vertices": (self.vertices, (-1, 2)), "curve_control_points": (self.curve_control_points, (n_c, 4, 2))}
        ints = {
            "triangles": (self.triangles, (-1, 3), n_v),
            "disc_edges": (self.disc_edges, (-1, 2), n_v),
            "curved_triangles": (self.curved_triangles, (n_c,), n_t),
            "curve_endpoints": (self.curve_endpoints, (n_c, 2), n_v),
            "curve_degree": (self.curve_degree, (n_c,), None),
            "disc_edge_piece": (self.disc_edge_piece, (n_e,), None),
            "curve_piece": (self.curve_piece, (n_c,), None),
        }
        for name, (a, shape) in floats.items():
            if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and _shape_ok(a.shape, shape)):
                raise MeshError(f"mesh: {name} must be a float64 array of shape {_shape_str(shape)}, got {_describe(a)}")
            if not np.isfinite(a).all():
                raise MeshError(f"mesh: {name} holds NaN or infinite values")
        for name, (a, shape, bound) in ints.items():
            if not (isinstance(a, np.ndarray) and np.issubdtype(a.dtype, np.integer) and _shape_ok(a.shape, shape)):
                raise MeshError(f"mesh: {name} must be an integer array of shape {_shape_str(shape)}, got {_describe(a)}")
            if bound is not None and a.size and (a.min() < 0 or a.max() >= bound):
                i = int(np.flatnonzero(((a < 0) | (a >= bound)).reshape(len(a), -1).any(axis=1))[0])
                raise MeshError(f"mesh: {name}[{i}] = {a[i].tolist()} is out of range [0, {bound})")
        if len(self.domain) != 4 or not np.isfinite(self.domain).all():
            raise MeshError(f"mesh: domain {self.domain} is not (x0, y0, x1, y1)")
        x0, y0, x1, y1 = self.domain
        if not (x1 > x0 and y1 > y0):
            raise MeshError(f"mesh: domain {self.domain} is empty")
        if n_t == 0:
            raise MeshError("mesh: there are no triangles")
        bad = ~np.isin(self.curve_degree, (2, 3))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise MeshError(f"mesh: curve {i} has degree {int(self.curve_degree[i])}, expected 2 or 3")

    def _check_conforming(self) -> None:
        v, t = self.vertices, self.triangles
        directed = t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).astype(np.int64)
        n = np.int64(len(v))
        key = directed[:, 0] * n + directed[:, 1]
        order = np.argsort(key, kind="stable")
        dup = np.flatnonzero(key[order][1:] == key[order][:-1])
        if len(dup):
            k = order[dup[0] + 1]
            a, b = directed[k]
            raise MeshError(
                f"mesh: edge ({a}, {b}) from {_xy(v[a])} to {_xy(v[b])} is used by more than two triangles "
                f"(triangles {order[dup[0]] // 3} and {k // 3} on the same side)"
            )
        twin = directed[:, 1] * n + directed[:, 0]
        pos = np.searchsorted(key[order], twin)
        has_twin = key[order][np.minimum(pos, len(key) - 1)] == twin
        lone = directed[~has_twin]
        x0, y0, x1, y1 = self.domain
        eps = tol.touch_rel * self.diagonal
        ab = v[lone]  # (K, 2, 2)
        on_border = (
            (np.abs(ab[..., 0] - x0) <= eps).all(axis=1)
            | (np.abs(ab[..., 0] - x1) <= eps).all(axis=1)
            | (np.abs(ab[..., 1] - y0) <= eps).all(axis=1)
            | (np.abs(ab[..., 1] - y1) <= eps).all(axis=1)
        )
        if not on_border.all():
            i = int(np.flatnonzero(~on_border)[0])
            e = lone[i]
            tri = int(np.flatnonzero(~has_twin)[i] // 3)
            raise MeshError(
                f"mesh: edge ({e[0]}, {e[1]}) from {_xy(v[e[0]])} to {_xy(v[e[1]])} of triangle {tri} has no "
                "neighbour across it but is not on the domain border (non-conforming mesh or hole)"
            )

    def _check_disc_edges(self) -> np.ndarray:
        """Returns the sorted keys of all undirected mesh edges, for later lookups."""
        v = self.vertices
        n = np.int64(len(v))
        edges, _ = self.edges()
        edge_key = edges[:, 0] * n + edges[:, 1]
        d = np.sort(self.disc_edges.astype(np.int64), axis=1)
        loop = d[:, 0] == d[:, 1]
        if loop.any():
            i = int(np.flatnonzero(loop)[0])
            raise MeshError(f"mesh: discontinuous edge {i} joins vertex {d[i, 0]} to itself")
        dk = d[:, 0] * n + d[:, 1]
        missing = ~_contains(edge_key, dk)
        if missing.any():
            i = int(np.flatnonzero(missing)[0])
            a, b = d[i]
            raise MeshError(f"mesh: discontinuous edge {i} from {_xy(v[a])} to {_xy(v[b])} is not a mesh edge")
        _, first, counts = np.unique(dk, return_index=True, return_counts=True)
        if (counts > 1).any():
            i = int(first[np.flatnonzero(counts > 1)[0]])
            raise MeshError(f"mesh: discontinuous edge {i} from {_xy(v[d[i, 0]])} to {_xy(v[d[i, 1]])} is listed twice")
        return edge_key

    def _check_curves(self, edge_key: np.ndarray, eps: float) -> None:
        v, t = self.vertices, self.triangles
        c = len(self.curved_triangles)
        if c == 0:
            return
        n = np.int64(len(v))
        tri = t[self.curved_triangles]  # (C, 3)
        ep = self.curve_endpoints.astype(np.int64)
        cp = self.curve_control_points
        corner = (tri[:, :, None] == ep[:, None, :]).any(axis=1)  # (C, 2)
        bad = ~corner.all(axis=1) | (ep[:, 0] == ep[:, 1])
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise MeshError(
                f"mesh: curve {i}'s endpoints {ep[i].tolist()} are not two corners of its triangle "
                f"{int(self.curved_triangles[i])} {tri[i].tolist()}"
            )
        off = np.maximum(np.abs(cp[:, 0] - v[ep[:, 0]]).max(axis=1), np.abs(cp[:, 3] - v[ep[:, 1]]).max(axis=1)) > eps
        if off.any():
            i = int(np.flatnonzero(off)[0])
            raise MeshError(
                f"mesh: curve {i}'s end control points {_pts(cp[i, [0, 3]])} are not at its endpoint vertices "
                f"{_pts(v[ep[i]])}"
            )
        holders, first, counts = np.unique(self.curved_triangles, return_index=True, return_counts=True)
        if (counts > 1).any():
            k = int(np.flatnonzero(counts > 1)[0])
            raise MeshError(f"mesh: triangle {int(holders[k])} holds two curves (curve {int(first[k])} and another)")

        p = v[tri]  # (C, 3, 2), counter-clockwise
        dist = np.stack([min_side_distance(cp, p[:, k], p[:, (k + 1) % 3]) for k in range(3)], axis=1)
        out = dist.min(axis=1) < -eps
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise MeshError(
                f"mesh: curve {i} with control points {_pts(cp[i])} leaves its triangle "
                f"{int(self.curved_triangles[i])} at {_pts(p[i])} by {-dist[i].min():.3g}"
            )
        chord = cp[:, 3] - cp[:, 0]
        normal = np.stack([chord[:, 1], -chord[:, 0]], axis=1)
        not_graph = min_side_distance(cp, cp[:, 0], cp[:, 0] + normal, derivative=True) < -eps
        if not_graph.any():
            i = int(np.flatnonzero(not_graph)[0])
            raise MeshError(f"mesh: curve {i} with control points {_pts(cp[i])} is not a graph over its chord")

        ck = np.sort(ep, axis=1)
        ck = ck[:, 0] * n + ck[:, 1]
        dk = np.sort(self.disc_edges.astype(np.int64), axis=1)
        dk = dk[:, 0] * n + dk[:, 1]
        shared = _contains(np.sort(dk), ck)
        if shared.any():
            i = int(np.flatnonzero(shared)[0])
            raise MeshError(f"mesh: curve {i}'s chord from {_xy(v[ep[i, 0]])} to {_xy(v[ep[i, 1]])} is also a discontinuous edge")
        _, first, counts = np.unique(ck, return_index=True, return_counts=True)
        if (counts > 1).any():
            i = int(first[np.flatnonzero(counts > 1)[0]])
            raise MeshError(f"mesh: curve {i}'s chord from {_xy(v[ep[i, 0]])} to {_xy(v[ep[i, 1]])} is another curve's chord too")


def min_side_distance(cp: np.ndarray, p: np.ndarray, q: np.ndarray, *, derivative: bool = False) -> np.ndarray:
    """Smallest signed distance of each cubic piece to the line through ``p`` and ``q``, over t in [0, 1].

    Exact (closed-form extrema of the cubic ``cross(q - p, B(t) - p) / |q - p|``); positive on the left of
    ``p -> q`` (inside a counter-clockwise triangle's edge). With ``derivative=True`` the same for
    ``cross(q - p, B'(t)) / |q - p|`` instead (a quadratic), e.g. the speed of the piece along a direction.

    cp : (N, 4, 2) float64; p, q : (N, 2) float64 with p != q
    returns (N,) float64 in the units of ``cp``
    """
    p0, p1, p2, p3 = cp[:, 0], cp[:, 1], cp[:, 2], cp[:, 3]
    d = q - p
    d = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    # power basis of B(t) - p: c0 + c1 t + c2 t^2 + c3 t^3
    c = [cross(d, p0 - p), cross(d, 3.0 * (p1 - p0)), cross(d, 3.0 * (p2 - 2.0 * p1 + p0)), cross(d, p3 - 3.0 * p2 + 3.0 * p1 - p0)]
    if derivative:
        c = [c[1], 2.0 * c[2], 3.0 * c[3], np.zeros_like(c[3])]
    # stationary points: c1 + 2 c2 t + 3 c3 t^2 = 0
    a, b, k = 3.0 * c[3], 2.0 * c[2], c[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4.0 * a * k
        sq = np.sqrt(np.maximum(disc, 0.0))
        qq = -0.5 * (b + np.where(b >= 0.0, sq, -sq))
        roots = np.stack([qq / a, k / qq, -k / b], axis=1)
    roots = np.clip(np.nan_to_num(roots, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    ts = np.concatenate([np.zeros((len(cp), 1)), np.ones((len(cp), 1)), roots], axis=1)
    val = c[0][:, None] + ts * (c[1][:, None] + ts * (c[2][:, None] + ts * c[3][:, None]))
    return val.min(axis=1)


def _contains(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Membership of ``keys`` (M,) in ascending ``sorted_keys`` (K,) -> (M,) bool."""
    if len(sorted_keys) == 0:
        return np.zeros(len(keys), dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return sorted_keys[pos] == keys


def _shape_ok(shape: tuple, want: tuple) -> bool:
    return len(shape) == len(want) and all(w == -1 or s == w for s, w in zip(shape, want))


def _shape_str(shape: tuple) -> str:
    return "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"


def _describe(a) -> str:
    return f"{a.dtype} {a.shape}" if isinstance(a, np.ndarray) else type(a).__name__


def _xy(p: np.ndarray) -> str:
    return f"({p[0]:.9g}, {p[1]:.9g})"


def _pts(ps: np.ndarray) -> str:
    return "[" + ", ".join(_xy(p) for p in ps) + "]"
