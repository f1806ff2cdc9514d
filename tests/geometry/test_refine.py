"""Curve refinement against the pixels (``dfc.geometry.sources.refine``): known sub-pixel offsets come back through
each pixel filter, junctions and T-junctions stay joined, curves stay inside the image, crossing curves are left as
given with a warning, curves outside the image are refused."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.bench.pixel_filters import filtered_raster
from dfc.bench.scenes import AnalyticScene, _pieces
from dfc.bench.speed.curves_auto import compare
from dfc.errors import InputError
from dfc.geometry.sources.auto import refine_detected
from dfc.geometry.sources.refine import GAUSS_HERMITE, _gaussian_side, crossings, refine_curves
from dfc.pixel_filter import parse

OFFSET = np.array([0.13, -0.09])


def _quad_and_disc(size: float = 56.0) -> AnalyticScene:
    """A quadrilateral (lines) and a disc (four cubics, within 0.003 px of the circle whose inside the values
    follow): 0.85 and 0.1 on 0.45."""
    quad = [(7.3, 8.2), (22.1, 9.0), (20.4, 45.2), (6.9, 43.7)]
    c, r = np.array([40.2, 27.3]), 9.1
    k = 0.5522847498 * r
    circle = [(3, [(c[0] + r, c[1]), (c[0] + r, c[1] + k), (c[0] + k, c[1] + r), (c[0], c[1] + r)]),
              (3, [(c[0], c[1] + r), (c[0] - k, c[1] + r), (c[0] - r, c[1] + k), (c[0] - r, c[1])]),
              (3, [(c[0] - r, c[1]), (c[0] - r, c[1] - k), (c[0] - k, c[1] - r), (c[0], c[1] - r)]),
              (3, [(c[0], c[1] - r), (c[0] + k, c[1] - r), (c[0] + r, c[1] - k), (c[0] + r, c[1])])]
    chains = [("quad", [(1, [quad[i], quad[(i + 1) % 4]]) for i in range(4)]), ("disc", circle)]
    curves = _pieces(chains, (0.0, 0.0, size, size))
    poly = np.array(quad)

    def value(xy):
        a, b = poly, np.roll(poly, -1, axis=0)
        cross = ((b[:, 0] - a[:, 0])[None] * (xy[:, 1:2] - a[:, 1][None])
                 - (b[:, 1] - a[:, 1])[None] * (xy[:, 0:1] - a[:, 0][None]))
        out = np.where(np.all(cross > 0, axis=1) | np.all(cross < 0, axis=1), 0.85, 0.45)
        return np.where(np.hypot(*(xy - c).T) < r, 0.1, out)[:, None]

    return AnalyticScene("quad and disc", curves, ["Y"], value)


@pytest.fixture(scope="module")
def shapes():
    return _quad_and_disc()


@pytest.mark.parametrize("spec, mean, p95", [("box", 0.01, 0.02), ("gaussian:0.5", 0.01, 0.02),
                                             ("box:4", 0.015, 0.05)])
def test_a_known_offset_comes_back_through_each_filter(shapes, spec, mean, p95):
    """A raster made with the filter, its curves moved by (0.13, −0.09) px (0.11 px mean distance): the refined
    curves lie within the tolerance of the true ones (box:4: its 4 x 4 sub-samples leave a near-horizontal edge
    free within a quarter pixel, hence the wider p95)."""
    pixels = filtered_raster(shapes, 56, 56, spec)
    true = shapes.curves
    moved = replace(true, control_points=true.control_points + OFFSET)
    assert compare(true, moved)["mean_px"] > 0.1
    refined = refine_curves(pixels, moved, parse(spec))
    assert refined.warning is None and refined.pixels > 50
    assert refined.misfit_after < refined.misfit_before
    found = compare(true, refined.curves)
    assert found["mean_px"] <= mean and found["p95_px"] <= p95, found
    closed = refined.curves.control_points
    for c in range(true.n_curves):  # each outline stays closed: its pieces still meet end to start
        cp = closed[refined.curves.curve == c]
        assert np.abs(cp[:, 3] - np.roll(cp[:, 0], -1, axis=0)).max() < 1e-9
    lines = refined.curves.degree == 1  # lines stay lines
    chord = closed[lines, 3] - closed[lines, 0]
    np.testing.assert_allclose(closed[lines, 1], closed[lines, 0] + chord / 3, atol=1e-9)



@pytest.mark.parametrize("made, first", [("box:6", "box:16"), ("box:16", "box:6")])
def test_a_filter_detected_again_along_the_refined_curves_refines_them_again(shapes, made, first):
    """Curves a few hundredths of a pixel off cannot tell a box of 6 x 6 sub-samples from one of 16 x 16: refined
    through the wrong one, they show the right one, and refined again through it they come closer."""
    pixels = filtered_raster(shapes, 56, 56, made)
    true = shapes.curves
    moved = replace(true, control_points=true.control_points + OFFSET)
    first_pass = refine_curves(pixels, moved, parse(first))
    once = compare(true, first_pass.curves)
    refined = refine_detected(pixels, moved, parse(first))
    assert refined.pixel_filter == made and refined.warning is None
    again = compare(true, refined.curves)
    assert again["mean_px"] < 0.75 * once["mean_px"] and again["p95_px"] <= 0.012 < once["p95_px"], (once, again)
    assert refined.moved.max() == pytest.approx(np.linalg.norm(refined.curves.control_points - moved.control_points,
                                                               axis=2).max())
    # the misfit before is that of the curves as given (0.11 px off: about 7.6 % of the jump through either box),
    # not of the first refinement's (under 1 %)
    assert refined.misfit_before == pytest.approx(first_pass.misfit_before, rel=0.1)
    assert refined.misfit_before > 5 * refined.misfit_after


def test_moves_and_misfit_are_measured_from_the_origin_given(shapes):
    """``origin``: a refinement that continues from refined curves reports its move and its misfit before from the
    curves it was asked to measure from; without it, from the curves it starts at."""
    pixels = filtered_raster(shapes, 56, 56, "box")
    moved = replace(shapes.curves, control_points=shapes.curves.control_points + OFFSET)
    first = refine_curves(pixels, moved, parse("box"))
    plain = refine_curves(pixels, first.curves, parse("box"))
    measured = refine_curves(pixels, first.curves, parse("box"), origin=moved)
    np.testing.assert_array_equal(measured.curves.control_points, plain.curves.control_points)
    assert measured.misfit_after == plain.misfit_after
    assert plain.moved.max() < 0.1 < measured.moved.max()  # the given offset is 0.16 px
    assert measured.moved.max() == pytest.approx(np.linalg.norm(measured.curves.control_points - moved.control_points,
                                                                axis=2).max())
    assert measured.misfit_before > 5 * plain.misfit_before
    with pytest.raises(ValueError, match="origin"):
        refine_curves(pixels, first.curves, parse("box"), origin=replace(moved, domain=(0.0, 0.0, 112.0, 112.0)))


def test_a_filter_the_refined_curves_confirm_is_refined_with_once(shapes):
    pixels = filtered_raster(shapes, 56, 56, "gaussian:0.5")
    moved = replace(shapes.curves, control_points=shapes.curves.control_points + OFFSET)
    refined = refine_detected(pixels, moved, parse("gaussian:0.5"))
    assert refined.pixel_filter == "gaussian:0.5"
    np.testing.assert_array_equal(refined.curves.control_points,
                                  refine_curves(pixels, moved, parse("gaussian:0.5")).curves.control_points)

def test_edges_beside_hdr_light_are_refined(shapes):
    """The disc made an emitter (40 against the quad's jump of 0.4): the quad's pixels still count (a jump is
    measured tone-mapped, as the file's PSNR is) and both outlines come back from the known offset."""
    def value(xy):
        v = shapes.value(xy)
        return np.where(v == 0.1, 40.0, v)

    pixels = filtered_raster(replace(shapes, value=value), 56, 56, "gaussian:0.5")
    true = shapes.curves
    refined = refine_curves(pixels, replace(true, control_points=true.control_points + OFFSET), parse("gaussian:0.5"))
    found = compare(true, refined.curves)
    assert found["mean_px"] <= 0.01 and found["p95_px"] <= 0.02, found


@settings(max_examples=25, deadline=None)
@given(along=st.floats(-1.5, 1.5), across=st.floats(-1.5, 1.5), kappa=st.floats(-0.3, 0.3),
       sigma=st.floats(0.3, 1.0))
def test_gaussian_share_and_moment_are_the_filter_on_the_parabola_side(along, across, kappa, sigma):
    # the closed form across the curve (normal tail and first moment) against a midpoint sum of the isotropic
    # Gaussian, 1000 cells along and 4000 across (a cell row holds at most 1.2e-3 of the mass)
    u, v = (((np.arange(n) + 0.5) / n * 2 - 1) * 6 * sigma for n in (1000, 4000))
    gu, gv = np.exp(-0.5 * (u / sigma) ** 2), np.exp(-0.5 * (v / sigma) ** 2)
    U, V = np.meshgrid(u, v, indexing="ij")
    w = np.outer(gu / gu.sum(), gv / gv.sum()) * (across + V - 0.5 * kappa * (along + U) ** 2 > 0)
    nodes, weights = np.polynomial.hermite_e.hermegauss(GAUSS_HERMITE)
    at = [torch.tensor([[x]], dtype=torch.float64) for x in (along, across, kappa)]
    share, moment = _gaussian_side(*at,
                                   torch.from_numpy(sigma * nodes), torch.from_numpy(weights / weights.sum()), sigma)
    assert float(share[0]) == pytest.approx(w.sum(), abs=1e-3)
    assert moment[0].numpy() == pytest.approx([(w * U).sum(), (w * V).sum()], abs=1e-3 * sigma)


def test_point_samples_end_on_the_side_their_pixels_say(shapes):
    """Point samples hold no mixture: a curve is only known to lie between pixel centres of different values. After
    refinement the pixel centres lie on the side of the curves their values say (the moved curves get 56 wrong; one
    may stay wrong at a corner, whose pixels are not fitted)."""
    from dfc.bench.scenes import inside
    from dfc.geometry import bezier

    pixels = filtered_raster(shapes, 56, 56, "point")[..., 0]
    true = shapes.curves
    moved = replace(true, control_points=true.control_points + 3 * OFFSET)
    jj, ii = np.mgrid[0:56, 0:56]
    centres = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], axis=1)

    def wrong(curves):
        outline = [bezier.flatten(curves.control_points[curves.curve == c], 64)[:, :-1].reshape(-1, 2) for c in (0, 1)]
        made = np.where(inside(centres, outline[1]), 0.1, np.where(inside(centres, outline[0]), 0.85, 0.45))
        return int((np.abs(made - pixels.ravel()) > 1e-6).sum())

    assert wrong(true) == 0 and wrong(moved) > 50
    refined = refine_curves(pixels, moved, parse("point"))
    assert wrong(refined.curves) <= 1
    assert compare(true, refined.curves)["mean_px"] < 0.5 * compare(true, moved)["mean_px"]


