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
    """A triangle whose doubled area is below this (× diagonal²) counts as degenerate."""


tol = Tolerances()
