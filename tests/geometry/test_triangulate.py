"""Tests of dfc.geometry.triangulate: fuzzed curve sets mesh, validate and keep every piece of the input."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from dfc.errors import MeshError, TriangleBudgetError
from dfc.geometry import bezier
from dfc.geometry.curves import Curves, elevate
from dfc.geometry.sources import read_curves
from dfc.geometry.triangulate import _box_pairs, halving_points, triangulate

DOMAIN = (0.0, 0.0, 4.0, 3.0)


def make_curves(pieces: list[tuple[int, list[tuple[float, float]]]], domain=DOMAIN) -> Curves:
    """Curves from [(degree, control points of that degree)], one input curve per piece."""
    cp = np.stack([elevate(np.array([pts], dtype=np.float64), deg)[0] for deg, pts in pieces])
    n = len(pieces)
    return Curves(domain, cp, [deg for deg, _ in pieces], np.arange(n), np.tile([0.0, 1.0], (n, 1)),
                  [f"piece {i}" for i in range(n)], [None] * n)


def mesh_pieces(mesh) -> np.ndarray:
    """Every discontinuity of the mesh as cubic control points (K, 4, 2)."""
    lines = elevate(mesh.vertices[mesh.disc_edges], 1)
    return np.concatenate([lines, mesh.curve_control_points])


def samples(cp: np.ndarray, spacing: float) -> np.ndarray:
    """Points along each piece, at most about ``spacing`` apart (control-polygon length / spacing per piece)."""
    length = np.hypot(*np.diff(cp, axis=1).transpose(2, 0, 1)).sum(axis=1)
    n = np.ceil(length / spacing).astype(np.int64) + 1
    idx = np.repeat(np.arange(len(cp)), n + 1)
    t = (np.arange(idx.size) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)) / np.repeat(n, n + 1)
    return bezier.evaluate(cp[idx], t)


def assert_same_drawing(curves: Curves, mesh, tolerance: float) -> None:
    """The mesh's discontinuities and the input clipped to the domain cover each other (sampled)."""
    x0, y0, x1, y1 = curves.domain
    ours = mesh_pieces(mesh)
    cp = curves.control_points
    # a speck (a piece within ``tolerance``) may shrink to nothing in the clean-up or stay as a short line: the mesh
    # need not draw it, but what the mesh draws is measured against every input piece
    pts = samples(cp[np.ptp(cp, axis=1).max(axis=1) > tolerance], tolerance / 2)
    inside = (pts[:, 0] > x0 + tolerance) & (pts[:, 0] < x1 - tolerance) & (pts[:, 1] > y0 + tolerance) & (pts[:, 1] < y1 - tolerance)
    if not len(ours):
        assert not inside.any(), "the mesh lost every input curve"
        return
    # mesh -> input
    d, _ = cKDTree(samples(cp, tolerance / 2)).query(samples(ours, tolerance))
    assert d.max() < tolerance, f"a mesh discontinuity is {d.max():.3g} away from every input curve"
    # input (inside the domain, away from the border) -> mesh
    if inside.any():
        d, _ = cKDTree(samples(ours, tolerance / 2)).query(pts[inside])
        assert d.max() < tolerance, f"an input point is {d.max():.3g} away from the mesh's discontinuities"


# ---------------------------------------------------------------------------------------------- fuzzing

# coordinates snap to a coarse lattice half of the time, so that endpoints are shared and junctions form
_lattice = st.integers(-1, 9).map(lambda k: k * 0.5)
_free = st.floats(-0.5, 4.5, allow_nan=False)
_coord = st.one_of(_lattice, _free)
_point = st.tuples(_coord, _coord.map(lambda v: v * 0.75))
_piece = st.integers(1, 3).flatmap(lambda deg: st.tuples(st.just(deg), st.lists(_point, min_size=deg + 1, max_size=deg + 1)))


