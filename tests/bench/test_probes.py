"""Probes from the curves alone: junctions at corners and meetings, tips at the free ends of open curves, smooth
points far from every curve."""

import numpy as np
import pytest

from dfc.bench.probes import PROBE_KINDS, junctions, labelled_probes, smooth_points, tips
from dfc.bench.scenes import sample_scene, shapes_scene, strokes_scene
from dfc.geometry import bezier

SHAPES, STROKES, SAMPLE = shapes_scene(), strokes_scene(), sample_scene()


def _distance(points, curves):
    poly = bezier.flatten(curves.control_points, 200).reshape(-1, 2)
    return np.min(np.linalg.norm(points[:, None] - poly[None], axis=2), axis=1)


def test_star_points_and_lens_corners_are_junctions():
    found = junctions(SHAPES.curves)
    star = SHAPES.curves.control_points[SHAPES.curves.curve == SHAPES.curves.names.index("star")][:, 0]
    lens = np.array([[60.0, 200.0], [180.0, 200.0]])
    expected = np.concatenate([star, lens])
    assert len(found) == len(expected)
    assert np.min(np.linalg.norm(found[:, None] - expected[None], axis=2), axis=1).max() < 1e-9
    circle = np.array([[100.0, 75.0]])  # a smooth join of the circle's cubics is no junction
    assert np.min(np.linalg.norm(found - circle, axis=1)) > 1.0


def test_free_ends_of_open_strokes_are_tips():
    found = tips(STROKES.curves)
    expected = np.array([[40, 60], [200, 50], [50, 200], [170, 210], [190, 120], [200, 215]], dtype=float)
    assert len(found) == 6
    assert np.min(np.linalg.norm(found[:, None] - expected[None], axis=2), axis=1).max() < 1e-9
    assert len(tips(SHAPES.curves)) == 0  # closed curves only
    assert np.allclose(tips(SAMPLE.curves), [[30, 40], [130, 70]])  # the arch's ends lie on the border


@pytest.mark.parametrize("scene", [SHAPES, STROKES, SAMPLE], ids=lambda s: s.name)
def test_smooth_points_are_far_from_curves_and_border(scene):
    pts = smooth_points(scene.curves, 3)
    assert pts.shape == (3, 2) and len(np.unique(pts, axis=0)) == 3
    assert _distance(pts[:1], scene.curves)[0] > 20.0
    x0, y0, x1, y1 = scene.domain
    assert np.all((pts > [x0 + 10, y0 + 10]) & (pts < [x1 - 10, y1 - 10]))


def test_labelled_probes_in_kind_order():
    points, kinds = labelled_probes(STROKES.curves, {"edge": 1, "junction": 1, "tip": 2, "smooth": 1})
    assert kinds == ["edge", "junction", "tip", "tip", "smooth"] and points.shape == (5, 2)
    assert _distance(points[:4], STROKES.curves).max() < 1e-3
    points, kinds = labelled_probes(SHAPES.curves)
    assert set(kinds) == set(PROBE_KINDS) - {"tip"}
