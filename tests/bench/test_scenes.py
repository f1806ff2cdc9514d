"""Analytic scenes: the registry, exact jumps of one across strokes, continuity away from the curves."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.bench.scenes import (
    FLATTEN,
    HDR_GAIN,
    SCENES,
    default_probes,
    get_scene,
    sample_scene,
    shapes_scene,
    strokes_scene,
    subtended,
)
from dfc.errors import InputError
from dfc.geometry.bezier import evaluate

DELTA = 1e-6
"""Half the gap between the two points compared across a line (domain units of a 256-wide scene)."""

STROKES = strokes_scene()


def _across(p: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(2, 2): p ± DELTA times the unit normal of ``direction``."""
    n = np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)
    return np.stack([p - DELTA * n, p + DELTA * n])


def _points(cp: np.ndarray, n: int) -> np.ndarray:
    """(P · n, 2) points of the pieces cp (P, 4, 2) at n evenly spaced parameters."""
    return evaluate(cp, np.tile(np.linspace(0, 1, n), (len(cp), 1))).reshape(-1, 2)


def test_registry_holds_every_scene():
    assert {"sample", "shapes", "strokes", "hdr"} <= set(SCENES)
    assert SCENES["sample"] is sample_scene
    for name in SCENES:
        scene = get_scene(name)
        x0, y0, x1, y1 = scene.domain
        xy = np.random.default_rng(0).random((200, 2)) * [x1 - x0, y1 - y0] + [x0, y0]
        v = scene.value(xy)
        assert scene.name == name and v.shape == (200, len(scene.channels)) and np.isfinite(v).all()
        assert len(scene.curves) > 0


def test_unknown_scene_names_the_known_ones():
    with pytest.raises(InputError, match="shapes"):
        get_scene("nope")


@settings(max_examples=40, deadline=None)
@given(st.integers(0, len(STROKES.curves) - 1), st.integers(0, FLATTEN - 1), st.floats(0.05, 0.95))
def test_strokes_jump_by_exactly_one_across_a_stroke(piece, k, s):
    """The discontinuity is the flattened polyline: cross it between two of its vertices."""
    cp = STROKES.curves.control_points[piece]
    n = 1 if STROKES.curves.degree[piece] == 1 else FLATTEN
    a, b = evaluate(cp[None], np.array([[k % n / n, (k % n + 1) / n]]))[0]
    v = STROKES.value(_across(a + s * (b - a), b - a))[:, 0]
    assert abs(abs(v[1] - v[0]) - 1.0) < 1e-4


@settings(max_examples=40, deadline=None)
@given(st.floats(0, 256), st.floats(0, 256), st.floats(0, 2 * np.pi))
def test_strokes_are_continuous_away_from_the_strokes(x, y, angle):
    p = np.array([x, y])
    cp = STROKES.curves.control_points
    curve_pts = _points(cp, 2001)
    if np.min(np.linalg.norm(curve_pts - p, axis=1)) < 1.0:
        return  # too close to a stroke to tell a jump from a steep slope
    v = STROKES.value(_across(p, np.array([np.cos(angle), np.sin(angle)])))[:, 0]
    assert abs(v[1] - v[0]) < 1e-4


def test_strokes_are_continuous_past_a_tip():
    """Beyond an open end the value has no jump: crossing the stroke's extension changes nothing."""
    cp = STROKES.curves.control_points[0]
    tip, tangent = cp[0], cp[0] - cp[1]
    for dist in (0.5, 5.0, 20.0):
        p = tip + dist * tangent / np.linalg.norm(tangent)
        v = STROKES.value(_across(p, tangent))[:, 0]
        assert abs(v[1] - v[0]) < 1e-4


def test_shapes_jump_across_a_polygon_edge_and_not_across_a_free_line():
    scene = shapes_scene()
    star = scene.curves.control_points[scene.curves.curve == scene.curves.names.index("star")]
    a, b = star[0, 0], star[0, 3]
    v = scene.value(_across((a + b) / 2, b - a))
    assert np.abs(v[1] - v[0]).max() > 0.05
    w = scene.value(_across(np.array([10.0, 250.0]), np.array([1.0, 0.3])))  # background only
    assert np.abs(w[1] - w[0]).max() < 1e-4