@st.composite
def curve_sets(draw):
    pieces = draw(st.lists(_piece, min_size=1, max_size=10))
    kind = draw(st.sampled_from(["plain", "loop", "lens", "near_parallel", "tip"]))
    if kind == "loop":  # a closed chain of cubics
        c = np.array(draw(st.tuples(st.floats(1.0, 3.0), st.floats(0.8, 2.2))))
        r = draw(st.floats(0.2, 0.8))
        k = np.array([0.0, 0.5523, 1.0])
        quarter = [[(1, 0), (1, k[1]), (k[1], 1), (0, 1)]]
        for q in range(4):
            rot = np.array([[np.cos(q * np.pi / 2), -np.sin(q * np.pi / 2)], [np.sin(q * np.pi / 2), np.cos(q * np.pi / 2)]])
            pts = (np.array(quarter[0]) @ rot.T) * r + c
            pieces.append((3, [tuple(p) for p in pts]))
    elif kind == "lens":  # two curves between the same endpoints
        a, b = draw(_point), draw(_point)
        m = 0.5 * (np.array(a) + np.array(b))
        off = draw(st.floats(0.1, 1.0))
        pieces += [(2, [a, tuple(m + off), b]), (2, [a, tuple(m - off), b])]
    elif kind == "near_parallel":
        a, b = np.array(draw(_point)), np.array(draw(_point))
        gap = draw(st.floats(1e-6, 1e-2))
        pieces += [(1, [tuple(a), tuple(b)]), (2, [tuple(a + gap), tuple(0.5 * (a + b) + [gap, 2 * gap]), tuple(b + gap)])]
    elif kind == "tip":  # an open stroke ending inside the domain, nearly straight
        a = np.array(draw(_point))
        pieces.append((3, [tuple(a), tuple(a + [0.3, 0.001]), tuple(a + [0.6, -0.001]), tuple(a + [0.9, 0.0])]))
    return make_curves(pieces)


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(curves=curve_sets(), density=st.sampled_from([None, 0.05, 0.5]))
def test_fuzzed_curves_mesh_validate_and_keep_every_piece(curves, density):
    assert_meshes(curves, density)


def assert_meshes(curves: Curves, density: float | None) -> None:
    """``curves`` mesh at the area bound ``density``, the mesh validates and draws them, or the mesher names one of
    its known limits (the example is then discarded)."""
    try:
        mesh = triangulate(curves, max_area=density)
    except MeshError as e:
        # known limits: curves tangent to each other (or to a line piece) at a shared endpoint on the same side,
        # and curves that run within the snap distance of each other without being merged by the clean-up
        assume(not re.search("tangent at their shared endpoint|cannot separate|would be split", str(e)))
        raise
    mesh.validate()
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)


@settings(max_examples=30, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(curves=curve_sets(), n_extra=st.integers(1, 60), seed=st.integers(0, 2**16))
def test_fuzzed_extra_points_keep_the_mesh_valid_and_the_curves(curves, n_extra, seed):
    """Refinement points anywhere (also on curves, outside the domain, on top of each other): a valid mesh that
    still draws the curves, with every kept point a vertex."""
    base_stats = {}
    try:
        base = triangulate(curves, max_triangles=200, stats=base_stats)
    except TriangleBudgetError:
        assume(False)  # the curves alone need more than 200 triangles
    except MeshError as e:
        assume(not re.search("tangent at their shared endpoint|cannot separate|would be split", str(e)))
        raise
    rng = np.random.default_rng(seed)
    extra = rng.uniform([-0.5, -0.5], [4.5, 3.5], (n_extra, 2))
    extra = np.concatenate([extra, extra[:3] + 1e-9, base.vertices[:2], samples(curves.control_points, 0.5)[:5]])
    stats = {}
    mesh = triangulate(curves, max_triangles=200, extra_points=extra, stats=stats)
    mesh.validate()
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)
    # every kept point is a vertex besides the base mesh's (apexes of curved pieces come and go with the points;
    # a point in a tangent triangle halves a piece instead, which changes the rest of the mesh)
    if not stats["halved"]:
        assert mesh.n_vertices - stats["apexes"] >= base.n_vertices - base_stats["apexes"] + stats["extra"]
    if stats["extra"]:
        d, _ = cKDTree(mesh.vertices).query(extra)
        assert (d < 1e-12).sum() >= stats["extra"]


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(curves=curve_sets(), picks=st.lists(st.integers(0, 10**6), min_size=1, max_size=6))
def test_fuzzed_points_in_tangent_triangles_halve_their_pieces(curves, picks):
    """Refinement points at the centroids of curved pieces' tangent triangles, proposed round after round: each
    halves its piece (one more curved piece per point), the mesh stays valid and draws the same curves."""
    try:
        mesh = triangulate(curves, max_triangles=400)
    except (TriangleBudgetError, MeshError) as e:
        assume(isinstance(e, MeshError) and not isinstance(e, TriangleBudgetError)
               and not re.search("tangent at their shared endpoint|cannot separate|would be split", str(e)))
        raise
    assume(len(mesh.curve_control_points))
    extra = np.zeros((0, 2))
    for pick in picks:
        cp = mesh.curve_control_points[pick % len(mesh.curve_control_points)]
        centroid = halving_points(cp[None])[0]
        assume(np.isfinite(bezier.tangent_apex(cp[None])).all() and np.hypot(*(cp[3] - cp[0])) > 1e-3)
        extra = np.concatenate([extra, centroid[None]])
        stats = {}
        halved = triangulate(curves, max_triangles=400, extra_points=extra, stats=stats)
        halved.validate()
        assert_same_drawing(curves, halved, 1e-3 * curves.diagonal)
        assert len(halved.curve_control_points) == len(mesh.curve_control_points) + 1
        assert stats["halved"] == len(extra) and stats["extra"] == 0
        mesh = halved


