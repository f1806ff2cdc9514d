"""Curved constrained triangulation of the domain rectangle (docs/design.md §4), vectorised.

Every line piece becomes exactly one mesh edge and every curved piece lies inside one triangle whose
two corners are the piece's endpoints. The recipe:

1. clean-up (``dfc.geometry.cleanup.clean``): pieces meet only at shared endpoints and every curved piece is a
   convex graph over its chord turning by at most 90°; line pieces longer than the nominal edge length
   are cut into equal parts, so that long straight curves get vertices (and features) along them;
2. *tangent triangles* (A, X, B), X where the end tangents meet, contain their pieces. Conflict loop:
   halve (``dfc.geometry.bezier.split``) every piece whose tangent triangle leaves the domain, overlaps another
   tangent triangle, crosses a line piece or contains a vertex, until none does; then each refinement point
   (``extra_points``) inside a tangent triangle halves that piece once;
3. density: refine a chord-only constrained Delaunay triangulation (pythoncdt) to the size target and
   keep its Steiner points that are off the constraints and outside every tangent triangle;
4. final CDT of the domain border, line pieces and chords; only where the triangle beside a chord does
   not contain its piece, the apex X and the edges AX, XB are added and the CDT is rebuilt.

Size: ``max_area`` (or ``edge_length``) bounds triangle areas, ``grading`` lets the size grow away
from the curves, ``max_triangles`` caps the count. With none of them the target is
``DEFAULT_TRIANGLES`` triangles over the domain (plus what the curves force).
"""

from __future__ import annotations

import time
from dataclasses import replace
from functools import partial

import numpy as np
import pythoncdt as cdt
from scipy.spatial import cKDTree

from ..errors import MeshError, TriangleBudgetError
from . import bezier
from .cleanup import clean
from .curves import Curves, split_pieces
from .mesh import Mesh, min_side_distance
from .plane import closest_on_segments, cross
from .tolerances import tol

__all__ = ["triangulate", "constrained_delaunay", "halving_points", "nominal_edge", "retriangulate",
           "DEFAULT_TRIANGLES", "GRID_SNAP", "STEINER_STEPS_PER_EDGE"]

DEFAULT_TRIANGLES = 2000
"""Triangle count the default density aims at over the whole domain (area bound = domain area / 1000)."""

STEINER_STEPS_PER_EDGE = 8
"""With ``lattice_bits``, free vertices snap to a lattice whose step is at most the nominal edge length over this
(a power of two of grid steps; CHANGELOG.md, "Meshes derived in the decoder")."""

GRID_SNAP = 2.0
"""With ``lattice_bits``, the clean-up merges end points and intersections closer than this many steps of that grid
(or ``tol.snap_rel`` of the diagonal if more): closer curve vertices could round to one grid point."""

_MAX_ROUNDS = 100  # conflict-loop rounds; each halves the offending pieces (pieces that cannot be separated, halved
# down to the merge distance, about 23 halvings from the diagonal, name their conflict: in turns with a neighbour, 70)
_MIN_HALVED_CHORD = 1e-4  # share of the domain's diagonal under which a refinement point halves no piece
_HALVING_TRIANGLES = 4  # triangles a halving may add (its middle vertex and an apex) beyond max_triangles
_MAX_MIN_ANGLE = 34.0  # Ruppert-style refinement terminates for angle bounds below about 34°
_STEINER_PER_AREA = 0.8  # Steiner vertices inserted per (domain area / area bound), measured on pythoncdt
_EQUILATERAL = np.sqrt(3.0) / 4.0  # area of the equilateral triangle with unit edges


