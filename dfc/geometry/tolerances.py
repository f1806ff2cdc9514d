"""All geometric tolerances in one place (the habit of ``trimesh.constants.tol``).

Tolerances named ``*_rel`` are relative to the domain's diagonal length, so the same curves give
the same mesh whatever their units. Modules read ``tol`` instead of hard-coding epsilons."""

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    snap_rel: float = 1e-7
    """Endpoints and intersection points closer than this (× diagonal) are merged into one vertex."""
    zero_length_rel: float = 1e-9
    """Pieces whose control polygon is shorter than this (× diagonal) are dropped."""
    cdt_min_dist_rel: float = 1e-12
    """``min_dist_to_constraint_edge`` handed to the CDT (× diagonal)."""
    area_rel: float = 1e-9
    """Relative tolerance on the sum of triangle areas against the domain area in ``Mesh.validate``."""
    degenerate_rel: float = 1e-14
    """A triangle whose height over its longest edge is below this (× diagonal) counts as degenerate."""
    svg_arc_rel: float = 1e-6
    """SVG elliptical arcs become cubics that stray at most this far (× diagonal) from the exact arc."""
    touch_rel: float = 1e-10
    """Gap (× diagonal) below which shapes count as touching: tangent triangles and line pieces may touch
    in the triangulation's conflict loop, and a curve may leave its triangle by this much in ``Mesh.validate``."""
    distinct_rel: float = 1e-9
    """Within one Bézier piece, control points closer than this (× the control polygon's size) coincide
    (end tangents); also the relative zero for curvature and tangent-crossing tests in ``dfc.geometry.bezier``."""
    min_piece_rel: float = 1e-6
    """Clean-up splits no curved piece smaller than this (× diagonal); one that still is not a graph over its
    chord (a cusp) becomes a line."""


tol = Tolerances()
