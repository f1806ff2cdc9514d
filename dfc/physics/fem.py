"""FEM solutions sampled for the codec, barrier-aware.

Values inside an element are its linear (or nearest-node) interpolation, never across a barrier curve: an element
that a barrier crosses (possible when the mesh does not duplicate its nodes along the barrier) is evaluated at a
point from only the nodes it *sees*, those whose straight segment to the point crosses no barrier, with the
barycentric weights renormalised over them. With duplicated nodes no element straddles a barrier and this is plain
P1 interpolation. Solutions are ``dfc.io.fem.FemSolution``s.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import InputError
from ..geometry import bezier
from ..geometry.curves import Curves
from ..geometry.plane import cross, triangle_areas
from ..io.fem import FemSolution

__all__ = ["SAMPLES_PER_TRIANGLE", "barrier_segments", "evaluate_fem", "fem_curves", "interpolate", "node_points",
           "sample_fem"]

SAMPLES_PER_TRIANGLE = 4
"""``sample_fem`` draws this many interior points per element on average (area-weighted), besides the nodes."""
NODE_NUDGE = 1e-3
"""Nodes are evaluated this fraction of the way towards the centroid of one of their elements, so that each copy
of a node duplicated along a barrier is read on its own side."""
CURVE_SEGMENTS = 16
"""Curved barrier pieces are flattened into this many straight segments for the side test."""
SIDE_EPS = 1e-9
"""Distances below this fraction of the domain's diagonal count as "on the barrier" (no crossing)."""
CROSS_BLOCK = 1 << 22
"""(point, node, barrier segment) triples tested per block in the side test (bounds memory)."""
MODES = ("linear", "nearest")



def fem_curves(solution: FemSolution, curves: Curves) -> Curves:
    """The barrier curves over the codec's domain for ``solution``.

    Every curve (its control points) must lie in the mesh's extent, within 1e-9 of its size (``InputError``
    otherwise). The domain is the curves' own when it contains the mesh's extent, else that extent.
    """
    x0, y0, x1, y1 = solution.extent
    tol = 1e-9 * max(x1 - x0, y1 - y0)
    cp = curves.control_points.reshape(-1, 2)
    if len(cp) and ((cp.min(axis=0) < [x0 - tol, y0 - tol]).any() or (cp.max(axis=0) > [x1 + tol, y1 + tol]).any()):
        raise InputError(f"the curves reach outside the mesh's extent ({x0:.6g}, {y0:.6g}, {x1:.6g}, {y1:.6g})")
    cx0, cy0, cx1, cy1 = curves.domain
    if cx0 <= x0 + tol and cy0 <= y0 + tol and cx1 >= x1 - tol and cy1 >= y1 - tol:
        return curves
    return replace(curves, domain=(x0, y0, x1, y1))


def barrier_segments(curves: Curves) -> np.ndarray:
    """(S, 2, 2) float64 straight segments approximating every piece (curved ones flattened)."""
    cp = np.asarray(curves.control_points, dtype=np.float64)
    if len(cp) == 0:
        return np.zeros((0, 2, 2))
    lines = np.asarray(curves.degree) == 1
    parts = [np.stack([cp[lines, 0], cp[lines, 3]], axis=1)]
    poly = bezier.flatten(cp[~lines], CURVE_SEGMENTS) if (~lines).any() else np.zeros((0, 2, 2))
    parts.append(np.stack([poly[:, :-1], poly[:, 1:]], axis=2).reshape(-1, 2, 2))
    return np.concatenate(parts)


