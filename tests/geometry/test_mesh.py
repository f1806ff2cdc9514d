"""Tests of dfc.geometry.mesh: Mesh.validate accepts a good mesh and names each kind of broken one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dfc.errors import MeshError
from dfc.geometry.curves import Curves
from dfc.geometry.mesh import Mesh, min_side_distance


def good_mesh() -> Mesh:
    """The unit square as four triangles around its centre, with one line piece and one quadratic.

    Vertices: 0 (0,0), 1 (1,0), 2 (1,1), 3 (0,1), 4 (0.5,0.5). Triangle 0 (0, 1, 4) holds the arc from
    vertex 0 to vertex 1 bulging up to y = 0.2; the line piece is the edge (3, 4).
    """
    v = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], dtype=np.float64)
    t = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], dtype=np.int64)
    q = np.array([[0.0, 0.0], [0.5, 0.4], [1.0, 0.0]])
    cp = np.array([[q[0], q[0] + 2 / 3 * (q[1] - q[0]), q[2] + 2 / 3 * (q[1] - q[2]), q[2]]])
    return Mesh(
        domain=(0.0, 0.0, 1.0, 1.0), vertices=v, triangles=t,
        disc_edges=np.array([[3, 4]], dtype=np.int64),
        curved_triangles=np.array([0], dtype=np.int64), curve_endpoints=np.array([[0, 1]], dtype=np.int64),
        curve_control_points=cp, curve_degree=np.array([2], dtype=np.int8),
        disc_edge_piece=np.array([0], dtype=np.int64), curve_piece=np.array([1], dtype=np.int64),
    )


def broken(**changes) -> Mesh:
    return dataclasses.replace(good_mesh(), **changes)


def test_good_mesh_validates():
    m = good_mesh()
    m.validate()
    assert m.n_disc_vertices == 4
    edges, counts = m.edges()
    assert len(edges) == 8 and (counts == 2).sum() == 4


def _with(name, fn):
    m = good_mesh()
    a = getattr(m, name).copy()
    fn(a)
    return dataclasses.replace(m, **{name: a})


CASES = {
    "flipped triangle": (lambda: _with("triangles", lambda t: t.__setitem__(1, t[1, ::-1])), "clockwise"),
    "dropped triangle": (lambda: broken(triangles=good_mesh().triangles[:3]), "sum to|no neighbour"),
    "duplicated triangle": (lambda: broken(triangles=np.concatenate([good_mesh().triangles, good_mesh().triangles[:1]])), "more than two"),
    "degenerate triangle": (lambda: _with("vertices", lambda v: v.__setitem__(4, [0.5, 0.0])), "degenerate|clockwise"),
    "vertex outside": (lambda: _with("vertices", lambda v: v.__setitem__(2, [1.5, 1.0])), "outside the domain"),
    "index out of range": (lambda: _with("triangles", lambda t: t.__setitem__((0, 0), 9)), "out of range"),
    "float triangles": (lambda: broken(triangles=good_mesh().triangles.astype(float)), "integer array"),
    "wrong shape": (lambda: broken(vertices=np.zeros((5, 3))), "shape"),
    "nan vertex": (lambda: _with("vertices", lambda v: v.__setitem__((4, 0), np.nan)), "NaN"),
    "disc edge not a mesh edge": (lambda: broken(disc_edges=np.array([[1, 3]])), "not a mesh edge"),
    "disc edge twice": (lambda: broken(disc_edges=np.array([[3, 4], [4, 3]]), disc_edge_piece=np.array([0, 0])), "twice"),
    "curve cp out of triangle": (lambda: _with("curve_control_points", lambda c: c.__setitem__((0, 1, 1), 0.9)), "leaves its triangle"),
    "curve endpoints not corners": (lambda: broken(curve_endpoints=np.array([[0, 2]])), "corners"),
    "curve in wrong triangle": (lambda: broken(curved_triangles=np.array([2])), "corners"),
    "curve end off its vertex": (lambda: _with("curve_control_points", lambda c: c.__setitem__((0, 0, 0), 0.01)), "not at its endpoint"),
    "chord shared with disc edge": (lambda: broken(disc_edges=np.array([[0, 1]])), "also a discontinuous edge"),
    "bad degree": (lambda: broken(curve_degree=np.array([1], dtype=np.int8)), "degree"),
    "length mismatch": (lambda: broken(curve_piece=np.array([1, 2])), "shape"),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_validate_catches(name):
    make, match = CASES[name]
    with pytest.raises(MeshError, match=match):
        make().validate()


def _two_curve_mesh(cp2, tri2, ep2):
    m = good_mesh()
    return dataclasses.replace(
        m, curved_triangles=np.array([0, tri2]), curve_endpoints=np.array([[0, 1], ep2]),
        curve_control_points=np.concatenate([m.curve_control_points, cp2[None]]),
        curve_degree=np.array([2, 3], dtype=np.int8), curve_piece=np.array([1, 2]),
    )


def test_validate_catches_shared_chord_and_shared_triangle():
    below = np.array([[0.0, 0.0], [0.3, 0.05], [0.7, 0.05], [1.0, 0.0]])
    with pytest.raises(MeshError, match="holds two curves"):
        _two_curve_mesh(below, 0, [0, 1]).validate()
    # a second curve on the same chord, in the same triangle but reported once: the chord check fires
    m = _two_curve_mesh(below, 1, [0, 1])
    with pytest.raises(MeshError, match="corners|another curve's chord"):
        m.validate()


def test_validate_catches_curve_that_is_not_a_graph():
    # a cubic that runs back past its start along the chord, inside the triangle (0, 1, 4)
    cp = np.array([[[0.0, 0.0], [0.9, 0.3], [-0.2, 0.3], [1.0, 0.0]]])
    m = broken(curve_control_points=cp, curve_degree=np.array([3], dtype=np.int8))
    with pytest.raises(MeshError, match="graph over its chord|leaves its triangle"):
        m.validate()
    cp = np.array([[[0.0, 0.0], [1.2, 0.1], [-0.2, 0.1], [1.0, 0.0]]])  # stays in the triangle, turns back
    m = broken(curve_control_points=cp, curve_degree=np.array([3], dtype=np.int8))
    with pytest.raises(MeshError, match="graph over its chord"):
        m.validate()


def test_min_side_distance_is_exact():
    rng = np.random.default_rng(0)
    cp = rng.random((50, 4, 2))
    p, q = rng.random((50, 2)), rng.random((50, 2))
    t = np.linspace(0, 1, 20001)
    w = np.stack([(1 - t) ** 3, 3 * (1 - t) ** 2 * t, 3 * (1 - t) * t**2, t**3], axis=1)
    pts = np.einsum("tk,nkd->ntd", w, cp)
    d = q - p
    dist = (d[:, None, 0] * (pts[..., 1] - p[:, None, 1]) - d[:, None, 1] * (pts[..., 0] - p[:, None, 0])) / np.hypot(*d.T)[:, None]
    got = min_side_distance(cp, p, q)
    assert np.all(got <= dist.min(axis=1) + 1e-12)
    assert np.allclose(got, dist.min(axis=1), atol=1e-7)


def test_triangulated_mesh_survives_a_round_trip_of_its_arrays():
    from dfc.geometry.triangulate import triangulate

    n = 1
    curves = Curves((0, 0, 2, 1), np.array([[[0.2, 0.2], [0.6, 0.9], [1.4, 0.9], [1.8, 0.2]]]), [3], np.arange(n),
                    np.tile([0.0, 1.0], (n, 1)), ["c"], [None])
    m = triangulate(curves)
    m.validate()
    m2 = dataclasses.replace(m, triangles=m.triangles[:, [1, 2, 0]])  # rotating corners keeps it valid
    m2.validate()
    m3 = dataclasses.replace(m, triangles=m.triangles[:, [0, 2, 1]])
    with pytest.raises(MeshError, match="clockwise"):
        m3.validate()