def triangulate(
    curves: Curves,
    *,
    max_area: float | None = None,
    edge_length: float | None = None,
    grading: float | None = None,
    max_triangles: int | None = None,
    min_angle: float = 20.0,
    extra_points: np.ndarray | None = None,
    lattice_bits: int | None = None,
    stats: dict | None = None,
) -> Mesh:
    """Curved constrained triangulation of ``curves.domain`` with every piece of ``curves`` built in.

    Parameters
    ----------
    curves : Curves
        The discontinuity curves; cleaned up first (``dfc.geometry.cleanup.clean``).
    max_area : float, optional
        Largest triangle area away from the curves' forced triangles, in domain units².
    edge_length : float, optional
        Target edge length in domain units (an area bound of the equilateral triangle); not with ``max_area``.
    grading : float, optional
        Growth rate ≥ 0 of the target edge length with the distance ``d`` to the curves:
        ``h(d) = h0 + grading * d``; ``None`` or 0 keeps the size uniform.
    max_triangles : int, optional
        Cap on the triangle count: the density is lowered until it fits. Alone, it sets the density.
    min_angle : float
        Smallest-angle target in degrees for the Steiner points (0 to 34; 0 switches it off).
    extra_points : (M, 2) float64, optional
        Error-driven refinement. A point inside a curved piece's tangent triangle halves that piece, once, in order
        (``_halve_at``); the others are further vertices, added to the Steiner points the size knobs give (which
        ``max_triangles`` alone caps) except where one would lie in a tangent triangle, outside the domain's
        interior, or within ``tol.snap_rel`` of the diagonal of an input vertex or constraint.
    lattice_bits : int, optional
        Snap the free vertices (Steiner and ``extra_points``) to a sub-lattice of the ``lattice_bits`` grid of
        ``dfc.io.meshcodec`` (coordinates ``min(k · 2**s, 2**bits - 1)`` grid steps; ``2**s`` steps at most the
        nominal edge length over ``STEINER_STEPS_PER_EDGE``) before the final triangulation, dropping those that then
        coincide, land near a constraint or in a tangent triangle; the vertices on curves keep their positions, but
        the clean-up merges those closer than ``GRID_SNAP`` grid steps.
    stats : dict, optional
        Filled with timings in seconds (``clean_s``, ``conflict_s``, ``density_s``, ``cdt_s``) and counts
        (``pieces_in``, ``pieces_clean``, ``pieces_final``, ``halved``, ``apexes``, ``steiner``, ``vertices``,
        ``triangles``).

    Returns
    -------
    Mesh
        Counter-clockwise triangles; ``validate()`` passes.

    Raises
    ------
    MeshError
        Bad size arguments, pieces that cannot be separated (e.g. two curves tangent at a shared endpoint on the
        same side), or curves that alone need more than ``max_triangles`` triangles.
    """
    if not isinstance(curves, Curves):
        raise MeshError(f"triangulate: expected Curves, got {type(curves).__name__}")
    _check_sizes(max_area, edge_length, grading, max_triangles, min_angle)
    stats = {} if stats is None else stats
    clock = time.perf_counter()
    pieces = clean(curves, tol=_clean_tolerances(curves, lattice_bits))
    pieces = split_pieces(pieces, _line_length(pieces.domain, max_area, edge_length, max_triangles),
                          lines=True, curved=False)
    stats["clean_s"] = time.perf_counter() - clock
    stats["pieces_in"], stats["pieces_clean"] = len(curves), len(pieces)

    clock = time.perf_counter()
    domain, eps = pieces.domain, tol.touch_rel * pieces.diagonal
    lines, line_piece, cp, degree, curve_piece, apex = _separate_pieces(pieces, eps)
    extra = np.zeros((0, 2)) if extra_points is None else np.asarray(extra_points, np.float64).reshape(-1, 2)
    n_pieces = len(cp)
    cp, degree, curve_piece, extra = _halve_at(extra, cp, degree, curve_piece, apex, eps, domain)
    if len(cp) > n_pieces:
        cp, degree, curve_piece, apex = _separate(cp, degree, curve_piece, lines, domain, eps)
    stats["conflict_s"] = time.perf_counter() - clock
    stats["halved"] = len(cp) - n_pieces
    stats["pieces_final"] = len(lines) + len(cp)
    # the Steiner points still make way for the pieces halvings add, but like refinement vertices the halvings
    # themselves may go over the cap
    cap = None if max_triangles is None else max_triangles + _HALVING_TRIANGLES * stats["halved"]

    clock = time.perf_counter()
    points, line_edges, line_piece, chords = _constraint_graph(domain, lines, line_piece, cp)
    tangent = _ccw_triangles(cp[:, 0], apex, cp[:, 3])
    fixed = np.concatenate([line_edges, chords])
    n_border = int(_on_border(points, domain).sum())
    floor_count = 2 * len(points) - n_border - 2
    if cap is not None and floor_count > cap:
        raise TriangleBudgetError(
            f"triangulate: the {len(pieces)} cleaned-up pieces alone need at least {floor_count} triangles, "
            f"more than max_triangles = {max_triangles}", floor_count
        )
    area0, budget = _size_target(domain, max_area, edge_length, max_triangles, floor_count, len(cp))
    target = _target_area(area0, grading, np.concatenate([lines.reshape(-1, 2, 2), cp[:, [0, 3]]]), cp, domain)
    steiner = _steiner_points(points, fixed, domain, tangent, target, area0, budget, min_angle, eps)
    shift = None if lattice_bits is None else _lattice_shift(
        domain, lattice_bits, _line_length(domain, max_area, edge_length, max_triangles))
    if shift is not None:
        steiner = _free_points(_snap(steiner, domain, lattice_bits, shift), points, np.zeros((0, 2)), lines, cp,
                               tangent, domain, eps, border=True)
    stats["density_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    build = partial(_final_mesh, points, line_edges=line_edges, line_piece=line_piece, chords=chords, cp=cp,
                    degree=degree, curve_piece=curve_piece, apex=apex, domain=domain, eps=eps)
    mesh, n_apex, steiner = _within_budget(build, steiner, max_triangles, cap)
    stats["extra"] = 0
    if len(extra):
        if shift is not None:
            extra = _snap(extra, domain, lattice_bits, shift)
        extra = _free_points(extra, points, steiner, lines, cp, tangent, domain, eps)
        if len(extra):
            steiner = np.concatenate([steiner, extra])
            mesh, n_apex = build(steiner)
        stats["extra"] = len(extra)
    stats["cdt_s"] = time.perf_counter() - clock
    stats.update(apexes=n_apex, steiner=len(steiner), vertices=mesh.n_vertices, triangles=mesh.n_triangles)
    return mesh


def _clean_tolerances(curves: Curves, lattice_bits: int | None):
    """``tol`` with ``snap_rel`` raised to ``GRID_SNAP`` steps of the ``lattice_bits`` grid over ``curves.domain``."""
    if lattice_bits is None:
        return tol
    x0, y0, x1, y1 = curves.domain
    step = max(x1 - x0, y1 - y0) / (2.0**lattice_bits - 1.0)
    return replace(tol, snap_rel=max(tol.snap_rel, GRID_SNAP * step / curves.diagonal))


def _separate_pieces(pieces: Curves, eps: float):
    """Line pieces (L, 2, 2) with their piece indices (L,), and the curved pieces after the conflict loop
    (``_separate``): control points (C, 4, 2), degrees, piece indices and tangent-triangle apexes (C, 2)."""
    control_points = _snap_ends_to_border(pieces.control_points, pieces.domain, eps)
    is_line = pieces.degree == 1
    lines = control_points[is_line][:, [0, 3]]
    cp, degree, curve_piece, apex = _separate(
        control_points[~is_line], pieces.degree[~is_line], np.flatnonzero(~is_line), lines, pieces.domain, eps
    )
    return lines, np.flatnonzero(is_line), cp, degree, curve_piece, apex


