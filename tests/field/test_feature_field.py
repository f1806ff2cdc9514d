"""FeatureField: the continuity theorem (paper Thm 4.3) on fuzzed meshes, gradients, API contracts."""

import numpy as np
import pytest
import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from dfc.errors import InputError
from dfc.field import FeatureField
from dfc.geometry.curves import Curves

from ._continuity import SMOOTH, check_all, evaluate, random_field
from ._meshes import bezier, circle_mesh, mesh_edges, needle_mesh, random_mesh, s_mesh


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([0.15, 0.4, 0.7]))
def test_continuity_theorem_random_meshes(seed, disc_fraction):
    """Random Delaunay meshes with random discontinuous edges (junctions of any valence, open tips)
    and random curved pieces (some on chains with edges and other curves)."""
    check_all(random_field(random_mesh(seed, disc_fraction=disc_fraction, n_curves=6), seed))


@pytest.mark.parametrize("build", [circle_mesh, s_mesh], ids=["circle_of_four_cubics", "s_of_two_pieces"])
def test_continuity_theorem_curve_chains(build):
    """Chains of curved pieces: continuous across every chord (no seam), jump across every piece."""
    check_all(random_field(build()))


def test_continuity_theorem_short_edge_in_needle_triangles():
    """A 1e-6 discontinuous edge between triangles 4e5 times as long (a tiny line piece of the clean-up):
    the jump must persist down to 1e-13 from the edge, so point location must not cross it."""
    check_all(random_field(needle_mesh(), 205))


def _random_curves(seed: int) -> Curves:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 6))
    cp = rng.uniform(0.1, 0.9, (n, 4, 2))
    degree = rng.integers(1, 4, n)
    lines = degree == 1
    cp[lines, 1] = cp[lines, 0] + (cp[lines, 3] - cp[lines, 0]) / 3
    cp[lines, 2] = cp[lines, 0] + 2 * (cp[lines, 3] - cp[lines, 0]) / 3
    quad = degree == 2                                   # control point cp[:, 1], degree-elevated
    q = cp[quad, 1].copy()
    cp[quad, 1] = cp[quad, 0] + 2 / 3 * (q - cp[quad, 0])
    cp[quad, 2] = cp[quad, 3] + 2 / 3 * (q - cp[quad, 3])
    return Curves((0.0, 0.0, 1.0, 1.0), cp, degree, np.arange(n), np.tile([0.0, 1.0], (n, 1)),
                  [f"c{i}" for i in range(n)], [None] * n)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1))
@example(205)  # a cusp demoted to 1e-6 line pieces: needle triangles (see test_continuity_theorem_short_edge_...)
@pytest.mark.slow
def test_continuity_theorem_through_triangulate(seed):
    """Random crossing lines, quadratics and cubics meshed by dfc.geometry.triangulate."""
    from dfc.geometry.triangulate import triangulate

    mesh = triangulate(_random_curves(seed), max_triangles=400)
    check_all(random_field(mesh, seed))


def _sliver_points(mesh):
    """One point inside each curved piece's sliver: halfway between the chord midpoint and the piece."""
    cp = mesh.curve_control_points
    mid = np.array([bezier(c, np.array([0.5]))[0] for c in cp])
    return 0.5 * (mid + 0.5 * (cp[:, 0] + cp[:, 3]))


def test_curve_features_receive_gradients():
    mesh = random_mesh(2)
    field = random_field(mesh)
    idx, w = field.query(torch.as_tensor(_sliver_points(mesh)))
    curve_rows = field.layout.n_vertex_features + np.arange(len(mesh.curved_triangles))
    np.testing.assert_array_equal(idx[:, 6].numpy(), curve_rows)
    assert torch.all(w[:, 6] > 0)
    field.features(torch.as_tensor(_sliver_points(mesh))).pow(2).sum().backward()
    grad = field.bank.grad[0, curve_rows]
    assert torch.all(grad.abs().sum(1) > 0)


