"""Reference solution of a diffusion-curve scene: a finite-difference Laplace solve on a fine grid.

The problem is the one ``dfc.physics.wos`` samples: ``Δu = 0`` in the domain, the left/right ``SideValues`` on the
two sides of every curve, zero flux through the canvas border.

Discretisation (Shortley–Weller). The unknowns are the grid nodes at the pixel centres of a ``W × H``
raster over the domain (``spec/conventions.md``), spacing ``hx``, ``hy``. The curves (cleaned up and
flattened into polylines finer than half a cell, ``dfc.physics.wos.flatten_curves``) cut the grid edges they cross:
a cut edge couples nothing, and each of its two nodes sees instead a Dirichlet node at the crossing, at
its true distance ``θ h`` (``θ`` clamped to at least ``MIN_THETA``), carrying the value of the node's own
side at the crossing's curve parameter. Per axis the node's equation is the non-uniform second difference
``2 / (h₋ + h₊) · ((u₊ − u) / h₊ − (u − u₋) / h₋)``.
At the border the neighbour beyond it is the node's
mirror image (the border lies half a cell away), so that difference is 0: the zero-flux condition.
The sparse system is solved once per scene with SuperLU (``scipy.sparse.linalg.splu``), all channels together.

The scheme is second-order accurate away from the curves and converges at first order or better at nodes
next to a cut; curves that cross no grid edge (features under a cell) are not seen, so solve finer than the
smallest feature of interest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from ..errors import InputError
from ..geometry.curves import Curves
from ..geometry.plane import cross
from .wos import FLATNESS_REL, Scene, flatten_curves

__all__ = ["MIN_THETA", "ReferenceSolution", "reference_solution", "solve_reference"]

MIN_THETA = 1e-3
"""Smallest distance from a node to a crossing, in cells: keeps the system's conditioning bounded."""
CUT_SPACING = 0.5
"""Polyline segments used to find crossings are at most this long, in cells (so one crosses at most one
grid line per axis)."""