def _halve_at(points, cp, degree, piece, apex, eps, domain):
    """Refinement along the curves: each of ``points`` (M, 2) that lies in a curved piece's tangent triangle halves
    the first piece (in the current order) whose tangent triangle holds it, the points taken in order, so points
    proposed in the halves of an earlier round's pieces halve those halves (``halving_points``); pieces whose chord
    is under ``_MIN_HALVED_CHORD`` of the domain's diagonal stay whole. ``cp`` (C, 4, 2), ``degree``, ``piece``
    (C,), ``apex`` (C, 2) as ``_separate`` returns them. Returns the pieces' ``cp``, ``degree``, ``piece`` (halves
    in their parent's place) and the points in no tangent triangle (M', 2)."""
    if not len(points) or not len(cp):
        return cp, degree, piece, points
    tri = _ccw_triangles(cp[:, 0], apex, cp[:, 3])
    i, k = _box_pairs(tri.min(axis=1), tri.max(axis=1), points, points)
    held = np.zeros(len(points), dtype=bool)
    held[k[(_signed_edges(tri[i], points[k]) >= -eps).all(axis=1)]] = True
    x0, y0, x1, y1 = domain
    shortest = _MIN_HALVED_CHORD * np.hypot(x1 - x0, y1 - y0)
    for p in points[held]:
        inside = (_signed_edges(tri, np.broadcast_to(p, (len(cp), 2))) >= -eps).all(axis=1)
        inside &= np.hypot(*(cp[:, 3] - cp[:, 0]).T) >= shortest
        if not inside.any():
            continue
        c = int(np.flatnonzero(inside)[0])
        left, right = bezier.split(cp[c : c + 1], np.array([0.5]))
        halves = np.concatenate([left, right])
        x = _apexes(halves)[0]

        def splice(old, new):
            return np.concatenate([old[:c], new, old[c + 1 :]])

        cp, tri = splice(cp, halves), splice(tri, _ccw_triangles(halves[:, 0], x, halves[:, 3]))
        degree, piece = splice(degree, degree[[c, c]]), splice(piece, piece[[c, c]])
    return cp, degree, piece, points[~held]


def halving_points(cp: np.ndarray) -> np.ndarray:
    """(C, 2) float64: for curved pieces ``cp`` (C, 4, 2), the centroid of each one's tangent triangle, the point that
    passed in ``triangulate``'s ``extra_points`` halves that piece."""
    return (cp[:, 0] + cp[:, 3] + _apexes(cp)[0]) / 3.0


