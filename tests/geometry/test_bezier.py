"""Tests of the vectorised Bézier kernel against direct formulas."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.geometry import bezier as bz
from dfc.geometry.curves import elevate

seeds = st.integers(0, 2**31 - 1)


def _random(seed, n=16):
    rng = np.random.default_rng(seed)
    return rng.uniform(-5.0, 5.0, size=(n, 4, 2)), rng.uniform(0.0, 1.0, size=n), rng


def _direct(cp, t):
    t = t[:, None]
    return ((1 - t) ** 3 * cp[:, 0] + 3 * (1 - t) ** 2 * t * cp[:, 1] + 3 * (1 - t) * t**2 * cp[:, 2] + t**3 * cp[:, 3])


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_evaluate_and_derivatives_match_formulas(seed):
    cp, t, _ = _random(seed)
    np.testing.assert_allclose(bz.evaluate(cp, t), _direct(cp, t), atol=1e-12)
    h = 1e-6
    fd = (_direct(cp, t + h) - _direct(cp, t - h)) / (2 * h)
    np.testing.assert_allclose(bz.derivative(cp, t), fd, atol=1e-6)
    fd2 = (_direct(cp, t + h) - 2 * _direct(cp, t) + _direct(cp, t - h)) / h**2
    np.testing.assert_allclose(bz.second_derivative(cp, t), fd2, atol=1e-2)
    grid = np.tile(np.linspace(0, 1, 5), (len(cp), 1))
    out = bz.evaluate(cp, grid)
    assert out.shape == (len(cp), 5, 2)
    np.testing.assert_array_equal(out[:, 0], cp[:, 0])  # the ends are exact
    np.testing.assert_array_equal(out[:, -1], cp[:, 3])
    assert bz.derivative(cp, grid).shape == bz.second_derivative(cp, grid).shape == (len(cp), 5, 2)


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_split_halves_reproduce_the_curve(seed):
    cp, t, _ = _random(seed)
    left, right = bz.split(cp, t)
    np.testing.assert_array_equal(left[:, 3], right[:, 0])
    np.testing.assert_array_equal(left[:, 3], bz.evaluate(cp, t))
    u = np.linspace(0.0, 1.0, 7)
    for k in u:
        uk = np.full(len(cp), k)
        np.testing.assert_allclose(bz.evaluate(left, uk), bz.evaluate(cp, t * k), atol=1e-12)
        np.testing.assert_allclose(bz.evaluate(right, uk), bz.evaluate(cp, t + (1 - t) * k), atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_split_many_and_subsegment(seed):
    cp, _, rng = _random(seed)
    ts = np.sort(rng.uniform(0.0, 1.0, size=4))
    parts = bz.split_many(cp[0], ts)
    assert parts.shape == (5, 4, 2)
    np.testing.assert_array_equal(parts[:-1, 3], parts[1:, 0])
    np.testing.assert_array_equal(parts[0, 0], cp[0, 0])
    np.testing.assert_array_equal(parts[-1, 3], cp[0, 3])
    knots = np.concatenate([[0.0], ts, [1.0]])
    mid = 0.5 * (knots[:-1] + knots[1:])
    expected = bz.evaluate(np.repeat(cp[:1], 5, 0), mid)
    np.testing.assert_allclose(bz.evaluate(parts, np.full(5, 0.5)), expected, atol=1e-12)
    rev = bz.subsegment(cp, np.ones(len(cp)), np.zeros(len(cp)))  # reversed
    np.testing.assert_allclose(rev, cp[:, ::-1], atol=1e-12)


def test_flatten_shape_and_ends():
    cp, _, _ = _random(0, n=3)
    poly = bz.flatten(cp, 10)
    assert poly.shape == (3, 11, 2)
    np.testing.assert_array_equal(poly[:, 0], cp[:, 0])
    np.testing.assert_allclose(poly[:, 5], _direct(cp, np.full(3, 0.5)), atol=1e-12)


def test_inflections_of_known_curves():
    s_curve = np.array([[[0, 0], [1, 1], [2, -1], [3, 0]]], float)
    np.testing.assert_allclose(bz.inflections(s_curve)[0, 0], 0.5, atol=1e-14)
    assert np.isnan(bz.inflections(s_curve)[0, 1])
    quad = elevate(np.array([[[0, 0], [1, 2], [3, 0]]], float), 2)
    line = elevate(np.array([[[0, 0], [3, 1]]], float), 1)
    assert np.isnan(bz.inflections(np.concatenate([quad, line]))).all()


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_inflections_are_roots_of_the_curvature(seed):
    cp, _, _ = _random(seed)
    r = bz.inflections(cp)
    i, k = np.nonzero(np.isfinite(r))
    t = r[i, k]
    d1, d2 = bz.derivative(cp[i], t), bz.second_derivative(cp[i], t)
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    scale = np.abs(np.diff(cp[i], axis=1)).max(axis=(1, 2)) ** 2 * 100
    assert (np.abs(cross) <= 1e-9 * scale).all()
    # the sign of the curvature changes at every reported root
    for row, tt in zip(i, t):
        eps = 1e-6
        d1a, d2a = bz.derivative(cp[[row, row]], np.array([tt - eps, tt + eps])), bz.second_derivative(
            cp[[row, row]], np.array([tt - eps, tt + eps]))
        c = d1a[:, 0] * d2a[:, 1] - d1a[:, 1] * d2a[:, 0]
        assert c[0] * c[1] <= 0


def test_chord_frame_maps_chord_to_unit_segment():
    cp, _, _ = _random(3)
    origin, rot, length = bz.chord_frame(cp)
    rrt = np.einsum("nij,nkj->nik", rot, rot)
    np.testing.assert_allclose(rrt, np.tile(np.eye(2), (len(cp), 1, 1)), atol=1e-12)
    np.testing.assert_allclose(length, np.hypot(*(cp[:, 3] - cp[:, 0]).T))
    local = bz.to_chord_frame(cp, cp)
    np.testing.assert_allclose(local[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(local[:, 3], np.tile([1.0, 0.0], (len(cp), 1)), atol=1e-12)
    # distances scale by 1 / length
    d_world = np.hypot(*(cp[:, 1] - cp[:, 2]).T)
    d_local = np.hypot(*(local[:, 1] - local[:, 2]).T)
    np.testing.assert_allclose(d_local * length, d_world, rtol=1e-12)


def test_end_tangents_skip_coincident_control_points():
    cp = np.array([[[0, 0], [0, 0], [1, 2], [3, 3]], [[0, 0], [1, 0], [2, 2], [2, 2]]], float)
    t0, t1 = bz.end_tangents(cp)
    np.testing.assert_allclose(t0[0], np.array([1, 2]) / np.sqrt(5))
    np.testing.assert_allclose(t1[0], np.array([2, 1]) / np.sqrt(5))
    np.testing.assert_allclose(t0[1], [1, 0])
    np.testing.assert_allclose(t1[1], np.array([1, 2]) / np.sqrt(5))
    point = np.zeros((1, 4, 2))
    assert np.isnan(bz.end_tangents(point)[0]).all()


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_tangent_apex_of_an_elevated_quadratic_is_its_control_point(seed):
    q = np.random.default_rng(seed).uniform(-5, 5, size=(8, 3, 2))
    x = bz.tangent_apex(elevate(q, 2))
    ok = np.isfinite(x).all(axis=1)
    np.testing.assert_allclose(x[ok], q[ok, 1], atol=1e-6)
    assert np.isnan(bz.tangent_apex(elevate(np.array([[[0, 0], [3, 1]]], float), 1))).all()


def test_turning_and_graph_over_chord():
    k = 4.0 / 3.0 * (np.sqrt(2) - 1)  # quarter circle
    arc = np.array([[[1, 0], [1, k], [k, 1], [0, 1]]], float)
    np.testing.assert_allclose(bz.total_turning(arc), np.pi / 2, atol=1e-9)
    np.testing.assert_allclose(bz.turning_angle(arc), np.pi / 2, atol=1e-12)
    hook = np.array([[[0, 0], [2, 1], [-1, 1], [1, 0]]], float)
    assert bz.monotone_over_chord(arc)[0] and not bz.monotone_over_chord(hook)[0]
    closed = np.array([[[0, 0], [1, 1], [-1, 1], [0, 0]]], float)
    assert not bz.monotone_over_chord(closed)[0]
    cusp = np.array([[[0, 0], [3, 3], [0, 3], [3, 0]]], float)
    assert np.isnan(bz.total_turning(cusp))[0]


def test_branches_of_a_rounded_cusp_are_graphs_over_their_chords():
    # the control points at a cusp's rounded root coincide only up to rounding, here with a step backwards
    cp = np.array([[[36.44365735511275, -0.28045404668036333], [49.61216063092667, 12.888049229133554],
                    [36.44365735511275, 12.888049229133554], [49.61216063092667, -0.28045404668036333]]])
    r = bz.cusps(cp, 1e-9)[0, 0]
    branches = bz.subsegment(np.repeat(cp, 2, axis=0), np.array([0.25, r]), np.array([r, 0.75]))
    assert bz.monotone_over_chord(branches).all()


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_monotone_over_chord_matches_dense_sampling(seed):
    cp, _, _ = _random(seed, n=64)
    t = np.tile(np.linspace(0, 1, 2001), (len(cp), 1))
    x = bz.to_chord_frame(cp, bz.evaluate(cp, t))[..., 0]
    sampled = (np.diff(x, axis=1) > 0).all(axis=1)
    exact = bz.monotone_over_chord(cp)
    assert (exact <= sampled).all()  # exact ⇒ sampled; the converse can miss tiny dips between samples
    margin = np.diff(x, axis=1).min(axis=1)
    assert (exact[margin > 1e-6] == sampled[margin > 1e-6]).all()


def test_self_intersections():
    loop = np.array([[[0, 0], [4, 4], [-1, 4], [3, 0]]], float)
    st_ = bz.self_intersections(loop)[0]
    assert 0 < st_[0] < st_[1] < 1
    p = bz.evaluate(np.repeat(loop, 2, 0), st_)
    np.testing.assert_allclose(p[0], p[1], atol=1e-12)
    plain = np.array([[[0, 0], [1, 1], [2, 1], [3, 0]]], float)
    quad = elevate(np.array([[[0, 0], [1, 2], [3, 0]]], float), 2)
    assert np.isnan(bz.self_intersections(np.concatenate([plain, quad]))).all()


def test_cusps_of_a_cusp_and_a_fold():
    cusp = np.array([[[0, 0], [3, 3], [0, 3], [3, 0]]], float)
    np.testing.assert_allclose(bz.cusps(cusp, 1e-9)[0, 0], 0.5, atol=1e-12)
    fold = np.array([[[1, 1], [3, 1], [0, 1], [2, 1]]], float)  # reverses twice along y = 1
    r = bz.cusps(fold, 1e-9)[0]
    np.testing.assert_allclose(r[:2], [(5 - np.sqrt(5)) / 10, (5 + np.sqrt(5)) / 10], atol=1e-12)
    np.testing.assert_allclose(bz.derivative(np.repeat(fold, 2, 0), r[:2]), 0.0, atol=1e-12)
    smooth = np.array([[[0, 0], [1, 1], [2, 1], [3, 0]]], float)
    assert np.isnan(bz.cusps(smooth, 1e-9)).all()


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_bernstein_roots_match_numpy(seed):
    b = np.random.default_rng(seed).uniform(-1, 1, size=(1, 4))
    r = bz.bernstein_roots(b)[0]
    b0, b1, b2, b3 = b[0]
    power = [-b0 + 3 * b1 - 3 * b2 + b3, 3 * b0 - 6 * b1 + 3 * b2, -3 * b0 + 3 * b1, b0]
    ref = np.roots(power)
    ref = np.sort(ref[(np.abs(ref.imag) < 1e-9) & (ref.real > 1e-6) & (ref.real < 1 - 1e-6)].real)
    np.testing.assert_allclose(r[np.isfinite(r)], ref, atol=1e-6)


def test_closest_parameter_and_refine_intersections():
    cp, t, _ = _random(5)
    t_found = bz.closest_parameter(cp, bz.evaluate(cp, t), np.clip(t + 0.01, 0, 1))
    np.testing.assert_allclose(bz.evaluate(cp, t_found), bz.evaluate(cp, t), atol=1e-9)
    a = elevate(np.array([[[0, 0], [4, 2]]], float), 1)
    b = elevate(np.array([[[0, 2], [4, 0]]], float), 1)
    s, u, gap = bz.refine_intersections(a, b, [0.2], [0.9])
    np.testing.assert_allclose([s[0], u[0], gap[0]], [0.5, 0.5, 0.0], atol=1e-12)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"expected \(N, 4, 2\)"):
        bz.evaluate(np.zeros((3, 3, 2)), np.zeros(3))
    with pytest.raises(ValueError, match="t: expected"):
        bz.evaluate(np.zeros((3, 4, 2)), np.zeros(2))
    with pytest.raises(ValueError, match=r"expected \(4, 2\)"):
        bz.split_many(np.zeros((2, 4, 2)), [0.5])
