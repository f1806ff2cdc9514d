"""Which pixels of a raster the discontinuities of a mesh cross (the mixed pixels a fit leaves out)."""

from __future__ import annotations

import numpy as np

__all__ = ["EDGE_SAMPLE_SPACING", "EdgeMask", "edge_pixels"]

EDGE_SAMPLE_SPACING = 0.25
"""``edge_pixels`` samples each discontinuity at this spacing, in pixels."""
_CHUNK_POINTS = 1 << 22
"""Curve samples evaluated at a time (bounds the temporary memory of a band)."""


class EdgeMask:
    """The mixed pixels of a ``width × height`` raster of ``window`` (x0, y0, x1, y1; default ``mesh.domain``), band
    by band or tile by tile (``rows``).

    Straight discontinuous edges and curved pieces are sampled every ``EDGE_SAMPLE_SPACING`` pixels, so a pixel
    whose corner a curve clips by less than that may be missed (its blend is slight). A band (or tile) evaluates only
    the pieces whose control polygon reaches it, and marks exactly the pixels the whole raster's mask has there.
    """

    def __init__(self, mesh, height: int, width: int, window=None):
        x0, y0, x1, y1 = mesh.domain if window is None else window
        v = mesh.vertices
        a, b = v[mesh.disc_edges[:, 0]], v[mesh.disc_edges[:, 1]]
        lines = np.stack([a, a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0, b], axis=1)
        cp = np.concatenate([lines, np.asarray(mesh.curve_control_points, dtype=np.float64).reshape(-1, 4, 2)])
        self.height, self.width = height, width
        self.scale = np.array([width / (x1 - x0), height / (y1 - y0)])
        self.cp = (cp - [x0, y0]) * self.scale  # (P, 4, 2) in pixel units
        polygon = np.linalg.norm(np.diff(self.cp, axis=1), axis=2).sum(axis=1)  # ≥ arc length, in pixels
        self.n = np.maximum(np.ceil(polygon / EDGE_SAMPLE_SPACING).astype(np.int64) + 1, 2)
        self.row_lo = np.floor(self.cp[..., 1].min(axis=1))  # the curve lies in its control polygon's hull
        self.row_hi = np.floor(self.cp[..., 1].max(axis=1))
        self.col_lo = np.floor(self.cp[..., 0].min(axis=1))
        self.col_hi = np.floor(self.cp[..., 0].max(axis=1))

    def rows(self, y0: int = 0, y1: int | None = None, *, cols: tuple[int, int] | None = None) -> np.ndarray:
        """(y1 - y0, W) bool: the mask's rows ``y0 .. y1 - 1`` (default all rows); with ``cols=(x0, x1)`` only
        columns ``x0 .. x1 - 1``, (y1 - y0, x1 - x0) (a tile)."""
        y1 = self.height if y1 is None else y1
        x0, x1 = cols or (0, self.width)
        out = np.zeros((y1 - y0, x1 - x0), dtype=bool)
        pieces = np.flatnonzero((self.row_hi >= y0) & (self.row_lo < y1) & (self.col_hi >= x0) & (self.col_lo < x1))
        ends = np.cumsum(self.n[pieces])
        start = 0
        while start < len(pieces):  # chunks of about _CHUNK_POINTS samples
            stop = max(start + 1, int(np.searchsorted(ends, ends[start] - self.n[pieces[start]] + _CHUNK_POINTS)))
            self._mark(out, y0, x0, pieces[start:stop])
            start = stop
        return out

    def _mark(self, out: np.ndarray, y0: int, x0: int, pieces: np.ndarray) -> None:
        n = self.n[pieces]
        piece = np.repeat(pieces, n)
        first = np.repeat(np.cumsum(n) - n, n)
        t = (np.arange(len(piece)) - first) / (np.repeat(n, n) - 1)
        s = 1.0 - t
        w = np.stack([s**3, 3 * s * s * t, 3 * s * t * t, t**3], axis=1)  # (M, 4) Bernstein weights
        ij = np.floor(np.einsum("mk,mkd->md", w, self.cp[piece])).astype(np.int64)
        inside = (ij[:, 0] >= x0) & (ij[:, 0] < x0 + out.shape[1]) & (ij[:, 1] >= y0) & (ij[:, 1] < y0 + len(out))
        out[ij[inside, 1] - y0, ij[inside, 0] - x0] = True


def edge_pixels(mesh, height: int, width: int, window=None, *, rows: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool — or (y1 - y0, W) for ``rows=(y0, y1)`` — pixels of a ``width × height`` raster of ``window``
    (default ``mesh.domain``) crossed by a discontinuity (``EdgeMask``). Their values blend both sides (a
    box-filtered image), which no side of a sharp field can match."""
    return EdgeMask(mesh, height, width, window).rows(*(rows or (0, height)))