def _apexes(cp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(apexes (C, 2), found (C,) bool) of curved pieces ``cp`` (C, 4, 2): ``bezier.tangent_apex``, the chord's
    middle where the end tangents are parallel (``found`` False)."""
    apex = bezier.tangent_apex(cp)
    found = np.isfinite(apex).all(axis=1)
    apex[~found] = 0.5 * (cp[~found, 0] + cp[~found, 3])
    return apex, found


def _join_forks(a, b, apex, found, eps):
    """(apexes (C, 2), moved (C,) bool): two pieces leaving a shared endpoint along one tangent ray (a fork whose
    branches part to either side) have their apexes on that ray, and the nearer would lie on the other's apex edge,
    which no triangulation keeps whole; the nearer moves out to the farther, so the two tangent triangles share that
    edge (a tangent triangle grown along its ray still holds its piece). ``a``, ``b``, ``apex`` (C, 2) end points and
    apexes, ``found`` (C,) whether the apex is the end tangents' meeting point (the others are left alone)."""
    apex, moved = apex.copy(), np.zeros(len(apex), dtype=bool)
    ends = np.concatenate([a, b])
    piece = np.tile(np.arange(len(apex)), 2)
    _, group = np.unique(ends, axis=0, return_inverse=True)
    order = np.argsort(group.reshape(-1), kind="stable")
    group = group.reshape(-1)[order]
    for step in range(1, len(order)):
        same = np.flatnonzero(group[step:] == group[:-step])
        if not len(same):
            break
        i, j = piece[order[same]], piece[order[same + step]]
        at = ends[order[same]]
        keep = found[i] & found[j] & (i != j) & ~moved[i] & ~moved[j]
        i, j, at = i[keep], j[keep], at[keep]
        near_i = np.hypot(*(apex[i] - at).T) <= np.hypot(*(apex[j] - at).T)
        near, far = np.where(near_i, i, j), np.where(near_i, j, i)
        join = closest_on_segments(apex[near], apex[near], at, apex[far])[2] <= eps
        join &= ~np.all(apex[near] == apex[far], axis=1)
        ray = apex[far] - at
        join &= cross(ray, _far_end(a, b, near, at) - at) * cross(ray, _far_end(a, b, far, at) - at) < 0  # either side
        near, far = near[join], far[join]
        near, first = np.unique(near, return_index=True)  # one move per piece and round
        apex[near], moved[near] = apex[far[first]], True
    return apex, moved


def _far_end(a, b, k, at):
    """(K, 2): the end of each piece ``k`` (K,) that is not the point ``at`` (K, 2); ``a``, ``b`` (C, 2) ends."""
    return np.where(np.all(a[k] == at, axis=1)[:, None], b[k], a[k])


def _constraint_graph(domain, lines, line_piece, cp):
    """The CDT's input vertices and constraint edges: (points (V, 2) — the domain's corners and every piece's
    endpoints, deduplicated —, line edges (L, 2) into points (duplicates dropped), their pieces (L,), chords (C, 2))."""
    x0, y0, x1, y1 = domain
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    n_l, n_c = len(lines), len(cp)
    points, inverse = np.unique(
        np.concatenate([corners, lines[:, 0], lines[:, 1], cp[:, 0], cp[:, 3]]), axis=0, return_inverse=True
    )
    inverse = inverse.reshape(-1)
    line_edges = np.stack([inverse[4 : 4 + n_l], inverse[4 + n_l : 4 + 2 * n_l]], axis=1)
    line_edges, first = np.unique(np.sort(line_edges, axis=1), axis=0, return_index=True)
    chords = np.stack([inverse[4 + 2 * n_l : 4 + 2 * n_l + n_c], inverse[4 + 2 * n_l + n_c :]], axis=1)
    return points, line_edges, line_piece[first], chords


def _within_budget(build, steiner: np.ndarray, max_triangles: int | None, cap: int | None = None):
    """(mesh, apexes, Steiner points used): ``build(steiner)``, dropping Steiner points at random (seeded) until the
    mesh has at most ``max_triangles`` triangles; ``TriangleBudgetError`` when the curves alone need more than
    ``cap`` (default ``max_triangles``)."""
    cap = max_triangles if cap is None else cap
    mesh, n_apex = build(steiner)
    while max_triangles is not None and mesh.n_triangles > max_triangles and len(steiner):
        keep = max(0, len(steiner) - (mesh.n_triangles - max_triangles + 1) // 2 - 1)
        steiner = steiner[np.sort(np.random.default_rng(0).permutation(len(steiner))[:keep])]
        mesh, n_apex = build(steiner)
    if cap is not None and mesh.n_triangles > cap:
        raise TriangleBudgetError(
            f"triangulate: the curves alone need {mesh.n_triangles} triangles, more than max_triangles = {max_triangles}",
            mesh.n_triangles,
        )
    return mesh, n_apex, steiner


def _free_points(extra, points, steiner, lines, cp, tangent, domain, eps, border=False) -> np.ndarray:
    """The points of ``extra`` (M, 2) strictly inside the domain (``border``: or exactly on its border), outside every
    tangent triangle (C, 3, 2) and farther than ``tol.snap_rel`` of the diagonal from the vertices (``points``,
    ``steiner``), line pieces (L, 2, 2), curved pieces' chords and from each other (the first of two close points is
    kept)."""
    x0, y0, x1, y1 = domain
    gap = tol.snap_rel * float(np.hypot(x1 - x0, y1 - y0))
    keep = (extra[:, 0] > x0 + gap) & (extra[:, 0] < x1 - gap) & (extra[:, 1] > y0 + gap) & (extra[:, 1] < y1 - gap)
    if border:
        inside = (extra[:, 0] >= x0) & (extra[:, 0] <= x1) & (extra[:, 1] >= y0) & (extra[:, 1] <= y1)
        keep |= inside & _on_border(extra, domain)
    if len(tangent):
        lo, hi = tangent.min(axis=1), tangent.max(axis=1)
        i, k = _box_pairs(lo, hi, extra, extra)
        keep[k[(_signed_edges(tangent[i], extra[k]) >= -eps).all(axis=1)]] = False
    extra = extra[keep]
    near = cKDTree(np.concatenate([points, steiner])).query(extra)[0] if len(extra) else np.zeros(0)
    extra = extra[near > gap]
    segments = np.concatenate([lines.reshape(-1, 2, 2), cp[:, [0, 3]]])
    if len(segments) and len(extra):
        a, b = segments[:, 0], segments[:, 1]
        lo, hi = np.minimum(a, b) - gap, np.maximum(a, b) + gap
        i, k = _box_pairs(lo, hi, extra, extra)
        d = b[i] - a[i]
        t = np.clip(np.einsum("nd,nd->n", extra[k] - a[i], d) / np.maximum(np.einsum("nd,nd->n", d, d), 1e-300), 0, 1)
        close = np.hypot(*(a[i] + t[:, None] * d - extra[k]).T) <= gap
        drop = np.zeros(len(extra), bool)
        drop[k[close]] = True
        extra = extra[~drop]
    if len(extra) > 1:
        pairs = cKDTree(extra).query_pairs(gap, output_type="ndarray")
        drop = np.zeros(len(extra), bool)
        drop[pairs.max(axis=1)] = True
        extra = extra[~drop]
    return extra


def _lattice_shift(domain, bits: int, edge: float) -> int | None:
    """``s`` of the free vertices' lattice (``triangulate``'s ``lattice_bits``): the largest with ``2**s`` grid steps
    at most ``edge / STEINER_STEPS_PER_EDGE`` along the longer side, at most ``bits - 1``; None below 2 steps."""
    if not 2 <= bits <= 23:
        raise MeshError(f"triangulate: lattice_bits must be in 2..23, got {bits!r}")
    x0, y0, x1, y1 = domain
    steps = edge / STEINER_STEPS_PER_EDGE * (2**bits - 1) / max(x1 - x0, y1 - y0)
    if not steps >= 2.0:
        return None
    return min(int(np.floor(np.log2(steps))), bits - 1)


def _snap(p: np.ndarray, domain, bits: int, shift: int) -> np.ndarray:
    """Points (N, 2) moved to the nearest lattice point ``min(k · 2**shift, M)`` grid steps (``M = 2**bits - 1``),
    in domain coordinates exactly as ``dfc.io.meshcodec`` decodes grid integers (spec/dfield.md §1)."""
    M = 2**bits - 1
    lo, hi = np.array(domain[:2], np.float64), np.array(domain[2:], np.float64)
    q = np.clip(np.rint((p - lo) / (hi - lo) * M), 0, M)
    k = np.rint(q / 2.0**shift)
    t = np.minimum(k * 2.0**shift, M) / M
    return (1.0 - t) * lo + t * hi


def _snap_ends_to_border(cp, domain, eps) -> np.ndarray:
    """Copy of cp (P, 4, 2) with end-point coordinates within ``eps`` of a domain side set exactly onto it."""
    cp = cp.copy()
    ends = cp[:, [0, 3]]
    for axis, value in ((0, domain[0]), (1, domain[1]), (0, domain[2]), (1, domain[3])):
        coord = ends[..., axis]
        coord[np.abs(coord - value) <= eps] = value
    cp[:, [0, 3]] = ends
    return cp


def _check_sizes(max_area, edge_length, grading, max_triangles, min_angle) -> None:
    def positive(name, value):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise MeshError(f"triangulate: {name} must be a positive number, got {value!r}")

    positive("max_area", max_area)
    positive("edge_length", edge_length)
    if max_area is not None and edge_length is not None:
        raise MeshError("triangulate: give max_area or edge_length, not both")
    if grading is not None and not (np.isfinite(grading) and grading >= 0):
        raise MeshError(f"triangulate: grading must be a number >= 0, got {grading!r}")
    if max_triangles is not None and not (int(max_triangles) == max_triangles and max_triangles >= 2):
        raise MeshError(f"triangulate: max_triangles must be an integer >= 2, got {max_triangles!r}")
    if not (0.0 <= min_angle <= _MAX_MIN_ANGLE):
        raise MeshError(f"triangulate: min_angle must be in [0, {_MAX_MIN_ANGLE}] degrees, got {min_angle!r}")


def nominal_edge(domain, n_triangles: int | None = None) -> float:
    """Nominal edge length of a mesh of ``n_triangles`` (None: ``DEFAULT_TRIANGLES``) over the rectangle ``domain``
    (x0, y0, x1, y1): the edge of an equilateral triangle of the domain's area over ``n_triangles``."""
    x0, y0, x1, y1 = domain
    return float(np.sqrt((x1 - x0) * (y1 - y0) / (n_triangles or DEFAULT_TRIANGLES) / _EQUILATERAL))


def _line_length(domain, max_area, edge_length, max_triangles) -> float:
    """Longest line piece kept whole: the nominal edge length of the size target (an equilateral triangle of
    ``max_area``, or ``nominal_edge`` of ``max_triangles``). A line piece is one mesh edge, so a longer one would
    leave the field along it only its two end vertices' features."""
    if edge_length is not None:
        return float(edge_length)
    if max_area:
        return float(np.sqrt(max_area / _EQUILATERAL))
    return nominal_edge(domain, max_triangles)


def _size_target(domain, max_area, edge_length, max_triangles, floor_count, n_curved) -> tuple[float, int]:
    """Area bound near the curves and the most Steiner points allowed (-1: no limit)."""
    x0, y0, x1, y1 = domain
    area = (x1 - x0) * (y1 - y0)
    if max_area is not None:
        area0 = float(max_area)
    elif edge_length is not None:
        area0 = _EQUILATERAL * float(edge_length) ** 2
    elif max_triangles is not None:
        area0 = 0.0
    else:
        area0 = area / (DEFAULT_TRIANGLES / 2)
    if max_triangles is None:
        return area0, -1
    # each interior vertex adds two triangles; keep a reserve for the apexes (about 7 % of curved pieces)
    budget = max(0, (int(max_triangles) - floor_count) // 2 - int(np.ceil(0.1 * n_curved)))
    area0 = max(area0, _STEINER_PER_AREA * area / max(budget, 1))
    return area0, budget


def _target_area(area0: float, grading, segments: np.ndarray, cp: np.ndarray, domain):
    """Target area as a function of position, (N, 2) float64 -> (N,) float64 domain units²; None when uniform."""
    if not grading:
        return None
    x0, y0, x1, y1 = domain
    cap = (x1 - x0) * (y1 - y0) / 4.0
    h0 = np.sqrt(area0 / _EQUILATERAL)
    # sample the pieces every h0 / 2 (chords for lines, 16 points for curves) for a distance look-up
    a, b = segments[:, 0], segments[:, 1]
    n = np.maximum(1, np.ceil(2.0 * np.hypot(*(b - a).T) / h0)).astype(np.int64)
    n = np.minimum(n, 4096)
    s = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    t = (s / np.repeat(n, n))[:, None]
    idx = np.repeat(np.arange(len(segments)), n)
    samples = [a[idx] + t * (b - a)[idx]]
    if len(cp):
        samples.append(bezier.flatten(cp, 16).reshape(-1, 2))
    samples.append(np.array([[x0, y0]]) if not len(segments) else segments[:1, 0])
    tree = cKDTree(np.concatenate(samples))

    def target(xy):
        d, _ = tree.query(xy)
        return np.minimum(_EQUILATERAL * (h0 + grading * d) ** 2, cap)

    return target


# ---------------------------------------------------------------------------------------------- conflict loop


def _separate(cp, degree, piece, lines, domain, eps):
    """Halve curved pieces until their tangent triangles are free of conflicts.

    cp : (C, 4, 2) float64; degree, piece : (C,); lines : (L, 2, 2) float64 line pieces
    returns cp, degree, piece of the halved pieces and their apexes (C', 2) float64 (clamped into the domain)

    Each round checks only the *active* pieces: the halves of the last round's bad pieces and the pieces that were
    in a conflict without being halved. A piece in no conflict stays out of conflicts (halves lie inside their
    parent's tangent triangle), so rounds after the first cost what the few halved pieces cost; when the active
    pieces are free of conflicts, a last check of every piece confirms it (and restarts the loop if it does not).
    """
    x0, y0, x1, y1 = domain
    lo_d, hi_d = np.array([x0, y0]), np.array([x1, y1])
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    min_chord = tol.snap_rel * np.hypot(x1 - x0, y1 - y0)
    seg_lo, seg_hi = lines.min(axis=1), lines.max(axis=1)
    active = np.ones(len(cp), dtype=bool)
    for _ in range(_MAX_ROUNDS):
        a, b = cp[:, 0], cp[:, 3]
        apex, found = _apexes(cp)
        apex, moved = _join_forks(a, b, apex, found, eps)
        bad = ~found | ((apex < lo_d - eps) | (apex > hi_d + eps)).any(axis=1)
        tri = _ccw_triangles(a, apex, b)
        lo, hi = tri.min(axis=1), tri.max(axis=1)
        check = np.flatnonzero(active | moved)
        conflict = np.zeros(len(cp), dtype=bool)

        oi, oj = _box_pairs(lo[check], hi[check], lo[check], hi[check], same=True)
        oi, oj = check[oi], check[oj]
        hit = ~(_separated(tri[oi], tri[oj], eps) | _separated(tri[oj], tri[oi], eps))
        oi, oj = oi[hit], oj[hit]
        conflict[oi] = conflict[oj] = True
        li, lj = np.hypot(*(b[oi] - a[oi]).T), np.hypot(*(b[oj] - a[oj]).T)
        bad[oi[li >= 0.5 * lj]] = True
        bad[oj[lj >= 0.5 * li]] = True

        i, k = _box_pairs(lo[check], hi[check], seg_lo, seg_hi)
        i = check[i]
        seg = lines[k]
        d = _signed(seg[:, 0], seg[:, 1], tri[i])
        apart = _separated(tri[i], seg, eps) | (d.max(axis=1) <= eps) | (d.min(axis=1) >= -eps)
        bad[i[~apart]] = True
        on_line = closest_on_segments(apex[i], apex[i], seg[:, 0], seg[:, 1])[2] <= eps
        bad[i[on_line]] = True  # an apex (a CDT vertex) on a line splits it

        points = np.unique(np.concatenate([corners, lines.reshape(-1, 2), a, b]), axis=0)
        i, k = _box_pairs(lo[check], hi[check], points, points)
        i = check[i]
        p = points[k]
        own = (p == a[i]).all(axis=1) | (p == b[i]).all(axis=1)
        inside = (_signed_edges(tri[i], p) >= -eps).all(axis=1) & ~own
        bad[i[inside]] = True

        bad &= active
        if not bad.any():
            if active.all():
                return cp, degree, piece, np.clip(apex, lo_d, hi_d)
            active[:] = True  # confirm with every piece
            continue
        short = bad & (np.hypot(*(b - a).T) < min_chord)
        if short.any():
            c = int(np.flatnonzero(short)[0])
            raise MeshError(_separation_failure(cp, piece, c, oi, oj))
        left, right = bezier.split(cp[bad], np.full(int(bad.sum()), 0.5))
        cp = np.concatenate([cp[~bad], left, right])
        degree = np.concatenate([degree[~bad], degree[bad], degree[bad]])
        piece = np.concatenate([piece[~bad], piece[bad], piece[bad]])
        active = np.concatenate([conflict[~bad], np.ones(2 * int(bad.sum()), dtype=bool)])
    raise MeshError(f"triangulate: tangent triangles still conflict after {_MAX_ROUNDS} rounds of halving")


def _separation_failure(cp, piece, c, oi, oj) -> str:
    """Message when piece ``c`` cannot be halved any more; ``oi, oj`` (K,) are the overlapping pairs."""
    t0, t1 = bezier.end_tangents(cp)
    ends, away = (cp[:, 0], cp[:, 3]), (t0, -t1)  # unit tangents pointing away from each end
    for e in range(2):
        for f in range(2):
            same = (ends[e][oi] == ends[f][oj]).all(axis=1)
            u, v = away[e][oi], away[f][oj]
            tangent = same & (np.abs(cross(u, v)) < np.sqrt(tol.distinct_rel)) & ((u * v).sum(axis=1) > 0)
            if tangent.any():
                k = int(np.flatnonzero(tangent)[0])
                return (
                    f"triangulate: curved pieces {int(piece[oi[k]])} and {int(piece[oj[k]])} are tangent at their "
                    f"shared endpoint {_xy(ends[e][oi[k]])}; no triangle can hold either"
                )
    return (
        f"triangulate: cannot separate the tangent triangle of curved piece {int(piece[c])} near {_xy(cp[c, 0])} "
        "from its neighbours"
    )


def _ccw_triangles(a, x, b) -> np.ndarray:
    """Triangles (A, X, B) as counter-clockwise corner stacks: (N, 2) each -> (N, 3, 2)."""
    left = cross(b - a, x - a) > 0
    return np.where(left[:, None, None], np.stack([a, b, x], axis=1), np.stack([a, x, b], axis=1))


def _signed(p, q, pts) -> np.ndarray:
    """Signed distances of pts (N, K, 2) to the lines p -> q ((N, 2) each), left positive -> (N, K)."""
    d = q - p
    return cross(d[:, None], pts - p[:, None]) / np.hypot(*d.T)[:, None]


def _signed_edges(tri, p) -> np.ndarray:
    """Signed distances of points p (N, 2) to the three edges of CCW triangles (N, 3, 2) -> (N, 3)."""
    return np.stack([_signed(tri[:, k], tri[:, (k + 1) % 3], p[:, None])[:, 0] for k in range(3)], axis=1)


def _separated(tri, other, eps) -> np.ndarray:
    """Whether an edge line of CCW triangles (N, 3, 2) has all points of ``other`` (N, K, 2) outside (within eps)."""
    out = np.zeros(len(tri), dtype=bool)
    for k in range(3):
        out |= _signed(tri[:, k], tri[:, (k + 1) % 3], other).max(axis=1) <= eps
    return out


def _box_pairs(lo_a, hi_a, lo_b, hi_b, *, same=False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs of overlapping closed boxes, found through a hierarchy of uniform grids.

    Each box goes to the level whose cell is at least its size; two levels meet on the coarser one's grid,
    where every box covers at most 2 × 2 cells, so the work follows the output even for mixed sizes.
    lo_a, hi_a : (A, 2) float64 box corners; lo_b, hi_b : (B, 2) float64
    same : the two sets are one set; only pairs i < j are returned
    returns i, j : (K,) int64
    """
    empty = np.zeros(0, dtype=np.int64)
    if not len(lo_a) or not len(lo_b):
        return empty, empty
    origin = np.minimum(lo_a.min(axis=0), lo_b.min(axis=0))
    span = float((np.maximum(hi_a.max(axis=0), hi_b.max(axis=0)) - origin).max())
    base = max(span / 65536.0, np.finfo(float).tiny)

    def level(lo, hi):
        return np.ceil(np.log2(np.maximum((hi - lo).max(axis=1), base) / base)).astype(np.int64)

    level_a, level_b = level(lo_a, hi_a), level(lo_b, hi_b)
    out_i, out_j = [], []
    for la in np.unique(level_a):
        ia = np.flatnonzero(level_a == la)
        for lb in np.unique(level_b):
            if same and lb < la:
                continue
            jb = np.flatnonzero(level_b == lb)
            i, j = _grid_join(lo_a[ia], hi_a[ia], lo_b[jb], hi_b[jb], origin, base * 2.0 ** max(la, lb))
            i, j = ia[i], jb[j]
            if same and la == lb:  # found both ways round
                keep = i < j
                i, j = i[keep], j[keep]
            elif same:
                i, j = np.minimum(i, j), np.maximum(i, j)
            out_i.append(i)
            out_j.append(j)
    return np.concatenate(out_i), np.concatenate(out_j)


def _grid_join(lo_a, hi_a, lo_b, hi_b, origin, cell) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping pairs of boxes on one grid of square cells; each pair is reported once."""
    top = np.maximum(hi_a.max(axis=0), hi_b.max(axis=0))
    rows = int((top[1] - origin[1]) / cell) + 2

    def cells(lo, hi):
        i0 = np.floor((lo - origin) / cell).astype(np.int64)
        n = np.floor((hi - origin) / cell).astype(np.int64) - i0 + 1
        count = n[:, 0] * n[:, 1]
        box = np.repeat(np.arange(len(lo)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        nx = n[box, 0]
        return box, (i0[box, 0] + k % nx) * rows + i0[box, 1] + k // nx

    box_a, key_a = cells(lo_a, hi_a)
    box_b, key_b = cells(lo_b, hi_b)
    order = np.argsort(key_b, kind="stable")
    box_b, key_b = box_b[order], key_b[order]
    start, stop = np.searchsorted(key_b, key_a, "left"), np.searchsorted(key_b, key_a, "right")
    count = stop - start
    i, key = np.repeat(box_a, count), np.repeat(key_a, count)
    j = box_b[np.repeat(start, count) + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)]
    # report each pair once: in the cell holding the lower-left corner of the two boxes' intersection
    ref = np.floor((np.maximum(lo_a[i], lo_b[j]) - origin) / cell).astype(np.int64)
    keep = (ref[:, 0] * rows + ref[:, 1] == key) & (lo_a[i] <= hi_b[j]).all(axis=1) & (lo_b[j] <= hi_a[i]).all(axis=1)
    return i[keep], j[keep]


# ---------------------------------------------------------------------------------------------- CDT


def _on_border(points, domain) -> np.ndarray:
    x0, y0, x1, y1 = domain
    return (points[:, 0] == x0) | (points[:, 0] == x1) | (points[:, 1] == y0) | (points[:, 1] == y1)


def _border_edges(points, domain) -> np.ndarray:
    """Chains of the points lying exactly on each side of the domain: (K, 2) int64 vertex pairs."""
    x0, y0, x1, y1 = domain
    out = []
    for axis, value in ((1, y0), (0, x1), (1, y1), (0, x0)):
        on = np.flatnonzero(points[:, axis] == value)
        on = on[np.argsort(points[on, 1 - axis], kind="stable")]
        out.append(np.stack([on[:-1], on[1:]], axis=1))
    return np.concatenate(out)


def _cdt(points, edges, domain) -> cdt.Triangulation:
    """Constrained Delaunay triangulation (not finalised) of points (N, 2) with edges (K, 2) and the border."""
    x0, y0, x1, y1 = domain
    t = cdt.Triangulation(
        cdt.VertexInsertionOrder.AS_PROVIDED,
        cdt.IntersectingConstraintEdges.TRY_RESOLVE,
        tol.cdt_min_dist_rel * float(np.hypot(x1 - x0, y1 - y0)),
    )
    t.insert_vertices(np.ascontiguousarray(points, dtype=np.float64))
    all_edges = np.concatenate([_border_edges(points, domain), edges.reshape(-1, 2)])
    t.insert_edges(np.ascontiguousarray(all_edges, dtype=np.uint32))
    return t


def constrained_delaunay(points: np.ndarray, edges: np.ndarray, domain) -> np.ndarray:
    """Triangles (T, 3) int64, counter-clockwise, of the constrained Delaunay triangulation of ``points`` (V, 2)
    float64 (inside the closed ``domain``, distinct) with the constraint ``edges`` (K, 2) int64 and the chains of
    points on each side of the domain, as pythoncdt computes it (points inserted in the given order).

    Raises ``MeshError`` when constraints cross or a point lies on a constraint (the triangulation would need a
    vertex that is not in ``points`` or would split an edge), or when the triangles do not cover every point."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    t = _cdt(points, np.asarray(edges, np.int64).reshape(-1, 2), domain)
    t.erase_outer_triangles()
    _check_constraints_kept(t, points, domain)
    v, tri = _arrays(t)
    p = v[tri]
    flip = cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) < 0
    tri[flip] = tri[flip][:, ::-1]
    if len(np.unique(tri)) != len(points):
        raise MeshError("triangulate: a point is in no triangle of the constrained Delaunay triangulation")
    return tri


def retriangulate(mesh: Mesh, vertices: np.ndarray) -> Mesh:
    """``mesh`` with its vertices moved to ``vertices`` (V, 2) float64 (distinct, in the domain; a small move, such as
    rounding to a storage grid) and its triangles rebuilt as the constrained Delaunay triangulation of them, the
    constraints being the discontinuous edges and every edge of the curved triangles. Each curved piece moves with
    its old triangle (its inner control points keep their barycentric coordinates in it); the vertex order and every
    index into the vertices are kept. Where the move turns a thin triangle over, the new mesh simply has a
    different triangle there. Raises ``MeshError`` when the moved constraints cross or a vertex lands on one."""
    v = np.asarray(vertices, np.float64)
    old = np.asarray(mesh.vertices, np.float64)
    ctri = np.asarray(mesh.triangles, np.int64)[np.asarray(mesh.curved_triangles, np.int64)]
    ring = np.concatenate([ctri[:, [0, 1]], ctri[:, [1, 2]], ctri[:, [2, 0]]])
    tri = constrained_delaunay(v, np.concatenate([np.asarray(mesh.disc_edges, np.int64).reshape(-1, 2), ring]),
                               mesh.domain)
    cp = np.array(mesh.curve_control_points, np.float64)
    moved = (v[ctri] != old[ctri]).any(axis=(1, 2))  # pieces whose triangle stays keep their control points exactly
    if moved.any():
        t = ctri[moved]
        a, b, c = (old[t[:, k]] for k in range(3))
        d, e, inner = (b - a)[:, None], (c - a)[:, None], cp[moved, 1:3] - a[:, None]
        det = cross(d, e)
        u, w = cross(inner, e) / det, cross(d, inner) / det  # (M, 2): inner = a + u d + w e
        na, nb, nc = (v[t[:, k]] for k in range(3))
        cp[moved, 1:3] = na[:, None] + u[..., None] * (nb - na)[:, None] + w[..., None] * (nc - na)[:, None]
        ends = np.asarray(mesh.curve_endpoints, np.int64)[moved]
        cp[moved, 0], cp[moved, 3] = v[ends[:, 0]], v[ends[:, 1]]
    holder = _chord_triangles(tri, np.asarray(mesh.curve_endpoints, np.int64).reshape(-1, 2), cp, len(v))
    return Mesh(domain=mesh.domain, vertices=v, triangles=tri, disc_edges=mesh.disc_edges,
                curved_triangles=holder, curve_endpoints=mesh.curve_endpoints, curve_control_points=cp,
                curve_degree=mesh.curve_degree, disc_edge_piece=mesh.disc_edge_piece, curve_piece=mesh.curve_piece)


def _arrays(t: cdt.Triangulation) -> tuple[np.ndarray, np.ndarray]:
    v = t.vertices_array()
    return np.stack([v["x"], v["y"]], axis=1), t.triangles_array()["vertices"].astype(np.int64)


def _steiner_points(points, fixed, domain, tangent, target, area0, budget, min_angle, eps) -> np.ndarray:
    """Interior points (S, 2) float64 of a refined chord-only CDT, off the constraints and the tangent triangles."""
    t = _cdt(points, fixed, domain)
    n0 = 3 + len(points)  # pythoncdt keeps the three super-triangle vertices first until it is finalised
    x0, y0, x1, y1 = domain
    levels = [area0]
    while target is not None and levels[-1] * 4.0 < (x1 - x0) * (y1 - y0) / 4.0:
        levels.append(levels[-1] * 4.0)
    h_min = 0.25 * np.sqrt(area0 / _EQUILATERAL)
    limit = budget if budget >= 0 else np.iinfo(np.int32).max

    def left():
        return int(limit - (t.vertices_count() - n0))

    for k, level in enumerate(reversed(levels)):
        if left() <= 0:
            break
        freeze = t.collect_outer_triangles()
        if len(levels) > 1:
            v, tri = _arrays(t)
            coarse = np.flatnonzero(target(v[tri].mean(axis=1)) >= 4.0 * level)
            freeze |= set(coarse.tolist()) if k else set()
        t.refine_triangles(left(), cdt.RefinementCriterion.LARGEST_AREA, level, to_erase=freeze, min_edge_length=h_min)
    if min_angle > 0 and left() > 0:
        t.refine_triangles(
            left(), cdt.RefinementCriterion.SMALLEST_ANGLE, cdt.deg_to_rad(min_angle),
            to_erase=t.collect_outer_triangles(), min_edge_length=h_min,
        )
    v, _ = _arrays(t)
    on_edge = np.zeros(len(v), dtype=bool)
    fixed_now = np.array([(e.v1, e.v2) for e in t.fixed_edges_iter()], dtype=np.int64).reshape(-1, 2)
    on_edge[fixed_now.ravel()] = True
    new = np.arange(n0, len(v))
    new = new[~on_edge[new] | _on_border(v[new], domain)]
    pts = v[new]
    lo, hi = tangent.min(axis=1), tangent.max(axis=1)
    i, k = _box_pairs(lo, hi, pts, pts)
    inside = (_signed_edges(tangent[i], pts[k]) >= -eps).all(axis=1)
    drop = np.zeros(len(pts), dtype=bool)
    drop[k[inside]] = True
    return pts[~drop]


def _final_mesh(points, steiner, line_edges, line_piece, chords, cp, degree, curve_piece, apex, domain, eps):
    """Build the final CDT, adding apexes where a chord's triangle does not contain its piece.

    returns Mesh, number of apexes inserted
    """
    base = np.concatenate([points, steiner])
    edges = np.concatenate([line_edges, chords])
    need = np.zeros(len(cp), dtype=bool)
    while True:  # terminates: every pass adds apexes, and a piece with its apex is alone in its tangent triangle
        src = np.flatnonzero(need)
        unique_apex, ids = np.unique(apex[src], axis=0, return_inverse=True)  # touching tangent triangles share X
        ids = len(base) + ids.reshape(-1)
        apex_edges = np.concatenate([np.stack([chords[src, 0], ids], 1), np.stack([ids, chords[src, 1]], 1)])
        v = np.concatenate([base, unique_apex])
        tri = constrained_delaunay(v, np.concatenate([edges, apex_edges]), domain)
        holder = _chord_triangles(tri, chords, cp, len(v))
        corner = v[tri[holder]]
        dist = np.stack([min_side_distance(cp, corner[:, k], corner[:, (k + 1) % 3]) for k in range(3)], axis=1)
        shared = np.ones(len(cp), dtype=bool)  # all but one of the pieces sharing a triangle
        shared[np.unique(holder, return_index=True)[1]] = False
        missing = (dist.min(axis=1) < -eps) | shared
        if not missing.any():
            break
        if need[missing].any():
            c = int(np.flatnonzero(missing & need)[0])
            raise MeshError(
                f"triangulate: curved piece {int(curve_piece[c])} near {_xy(cp[c, 0])} is not alone in its tangent triangle"
            )
        need |= missing
    mesh = Mesh(
        domain=domain,
        vertices=v,
        triangles=tri,
        disc_edges=line_edges.astype(np.int64),
        curved_triangles=holder.astype(np.int64),
        curve_endpoints=chords.astype(np.int64),
        curve_control_points=cp,
        curve_degree=degree.astype(np.int8),
        disc_edge_piece=line_piece.astype(np.int64),
        curve_piece=curve_piece.astype(np.int64),
    )
    return mesh, int(need.sum())


def _check_constraints_kept(t, pts, domain) -> None:
    """Raise if the CDT added vertices (crossing constraints) or split a line piece, chord or apex edge."""
    if t.vertices_count() != len(pts):
        extra = _arrays(t)[0][len(pts)]
        raise MeshError(f"triangulate: constraint edges cross near {_xy(extra)} (clean-up left an intersection)")
    x0, y0, x1, y1 = domain
    for _, originals in t.piece_to_originals_iter():
        for e in originals:
            ab = pts[[e.v1, e.v2]]
            if not ((ab[:, 0] == x0).all() or (ab[:, 0] == x1).all() or (ab[:, 1] == y0).all() or (ab[:, 1] == y1).all()):
                raise MeshError(f"triangulate: a vertex lies on the edge {_xy(ab[0])} - {_xy(ab[1])}, which would be split")


def _chord_triangles(tri, chords, cp, n) -> np.ndarray:
    """Index of the triangle on the curved side of each chord: tri (T, 3) CCW, chords (C, 2) -> (C,) int64."""
    if not len(chords):
        return np.zeros(0, dtype=np.int64)
    directed = tri[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = directed[:, 0] * np.int64(n) + directed[:, 1]
    order = np.argsort(key)
    a, b = cp[:, 0], cp[:, 3]
    mid = bezier.evaluate(cp, np.full(len(cp), 0.5))
    left = cross(b - a, mid - a) > 0
    want = np.where(left, chords[:, 0] * np.int64(n) + chords[:, 1], chords[:, 1] * np.int64(n) + chords[:, 0])
    pos = np.minimum(np.searchsorted(key[order], want), len(key) - 1)
    found = key[order][pos] == want
    if not found.all():
        c = int(np.flatnonzero(~found)[0])
        raise MeshError(f"triangulate: the chord of the curved piece at {_xy(a[c])} - {_xy(b[c])} is not a mesh edge")
    return order[pos] // 3


def _xy(p) -> str:
    return f"({p[0]:.9g}, {p[1]:.9g})"
