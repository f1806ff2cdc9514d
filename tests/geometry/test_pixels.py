"""The pixels a mesh's discontinuities cross."""

import numpy as np

from dfc.geometry.curves import Curves, elevate
from dfc.geometry.pixels import edge_pixels
from dfc.geometry.triangulate import triangulate


def test_edge_pixels_marks_crossed_pixels():
    cp = elevate(np.array([[(2.75, 0.0), (2.75, 8.0)]]), 1)
    mesh = triangulate(Curves((0.0, 0.0, 8.0, 8.0), cp, [1], [0], [(0, 1)], names=["l"], sides=[None]), max_triangles=50)
    mask = edge_pixels(mesh, 8, 16)  # 2 pixels per unit in x: x = 2.75 is the middle of column 5
    expect = np.zeros((8, 16), bool)
    expect[:, 5] = True
    np.testing.assert_array_equal(mask, expect)
