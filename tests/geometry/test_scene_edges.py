"""Feature edges of meshes (``dfc.geometry.sources.scene.edges``) and the chaining and fitting of their images
(``...scene.chains``): plain numpy, no Mitsuba needed."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.geometry import bezier
from dfc.geometry.sources.scene.chains import chain, fit_polylines
from dfc.geometry.sources.scene.edges import BOUNDARY, CREASE, SILHOUETTE, edge_table, feature_kinds, weld

CUBE_V = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
CUBE_F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def kinds(vertices, faces, eye, **kw):
    v, f = weld(vertices, faces)
    table = edge_table(f)
    return table, feature_kinds(v, table, np.asarray(eye, float), crease_angle=kw.pop("crease_angle", 30.0), **kw)


def test_cube_edges_are_creases_and_the_outline_is_a_loop():
    table, k = kinds(CUBE_V, CUBE_F, [3.0, 2.2, 4.1])
    assert len(table.edges) == 18 and np.all(table.count == 2)  # 12 edges + 6 face diagonals
    assert np.sum((k & CREASE) > 0) == 12 and not np.any(k & BOUNDARY)
    outline = table.edges[(k & SILHOUETTE) > 0]
    assert len(outline) == 6  # three faces seen: a hexagon
    assert np.all(np.bincount(outline.ravel(), minlength=8)[np.unique(outline)] == 2)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.booleans(), min_size=12, max_size=12), st.tuples(*[st.floats(2, 9)] * 3))
def test_kinds_do_not_depend_on_face_winding(flips, eye):
    faces = np.where(np.array(flips)[:, None], CUBE_F[:, ::-1], CUBE_F)
    table0, k0 = kinds(CUBE_V, CUBE_F, eye)
    table1, k1 = kinds(CUBE_V, faces, eye)
    np.testing.assert_array_equal(table0.edges, table1.edges)
    np.testing.assert_array_equal(k0, k1)


def test_split_vertices_are_welded_and_a_flat_grid_has_only_its_boundary():
    xs = np.arange(4.0)
    grid = np.array([[x, y, 0.0] for y in xs for x in xs])
    quads = [(i + 4 * j, i + 1 + 4 * j, i + 5 + 4 * j, i + 4 + 4 * j) for j in range(3) for i in range(3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    split = grid[faces].reshape(-1, 3)  # every triangle with its own three vertices, as OBJ seams do
    table, k = kinds(split, np.arange(len(split)).reshape(-1, 3), [1.5, 1.5, 5.0])
    assert len(table.edges) == 33
    assert np.sum(k == BOUNDARY) == 12 and np.sum(k != 0) == 12


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([0.02, 0.05, 0.3]))
def test_fitted_pieces_stay_within_the_tolerance_of_their_polyline(seed, tolerance):
    rng = np.random.default_rng(seed)
    # a smooth random stroke sampled unevenly, then a corner and a straight run
    t = np.sort(rng.uniform(0, 1, rng.integers(5, 200)))
    cp = rng.uniform(0, 100, (1, 4, 2))
    smooth = bezier.evaluate(np.repeat(cp, len(t), axis=0), t)
    straight = smooth[-1] + np.outer(np.linspace(0, 1, rng.integers(2, 6))[1:], rng.uniform(-30, 30, 2))
    points = np.vstack([smooth, straight])
    points = points[np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9]]
    offsets = np.array([0, len(points)])
    pieces, degree, polyline = fit_polylines(points, offsets, tolerance)
    assert np.all(polyline == 0) and set(degree.tolist()) <= {1, 3}
    assert np.array_equal(pieces[0, 0], points[0]) and np.array_equal(pieces[-1, 3], points[-1])
    assert np.array_equal(pieces[1:, 0], pieces[:-1, 3])
    dense = bezier.flatten(pieces, 64).reshape(-1, 2)
    probe = np.vstack([points, 0.5 * (points[1:] + points[:-1])])
    assert _distance_to_polyline(probe, dense).max() <= tolerance * 1.01
    assert _distance_to_polyline(dense, points).max() <= tolerance * 1.01
    assert len(pieces) < len(points)  # something was merged


def _distance_to_polyline(p, line):
    a, b = line[:-1], line[1:]
    ab = b - a
    out = np.empty(len(p))
    for lo in range(0, len(p), 256):
        q = p[lo:lo + 256, None]
        t = np.clip(np.einsum("nmk,mk->nm", q - a, ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-300), 0, 1)
        out[lo:lo + 256] = np.linalg.norm(q - a - t[..., None] * ab, axis=2).min(axis=1)
    return out


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_chains_use_every_segment_once_and_follow_shared_ends(seed):
    rng = np.random.default_rng(seed)
    ends = rng.integers(0, 12, (rng.integers(1, 30), 2))
    ends = ends[ends[:, 0] != ends[:, 1]]
    ids, offsets, closed = chain(ends)
    used = []
    for c in range(len(offsets) - 1):
        path = ids[offsets[c]:offsets[c + 1]]
        assert len(path) >= 2 and closed[c] == (path[0] == path[-1])
        used += [tuple(sorted(pair)) for pair in zip(path[:-1], path[1:])]
    assert sorted(used) == sorted(tuple(sorted(e)) for e in ends.tolist())
