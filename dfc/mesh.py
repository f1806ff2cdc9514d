"""The curved constrained triangulation the feature field lives on (DESIGN §4).

Plain arrays with fixed shapes; ``validate()`` checks every invariant the interpolation relies on.
Built by ``dfc.triangulate`` (module ``dfc.triangulate``); read back from ``.dfield`` files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import MeshError


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

    def validate(self) -> None:
        """Raise ``MeshError`` with a precise message if any invariant of DESIGN §4 is broken."""
        raise MeshError("Mesh.validate is not implemented yet")
