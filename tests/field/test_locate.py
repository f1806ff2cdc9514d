"""Point location: every point of the domain finds a triangle that contains it, deterministically."""

from fractions import Fraction

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.errors import MeshError
from dfc.field.locate import PointLocator

from ._meshes import cdt_triangles, mesh_edges, needle_mesh, random_mesh

TOL = 1e-12


def _locate(mesh, pts, **kw):
    loc = PointLocator(mesh.vertices, mesh.triangles, mesh.domain, **kw)
    xy = loc.clamp(torch.as_tensor(pts, dtype=torch.float64))
    tri, bary = loc(xy)
    return loc, xy, tri.numpy(), bary.numpy()


def _contained(mesh, pts, tri):
    """Exact-ish containment: signed areas of the point against the triangle's edges."""
    p = mesh.vertices[mesh.triangles[tri]]
    s = [(p[:, (i + 1) % 3, 0] - p[:, i, 0]) * (pts[:, 1] - p[:, i, 1])
         - (p[:, (i + 1) % 3, 1] - p[:, i, 1]) * (pts[:, 0] - p[:, i, 0]) for i in range(3)]
    return np.min(s, axis=0) >= -TOL


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([0.5, 2.0, 8.0]))
def test_random_border_and_vertex_points(seed, density):
    mesh = random_mesh(seed, n_points=int(np.random.default_rng(seed).integers(5, 80)))
    rng = np.random.default_rng(seed)
    edges = mesh_edges(mesh.triangles)
    s = rng.random((len(edges), 1))
    pts = np.concatenate([
        rng.random((2000, 2)),                                                        # random
        np.stack([rng.random(200), rng.integers(0, 2, 200)], 1),                      # bottom/top border
        np.stack([rng.integers(0, 2, 200), rng.random(200)], 1),                      # left/right border
        mesh.vertices,                                                                # vertices
        mesh.vertices[edges[:, 0]] * (1 - s) + mesh.vertices[edges[:, 1]] * s,        # on edges
    ])
    loc, xy, tri, bary = _locate(mesh, pts, cells_per_triangle=density)
    assert np.all(_contained(mesh, pts, tri))
    np.testing.assert_allclose(bary.sum(1), 1.0, atol=1e-12)
    assert bary.min() >= -1e-9
    np.testing.assert_allclose(loc.barycentric(xy, torch.as_tensor(tri)).numpy(), bary, atol=0)
    # deterministic, also when the same point comes in another batch
    tri2 = loc(xy.flip(0))[0].numpy()[::-1]
    np.testing.assert_array_equal(tri, tri2)


def _exactly_inside(tri_xy: np.ndarray, p: np.ndarray) -> bool:
    """Whether p (2,) lies in the closed counter-clockwise triangle (3, 2), in exact rational arithmetic."""
    (ax, ay), (bx, by), (cx, cy) = (map(Fraction, q) for q in tri_xy)
    px, py = map(Fraction, p)
    return all((qx - ox) * (py - oy) - (qy - oy) * (px - ox) >= 0
               for (ox, oy), (qx, qy) in (((ax, ay), (bx, by)), ((bx, by), (cx, cy)), ((cx, cy), (ax, ay))))


def test_needle_triangles_keep_points_on_their_side_of_a_short_edge():
    """1e-13 off a 1e-6 edge whose triangles are 4e5 times as long: no cancellation in 1 - l1 - l2 may
    put a point into the triangle across the edge (the field would take the other side's features)."""
    mesh = needle_mesh()
    a, b = mesh.vertices[mesh.disc_edges[0]]
    n = np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm(b - a)
    s = np.linspace(0.05, 0.95, 19)[:, None]
    q = np.concatenate([a + s * (b - a) + d * n for d in (1e-13, -1e-13, 1e-12, -1e-12)])
    _, xy, tri, bary = _locate(mesh, q)
    for k in range(len(q)):
        assert _exactly_inside(mesh.vertices[mesh.triangles[tri[k]]], xy[k].numpy()), f"point {k} is outside its triangle"
    assert bary.min() >= 0.0
    np.testing.assert_allclose(bary.sum(1), 1.0, atol=1e-9)


def test_outside_points_are_clamped():
    mesh = random_mesh(3)
    pts = np.array([[-1.0, 0.5], [2.0, 2.0], [0.5, -1e-3]])
    _, xy, tri, _ = _locate(mesh, pts)
    np.testing.assert_array_equal(xy.numpy(), [[0.0, 0.5], [1.0, 1.0], [0.5, 0.0]])
    assert np.all(_contained(mesh, xy.numpy(), tri))


def test_uncovered_domain_is_refused():
    mesh = random_mesh(4)
    with pytest.raises(MeshError, match="do not cover"):
        PointLocator(mesh.vertices, mesh.triangles[1:], mesh.domain, cells_per_triangle=50.0)


def test_clockwise_triangle_is_refused():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    tris = cdt_triangles(pts, np.zeros((0, 2)))
    with pytest.raises(MeshError, match="clockwise"):
        PointLocator(pts, tris[:, ::-1], (0.0, 0.0, 1.0, 1.0))
