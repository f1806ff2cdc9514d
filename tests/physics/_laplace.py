"""Laplace test scenes shared by the walk-on-spheres and reference-solver tests."""

import numpy as np

from dfc.geometry.curves import Curves, SideValues, elevate

X1, X2 = 16.3, 47.77  # two vertical lines across a 64 × 64 canvas, off the grid nodes
OUTER_LEFT, STRIP_LEFT, STRIP_RIGHT, OUTER_RIGHT = 0.7, 0.0, 1.0, 0.2


def sides(left, right) -> SideValues:
    """Constant values on the left and the right side of a curve."""
    return SideValues(np.zeros(1), np.atleast_2d(np.asarray(left, float)), np.zeros(1),
                      np.atleast_2d(np.asarray(right, float)))


def two_lines() -> Curves:
    """Lines x = X1, X2 drawn downwards (their left is +x): u is constant outside and linear between them,
    0.7 | (x − X1) / (X2 − X1) | 0.2."""
    lines = np.array([[[X1, 0.0], [X1, 64.0]], [[X2, 0.0], [X2, 64.0]]])
    return Curves((0, 0, 64, 64), elevate(lines, 1), [1, 1], [0, 1], [[0, 1], [0, 1]], ["x1", "x2"],
                  [sides([STRIP_LEFT], [OUTER_LEFT]), sides([OUTER_RIGHT], [STRIP_RIGHT])])
