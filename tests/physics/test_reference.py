import numpy as np
import pytest

from dfc.errors import InputError
from dfc.geometry.curves import Curves, SideValues, elevate
from dfc.physics.reference import reference_solution, solve_reference

from ._laplace import OUTER_LEFT, OUTER_RIGHT, X1, X2, two_lines


def _const(v) -> SideValues:
    v = np.atleast_2d(np.asarray(v, dtype=np.float64))
    return SideValues(np.zeros(1), v, np.zeros(1), v)


def two_lines_exact(xy: np.ndarray) -> np.ndarray:
    x = xy[:, 0]
    u = np.where(x < X1, OUTER_LEFT, np.where(x > X2, OUTER_RIGHT, (x - X1) / (X2 - X1)))
    return u[:, None]


def circle(cx: float, cy: float, r: float, n: int = 8) -> np.ndarray:
    """(n, 4, 2) cubics approximating a circle, clockwise on screen (so its inside is on the right)."""
    a = np.linspace(0.0, 2.0 * np.pi, n + 1)
    k = 4.0 / 3.0 * np.tan(np.pi / (2 * n))
    p = np.stack([np.cos(a), np.sin(a)], 1)
    tan = np.stack([-np.sin(a), np.cos(a)], 1)
    cp = np.stack([p[:-1], p[:-1] + k * tan[:-1], p[1:] - k * tan[1:], p[1:]], axis=1)
    return np.array([cx, cy]) + r * cp


R1, R2 = 8.0, 20.0  # annulus between two circles about (32, 32): u = ln(r / R2) / ln(R1 / R2)


def annulus() -> Curves:
    cp = np.concatenate([circle(32, 32, R1), circle(32, 32, R2)])
    n = len(cp) // 2
    t = np.concatenate([np.arange(n), np.arange(n)])
    return Curves((0, 0, 64, 64), cp, np.full(2 * n, 3), np.repeat([0, 1], n), np.stack([t, t + 1], 1),
                  ["inner", "outer"], [_const([1.0]), _const([0.0])])


def annulus_exact(xy: np.ndarray) -> np.ndarray:
    r = np.hypot(xy[:, 0] - 32, xy[:, 1] - 32)
    return np.clip(np.log(r / R2) / np.log(R1 / R2), 0.0, 1.0)[:, None]


def _nodes(n: int) -> np.ndarray:
    c = (np.arange(n) + 0.5) * (64.0 / n)
    x, y = np.meshgrid(c, c)
    return np.stack([x.ravel(), y.ravel()], 1)


def test_linear_solution_is_exact():
    # Shortley–Weller differences are exact for linear functions, whatever the distance to the cut
    for n in (20, 33):
        u = reference_solution(two_lines(), n, n)
        assert u.shape == (n, n, 1)
        np.testing.assert_allclose(u.reshape(-1, 1), two_lines_exact(_nodes(n)), atol=1e-10)


def test_neumann_border_gives_constant_outer_regions():
    u = reference_solution(two_lines(), 32, 24)  # not square: hx != hy
    x = (np.arange(32) + 0.5) * 2.0
    assert np.allclose(u[:, x < X1], OUTER_LEFT) and np.allclose(u[:, x > X2], OUTER_RIGHT)


def test_converges_on_the_annulus():
    errors = []
    for n in (32, 64, 128):
        xy = _nodes(n)
        r = np.hypot(xy[:, 0] - 32, xy[:, 1] - 32)
        inside = (r > R1) & (r < R2)
        u = reference_solution(annulus(), n, n).reshape(-1, 1)
        errors.append(np.abs(u - annulus_exact(xy))[inside].max())
    assert errors[0] > 2.5 * errors[1] > 2.5**2 * errors[2], errors  # about second order
    assert errors[2] < 2e-4


def test_at_interpolates_within_a_side():
    ref = solve_reference(two_lines(), 32, 32)
    # nodes at x = 15, 17 straddle X1 = 16.3: a blend across the line would give about (0.7 + 0.02) / 2
    pts = np.array([[16.2, 30.0], [16.4, 30.0], [X2 + 0.05, 63.0], [30.0, 20.3]])
    u = ref.at(pts)[:, 0]
    assert u[0] == pytest.approx(OUTER_LEFT) and u[2] == pytest.approx(OUTER_RIGHT)
    assert 0.0 < u[1] < 0.03  # the strip's own nodes only (held constant up to the line: O(h) there)
    assert u[3] == pytest.approx(two_lines_exact(pts[3:])[0, 0], abs=1e-9)
    r = solve_reference(annulus(), 96, 96)
    xy = np.random.default_rng(0).uniform(14, 50, (200, 2))
    rr = np.hypot(xy[:, 0] - 32, xy[:, 1] - 32)
    xy = xy[(rr > R1 + 1) & (rr < R2 - 1)]
    np.testing.assert_allclose(r.at(xy), annulus_exact(xy), atol=2e-3)  # bilinear: O(h²)


def test_errors():
    c = two_lines()
    with pytest.raises(InputError, match="no side values"):
        reference_solution(Curves(c.domain, c.control_points, c.degree, c.curve, c.t_range, c.names,
                                  [None, None]), 8, 8)
    tiny = elevate(np.array([[[10.1, 10.1], [10.2, 10.2]]]), 1)  # inside one cell of an 8 × 8 grid
    with pytest.raises(InputError, match="no curve crosses"):
        reference_solution(Curves((0, 0, 64, 64), tiny, [1], [0], [[0, 1]], ["dot"], [_const([1.0])]), 8, 8)
    with pytest.raises(ValueError, match="at least 2 × 2"):
        reference_solution(c, 1, 8)