def test_an_apex_on_a_line_piece_is_separated_from_it():
    """A quadratic that the clean-up cuts at its lowest point, where one half's control point (its tangent triangle's
    apex, a vertex of the CDT) lands on a line piece the curve never reaches (found by fuzzing): the half is halved
    until no apex lies on the line, instead of the CDT cutting the line at the apex."""
    curves = make_curves([(1, [(0.0, 1.125), (1.0, 1.125)]), (2, [(1.0, 2.625), (1.0, 0.0), (1e-9, 2.25)])])
    mesh = triangulate(curves, max_triangles=200)
    mesh.validate()
    assert len(mesh.curve_control_points) >= 2
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)


def test_a_tangent_fork_shares_its_apex_edge():
    """Two quadratics leave one point along one tangent and part to either side: their apexes lie on one ray, and
    the nearer one used to lie on the other's apex edge ("would be split"); now the two tangent triangles share the
    farther apex, each still holding its piece, and halving one branch keeps it so."""
    curves = make_curves([(2, [(0.5, 1.5), (1.5, 1.5), (2.5, 2.5)]), (2, [(0.5, 1.5), (2.5, 1.5), (3.5, 0.5)])])
    mesh = triangulate(curves, max_triangles=200)
    mesh.validate()
    assert len(mesh.curve_control_points) == 2
    apexes = [mesh.vertices[t][~np.isin(t, mesh.curve_endpoints[k])] for k, t in
              enumerate(mesh.triangles[mesh.curved_triangles])]
    np.testing.assert_array_equal(apexes[0], apexes[1])  # one shared vertex, the farther apex
    np.testing.assert_allclose(apexes[0], [[2.5, 1.5]], atol=1e-5)
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)
    halved = triangulate(curves, max_triangles=200, extra_points=halving_points(mesh.curve_control_points[:1]))
    halved.validate()
    assert len(halved.curve_control_points) == 3


def test_pieces_tangent_on_one_side_are_named_not_counted_out():
    """Two quadratics nested in the corner, tangent at their shared endpoint on one side (found by fuzzing): halving
    in turns reaches the merge distance after about 70 rounds, and the error names the piece that cannot be separated
    rather than the rounds spent."""
    curves = make_curves([(2, [(0.0, 1.125), (0.0, 0.0), (1.0, 0.0)]), (2, [(0.5, 0.0), (0.0, 0.0), (0.0, 1.125)])])
    with pytest.raises(MeshError, match="cannot separate|tangent at their shared endpoint"):
        triangulate(curves)