def _sectors(size: float, centre, spec: str):
    """(scene, raster made with ``spec``) of a Y junction at ``centre``: sectors of values 0.2, 0.55 and 0.9 between
    rays at 90°, 210° and 330° to the border, the first cut by a T's stem (value 0.7 beyond it) from the middle of the
    ray at 210° to the left border. Its curves: the three rays, then the stem."""
    c = np.asarray(centre, dtype=np.float64)
    angles = np.radians([90.0, 210.0, 330.0])
    ends = []
    for a in angles:
        d = np.array([np.cos(a), np.sin(a)])
        t = min(((0 if d[k] < 0 else size) - c[k]) / d[k] for k in (0, 1) if abs(d[k]) > 1e-12)
        ends.append(c + t * d)
    foot = c + 0.45 * (ends[1] - c)  # the stem's end on the ray at 210°
    stem_end = np.array([0.0, foot[1] + 6.0])

    def value(xy):
        rel = xy - c
        ang = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
        out = np.where((ang >= 90) & (ang < 210), 0.2, np.where((ang >= 210) & (ang < 330), 0.55, 0.9))
        # below the stem inside the 90..210 sector: another value
        stem = stem_end - foot
        side = stem[0] * (xy[:, 1] - foot[1]) - stem[1] * (xy[:, 0] - foot[0])
        out = np.where((ang >= 90) & (ang < 210) & (side < 0), 0.7, out)
        return out[:, None]

    chains = [(f"ray {k}", [(1, [tuple(c), tuple(e)])]) for k, e in enumerate(ends)]
    chains.append(("stem", [(1, [tuple(foot), tuple(stem_end)])]))
    curves = _pieces(chains, (0.0, 0.0, size, size))
    scene = AnalyticScene("sectors", curves, ["Y"], value)
    return scene, filtered_raster(scene, int(size), int(size), spec)


