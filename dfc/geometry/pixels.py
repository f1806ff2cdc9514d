"""Which pixels of a raster the discontinuities of a mesh cross (the mixed pixels a fit leaves out)."""

from __future__ import annotations

import numpy as np

__all__ = ["EDGE_SAMPLE_SPACING", "edge_pixels"]

EDGE_SAMPLE_SPACING = 0.25
"""``edge_pixels`` samples each discontinuity at this spacing, in pixels."""


def edge_pixels(mesh, height: int, width: int, window=None) -> np.ndarray:
    """(H, W) bool: pixels of a ``width × height`` raster of ``window`` (x0, y0, x1, y1; default ``mesh.domain``)
    crossed by a discontinuity.

    Their values blend both sides (a box-filtered image), which no side of a sharp field can match.
    Straight discontinuous edges and curved pieces are sampled every ``EDGE_SAMPLE_SPACING`` pixels,
    so a pixel whose corner a curve clips by less than that may be missed (its blend is slight).
    """
    x0, y0, x1, y1 = mesh.domain if window is None else window
    v = mesh.vertices
    a, b = v[mesh.disc_edges[:, 0]], v[mesh.disc_edges[:, 1]]
    lines = np.stack([a, a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0, b], axis=1)
    cp = np.concatenate([lines, np.asarray(mesh.curve_control_points, dtype=np.float64).reshape(-1, 4, 2)])
    out = np.zeros((height, width), dtype=bool)
    if len(cp) == 0:
        return out
    scale = np.array([width / (x1 - x0), height / (y1 - y0)])
    polygon = np.linalg.norm(np.diff(cp * scale, axis=1), axis=2).sum(axis=1)  # ≥ arc length, in pixels
    n = np.maximum(np.ceil(polygon / EDGE_SAMPLE_SPACING).astype(np.int64) + 1, 2)
    piece = np.repeat(np.arange(len(cp)), n)
    start = np.concatenate([[0], np.cumsum(n)[:-1]])
    t = (np.arange(len(piece)) - start[piece]) / (n[piece] - 1)
    s = 1.0 - t
    w = np.stack([s**3, 3 * s * s * t, 3 * s * t * t, t**3], axis=1)  # (M, 4) Bernstein weights
    pts = np.einsum("mk,mkd->md", w, cp[piece])
    ij = np.floor((pts - [x0, y0]) * scale).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < width) & (ij[:, 1] >= 0) & (ij[:, 1] < height)
    out[ij[inside, 1], ij[inside, 0]] = True
    return out