def test_a_point_in_a_tangent_triangle_halves_the_piece_and_keeps_its_geometry():
    """A quadratic arch: the centroid of its tangent triangle cuts it at t = 1/2, the halves draw the same arch; a
    point outside every tangent triangle is a vertex instead."""
    curves = make_curves([(2, [(0.5, 0.5), (2.0, 1.2), (3.5, 0.5)])])
    base = triangulate(curves, max_triangles=100)
    assert len(base.curve_control_points) == 1
    cp = base.curve_control_points[0]
    centroid = (cp[0] + cp[3] + bezier.tangent_apex(cp[None])[0]) / 3.0
    mesh = triangulate(curves, max_triangles=100, extra_points=[centroid, (3.8, 2.8)])
    mesh.validate()
    assert len(mesh.curve_control_points) == 2
    halves = mesh.curve_control_points[np.argsort(mesh.curve_control_points[:, 0, 0])]
    np.testing.assert_allclose(halves[0, 3], bezier.evaluate(cp[None], np.array([0.5]))[0], atol=1e-12)
    t = np.linspace(0.0, 1.0, 9)
    np.testing.assert_allclose(bezier.evaluate(np.repeat(halves[:1], 9, axis=0), t),
                               bezier.evaluate(np.repeat(cp[None], 9, axis=0), t / 2), atol=1e-12)
    assert not np.isclose(mesh.vertices, centroid).all(axis=1).any()
    assert np.isclose(mesh.vertices, (3.8, 2.8)).all(axis=1).any()


# ---------------------------------------------------------------------------------------------- fixed cases


def test_line_pieces_are_single_edges_and_curves_sit_in_their_triangle():
    curves = make_curves([
        (1, [(0.5, 0.5), (3.5, 2.5)]),
        (2, [(0.5, 2.5), (2.0, -0.5), (3.5, 2.5)]),
        (3, [(1.0, 1.0), (1.5, 2.8), (2.5, 2.8), (3.0, 1.0)]),
    ])
    mesh = triangulate(curves, max_area=0.05)
    mesh.validate()
    v = mesh.vertices
    # every disc edge is one of the cleaned line pieces' chords: collinear with the input line
    a, b = v[mesh.disc_edges[:, 0]], v[mesh.disc_edges[:, 1]]
    d = np.array([3.0, 2.0])
    for p in (a, b):
        cross = (p[:, 0] - 0.5) * d[1] - (p[:, 1] - 0.5) * d[0]
        assert np.abs(cross).max() < 1e-9
    tri = mesh.triangles[mesh.curved_triangles]
    assert (np.sort(tri, axis=1)[:, None] == np.sort(mesh.curve_endpoints, axis=1)[:, :, None]).any(axis=2).all()
    assert np.allclose(mesh.curve_control_points[:, 0], v[mesh.curve_endpoints[:, 0]])
    assert set(np.unique(mesh.curve_degree)) == {2, 3}
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)


def test_line_touching_a_curve_tangentially_within_snapping_distance_meshes():
    # a cylinder's silhouette line and its cap's outline as ``dfc curves`` wrote them for the corpus scene
    # (dfc.bench.corpus.SHAPES_SCENE): the line starts 2e-5 px (less than the snapping distance) off the fitted
    # outline, tangent to it. Pinning the outline to the line's end turned it by 1e-4 rad, and it crossed the line
    # again 0.003 px further on, 2e-7 px deep: "constraint edges cross" before the clean-up's second crossing pass
    curves = make_curves([
        (1, [(154.6383293546934, 131.3370998513711), (213.36501308874594, 118.60032744104156)]),
        (3, [(150.52127255323114, 133.79523129728818), (151.73031234237675, 132.47666689027346),
             (153.1872832513801, 131.61551209613194), (154.79784709740466, 131.30439984325315)]),
    ], domain=(0.0, 0.0, 256.0, 256.0))
    mesh = triangulate(curves)
    mesh.validate()
    assert_same_drawing(curves, mesh, 1e-3)


def test_a_piece_straightened_beside_a_near_tangent_curve_is_split_where_it_crosses_it():
    # a fuzzed example: two curves tangent at a shared end on the top border, both cut 1.3e-5 apart by a third; one
    # tail became a line (within the snapping distance of its chord) after the last crossing pass and crossed the
    # other tail 1e-8 deep ("constraint edges cross near (2.5005, 2.9992) (clean-up left an intersection)")
    curves = make_curves([(3, [(0.0, 0.0), (4.0, 0.0), (4.0, 0.5), (2.5, 3.0)]),
                          (3, [(0.0, 0.0), (0.0, 3.0), (0.0, 3.0), (4.0, 3.0)]),
                          (2, [(0.0, 0.0), (4.0, 0.5), (2.5, 3.0)])])
    mesh = triangulate(curves)
    mesh.validate()
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)


