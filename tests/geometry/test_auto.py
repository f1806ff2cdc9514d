"""``dfc.geometry.sources.auto``: the curves ``dfc encode --curves auto`` and the benchmarks fit an image with."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.special import erf

from dfc.geometry.curves import Curves, elevate, fit_curves_to_domain
from dfc.geometry.sources.auto import find_curves, ready_curves

pytest.importorskip("skimage")

W = H = 64


def _image():
    """A box-filtered step along x = 20.4 + 0.15 (y - 32) (64 × 64 points a pixel) and a soft shadow's edge (σ 3 px)
    at x = 44, in three channels."""
    ss = 64
    y, x = (np.mgrid[0:H * ss, 0:W * ss] + 0.5) / ss
    share = (x > _edge(y)).reshape(H, ss, W, ss).mean(axis=(1, 3))
    xc = (np.mgrid[0:H, 0:W][1] + 0.5).astype(np.float64)
    soft = 0.5 + 0.3 * 0.5 * (1 + erf((xc - 44.0) / (3.0 * np.sqrt(2))))
    return np.repeat(np.where(xc < 32, 0.2 + 0.6 * share, soft)[..., None], 3, axis=-1)


def _edge(y):
    return 20.4 + 0.15 * (y - 32.0)


def _lines(offset: float):
    """The step's line ``offset`` px right of it and the soft edge's, over the image's domain."""
    ends = [[[_edge(0.0) + offset, 0.0], [_edge(H) + offset, float(H)]], [[44.0, 0.0], [44.0, float(H)]]]
    cp = np.stack([elevate(np.array(e)[None], 1)[0] for e in ends])
    return Curves((0.0, 0.0, float(W), float(H)), cp, [1, 1], np.arange(2), [[0.0, 1.0]] * 2, ["step", "soft"],
                  [None] * 2, source="auto")


def _off(cp):
    """Distance (px) of control points (..., 2) over the image's domain from the step."""
    return np.abs(cp[..., 0] - _edge(cp[..., 1])) / np.hypot(1.0, 0.15)


@pytest.mark.parametrize("scale", [1.0, 0.25])
def test_ready_curves_prune_then_refine_over_any_domain(scale):
    """The soft edge is dropped, the step's curve (0.2 px off) is moved onto the step; the curves come back over their
    own domain with their source, the filter detected along them (the box) as the encoder detects it."""
    curves = fit_curves_to_domain(_lines(0.2), (0.0, 0.0, W * scale, H * scale))
    ready, pruned, refined = ready_curves(_image(), curves)
    assert pruned.kept.tolist() == [True, False] and refined is not None and not refined.warning
    assert ready.names == ["step"] and ready.source == "auto" and ready.domain == curves.domain
    assert _off(ready.control_points / scale).max() <= 0.02


def test_ready_curves_does_only_what_it_is_asked():
    curves = _lines(0.2)
    kept, pruned, refined = ready_curves(_image(), curves, refine=False)
    assert refined is None and kept.names == ["step"]
    np.testing.assert_array_equal(kept.control_points, curves.control_points[:1])
    moved, pruned, refined = ready_curves(_image(), curves, prune=False, pixel_filter="box")
    assert pruned is None and moved.names == ["step", "soft"]
    assert _off(moved.control_points[0]).max() <= 0.02
    same, pruned, refined = ready_curves(_image(), replace(curves, source="file"), prune=False, refine=False)
    assert pruned is refined is None and same.source == "file"


def test_find_curves_places_a_point_sampled_edge_with_the_point_filter():
    y, x = np.mgrid[0:H, 0:W] + 0.5
    image = (0.3 + 0.5 * ((x - 32.3) ** 2 + (y - 31.6) ** 2 < 20.7 ** 2))[..., None].repeat(3, axis=2)
    curves, used, record, detection = find_curves(image)
    assert str(used) == "point" and record["pixel_filter"] == "point" and curves.source == "auto"
    assert detection.filter == used and detection.pixels > 0  # the evidence the encode reports
    assert find_curves(image, "box")[3] is None  # a given filter is not detected
    assert record["curves"] == curves.n_curves == 1 and record["pieces"] == len(curves) <= 8
