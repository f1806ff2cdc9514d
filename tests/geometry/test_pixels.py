"""The pixels a mesh's discontinuities cross."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

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


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**16), st.integers(1, 40))
def test_edge_mask_bands_equal_the_whole_mask(seed, rows):
    from dfc.bench.speed.mesh import random_cubics
    from dfc.geometry.pixels import EdgeMask

    mesh = triangulate(random_cubics(3, seed), max_triangles=400)
    mask = EdgeMask(mesh, 90, 70)
    whole = edge_pixels(mesh, 90, 70)
    assert whole.any()
    bands = np.concatenate([mask.rows(y0, min(90, y0 + rows)) for y0 in range(0, 90, rows)])
    np.testing.assert_array_equal(bands, whole)
    np.testing.assert_array_equal(edge_pixels(mesh, 90, 70, rows=(13, 29)), whole[13:29])
    np.testing.assert_array_equal(mask.rows(13, 29, cols=(rows, 61)), whole[13:29, rows:61])  # a tile
