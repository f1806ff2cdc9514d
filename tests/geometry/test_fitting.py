"""Fitting lines and cubics to points (``dfc.geometry.fitting``): within the tolerance, corners kept sharp."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.geometry import bezier
from dfc.geometry.fitting import fit_points


def _distance_to(cp: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance (n,) from each point to the nearest piece (Newton from 17 starts on every piece)."""
    starts = np.linspace(0.0, 1.0, 17)
    many = np.repeat(cp, len(points) * len(starts), axis=0)
    pts = np.tile(np.repeat(points, len(starts), axis=0), (len(cp), 1))
    t = bezier.closest_parameter(many, pts, np.tile(starts, len(points) * len(cp)))
    d = np.linalg.norm(bezier.evaluate(many, t) - pts, axis=1)
    return d.reshape(len(cp), len(points), len(starts)).min(axis=(0, 2))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 40.0), min_size=8, max_size=8))
def test_points_on_a_cubic_are_fitted_within_tolerance(coords):
    cp = np.array(coords, dtype=np.float64).reshape(1, 4, 2)
    length = np.linalg.norm(np.diff(bezier.flatten(cp, 200)[0], axis=0), axis=1).sum()
    n = max(4, int(length))
    points = bezier.evaluate(cp, np.linspace(0.0, 1.0, n)[None])[0]  # about one point per unit of length
    points = points[np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-3]]
    if len(points) < 2:
        return
    degree, fitted = fit_points(points, tolerance=0.05, corner_angle=180.0)  # no corners: cusps fitted too
    assert np.array_equal(fitted[1:, 0], fitted[:-1, 3])  # a chain
    assert np.array_equal(fitted[0, 0], points[0]) and np.array_equal(fitted[-1, 3], points[-1])
    assert _distance_to(fitted, points).max() <= 0.05 + 1e-9
    assert set(degree.tolist()) <= {1, 3}


def test_polygon_with_gaps_at_its_corners_comes_back_exact():
    rng = np.random.default_rng(3)
    vertices = np.array([[10.0, 10.0], [50.0, 12.0], [44.0, 40.0], [14.0, 36.0]])
    points = []
    for a, b in zip(vertices, np.roll(vertices, -1, axis=0)):
        t = np.linspace(0.0, 1.0, int(np.linalg.norm(b - a)))[:, None]
        far = (t[:, 0] * np.linalg.norm(b - a) > 4) & ((1 - t[:, 0]) * np.linalg.norm(b - a) > 4)
        points.append((a + (b - a) * t)[far])  # no points within 4 units of a corner
    points = np.concatenate(points) + 0.005 * rng.standard_normal((sum(map(len, points)), 2))
    degree, cp = fit_points(points, tolerance=0.05, closed=True)
    assert degree.tolist() == [1, 1, 1, 1]
    corners = cp[:, 0][np.argsort(np.linalg.norm(cp[:, 0][:, None] - vertices[None], axis=2).argmin(axis=0))]
    assert np.abs(np.sort(cp[:, 0], axis=0) - np.sort(vertices, axis=0)).max() < 0.02
    assert np.array_equal(cp[-1, 3], cp[0, 0]) and len(corners) == 4


def test_circle_has_no_corners():
    t = np.linspace(0.0, 2 * np.pi, 80, endpoint=False)
    points = np.stack([20 + 9 * np.cos(t), 20 + 9 * np.sin(t)], axis=1)
    degree, cp = fit_points(points, tolerance=0.05, closed=True)
    tangents_out = bezier.derivative(cp, np.zeros(len(cp)))
    tangents_in = bezier.derivative(np.roll(cp, 1, axis=0), np.ones(len(cp)))
    cos = (tangents_out * tangents_in).sum(1) / np.linalg.norm(tangents_out, axis=1) / np.linalg.norm(tangents_in, axis=1)
    assert cos.min() > np.cos(np.radians(5))  # smooth everywhere, the seam included
    assert np.abs(np.linalg.norm(bezier.flatten(cp, 50).reshape(-1, 2) - 20, axis=1) - 9).max() < 0.05
