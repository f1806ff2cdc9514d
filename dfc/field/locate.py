"""Point location on a triangulation of a rectangle: which triangle holds each query (vectorised).

A uniform grid of cells covers the domain; every cell lists (CSR) the triangles that overlap it,
found by an exact separating-axis test with a small safety margin, ordered by how deep the cell
centre lies in them (largest minimum barycentric coordinate first, then triangle index), so the
first candidate usually holds the query. A query reads its cell's list: a cell with one candidate
resolves with one gather; otherwise all its candidates are tested at once (vectorised over the queries
whose first candidate misses), and the first whose barycentric coordinates are all ``>= 0`` wins (ties on shared edges and
vertices thus go deterministically to the earlier candidate of the query's cell).
When rounding makes every candidate miss, the candidate with the largest minimum barycentric
coordinate is taken. Queries outside the domain rectangle are clamped onto it first.

The hot path is torch (buffers move with ``.to(device)``), geometry in float64.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..errors import MeshError
from ..geometry.plane import cross

__all__ = ["PointLocator", "CELLS_PER_TRIANGLE"]

CELLS_PER_TRIANGLE = 32.0
"""Grid resolution: about this many cells per triangle (fewer candidates per cell vs. a larger table)."""

LOCATE_CHUNK = 1 << 16
"""Queries located per block."""
MISS_CHUNK = 1 << 15
"""Queries whose first candidate misses are resolved this many at a time (bounds the (M, K, 6) gather)."""
BUILD_CHUNK = 1 << 14
"""Triangles whose grid cells are listed at a time while the grid is built (bounds its temporary memory)."""
MISS_WINDOW = 3
"""Later candidates tested in the first window; each further window is twice as wide."""

_MARGIN = 1e-9
"""Cell/triangle overlap is kept within this fraction of the cell size, so boundary rounding never drops a triangle."""


def _cell_pairs(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray, origin: np.ndarray, h: float,
                shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """All (triangle, cell) pairs whose closed sets overlap (within the margin).

    v0, v1, v2 : (T, 2) float64 counter-clockwise corners; origin (2,), h cell size, shape (ny, nx).
    Returns tri (M,) int64 and cell (M,) int64 (row-major ``iy * nx + ix``).
    """
    ny, nx = shape
    corners = np.stack([v0, v1, v2], axis=1)
    lo = np.floor((corners.min(1) - origin) / h).astype(np.int64)
    hi = np.floor((corners.max(1) - origin) / h).astype(np.int64)
    lo = np.clip(lo, 0, [nx - 1, ny - 1])
    hi = np.clip(hi, 0, [nx - 1, ny - 1])
    wx, wy = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    count = wx * wy
    tri = np.repeat(np.arange(len(v0)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    ix = lo[tri, 0] + local % wx[tri]
    iy = lo[tri, 1] + local // wx[tri]
    bx0, by0 = origin[0] + ix * h, origin[1] + iy * h
    keep = np.ones(len(tri), bool)
    for a, b in ((v0, v1), (v1, v2), (v2, v0)):
        ex, ey = (b - a)[tri, 0], (b - a)[tri, 1]
        # Inside is cross(e, q - a) >= 0; its maximum over the cell is at the corner picked by -ey, ex.
        qx = bx0 + np.where(-ey > 0, h, 0.0)
        qy = by0 + np.where(ex > 0, h, 0.0)
        best = ex * (qy - a[tri, 1]) - ey * (qx - a[tri, 0])
        keep &= best >= -_MARGIN * h * np.hypot(ex, ey)
    return tri[keep], (iy * nx + ix)[keep]


def _barycentric(m: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Barycentric coordinates (l0, l1, l2) of points (x, y) in triangles with ``tri_affine`` rows m (..., 10).

    Each coordinate is measured from a vertex on the edge where it vanishes (l1, l2 from v0, l0 from v1), so
    its sign is right for points however close to that edge, even in needle triangles; the three sum to 1
    up to rounding."""
    dx, dy = x - m[..., 0], y - m[..., 1]
    l0 = m[..., 8] * (x - m[..., 6]) + m[..., 9] * (y - m[..., 7])
    l1 = m[..., 2] * dx + m[..., 3] * dy
    l2 = m[..., 4] * dx + m[..., 5] * dy
    return l0, l1, l2


