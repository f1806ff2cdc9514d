"""Bank layout: a deterministic function of the mesh with the documented row order."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.errors import MeshError
from dfc.field.layout import build_layout

from ._meshes import circle_mesh, random_mesh, s_mesh


def _disc_degree(mesh):
    pairs = np.unique(np.sort(np.concatenate([mesh.disc_edges, mesh.curve_endpoints]), axis=1), axis=0)
    return np.bincount(pairs.ravel(), minlength=mesh.n_vertices)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_rows_per_vertex_and_curve(seed):
    mesh = random_mesh(seed)
    lay = build_layout(mesh)
    k = _disc_degree(mesh)
    np.testing.assert_array_equal(lay.vertex_sectors, k)
    rows = np.where(k == 0, 1, 2 * k)
    np.testing.assert_array_equal(lay.vertex_offset, np.cumsum(rows) - rows)
    assert lay.n_vertex_features == rows.sum()
    assert lay.n_features == rows.sum() + len(mesh.curved_triangles)
    # Corner rows stay inside their vertex's block; start/end differ exactly at discontinuous vertices.
    v = mesh.triangles
    assert np.all((lay.corner_start >= lay.vertex_offset[v]) & (lay.corner_end < lay.vertex_offset[v] + rows[v]))
    np.testing.assert_array_equal(lay.corner_end - lay.corner_start, (k[v] > 0).astype(np.int64))
    # Interior vertices: every sector holds at least one corner, so every row is used.
    x = mesh.vertices
    inner = (x[:, 0] > 0) & (x[:, 0] < 1) & (x[:, 1] > 0) & (x[:, 1] < 1)
    used = np.zeros(lay.n_vertex_features, bool)
    used[lay.corner_start] = used[lay.corner_end] = True
    vertex_of_row = np.repeat(np.arange(mesh.n_vertices), rows)
    assert used[inner[vertex_of_row]].all()
    # Angles: alpha + beta never exceeds the sector, which sums to 2π around each discontinuous vertex.
    fin = np.isfinite(lay.corner_theta)
    assert np.all(lay.corner_alpha[fin] + lay.corner_beta[fin] <= lay.corner_theta[fin] + 1e-12)
    assert np.all(lay.corner_beta > 0)
    # Sliver rows: the endpoints' rows are their own vertex's, never the triangle's own sector rows; apex: curve row.
    ct = mesh.curved_triangles
    for c in range(len(ct)):
        apex = lay.curve_apex[c]
        assert lay.curve_sliver_rows[c, apex] == lay.n_vertex_features + c
        for i in {0, 1, 2} - {apex}:
            row = lay.curve_sliver_rows[c, i]
            vtx = mesh.triangles[ct[c], i]
            assert lay.vertex_offset[vtx] <= row < lay.vertex_offset[vtx] + rows[vtx]
            assert row not in (lay.corner_start[ct[c], i], lay.corner_end[ct[c], i]) or k[vtx] == 1


def test_deterministic():
    mesh = s_mesh()
    a, b = build_layout(mesh), build_layout(mesh)
    for f in dataclasses.fields(a):
        np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name))


def test_open_tip_far_row_is_the_other_side():
    """At a vertex whose only discontinuity is the chord (one sector of 2π), the sliver uses the
    sector's other bounding feature."""
    mesh = circle_mesh()
    lay = build_layout(mesh)
    assert np.all(lay.vertex_sectors[mesh.curve_endpoints] == 2)        # two chords at every circle vertex
    mesh = random_mesh(11, disc_fraction=0.0, n_curves=3)
    lay = build_layout(mesh)
    checked = 0
    for c, t in enumerate(mesh.curved_triangles):
        for i in {0, 1, 2} - {lay.curve_apex[c]}:
            vtx = mesh.triangles[t, i]
            if lay.vertex_sectors[vtx] == 1:
                own = {lay.corner_start[t, i], lay.corner_end[t, i]}
                assert lay.curve_sliver_rows[c, i] in own
                checked += 1
    assert checked > 0


def test_bad_curves_are_refused():
    mesh = random_mesh(5)
    bad = dataclasses.replace(mesh, curve_endpoints=mesh.curve_endpoints[::-1].copy())
    with pytest.raises(MeshError, match="endpoints"):
        build_layout(bad)
    two = dataclasses.replace(mesh, curved_triangles=np.full_like(mesh.curved_triangles, mesh.curved_triangles[0]))
    with pytest.raises(MeshError, match="more than one"):
        build_layout(two)