def test_junctions_and_t_junctions_stay_joined():
    scene, pixels = _sectors(40.0, (20.3, 17.6), "box:8")
    true = scene.curves
    cp = true.control_points.copy()
    cp[:3, 0] += OFFSET  # the Y junction moved: all three rays' start, and the stem's end with its ray
    cp[3, 0] = cp[1, 0] + 0.45 * (cp[1, 3] - cp[1, 0])
    cp[:, 1:3] = cp[:, 0:1] + (cp[:, 3:4] - cp[:, 0:1]) * np.array([1 / 3, 2 / 3])[None, :, None]
    given = replace(true, control_points=cp)
    refined = refine_curves(pixels, given, parse("box:8"))
    out = refined.curves.control_points
    assert refined.warning is None
    assert np.abs(out[:3, 0] - out[0, 0]).max() < 1e-9  # the Y's rays still share their start
    junction_error = np.linalg.norm(out[0, 0] - true.control_points[0, 0])
    assert junction_error < 0.5 * np.linalg.norm(OFFSET)
    ray = out[1]  # the stem's end still lies on the ray at 210° (a line: distance to its chord)
    d = ray[3] - ray[0]
    stem_start = out[3, 0]
    assert abs(d[0] * (stem_start[1] - ray[0, 1]) - d[1] * (stem_start[0] - ray[0, 0])) / np.linalg.norm(d) < 1e-9
    assert np.abs(out[:, 3][[0, 1, 2]] - true.control_points[:3, 3]).max() < 1.0  # border ends stay near
    for k in range(3):  # ends on the border stay on it
        end = out[k, 3]
        assert min(end[0], end[1], 40.0 - end[0], 40.0 - end[1]) < 1e-9
    assert (out >= 0).all() and (out <= 40.0).all()