class PointLocator(nn.Module):
    """Grid-accelerated point location.

    vertices : (V, 2) float64; triangles : (T, 3) int64 counter-clockwise;
    domain : (x0, y0, x1, y1) the rectangle the triangles cover.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, domain: tuple[float, float, float, float],
                 cells_per_triangle: float = CELLS_PER_TRIANGLE):
        super().__init__()
        verts = np.asarray(vertices, np.float64)
        tris = np.asarray(triangles, np.int64)
        if len(tris) == 0:
            raise MeshError("point location: the mesh has no triangles")
        x0, y0, x1, y1 = (float(d) for d in domain)
        width, height = x1 - x0, y1 - y0
        h = float(np.sqrt(width * height / (cells_per_triangle * len(tris))))
        nx, ny = max(1, int(np.ceil(width / h))), max(1, int(np.ceil(height / h)))
        v0, v1, v2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        origin = np.array([x0, y0])
        e1, e2 = v1 - v0, v2 - v0
        det = cross(e1, e2)
        if np.any(det <= 0):
            bad = int(np.flatnonzero(det <= 0)[0])
            raise MeshError(f"point location: triangle {bad} is degenerate or clockwise")
        # Barycentric map per triangle: (l1, l2) = inv([v1 - v0, v2 - v0]) @ (x - v0), and l0 from v1 along
        # its own gradient (not 1 - l1 - l2, which loses the sign next to a short edge v1 v2 of a needle).
        inv = np.stack([e2[:, 1], -e2[:, 0], -e1[:, 1], e1[:, 0]], axis=1) / det[:, None]
        e12 = v2 - v1
        grad0 = np.stack([-e12[:, 1], e12[:, 0]], axis=1) / det[:, None]
        parts = []
        for t0 in range(0, len(tris), BUILD_CHUNK):  # blocks of triangles bound the (triangle, cell) temporaries
            t1 = min(len(tris), t0 + BUILD_CHUNK)
            tri, cell = _cell_pairs(v0[t0:t1], v1[t0:t1], v2[t0:t1], origin, h, (ny, nx))
            tri += t0
            centre = origin + (np.stack([cell % nx, cell // nx], axis=1) + 0.5) * h
            d = centre - v0[tri]
            l1 = inv[tri, 0] * d[:, 0] + inv[tri, 1] * d[:, 1]
            l2 = inv[tri, 2] * d[:, 0] + inv[tri, 3] * d[:, 1]
            parts.append((tri.astype(np.int32), cell, np.minimum(np.minimum(l1, l2), 1.0 - l1 - l2)))
        tri, cell, depth = (np.concatenate(column) for column in zip(*parts))
        del parts
        order = np.lexsort((tri, -depth, cell))
        tri, cell = tri[order], cell[order]
        count = np.bincount(cell, minlength=nx * ny)
        if np.any(count == 0):
            empty = int(np.flatnonzero(count == 0)[0])
            cx, cy = x0 + (empty % nx + 0.5) * h, y0 + (empty // nx + 0.5) * h
            raise MeshError(f"point location: the triangles do not cover the domain near ({cx:.6g}, {cy:.6g})")
        self.domain = (x0, y0, x1, y1)
        self.register_buffer("lower", torch.tensor([x0, y0], dtype=torch.float64))
        self.register_buffer("upper", torch.tensor([x1, y1], dtype=torch.float64))
        self.cell_size = h
        self.grid_shape = (ny, nx)
        self.register_buffer("cell_start", torch.from_numpy((np.cumsum(count) - count).astype(np.int32)))
        self.register_buffer("cell_count", torch.from_numpy(count.astype(np.int32)))
        self.register_buffer("cell_triangles", torch.from_numpy(tri.astype(np.int32)))
        self.register_buffer("tri_affine", torch.from_numpy(np.concatenate([v0, inv, v1, grad0], axis=1)))  # (T, 10)

    def clamp(self, xy: torch.Tensor) -> torch.Tensor:
        """Clamp (N, 2) float64 points onto the domain rectangle (gradient zero outside)."""
        return xy.clamp(self.lower, self.upper)

    def barycentric(self, xy: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
        """Barycentric coordinates (N, 3) float64 of points (N, 2) float64 in triangles (N,) int64 (differentiable)."""
        return torch.stack(_barycentric(self.tri_affine.index_select(0, tri), xy[:, 0], xy[:, 1]), dim=1)

    @torch.no_grad()
    def forward(self, xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Locate points xy (N, 2) float64 (already clamped): triangle (N,) int64 holding each and the
        barycentric coordinates (N, 3) float64 there (not differentiable; see ``barycentric``)."""
        if len(xy) > LOCATE_CHUNK:  # blocks keep the temporaries small enough to be reused, not page-faulted in
            parts = [self._locate(xy[s:s + LOCATE_CHUNK]) for s in range(0, len(xy), LOCATE_CHUNK)]
            return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
        return self._locate(xy)

    def _locate(self, xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x0, y0, _, _ = self.domain
        ny, nx = self.grid_shape
        ix = torch.floor((xy[:, 0] - x0) / self.cell_size).long().clamp_(0, nx - 1)
        iy = torch.floor((xy[:, 1] - y0) / self.cell_size).long().clamp_(0, ny - 1)
        cell = iy * nx + ix
        start = self.cell_start.index_select(0, cell)
        tri = self.cell_triangles.index_select(0, start).long()
        bary = self.barycentric(xy, tri)
        count = self.cell_count.index_select(0, cell)
        miss = torch.nonzero((bary.amin(1) < 0) & (count > 1)).squeeze(1)
        for lo in range(0, miss.numel(), MISS_CHUNK):
            rows = miss[lo:lo + MISS_CHUNK]
            tri[rows], bary[rows] = self._candidates(xy.index_select(0, rows), start[rows], count[rows],
                                                     tri[rows], bary[rows])
        return tri, bary

    def _candidates(self, xy: torch.Tensor, start: torch.Tensor, count: torch.Tensor, tri: torch.Tensor,
                    bary: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Resolve queries (M, 2) whose first candidate ``tri`` (barycentric ``bary``) misses: the first later
        candidate (in cell order) that holds the query, else the one with the largest minimum barycentric
        coordinate. Candidates are tested in windows of doubling width, all queries of a window at once."""
        best = bary.amin(1)
        active = torch.arange(len(xy), device=xy.device)
        k0, width = 1, MISS_WINDOW
        while active.numel():
            k = k0 + torch.arange(width, device=xy.device)
            valid = k < count[active, None]                                           # (A, W)
            pos = torch.where(valid, start[active, None] + k, start[active, None])
            cand = self.cell_triangles[pos].long()                                    # (A, W)
            p = xy[active]
            l0, l1, l2 = _barycentric(self.tri_affine[cand], p[:, None, 0], p[:, None, 1])      # (A, W) each
            score = torch.minimum(torch.minimum(l0, l1), l2).masked_fill(~valid, -torch.inf)
            inside = score >= 0
            found = inside.any(1)
            pick = torch.where(found, inside.to(torch.uint8).argmax(1), score.argmax(1))[:, None]
            top = score.gather(1, pick)[:, 0]
            better = found | (top > best[active])
            upd = active[better]
            tri[upd] = cand.gather(1, pick)[better, 0]
            bary[upd] = torch.stack([lam.gather(1, pick)[better, 0] for lam in (l0, l1, l2)], dim=1)
            best[upd] = top[better]
            k0 += width
            active = active[~found & (count[active] > k0)]
            width *= 2
        return tri, bary