# end points on the border and at its corners, where the clip, the snap onto the border and the crossings meet
_on_border = st.one_of(
    st.tuples(st.sampled_from([0.0, 4.0]), st.floats(0.0, 3.0)),
    st.tuples(st.floats(0.0, 4.0), st.sampled_from([0.0, 3.0])),
    st.sampled_from([(0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0)]),
)
_border_point = st.one_of(_on_border, st.tuples(st.integers(0, 8), st.integers(0, 6)).map(lambda k: (k[0] / 2, k[1] / 2)),
                          st.tuples(st.floats(0.0, 4.0), st.floats(0.0, 3.0)))
_border_piece = st.integers(1, 3).flatmap(
    lambda deg: st.tuples(st.just(deg), st.lists(_border_point, min_size=deg + 1, max_size=deg + 1)))


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(pieces=st.lists(_border_piece, min_size=1, max_size=6), density=st.sampled_from([None, 0.5]))
def test_fuzzed_pieces_ending_on_the_border_mesh_validate_and_keep_every_piece(pieces, density):
    assert_meshes(make_curves(pieces), density)


@pytest.mark.parametrize("density", [None, 0.05, 0.5])
@pytest.mark.parametrize("pieces", [
    # a quadratic leaving a corner along the border, and a cubic folding back along the same border 1e-5 wide
    [(2, [(0.0, 0.0), (0.0, 0.375), (0.5, 0.0)]), (3, [(0.0, 0.0), (0.0, 0.375), (0.0, 0.0), (1e-5, 0.0)])],
    # a quadratic hairpin up the border and back, never more than 1e-5 inside it, beside a line to the border
    [(1, [(0.0, 0.375), (0.5, 0.0)]), (2, [(0.0, 0.0), (0.0, 1.125), (1e-5, 0.0)])],
    # a loop and a cubic both reaching a corner along the border, tangent: their last pieces share a chord, and the
    # halves, straightened, crossed ("constraint edges cross") 4.5e-7 above the border
    [(3, [(0.0, 0.0), (0.0, 1.5), (0.5, 0.0), (0.0, 0.0)]), (3, [(0.0, 3.0), (4.0, 0.0), (0.0, 0.0), (0.0, 0.0)])],
])
def test_pieces_running_along_the_border_lose_the_part_on_it(pieces, density):
    # fuzzed examples: the parts within the snapping distance of the border were kept ("constraint edges cross",
    # "discontinuous edge on the border is not a mesh edge") until the clip cut pieces where they enter that band
    curves = make_curves(pieces)
    mesh = triangulate(curves, max_area=density)
    mesh.validate()
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)


def test_triangles_are_counter_clockwise_and_cover_the_domain():
    mesh = triangulate(make_curves([(3, [(0.2, 0.2), (1.0, 2.9), (3.0, -1.0), (3.9, 2.8)])]))
    p = mesh.vertices[mesh.triangles]
    area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])
    assert (area2 > 0).all()
    assert np.isclose(area2.sum() / 2, 12.0)