def _side(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Signed distance of points w from the lines u→v (broadcast over leading axes; y down: < 0 is left)."""
    d = v - u
    n = np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-300)
    return cross(d, w - u) / n


def _crosses(p: np.ndarray, q: np.ndarray, segments: np.ndarray, eps: float) -> np.ndarray:
    """(M,) bool: does segment p→q ((M, 2) each) properly cross any barrier segment? Touching (an end within
    ``eps`` of the other segment's line) is no crossing, so a node on the barrier is seen from both sides."""
    out = np.zeros(len(p), dtype=bool)
    a, b = segments[:, 0], segments[:, 1]
    step = max(1, CROSS_BLOCK // max(1, len(segments)))
    for s in range(0, len(p), step):
        pp, qq = p[s:s + step, None], q[s:s + step, None]
        hit = np.ones((len(pp), len(segments)), dtype=bool)
        for d1, d2 in ((_side(a, b, pp), _side(a, b, qq)), (_side(pp, qq, a), _side(pp, qq, b))):
            hit &= (d1 * d2 < 0) & (np.abs(d1) > eps) & (np.abs(d2) > eps)
        out[s:s + step] = hit.any(axis=1)
    return out


def _straddling(solution: FemSolution, segments: np.ndarray) -> np.ndarray:
    """(T,) bool: elements whose bounding box meets a barrier segment's (candidates for the side test)."""
    out = np.zeros(len(solution.triangles), dtype=bool)
    if len(segments) == 0:
        return out
    corners = solution.points[solution.triangles]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    slo, shi = segments.min(axis=1), segments.max(axis=1)
    step = max(1, CROSS_BLOCK // len(segments))
    for s in range(0, len(lo), step):
        meet = (lo[s:s + step, None] <= shi) & (hi[s:s + step, None] >= slo)
        out[s:s + step] = meet.all(axis=2).any(axis=1)
    return out


def interpolate(solution: FemSolution, tri: np.ndarray, bary: np.ndarray, xy: np.ndarray, curves: Curves,
                mode: str = "linear") -> np.ndarray:
    """Values (N, C) float32 at points xy (N, 2) lying in elements tri (N,) with barycentric coordinates bary (N, 3).

    mode : "linear" (P1) or "nearest" (the value of the largest-weight node). Nodes across a barrier from the
    point are left out (module notes); a point that sees none of its element's nodes takes its nearest node.
    """
    if mode not in MODES:
        raise InputError(f"FEM sampling must be one of {', '.join(MODES)}, got {mode!r}")
    w = np.clip(np.asarray(bary, dtype=np.float64), 0.0, None)
    nodes = solution.triangles[tri]
    segments = barrier_segments(curves)
    check = np.flatnonzero(_straddling(solution, segments)[tri])
    if len(check):
        x0, y0, x1, y1 = solution.extent
        eps = SIDE_EPS * float(np.hypot(x1 - x0, y1 - y0))
        for k in range(3):
            blocked = _crosses(xy[check], solution.points[nodes[check, k]], segments, eps)
            w[check[blocked], k] = 0.0
        blind = check[w[check].sum(axis=1) == 0]
        w[blind] = np.arange(3) == np.argmax(bary[blind], axis=1)[:, None]
    if mode == "nearest":
        w = (np.arange(3) == w.argmax(axis=1)[:, None]).astype(np.float64)
    w /= w.sum(axis=1, keepdims=True)
    return np.einsum("nk,nkc->nc", w, solution.values[nodes].astype(np.float64)).astype(np.float32)


def node_points(solution: FemSolution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the nodal values are read: every node used by an element, moved ``NODE_NUDGE`` of the way towards
    the centroid of its first element. Returns xy (V', 2) float64, element (V',) int64 and barycentric (V', 3)."""
    tris = solution.triangles
    order = np.argsort(tris.ravel(), kind="stable")
    node, first = np.unique(tris.ravel()[order], return_index=True)
    element, corner = np.divmod(order[first], 3)
    bary = np.full((len(node), 3), NODE_NUDGE / 3.0)
    bary[np.arange(len(node)), corner] += 1.0 - NODE_NUDGE
    xy = np.einsum("nk,nkd->nd", bary, solution.points[tris[element]])
    return xy, element, bary


def sample_fem(solution: FemSolution, curves: Curves, *, per_triangle: float = SAMPLES_PER_TRIANGLE,
               mode: str = "linear", seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Training samples of a solution: its nodes (``node_points``) and ``per_triangle × T`` points drawn uniformly
    over the mesh's area (elements chosen by area, uniform inside), valued by ``interpolate``.

    Returns xy (N, 2) float64 and values (N, C) float32.
    """
    rng = np.random.default_rng(seed)
    corners = solution.points[solution.triangles]
    area = triangle_areas(corners)
    n = int(round(per_triangle * len(area)))
    tri = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    bary = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)
    node_xy, node_tri, node_bary = node_points(solution)
    tri = np.concatenate([node_tri, tri])
    bary = np.concatenate([node_bary, bary])
    xy = np.einsum("nk,nkd->nd", bary, corners[tri])
    return xy, interpolate(solution, tri, bary, xy, curves, mode)


def evaluate_fem(solution: FemSolution, curves: Curves, xy: np.ndarray, mode: str = "linear") -> np.ndarray:
    """The solution's values (N, C) float32 at arbitrary points xy (N, 2) of its extent, which the mesh must
    cover (located with ``dfc.field.locate.PointLocator``)."""
    import torch

    from ..field.locate import PointLocator

    locator = PointLocator(solution.points, solution.triangles, solution.extent)
    xy = np.asarray(xy, dtype=np.float64)
    tri, bary = locator(torch.from_numpy(xy))
    return interpolate(solution, tri.numpy(), bary.numpy(), xy, curves, mode)