@dataclass(frozen=True)
class ReferenceSolution:
    """A solved grid.

    values : (H, W, C) float64 solution at the pixel centres of a ``W × H`` raster over ``domain``
    domain : (x0, y0, x1, y1)
    scene : the ``dfc.physics.wos.Scene`` the solve used (curve geometry for ``at``)
    """

    values: np.ndarray
    domain: tuple[float, float, float, float]
    scene: Scene

    def at(self, xy) -> np.ndarray:
        """The solution at points (N, 2) in the domain -> (N, C) float64.

        Bilinear interpolation of the four surrounding nodes (the nearest ones at the border), leaving out the
        nodes that a curve separates from the point (the straight line to them crosses a polyline segment);
        when every node is separated, the value of the closest curve point on the point's side.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        h, w, _ = self.values.shape
        x0, y0, x1, y1 = self.domain
        cell = np.array([(x1 - x0) / w, (y1 - y0) / h])
        g = (xy - [x0, y0]) / cell - 0.5  # node coordinates
        i0 = np.clip(np.floor(g).astype(np.int64), 0, [w - 2 if w > 1 else 0, h - 2 if h > 1 else 0])
        f = np.clip(g - i0, 0.0, 1.0)
        corners = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
        idx = np.minimum(i0[:, None, :] + corners[None], [w - 1, h - 1])  # (N, 4, 2) node (i, j)
        wts = np.stack([(1 - f[:, 0]) * (1 - f[:, 1]), f[:, 0] * (1 - f[:, 1]), (1 - f[:, 0]) * f[:, 1],
                        f[:, 0] * f[:, 1]], axis=1)
        nodes = np.array([x0, y0]) + (idx + 0.5) * cell
        wts = wts * ~self._separated(xy, nodes, float(np.hypot(*cell)))
        total = wts.sum(axis=1)
        vals = np.einsum("nk,nkc->nc", wts, self.values[idx[..., 1], idx[..., 0]])
        out = np.empty_like(vals)
        ok = total > 0
        out[ok] = vals[ok] / total[ok, None]
        if (~ok).any():
            out[~ok] = self.scene.boundary_value(xy[~ok])
        return out

    def _separated(self, xy: np.ndarray, nodes: np.ndarray, reach: float) -> np.ndarray:
        """(N, 4) bool: the segment from each point to each of its nodes crosses a polyline segment."""
        out = np.zeros(nodes.shape[:2], dtype=bool)
        lines = self.scene.lines
        near = np.flatnonzero(self.scene.distance(xy) < reach)
        if not near.size:
            return out
        found = self.scene.tree.query_ball_point(xy[near], reach + lines.max_segment)
        counts = np.fromiter((len(v) for v in found), dtype=np.int64, count=len(found))
        if not counts.sum():
            return out
        vert = np.concatenate([np.asarray(v, dtype=np.int64) for v in found])
        point = np.repeat(near, counts)
        seg = np.concatenate([vert - 1, vert])
        point = np.concatenate([point, point])
        keep = seg >= 0
        seg, point = seg[keep], point[keep]
        keep = ~lines.last[seg]
        seg, point = seg[keep], point[keep]
        a, b = lines.vertices[seg], lines.vertices[seg + 1]
        p = xy[point]
        for k in range(nodes.shape[1]):
            hit = _segmentscross(p, nodes[point, k], a, b)
            np.logical_or.at(out[:, k], point[hit], True)
        return out


def _segmentscross(p, q, a, b) -> np.ndarray:
    """(M,) bool: segment p–q meets segment a–b (touching counts)."""
    d1, d2 = cross(q - p, a - p), cross(q - p, b - p)
    d3, d4 = cross(b - a, p - a), cross(b - a, q - a)
    return (d1 * d2 <= 0) & (d3 * d4 <= 0)


def solve_reference(curves: Curves | Scene, width: int, height: int) -> ReferenceSolution:
    """Solve the scene on the ``width × height`` grid of pixel centres (see the module docstring)."""
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer)) and width >= 2
            and height >= 2):
        raise ValueError(f"the reference grid needs at least 2 × 2 nodes, got {width} × {height}")
    scene = curves if isinstance(curves, Scene) else Scene(curves)
    x0, y0, x1, y1 = scene.domain
    hx, hy = (x1 - x0) / width, (y1 - y0) / height
    lines = flatten_curves(scene.curves.control_points, CUT_SPACING * min(hx, hy),
                           FLATNESS_REL * scene.curves.diagonal)
    n = width * height
    # per node and direction (0 +x, 1 −x, 2 +y, 3 −y): distance to the coupled value (cells) and its value
    theta = np.ones((n, 4))
    dirichlet = np.full((n, 4), False)
    value = np.zeros((n, 4, scene.n_channels))
    for axis in (0, 1):
        node_a, node_b, th, left_a, piece, t = _crossings(lines, scene.domain, width, height, axis)
        vals = {side: scene.side_values(piece, t, np.full(len(piece), side)) for side in (True, False)}
        va = np.where(left_a[:, None], vals[True], vals[False])  # node a's side
        vb = np.where(left_a[:, None], vals[False], vals[True])
        for node, dist, v, direction in ((node_a, th, va, 2 * axis), (node_b, 1.0 - th, vb, 2 * axis + 1)):
            order = np.lexsort((dist, node))  # the crossing nearest to each node wins
            first = np.ones(len(order), dtype=bool)
            first[1:] = node[order][1:] != node[order][:-1]
            sel = order[first]
            theta[node[sel], direction] = np.maximum(dist[sel], MIN_THETA)
            dirichlet[node[sel], direction] = True
            value[node[sel], direction] = v[sel]
    if not dirichlet.any():
        raise InputError(f"{scene.curves.source or 'curves'}: no curve crosses the {width} × {height} reference "
                         "grid: the problem has no Dirichlet values there")
    jj, ii = np.divmod(np.arange(n), width)
    neighbour = np.stack([np.where(ii + 1 < width, np.arange(n) + 1, -1), np.where(ii > 0, np.arange(n) - 1, -1),
                          np.where(jj + 1 < height, np.arange(n) + width, -1),
                          np.where(jj > 0, np.arange(n) - width, -1)], axis=1)
    spacing = np.array([hx, hx, hy, hy])
    dist = theta * spacing  # h₊, h₋ per axis
    axis_scale = 2.0 / (dist[:, 0::2] + dist[:, 1::2])  # (n, 2): 2 / (h₋ + h₊)
    coef = np.repeat(axis_scale, 2, axis=1) / dist  # weight of each direction's difference
    coef[(neighbour < 0) & ~dirichlet] = 0.0  # the mirror node beyond the border: zero difference
    coupled = (neighbour >= 0) & ~dirichlet
    rows = np.repeat(np.arange(n), 4).reshape(n, 4)
    diag = -coef.sum(axis=1)
    a = sparse.csc_matrix(
        (np.concatenate([diag, coef[coupled]]), (np.concatenate([np.arange(n), rows[coupled]]),
                                                np.concatenate([np.arange(n), neighbour[coupled]]))),
        shape=(n, n))
    rhs = -np.einsum("nd,ndc->nc", np.where(dirichlet, coef, 0.0), value)
    solution = splu(a).solve(rhs)
    return ReferenceSolution(solution.reshape(height, width, -1), scene.domain, scene)


def reference_solution(curves: Curves | Scene, width: int, height: int) -> np.ndarray:
    """(height, width, C) float64 reference solution at the pixel centres of a ``width × height`` raster."""
    return solve_reference(curves, width, height).values


def _crossings(lines, domain, width: int, height: int, axis: int):
    """Crossings of the polylines with the grid edges along ``axis`` (0: horizontal edges, 1: vertical).

    An edge along x joins nodes (i, j), (i + 1, j) and lies on the grid line y = y_j; a polyline segment
    crosses that line when its end points fall on different sides (half-open: a vertex on the line counts
    as below it). Returns node_a, node_b (M,) int64 flat node ids (a the lower i, resp. j), theta (M,) the
    crossing's position from a in cells, left_a (M,) bool whether a lies on the curve's left, and the piece
    (M,) and its parameter t (M,) at the crossing.
    """
    x0, y0, x1, y1 = domain
    origin = np.array([x0, y0])
    cell = np.array([(x1 - x0) / width, (y1 - y0) / height])
    along, across = axis, 1 - axis  # the edge runs along `along`; the grid line is at constant `across`
    seg = np.flatnonzero(~lines.last)
    p, q = lines.vertices[seg], lines.vertices[seg + 1]
    gp, gq = (p - origin) / cell - 0.5, (q - origin) / cell - 0.5
    rp, rq = np.floor(gp[:, across]), np.floor(gq[:, across])
    hit = rp != rq
    seg, p, q, gp, gq, rp, rq = seg[hit], p[hit], q[hit], gp[hit], gq[hit], rp[hit], rq[hit]
    line = np.maximum(rp, rq)  # segments are shorter than half a cell: they cross one grid line
    lam = (line - gp[:, across]) / (gq[:, across] - gp[:, across])
    pos = gp[:, along] + lam * (gq[:, along] - gp[:, along])
    i = np.floor(pos)
    size = (width, height)
    ok = (line >= 0) & (line < size[across]) & (i >= 0) & (i < size[along] - 1)
    seg, p, q, lam, pos, i, line = seg[ok], p[ok], q[ok], lam[ok], pos[ok], i[ok], line[ok]
    ij = np.empty((len(seg), 2), dtype=np.int64)
    ij[:, along], ij[:, across] = i, line
    node_a = ij[:, 1] * width + ij[:, 0]
    node_b = node_a + (1 if axis == 0 else width)
    a_xy = origin + (ij + 0.5) * cell
    x = p + lam[:, None] * (q - p)
    left_a = cross(q - p, a_xy - x) < 0.0
    t = lines.t[seg] + lam * (lines.t[seg + 1] - lines.t[seg])
    return node_a, node_b, pos - i, left_a, lines.piece[seg], t