def test_gradient_wrt_points_matches_finite_differences():
    """At centroids of straight triangles (clear of every discontinuity by far more than the step)."""
    mesh = s_mesh()
    field = random_field(mesh)
    straight = np.setdiff1d(np.arange(mesh.n_triangles), mesh.curved_triangles)
    pts = mesh.vertices[mesh.triangles[straight]].mean(1)
    rng = np.random.default_rng(0)
    xy = torch.as_tensor(pts).requires_grad_(True)
    direction = torch.as_tensor(rng.normal(size=(len(pts), 5)), dtype=torch.float32)
    (field.features(xy) * direction).sum().backward()
    h = 1e-4
    for axis in range(2):
        step = np.zeros(2)
        step[axis] = h
        fd = ((evaluate(field, pts + step) - evaluate(field, pts - step)) * direction.numpy()).sum(1) / (2 * h)
        np.testing.assert_allclose(xy.grad[:, axis].numpy(), fd, rtol=1e-2, atol=1e-2)


def test_vertex_and_edge_queries_are_finite_and_deterministic():
    mesh = random_mesh(7)
    field = random_field(mesh)
    e = mesh_edges(mesh.triangles)
    pts = np.concatenate([mesh.vertices, 0.5 * (mesh.vertices[e[:, 0]] + mesh.vertices[e[:, 1]]),
                          mesh.curve_control_points[:, 0]])
    xy = torch.as_tensor(pts).requires_grad_(True)
    f1 = field.features(xy)
    f1.sum().backward()
    assert torch.isfinite(f1).all() and torch.isfinite(xy.grad).all()
    f2 = field.features(torch.as_tensor(pts))
    assert torch.equal(f1.detach(), f2)
    # a vertex query uses one of the vertex's own features, unblended with other vertices
    idx, w = field.query(torch.as_tensor(mesh.vertices))
    lay = field.layout
    rows = np.where(lay.vertex_sectors == 0, 1, 2 * lay.vertex_sectors)
    used = w.numpy() > 1e-9  # rounding in the barycentric map leaves ~1e-16 at the other corners
    own = (idx.numpy() >= lay.vertex_offset[:, None]) & (idx.numpy() < (lay.vertex_offset + rows)[:, None])
    assert np.all(own[used])


def test_query_contract():
    field = random_field(circle_mesh())
    xy = torch.rand(5000, 2, dtype=torch.float64) * 1.2 - 0.1
    idx, w = field.query(xy)
    assert idx.shape == (5000, 7) and idx.dtype == torch.int64
    assert w.shape == (5000, 7) and w.dtype == torch.float32
    torch.testing.assert_close(w.sum(1), torch.ones(5000), atol=1e-6, rtol=0)
    assert torch.all(w >= 0) and torch.all((idx >= 0) & (idx < field.n_features))
    assert torch.all(idx[w[:, 6] == 0, 6] == 0)
    # features are exactly the weighted sum of bank rows (float32 result), for the same (float32) points: a point
    # within rounding of an edge may be located in the other triangle from its float64 copy
    f = field.features(xy.float())
    assert f.dtype == torch.float32 and f.shape == (5000, 5)
    idx, w = field.query(xy.float())
    ref = (w[..., None] * field.bank[0][idx]).sum(1)
    torch.testing.assert_close(f, ref, atol=1e-5, rtol=1e-5)