def test_hdr_is_shapes_with_gains():
    xy = np.random.default_rng(1).random((2000, 2)) * 256
    ratio = get_scene("hdr").value(xy) / shapes_scene().value(xy)
    assert set(np.round(np.unique(ratio), 6)) <= set(HDR_GAIN.values())
    assert get_scene("hdr").value(xy).max() > 10.0


@pytest.mark.parametrize("name", sorted(SCENES))
def test_default_probes_lie_on_a_discontinuity(name):
    scene = get_scene(name)
    probes = default_probes(scene)
    assert probes.shape == (2, 2)
    pts = _points(scene.curves.control_points, 4001)
    for p in probes:
        assert np.min(np.linalg.norm(pts - p, axis=1)) < 1e-9


def test_stripes_are_exact_band_by_band_and_graphs_of_their_pieces():
    from dfc.bench.scenes import Stripes

    scene = Stripes(300.0, boundaries=6, pieces=5, seed=3)
    curves = scene.curves()
    assert len(curves) == 30 and curves.domain == (0.0, 0.0, 300.0, 300.0)
    cp = curves.control_points
    np.testing.assert_allclose(np.diff(cp[..., 0], axis=1), 20.0)  # x linear in t: each piece is a graph y(x)
    t = np.linspace(0, 1, 9)
    on = evaluate(cp, np.tile(t, (len(cp), 1))).reshape(6, -1, 2)
    np.testing.assert_allclose(scene.boundary_y(on[0, :, 0])[0], on[0, :, 1], atol=1e-9)
    assert (np.diff(scene.boundary_y(np.linspace(0, 300, 1001)), axis=0) > 0).all()  # boundaries never meet
    rows = np.concatenate([scene.rows(y0, min(150, y0 + 17), 120, 150) for y0 in range(0, 150, 17)])
    X, Y = np.meshgrid((np.arange(120) + 0.5) * 2.5, (np.arange(150) + 0.5) * 2.0)
    exact = scene.value(np.stack([X.ravel(), Y.ravel()], 1)).reshape(150, 120, 3)
    np.testing.assert_allclose(rows, exact, rtol=0, atol=1e-6)
    p = np.array([[150.0, scene.boundary_y(np.array([150.0]))[2, 0]]])
    above, below = scene.value(p - [0, 1e-7]), scene.value(p + [0, 1e-7])
    assert np.abs(above - below).max() > 1e-3  # a jump across every boundary


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 60), st.booleans())
def test_subtended_runs_equal_the_segment_by_segment_sum(seed, n, closed):
    """The angle a polyline subtends, taken a run of segments at a time (the run's end points alone from outside its
    bounding box), equals the sum over every segment: for open and closed polylines, at points on, beside and far
    from them, on their vertices' coordinates (the boxes' edges) included."""
    rng = np.random.default_rng(seed)
    poly = np.cumsum(rng.normal(0.0, 1.0, (n, 2)), axis=0)
    if closed:
        poly = np.concatenate([poly, poly[:1]])
    inner = poly[rng.integers(0, len(poly), 40)] + rng.normal(0.0, 0.3, (40, 2))
    edges = np.stack([poly[rng.integers(0, len(poly), 40), 0], poly[rng.integers(0, len(poly), 40), 1]], axis=1)
    xy = np.concatenate([inner, edges, rng.uniform(poly.min() - 5, poly.max() + 5, (40, 2))])
    xy = xy[np.min(np.linalg.norm(xy[:, None] - poly[None], axis=2), axis=1) > 1e-6]  # off the vertices
    d = poly[None] - xy[:, None]
    a, b = d[:, :-1], d[:, 1:]
    whole = np.arctan2(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], (a * b).sum(-1)).sum(-1) / (2 * np.pi)
    np.testing.assert_allclose(subtended(xy, poly, run=4), whole, atol=1e-12)
    np.testing.assert_allclose(subtended(xy, poly), whole, atol=1e-12)