def _cross(u, v):
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def test_density_knobs():
    curves = make_curves([(2, [(0.5, 0.5), (2.0, 1.2), (3.5, 0.5)])])
    default = triangulate(curves)
    fine = triangulate(curves, max_area=0.002)
    by_length = triangulate(curves, edge_length=0.1)
    graded = triangulate(curves, max_area=0.002, grading=0.5)
    assert 1000 <= default.n_triangles <= 4000  # the documented default: about 2,000
    assert fine.n_triangles > 4 * default.n_triangles
    p = fine.vertices[fine.triangles]
    areas = 0.5 * np.abs(_cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
    assert np.median(areas) <= 0.002
    assert 0.5 < by_length.n_triangles / triangulate(curves, max_area=np.sqrt(3) / 4 * 0.01).n_triangles < 2.0
    assert graded.n_triangles < fine.n_triangles / 2
    # graded: triangles near the curve are about as small as the uniform ones, far ones larger
    for m in (graded, fine):
        m.validate()
    far = graded.vertices[graded.triangles].mean(axis=1)[:, 1] > 2.8
    pg = graded.vertices[graded.triangles]
    ag = 0.5 * np.abs(_cross(pg[:, 1] - pg[:, 0], pg[:, 2] - pg[:, 0]))
    assert np.median(ag[far]) > 4 * np.median(areas)


def test_max_triangles_caps_the_count():
    curves = make_curves([(3, [(0.2, 0.2), (1.0, 2.9), (3.0, -1.0), (3.9, 2.8)]), (1, [(0.1, 2.9), (3.9, 0.1)])])
    for cap in (300, 3000):
        mesh = triangulate(curves, max_triangles=cap)
        mesh.validate()
        assert mesh.n_triangles <= cap
        assert mesh.n_triangles > cap / 3
    capped = triangulate(curves, max_area=1e-4, max_triangles=2000)
    assert capped.n_triangles <= 2000
    with pytest.raises(MeshError, match="max_triangles"):
        triangulate(curves, max_triangles=5)


@pytest.mark.parametrize("kwargs, match", [
    ({"max_area": -1.0}, "max_area"),
    ({"edge_length": 0.0}, "edge_length"),
    ({"max_area": 1.0, "edge_length": 1.0}, "not both"),
    ({"grading": -0.1}, "grading"),
    ({"max_triangles": 1}, "max_triangles"),
    ({"min_angle": 50.0}, "min_angle"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(MeshError, match=match):
        triangulate(make_curves([(1, [(0.5, 0.5), (1.0, 1.0)])]), **kwargs)


def test_rejects_non_curves():
    with pytest.raises(MeshError, match="expected Curves"):
        triangulate(np.zeros((1, 4, 2)))


def test_extra_points_become_vertices_where_they_are_free():
    curves = make_curves([(1, [(0.5, 0.5), (3.5, 2.5)]), (2, [(0.5, 2.5), (2.0, 0.5), (3.5, 2.8)])])
    base = triangulate(curves, max_triangles=60)
    free = np.array([[3.0, 0.6], [0.6, 1.6], [3.6, 0.3]])
    on_line = np.array([[2.0, 1.5]])  # on the straight piece
    outside = np.array([[-1.0, 1.0], [4.0, 1.0]])  # outside, on the border
    near = base.vertices[:1] + 1e-12  # on an existing vertex
    stats = {}
    mesh = triangulate(curves, max_triangles=60, extra_points=np.concatenate([free, on_line, outside, near, free]),
                       stats=stats)
    mesh.validate()
    assert stats["extra"] == len(free) and mesh.n_vertices == base.n_vertices + len(free)
    assert cKDTree(mesh.vertices).query(free)[0].max() < 1e-12
    assert np.array_equal(mesh.disc_edges.shape, base.disc_edges.shape)  # the line piece stays one edge
    assert np.allclose(np.sort(mesh.curve_control_points.reshape(-1)), np.sort(base.curve_control_points.reshape(-1)))


def test_stats_report_every_stage():
    stats = {}
    mesh = triangulate(make_curves([(2, [(0.5, 0.5), (2.0, 2.5), (3.5, 0.5)])]), stats=stats)
    for key in ("clean_s", "conflict_s", "density_s", "cdt_s"):
        assert stats[key] >= 0.0
    assert stats["triangles"] == mesh.n_triangles and stats["vertices"] == mesh.n_vertices
    assert stats["pieces_in"] == 1


def test_box_pairs_matches_brute_force():
    rng = np.random.default_rng(3)
    lo = rng.random((300, 2))
    hi = lo + rng.random((300, 2)) ** 4 * 0.05
    hi[:3] = lo[:3] + 5.0  # a few boxes covering everything take the brute-force path
    pts = rng.random((200, 2))
    for a, b, same in (((lo, hi), (lo, hi), True), ((lo, hi), (pts, pts), False)):
        i, j = _box_pairs(*a, *b, same=same)
        overlap = (a[0][:, None] <= b[1][None]).all(-1) & (b[0][None] <= a[1][:, None]).all(-1)
        if same:
            overlap = np.triu(overlap, 1)
        assert sorted(zip(i.tolist(), j.tolist())) == sorted(zip(*np.nonzero(overlap)))


# ---------------------------------------------------------------------------------------------- real files


@pytest.mark.parametrize("name", ["svg/engine_geometry.svg", "diffusion-curves/poivron_orzan.xml",
                                  "diffusion-curves/sunset_illustration.xml", "diffusion-curves/test_curve.xml"])
def test_real_files_mesh_and_validate(shared_data, name):
    curves = read_curves(shared_data / name)
    mesh = triangulate(curves)
    mesh.validate()
    assert len(mesh.curved_triangles) + len(mesh.disc_edges) >= len(curves)
    assert_same_drawing(curves, mesh, 1e-3 * curves.diagonal)