def test_crossing_curves_are_left_as_given_with_a_warning(shapes):
    pixels = filtered_raster(shapes, 56, 56, "box")
    x = _pieces([("a", [(1, [(5.0, 5.0), (30.0, 30.0)])]), ("b", [(1, [(5.0, 30.0), (30.0, 5.0)])])],
                (0.0, 0.0, 40.0, 40.0))
    assert crossings(x.control_points) == [(0, 1)]
    refined = refine_curves(pixels, x, parse("box"))
    assert refined.warning is not None and "cross" in refined.warning and "'a'" in refined.warning
    np.testing.assert_array_equal(refined.curves.control_points, x.control_points)


def test_crossing_pieces_stay_and_the_others_are_refined(shapes):
    """Two crossing lines away from the disc are left as given (with a warning); the disc, moved by (0.13, −0.09)
    px, is refined back as when alone."""
    pixels = filtered_raster(shapes, 56, 56, "box")
    disc = shapes.curves.curve == 1
    true = replace(shapes.curves, control_points=shapes.curves.control_points[disc], degree=shapes.curves.degree[disc],
                   curve=np.zeros(int(disc.sum()), dtype=np.int64), t_range=shapes.curves.t_range[disc],
                   names=["disc"], sides=[None])
    x = _pieces([("a", [(1, [(2.0, 48.0), (6.0, 54.0)])]), ("b", [(1, [(2.0, 54.0), (6.0, 48.0)])])],
                (0.0, 0.0, 56.0, 56.0))
    moved = replace(true, control_points=true.control_points + OFFSET)
    both = replace(moved, control_points=np.concatenate([moved.control_points, x.control_points]),
                   degree=np.concatenate([moved.degree, x.degree]), curve=np.r_[moved.curve, x.curve + 1],
                   t_range=np.concatenate([moved.t_range, x.t_range]), names=["disc", "a", "b"], sides=[None] * 3)
    refined = refine_curves(pixels, both, parse("box"))
    assert refined.warning is not None and "'a' and 'b'" in refined.warning and "crossing pieces" in refined.summary()
    out = refined.curves.control_points
    np.testing.assert_array_equal(out[-2:], x.control_points)
    alone = refine_curves(pixels, moved, parse("box")).curves
    assert compare(true, replace(alone, control_points=out[:-2]))["mean_px"] <= 0.01


def test_shared_endpoints_are_no_crossing(shapes):
    assert crossings(shapes.curves.control_points) == []


def test_curves_outside_the_image_are_refused(shapes):
    pixels = filtered_raster(shapes, 56, 56, "box")
    out = _pieces([("far", [(1, [(5.0, 5.0), (45.0, 20.0)])])], (0.0, 0.0, 40.0, 40.0))
    with pytest.raises(InputError, match="'far' reaches outside the image"):
        refine_curves(pixels, out, parse("box"))