def test_packed_query_matches_full_query():
    from dfc.field.feature_field import pack_query, packed_rows, weighted_rows

    field = random_field(circle_mesh())
    idx, w = field.query(torch.rand(3000, 2, dtype=torch.float64))
    q = pack_query(idx, w)
    assert len(q.idx) == int((w != 0).sum()) < w.numel()  # zero-weight slots dropped (most points use three)
    assert torch.all(q.w != 0) and torch.equal(q.point[q.offsets], torch.arange(3000))
    grad = torch.randn(3000, field.dim)
    outs = []
    for rows in (lambda t: weighted_rows(t, idx, w), lambda t: packed_rows(t, q)):
        table = field.bank[0].detach().clone().requires_grad_(True)
        out = rows(table)
        out.backward(grad)
        outs.append((out.detach(), table.grad))
    torch.testing.assert_close(outs[1][0], outs[0][0], rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(outs[1][1], outs[0][1], rtol=1e-5, atol=1e-6)
    with torch.no_grad():  # the evaluation path (no custom backward) gives the same values
        torch.testing.assert_close(packed_rows(field.bank[0], q), outs[0][0], rtol=1e-6, atol=1e-7)


def test_bank_initialisation_and_buffers():
    mesh = random_mesh(1)
    a, b, c = FeatureField(mesh, dim=7, seed=3), FeatureField(mesh, dim=7, seed=3), FeatureField(mesh, dim=7, seed=4)
    assert a.bank.shape == (1, a.n_features, 7) and a.bank.dtype == torch.float32
    assert a.bank.abs().max() <= 2e-3 and a.bank.abs().max() > 1e-3
    assert torch.equal(a.bank, b.bank) and not torch.equal(a.bank, c.bank)
    assert a.times is None and a.dim == 7 and a.mesh is mesh
    names = {n for n, _ in a.named_buffers()}
    assert {"locator.cell_triangles", "locator.tri_affine", "interp.corner_rows", "interp.chord_local"} <= names


def test_time_slices_blend_linearly():
    mesh = random_mesh(6)
    field = FeatureField(mesh, dim=3, n_slices=3, times=[0.0, 1.0, 3.0])
    with torch.no_grad():
        field.bank.normal_()
    xy = torch.rand(100, 2, dtype=torch.float64)
    idx, w = field.query(xy)
    per_slice = [(w[..., None] * field.bank[s][idx]).sum(1).detach() for s in range(3)]
    for t, ref in [(0.0, per_slice[0]), (1.0, per_slice[1]), (3.0, per_slice[2]), (-5.0, per_slice[0]),
                   (9.0, per_slice[2]), (2.0, 0.5 * (per_slice[1] + per_slice[2])), (0.25, 0.75 * per_slice[0] + 0.25 * per_slice[1])]:
        torch.testing.assert_close(field.features(xy, t).detach(), ref, atol=1e-5, rtol=1e-5)
    ts = torch.tensor([0.0, 1.0, 3.0]).repeat_interleave(torch.tensor([30, 30, 40]))
    expect = torch.cat([per_slice[0][:30], per_slice[1][30:60], per_slice[2][60:]])
    torch.testing.assert_close(field.features(xy, ts).detach(), expect, atol=1e-5, rtol=1e-5)
    with pytest.raises(InputError, match="time"):
        field.features(xy)


def test_single_slice_ignores_time():
    field = random_field(random_mesh(8))
    xy = torch.rand(50, 2, dtype=torch.float64)
    assert torch.equal(field.features(xy, 0.7), field.features(xy))


@pytest.mark.parametrize("bad", [torch.zeros(3, 3), torch.zeros(4), torch.zeros(3, 2, dtype=torch.int64)])
def test_bad_points_are_refused(bad):
    with pytest.raises(InputError, match=r"\(N, 2\)"):
        random_field(random_mesh(0)).features(bad)


@pytest.mark.parametrize("kwargs, match", [({"dim": 0}, "dim"), ({"n_slices": 2}, "times"),
                                           ({"n_slices": 2, "times": [1.0, 1.0]}, "increasing"),
                                           ({"n_slices": 2, "times": [0.0]}, "times")])
def test_bad_settings_are_refused(kwargs, match):
    with pytest.raises(InputError, match=match):
        FeatureField(random_mesh(0), **kwargs)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    mesh = s_mesh()
    cpu = random_field(mesh)
    gpu = random_field(mesh).to("cuda")
    xy = torch.rand(10000, 2, dtype=torch.float64)
    torch.testing.assert_close(gpu.features(xy.cuda()).cpu(), cpu.features(xy), atol=1e-5, rtol=1e-5)
    assert SMOOTH > 0