def test_curves_over_another_domain_are_refined_in_its_units(shapes):
    """Curves over a domain twice the image's size are scaled onto it and back."""
    pixels = filtered_raster(shapes, 56, 56, "box")
    true = shapes.curves
    big = replace(true, domain=(0.0, 0.0, 112.0, 112.0), control_points=(true.control_points + OFFSET) * 2.0)
    refined = refine_curves(pixels, big, parse("box"))
    assert refined.curves.domain == big.domain
    back = replace(refined.curves, domain=true.domain, control_points=refined.curves.control_points / 2.0)
    assert compare(true, back)["mean_px"] < 0.02


def test_pieces_a_refinement_would_make_cross_are_held_and_the_others_refined(shapes):
    """A line ends 0.05 px outside the disc moved by (0.13, −0.09) px, 0.13 px inside the true one: refining the
    disc makes them cross, so the line and the disc piece it would cross stay as given (with a warning naming
    them) and the disc's other three pieces are refined, to within 0.02 px of the true circle."""
    pixels = filtered_raster(shapes, 56, 56, "box")
    disc = shapes.curves.curve == 1
    true = replace(shapes.curves, control_points=shapes.curves.control_points[disc], degree=shapes.curves.degree[disc],
                   curve=np.zeros(int(disc.sum()), dtype=np.int64), t_range=shapes.curves.t_range[disc],
                   names=["disc"], sides=[None])
    moved = replace(true, control_points=true.control_points + OFFSET)
    centre, y = np.array([40.2, 27.3]) + OFFSET, 31.3
    end = centre[0] - np.sqrt(9.1**2 - (y - centre[1]) ** 2) - 0.05
    line = _pieces([("line", [(1, [(25.0, y), (end, y)])])], (0.0, 0.0, 56.0, 56.0))
    both = replace(moved, control_points=np.concatenate([moved.control_points, line.control_points]),
                   degree=np.r_[moved.degree, line.degree], curve=np.r_[moved.curve, line.curve + 1],
                   t_range=np.concatenate([moved.t_range, line.t_range]), names=["disc", "line"], sides=[None] * 2)
    assert crossings(both.control_points) == []
    refined = refine_curves(pixels, both, parse("box"))
    assert refined.warning is not None and "'disc' and 'line' would make curves cross" in refined.warning
    out = refined.curves.control_points
    assert crossings(out) == []
    held = [k for k in range(5) if np.array_equal(out[k], both.control_points[k])]
    assert held == [1, 4]  # the quarter of the disc the line points into, and the line
    assert refined.to_dict()["left_as_given"] == 2 and "warning" not in refined.to_dict()  # a file's header: short

    def distance(k, cp):
        one = replace(true, control_points=cp[k:k + 1], degree=true.degree[k:k + 1], curve=true.curve[k:k + 1],
                      t_range=true.t_range[k:k + 1])
        return compare(replace(one, control_points=true.control_points[k:k + 1]), one)["mean_px"]

    for k in (0, 2, 3):
        assert distance(k, moved.control_points) > 0.05 and distance(k, out) < 0.02


def test_a_side_that_is_no_plane_gives_no_pixels(monkeypatch):
    """A vertical edge at x = 20.3 px (0.8 | 0.2) given at 20.43, and an uncurved texture step (0.2 → 0.35) 2.7 px
    to its right, where side B is read: read as a plane, that side pulls the curve away from the edge; the
    planarity test drops those pixels, so the curve stays as given."""
    from dfc.bench.scenes import AnalyticScene
    from dfc.geometry.sources import refine as module

    edge = _pieces([("edge", [(1, [(20.3, 0.0), (20.3, 40.0)])])], (0.0, 0.0, 40.0, 40.0))
    scene = AnalyticScene("edge", edge, ["Y"],
                          lambda xy: np.where(xy[:, 0] < 20.3, 0.8, np.where(xy[:, 0] > 23.0, 0.35, 0.2))[:, None])
    pixels = filtered_raster(scene, 40, 40, "box")
    given = replace(edge, control_points=edge.control_points + [0.13, 0.0])
    refined = refine_curves(pixels, given, parse("box"))
    assert refined.pixels == 0 and "no clean mixed pixels" in refined.summary()
    np.testing.assert_array_equal(refined.curves.control_points, given.control_points)
    monkeypatch.setattr(module, "PLANAR", np.inf)
    x = refine_curves(pixels, given, parse("box")).curves.control_points[0, :, 0]
    assert np.all(x > 20.435)  # away from the edge at 20.3
