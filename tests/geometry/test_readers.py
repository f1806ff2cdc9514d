"""Curve file readers: SVG path/shape semantics, the JSON schema and round trip, diffusion-curve XML."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.errors import CurveError
from dfc.geometry.curves import Curves, SideValues, elevate
from dfc.geometry.sources import read_curves
from dfc.geometry.sources import read_any, write_json
from dfc.geometry.sources.dcxml import read_dcxml
from dfc.geometry.sources.svg import arc_pieces
from dfc.geometry.tolerances import tol

from ..conftest import SAMPLES

SAMPLE_JSON = SAMPLES / "sample.json"

SVG_NS = 'xmlns="http://www.w3.org/2000/svg"'


def bezier(cp: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points (N, 2) of the cubic cp (4, 2) at parameters t (N,)."""
    t = t[:, None]
    return (1 - t) ** 3 * cp[0] + 3 * (1 - t) ** 2 * t * cp[1] + 3 * (1 - t) * t**2 * cp[2] + t**3 * cp[3]


def svg_curves(tmp_path, body: str, root: str = 'viewBox="0 0 100 100"') -> Curves:
    f = tmp_path / "t.svg"
    f.write_text(f"<svg {SVG_NS} {root}>{body}</svg>")
    return read_any(f)


def ends(c: Curves) -> np.ndarray:
    """(P, 2, 2) start and end point of every piece."""
    return c.control_points[:, [0, 3]]


# ----------------------------------------------------------------------------------------- SVG paths


def test_svg_lines_absolute_relative_hv_close(tmp_path):
    c = svg_curves(tmp_path, '<path id="a" d="M10,20 L30,40 l10,0 H60 h5 V80 v-5 Z"/>')
    expected = [[(10, 20), (30, 40)], [(30, 40), (40, 40)], [(40, 40), (60, 40)], [(60, 40), (65, 40)],
                [(65, 40), (65, 80)], [(65, 80), (65, 75)], [(65, 75), (10, 20)]]
    np.testing.assert_array_equal(ends(c), expected)
    assert (c.degree == 1).all() and c.names == ["path#a"]
    np.testing.assert_array_equal(c.t_range, np.stack([np.arange(7), np.arange(1, 8)], 1))
    np.testing.assert_allclose(c.control_points, elevate(np.array(expected, float), 1))


@pytest.mark.parametrize("d", ["M0,0 10,0 10,10", "m0,0 10,0 0,10", "M0,0 L10,0 10,10", "M0 0l10 0l0 10", "M0,0H10V10"])
def test_svg_implicit_repeats(tmp_path, d):
    c = svg_curves(tmp_path, f'<path d="{d}"/>')
    np.testing.assert_array_equal(ends(c), [[(0, 0), (10, 0)], [(10, 0), (10, 10)]])


@pytest.mark.parametrize("d", ["M0,0 C10,0 20,10 20,20 S30,40 40,40", "M0,0 c10,0 20,10 20,20 s10,20 20,20",
                               "M0,0 C10,0 20,10 20,20 30,30 30,40 40,40"])
def test_svg_smooth_cubic_reflects_the_previous_control_point(tmp_path, d):
    c = svg_curves(tmp_path, f'<path d="{d}"/>')
    assert list(c.degree) == [3, 3]
    np.testing.assert_array_equal(c.control_points[0], [(0, 0), (10, 0), (20, 10), (20, 20)])
    second = [(20, 20), (20, 30), (30, 40), (40, 40)] if "S" in d.upper() else [(20, 20), (30, 30), (30, 40), (40, 40)]
    np.testing.assert_array_equal(c.control_points[1], second)


def test_svg_smooth_cubic_without_previous_cubic_starts_at_current_point(tmp_path):
    c = svg_curves(tmp_path, '<path d="M5,5 S10,20 20,20"/>')
    np.testing.assert_array_equal(c.control_points[0], [(5, 5), (5, 5), (10, 20), (20, 20)])


@pytest.mark.parametrize("d", ["M0,0 Q10,10 20,0 T40,0", "m0,0 q10,10 20,0 t20,0", "M0,0 Q10,10 20,0 30,-10 40,0"])
def test_svg_quadratics_and_smooth_t(tmp_path, d):
    c = svg_curves(tmp_path, f'<path d="{d}"/>')
    assert list(c.degree) == [2, 2]
    np.testing.assert_allclose(c.control_points, elevate(np.array([[(0, 0), (10, 10), (20, 0)],
                                                                  [(20, 0), (30, -10), (40, 0)]], float), 2))


def _arc_points(c: Curves) -> np.ndarray:
    t = np.linspace(0, 1, 201)
    return np.concatenate([bezier(cp, t) for cp in c.control_points])


@pytest.mark.parametrize(
    "d, centre, r, sweep_fraction, through",
    [
        ("M0,0 A10,10 0 0 1 20,0", (10, 0), 10, 0.5, (10, -10)),  # sweep 1: increasing angle (clockwise on screen)
        ("M0,0 A10,10 0 0 0 20,0", (10, 0), 10, 0.5, (10, 10)),
        ("M0,0 A10,10 0 1 0 10,10", (0, 10), 10, 0.75, (-10 / math.sqrt(2), 10 + 10 / math.sqrt(2))),
        ("M0,0 A10,10 0 0 0 10,10", (10, 0), 10, 0.25, (10 - 10 / math.sqrt(2), 10 / math.sqrt(2))),
        ("M0,0 a10,10 0 1 1 10,10", (10, 0), 10, 0.75, (10 + 10 / math.sqrt(2), -10 / math.sqrt(2))),
        ("M0,0 A1,1 0 0 1 20,0", (10, 0), 10, 0.5, (10, -10)),  # radii too small are scaled up
    ],
)
def test_svg_arcs_flags_and_accuracy(tmp_path, d, centre, r, sweep_fraction, through):
    c = svg_curves(tmp_path, f'<path d="{d}"/>')
    assert (c.degree == 3).all()
    end = (20, 0) if "20,0" in d else (10, 10)
    np.testing.assert_allclose(c.control_points[0, 0], (0, 0), atol=1e-12)
    np.testing.assert_allclose(c.control_points[-1, 3], end, atol=1e-12)
    np.testing.assert_allclose(c.control_points[1:, 0], c.control_points[:-1, 3], atol=1e-12)  # a chain
    p = _arc_points(c)
    radial = np.abs(np.hypot(*(p - centre).T) - r)
    assert radial.max() <= tol.svg_arc_rel * c.diagonal
    assert np.hypot(*(p - through).T).min() < 1e-2
    length = np.hypot(*np.diff(p, axis=0).T).sum()
    assert length == pytest.approx(2 * math.pi * r * sweep_fraction, rel=1e-3)


def test_svg_rotated_elliptical_arc_stays_on_the_ellipse(tmp_path):
    c = svg_curves(tmp_path, '<path d="M50,50 A30,10 30 1 1 60,60"/>')
    p = _arc_points(c)
    # fit the centre of the ellipse with the file's radii and rotation, then check every point lies on it
    cx, cy = _centre_of(p)
    rot = np.radians(30)
    u = (p - (cx, cy)) @ np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
    value = np.hypot(u[:, 0] / 30, u[:, 1] / 10)
    assert np.abs(value - 1).max() * 30 <= tol.svg_arc_rel * c.diagonal * 3


def _centre_of(p: np.ndarray) -> np.ndarray:
    """Centre of the rotated ellipse (rx 30, ry 10, 30°) through points p: least squares on its conic form."""
    rot = np.radians(30)
    r = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
    m = r @ np.diag([1 / 30**2, 1 / 10**2]) @ r.T  # (p - c)^T M (p - c) = 1
    # linear in c and k = c^T M c - 1: p^T M p - 2 p^T M c + k = 0
    a = np.c_[-2 * p @ m, np.ones(len(p))]
    b = -np.einsum("ni,ij,nj->n", p, m, p)
    sol = np.linalg.lstsq(a, b, rcond=None)[0]
    return sol[:2]


def test_arc_piece_count_meets_tolerance_and_quarter_turns():
    assert arc_pieces(math.pi / 2, 1.0, 1.0) == 1
    assert arc_pieces(2 * math.pi, 1.0, 1.0) == 4  # never more than 90° per cubic
    assert arc_pieces(2 * math.pi, 100.0, 1e-3) > arc_pieces(2 * math.pi, 100.0, 1e-1)


def test_svg_degenerate_arcs(tmp_path):
    c = svg_curves(tmp_path, '<path d="M0,0 A0,5 0 0 1 10,10 A5,5 0 0 1 10,10"/>')
    np.testing.assert_array_equal(ends(c), [[(0, 0), (10, 10)]])  # zero radius: a line; same end: nothing
    assert list(c.degree) == [1]


def test_svg_nested_transforms(tmp_path):
    body = ('<g transform="translate(10,0)"><g transform="scale(2)"><path d="M1,1 L2,1"/>'
            '<g transform="rotate(90)"><path d="M1,0 L2,0"/></g></g></g>'
            '<path transform="matrix(1 0 0 1 5 5) skewX(45)" d="M0,0 L0,10"/>')
    c = svg_curves(tmp_path, body)
    np.testing.assert_allclose(ends(c), [[(12, 2), (14, 2)], [(10, 2), (10, 4)], [(5, 5), (15, 15)]], atol=1e-12)


def test_svg_subpaths_moves_and_close(tmp_path):
    c = svg_curves(tmp_path, '<path id="p" d="M5,5 M0,0 L10,0 L0,0 Z m20,20 l1,0 Z l0,3"/><path d="M1,1"/>')
    # the empty move and the M-only path vanish; the degenerate Z adds nothing; after Z a new subpath starts
    assert c.names == ["path#p subpath 0", "path#p subpath 1", "path#p subpath 2"]
    np.testing.assert_array_equal(c.curve, [0, 0, 1, 1, 2])
    np.testing.assert_array_equal(ends(c), [[(0, 0), (10, 0)], [(10, 0), (0, 0)], [(20, 20), (21, 20)],
                                            [(21, 20), (20, 20)], [(20, 20), (20, 23)]])
    np.testing.assert_array_equal(c.t_range[:, 0], [0, 1, 0, 1, 0])


# ---------------------------------------------------------------------------------------- SVG shapes


def test_svg_basic_shapes(tmp_path):
    body = ('<rect x="1" y="2" width="3" height="4"/><line x1="0" y1="0" x2="5" y2="6"/>'
            '<polyline points="0,0 1,0 1,1"/><polygon points="0,0 4,0 0,3"/>')
    c = svg_curves(tmp_path, body)
    assert c.names == ["rect[0]", "line[1]", "polyline[2]", "polygon[3]"]
    assert np.bincount(c.curve).tolist() == [4, 1, 2, 3] and (c.degree == 1).all()
    np.testing.assert_array_equal(ends(c)[c.curve == 0, 0], [(1, 2), (4, 2), (4, 6), (1, 6)])
    np.testing.assert_array_equal(ends(c)[c.curve == 3], [[(0, 0), (4, 0)], [(4, 0), (0, 3)], [(0, 3), (0, 0)]])


def test_svg_circle_ellipse_rounded_rect(tmp_path):
    body = '<circle cx="50" cy="50" r="30"/><ellipse cx="50" cy="50" rx="40" ry="20"/><rect x="10" y="10" width="50" height="30" rx="5"/>'
    c = svg_curves(tmp_path, body)
    t = np.linspace(0, 1, 101)
    circle = np.concatenate([bezier(cp, t) for cp in c.control_points[c.curve == 0]])
    assert np.abs(np.hypot(*(circle - 50).T) - 30).max() <= tol.svg_arc_rel * c.diagonal
    ellipse = np.concatenate([bezier(cp, t) for cp in c.control_points[c.curve == 1]])
    assert np.abs(np.hypot((ellipse[:, 0] - 50) / 40, (ellipse[:, 1] - 50) / 20) - 1).max() * 40 <= 2 * tol.svg_arc_rel * c.diagonal
    rect = c.curve == 2
    assert sorted(np.bincount(c.degree[rect], minlength=4)[[1, 3]] > 0) == [True, True]
    assert (c.degree[rect] == 1).sum() == 4
    corners = ends(c)[rect].reshape(-1, 2)
    assert corners[:, 0].min() == pytest.approx(10) and corners[:, 1].max() == pytest.approx(40)
    # closed: each shape ends where it starts
    for k in range(3):
        cp = c.control_points[c.curve == k]
        np.testing.assert_allclose(cp[-1, 3], cp[0, 0], atol=1e-9)


# ---------------------------------------------------------------------------------- SVG viewport/units


def test_svg_coordinates_stay_in_viewbox_units(tmp_path):
    root = 'width="200mm" height="100mm" viewBox="10 20 40 20"'
    c = svg_curves(tmp_path, '<path d="M10,20 L50,40"/><circle cx="30" cy="30" r="5"/>', root)
    assert c.domain == (10, 20, 50, 40)
    np.testing.assert_allclose(ends(c)[0], [(10, 20), (50, 40)], atol=1e-12)
    circle = c.control_points[c.curve == 1][:, 0]
    np.testing.assert_allclose(np.hypot(*(circle - 30).T), 5, atol=1e-9)


def test_svg_viewbox_with_other_aspect_ratio(tmp_path):
    c = svg_curves(tmp_path, '<path d="M0,0 L10,5"/>', 'width="100" height="100" viewBox="0 0 10 5"')
    assert c.domain == (0, 0, 10, 5)
    np.testing.assert_allclose(ends(c)[0], [(0, 0), (10, 5)], atol=1e-12)


def test_svg_without_viewbox_uses_width_height_in_px(tmp_path):
    c = svg_curves(tmp_path, '<path d="M0,0 L3,4"/>', 'width="120" height="80"')
    assert c.domain == (0, 0, 120, 80)
    c = svg_curves(tmp_path, '<path d="M0,0 L3,4"/>', 'width="1in" height="2in"')
    assert c.domain == pytest.approx((0, 0, 96, 192))
    np.testing.assert_array_equal(ends(c)[0], [(0, 0), (3, 4)])


def test_svg_ignores_text_defs_and_hidden(tmp_path):
    body = ('<defs><path id="d" d="M0,0 L1,1"/></defs><text x="1" y="1">x</text>'
            '<path d="M2,2 L3,3" style="display:none"/><use href="#d" x="10"/>')
    c = svg_curves(tmp_path, body)
    np.testing.assert_allclose(ends(c), [[(10, 0), (11, 1)]])


def test_svg_without_shapes_is_empty(tmp_path):
    c = svg_curves(tmp_path, "")
    assert len(c) == 0 and c.n_curves == 0 and c.domain == (0, 0, 100, 100)


@pytest.mark.parametrize(
    "text, message",
    [
        (f'<svg {SVG_NS}><path d="M0,0 L1,1"/></svg>', "no viewBox and no absolute width and height"),
        (f'<svg {SVG_NS} width="100%" height="100%"><path d="M0,0 L1,1"/></svg>', "domain is unknown"),
        (f'<svg {SVG_NS} viewBox="0 0 10 zz"/>', "viewBox"),
        (f'<svg {SVG_NS} viewBox="0 0 10 0"/>', "viewBox"),
        (f'<svg {SVG_NS} viewBox="0 0 9 9">\n<path id="q" d="M0,0 L1,x"/></svg>', "line 2: <path id='q'>: malformed path data"),
        (f'<svg {SVG_NS} viewBox="0 0 9 9">\n<path d="M0,0 L1,1"></svg>', "line 2, column"),
        (f'<svg {SVG_NS} viewBox="0 0 9 9"><path d="M0,0 L1e400,1"/></svg>', "NaN or infinite"),
        (f'<svg {SVG_NS} viewBox="0 0 9 9"><path d="L1,1"/></svg>', "must begin with a moveto"),
        ("<html/>", "not <svg>"),
        ("  \n", "empty file"),
    ],
)
def test_svg_errors(tmp_path, text, message):
    f = tmp_path / "bad.svg"
    f.write_text(text)
    with pytest.raises(CurveError, match="bad.svg") as e:
        read_any(f)
    assert message in str(e.value)


def test_svg_engine_geometry(shared_data):
    c = read_curves(shared_data / "svg" / "engine_geometry.svg")
    assert c.domain == (0, 0, 989.52, 1037)
    assert c.n_curves == 6  # the two move-only paths vanish: outline, 4 circles, inner loop
    assert 60 <= len(c) <= 300
    assert set(np.unique(c.degree)) == {1, 3}
    slack = 13 / 2  # half the widest stroke
    p = c.control_points[:, [0, 3]].reshape(-1, 2)
    x0, y0, x1, y1 = c.domain
    assert (p[:, 0] >= x0 - slack).all() and (p[:, 0] <= x1 + slack).all()
    assert (p[:, 1] >= y0 - slack).all() and (p[:, 1] <= y1 + slack).all()
    # the big circle keeps its radius in viewBox units
    circle = c.control_points[c.curve == 1][:, 0]
    np.testing.assert_allclose(np.hypot(*(circle - (511.86, 791.25)).T), 135.34, atol=1e-9)


# ----------------------------------------------------------------------------------------------- JSON


def _sample_curves() -> Curves:
    line = elevate(np.array([[(0.1, 0.2), (3.3, 1.7)]]), 1)
    quad = elevate(np.array([[(3.3, 1.7), (4.1, 5.9), (7.0, 2.0)]]), 2)
    cubic = np.array([[(1.0, 1.0), (2.0, 9.0), (8.0, 9.0), (9.0, 1.0)]])
    cp = np.concatenate([line, quad, cubic])
    sides = SideValues(np.array([0.0, 2.0]), np.array([[1.0, 0.0, 0.5], [0.2, 0.3, 0.4]]),
                       np.array([0.0, 1.0, 2.0]), np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5]]))
    return Curves((0, 0, 10, 10), cp, [1, 2, 3], [0, 0, 1], [[0, 1], [1, 2], [0, 1]], ["edge", "curves[1]"], [sides, None])


def _assert_same(a: Curves, b: Curves) -> None:
    assert a.domain == b.domain and a.names == b.names
    np.testing.assert_array_equal(a.degree, b.degree)
    np.testing.assert_array_equal(a.curve, b.curve)
    np.testing.assert_array_equal(a.t_range, b.t_range)
    exact = a.degree != 2
    np.testing.assert_array_equal(a.control_points[exact], b.control_points[exact])
    scale = max(1.0, float(np.abs(a.control_points).max(initial=0)))  # quadratics: a few ulps of the coordinates
    np.testing.assert_allclose(a.control_points[~exact], b.control_points[~exact], rtol=0, atol=8 * np.finfo(float).eps * scale)
    for sa, sb in zip(a.sides, b.sides):
        assert (sa is None) == (sb is None)
        if sa is not None:
            for f in ("left_s", "left", "right_s", "right"):
                np.testing.assert_array_equal(getattr(sa, f), getattr(sb, f))


def test_json_round_trip(tmp_path):
    a = _sample_curves()
    write_json(a, tmp_path / "c.json")
    b = read_any(tmp_path / "c.json")
    _assert_same(a, b)
    assert b.source.endswith("c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["format"] == "dfc-curves/1"
    assert [p["type"] for p in doc["curves"][0]["pieces"]] == ["line", "quadratic"]
    assert doc["curves"][0]["pieces"][1]["points"][1] == pytest.approx([4.1, 5.9], abs=1e-14)


def test_json_round_trip_keeps_split_t_ranges(tmp_path):
    a = _sample_curves()
    a = Curves(a.domain, a.control_points, a.degree, a.curve, [[0, 0.5], [0.5, 2], [0, 1]], a.names, a.sides)
    write_json(a, tmp_path / "c.json")
    _assert_same(a, read_any(tmp_path / "c.json"))


points = st.floats(-1e3, 1e3, allow_nan=False).map(float)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([1, 2, 3]), st.lists(st.tuples(points, points), min_size=4, max_size=4),
                          st.integers(0, 3)), min_size=0, max_size=12))
def test_json_round_trip_property(tmp_path_factory, pieces):
    degree = np.array([d for d, _, _ in pieces], dtype=np.int8)
    raw = [np.array(p[: d + 1], float) for d, p, _ in pieces]
    cp = np.stack([elevate(r[None], d)[0] for (d, _, _), r in zip(pieces, raw)]) if pieces else np.zeros((0, 4, 2))
    curve = np.sort([c for _, _, c in pieces]).astype(np.int64)
    k = np.concatenate([np.arange((curve == c).sum()) for c in range(4)]) if pieces else np.zeros(0)
    a = Curves((-1e3, -1e3, 1e3, 1e3), cp, degree, curve, np.stack([k, k + 1], 1) if pieces else np.zeros((0, 2)),
               [f"c{i}" for i in range(4)], [None] * 4)
    f = tmp_path_factory.mktemp("rt") / "c.json"
    write_json(a, f)
    b = read_any(f)
    _assert_same(a, b)


LINE = {"type": "line", "points": [[0, 0], [1, 1]]}


def doc_with(curves=None, pieces=None) -> dict:
    """A JSON curves document over the unit square."""
    doc = {"domain": [0, 0, 1, 1]}
    doc.update({k: v for k, v in (("curves", curves), ("pieces", pieces)) if v is not None})
    return doc


def stops(*pairs) -> list[dict]:
    return [{"s": s, "value": v} for s, v in pairs]


def test_json_top_level_pieces_and_empty(tmp_path):
    f = tmp_path / "c.json"
    cubic = {"type": "cubic", "points": [[0, 1], [0, 0], [1, 0], [1, 1]]}
    f.write_text(json.dumps({"domain": [0, 0, 1, 1], "pieces": [LINE, cubic]}))
    c = read_any(f)
    assert c.names == ["pieces[0]", "pieces[1]"] and c.curve.tolist() == [0, 1]
    f.write_text('{"domain": [0, 0, 2, 1]}')
    c = read_any(f)
    assert len(c) == 0 and c.domain == (0, 0, 2, 1)


@pytest.mark.parametrize(
    "doc, message",
    [
        (doc_with([{"pieces": [LINE]}, {"pieces": [LINE]}, {"pieces": [{"type": "cubic", "points": [[0, 0], [1, 1], [2, 2]]}]}]),
         "c.json: curves[2].pieces[0]: cubic needs 4 points, got 3"),
        ({"curves": []}, "missing key 'domain'"),
        ({"domain": [0, 0, 1]}, "domain: expected 4 numbers, got 3"),
        ({"domain": [0, 0, 0, 1]}, "domain: [0.0, 0.0, 0.0, 1.0] is not a rectangle"),
        ({"domain": [0, 0, 1, 1], "format": "dfc-curves/9"}, "unsupported format"),
        ({"domain": [0, 0, 1, 1], "curve": []}, "unknown key 'curve'"),
        (doc_with(pieces=[{"type": "arc", "points": []}]), "pieces[0].type: 'arc' is not one of"),
        (doc_with(pieces=[{"type": "line", "points": [[0, 0], [1, True]]}]), "pieces[0].points[1]: expected a list of numbers"),
        (doc_with(pieces=[{"type": "line", "points": [[0, 0], ["1", 1]]}]), "expected a list of numbers"),
        (doc_with(pieces=[{"type": "line", "points": [[0, 0], [1, 1]], "t": [1, 1]}]), "must be increasing"),
        (doc_with([{"pieces": [LINE], "left": stops((0, [1]))}]), "give both 'left' and 'right'"),
        (doc_with([{"pieces": [LINE], "left": stops((0, [1])), "right": stops((2, [1]))}]),
         "curves[0].right: positions s must lie in the curve's parameter range [0, 1]"),
        (doc_with([{"pieces": [LINE], "left": stops((0.5, [1]), (0.2, [1])), "right": stops((0, [1]))}]), "non-decreasing"),
        (doc_with([{"pieces": [LINE], "left": stops((0, [1]), (1, [1, 2])), "right": stops((0, [1]))}]), "same non-zero length"),
        (doc_with([{"pieces": [LINE], "left": stops((0, [1])), "right": stops((0, [1]))},
                   {"pieces": [LINE], "left": stops((0, [1, 2])), "right": stops((0, [1, 2]))}]),
         "different lengths across curves"),
        ([1, 2], "expected an object, got a list"),
    ],
)
def test_json_errors(tmp_path, doc, message):
    f = tmp_path / "c.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(CurveError) as e:
        read_any(f)
    assert message in str(e.value) and "c.json" in str(e.value)


@pytest.mark.parametrize(
    "text, message",
    [
        ('{"domain": [0, 0, 1, 1], "pieces": [{"type": "line", "points": [[0, NaN], [1, 1]]}]}', "pieces[0].points[0]: NaN or infinite"),
        ('{"domain": [0, 0, Infinity, 1]}', "domain: NaN or infinite"),
        ('{"domain": [0, 0, 1, 1],\n "pieces": [}', "line 2, column"),
        ("", "empty file"),
    ],
)
def test_json_text_errors(tmp_path, text, message):
    f = tmp_path / "c.json"
    f.write_text(text)
    with pytest.raises(CurveError, match="c.json") as e:
        read_any(f)
    assert message in str(e.value)


# ------------------------------------------------------------------------------------ diffusion-curve XML


def test_xml_shipped_files(shared_data):
    folder = shared_data / "diffusion-curves"
    for name, n_curves in [("poivron_orzan.xml", 38), ("sunset_illustration.xml", 1), ("test_curve.xml", 1)]:
        c = read_any(folder / name)
        assert c.domain == (0, 0, 512, 512) and c.n_curves == n_curves
        assert (c.degree == 3).all()
        raw = (folder / name).read_text()
        declared = [int(v) for v in __import__("re").findall(r'nb_control_points="(\d+)"', raw)]
        assert np.bincount(c.curve).tolist() == [(n - 1) // 3 for n in declared]  # 3k + 1 -> k cubics
        assert all((n - 1) % 3 == 0 for n in declared)
        for ci, side in enumerate(c.sides):
            k = (c.curve == ci).sum()
            assert side is not None and side.left.shape[1] == side.right.shape[1] == 3
            for s, v in ((side.left_s, side.left), (side.right_s, side.right)):
                assert s[0] == 0 and s[-1] == k and (np.diff(s) >= 0).all()  # globalID / 10 spans [0, k]
                assert ((v >= 0) & (v <= 1)).all()
        p = c.control_points.reshape(-1, 2)
        assert (p >= 0).all() and (p <= 512).all()
        # chains: consecutive cubics of one curve share their end points
        same = c.curve[1:] == c.curve[:-1]
        np.testing.assert_array_equal(c.control_points[1:, 0][same], c.control_points[:-1, 3][same])


def test_xml_orzan_transposes_and_swaps_red_blue(shared_data):
    c = read_any(shared_data / "diffusion-curves" / "poivron_orzan.xml")
    # file: <control_point x="122.3125" y="310.5"/>, <left_color G="59" R="46" globalID="0" B="181"/>
    np.testing.assert_array_equal(c.control_points[0, 0], (310.5, 122.3125))
    np.testing.assert_allclose(c.sides[0].left[0], np.array([181, 59, 46]) / 255)
    # plausibility: the pepper's outline (curve 33) is red on the pepper side and near-white outside
    side = c.sides[33]
    assert side.left[:, 0].mean() > 0.6 > side.left[:, 2].mean() and side.right.mean() > 0.85


def test_xml_pepper_outline_is_red_inside(shared_data):
    c = read_any(shared_data / "diffusion-curves" / "poivron_orzan.xml")
    cp = c.control_points[c.curve == 33]
    k = len(cp)
    mid = cp[k // 2]
    point, tangent = bezier(mid, np.array([0.5]))[0], 0.75 * (mid[3] + mid[2] - mid[1] - mid[0])
    left_normal = np.array([tangent[1], -tangent[0]])  # cross(tangent, left_normal) < 0: dfc's left
    centre = c.control_points.reshape(-1, 2).mean(0)
    assert np.dot(left_normal, centre - point) > 0  # the left side faces the pepper ...
    assert c.sides[33].at(np.array([k // 2 + 0.5]), "left")[0, 0] > 0.6  # ... and is red


def test_xml_test_curve_is_sunset_in_orzan_encoding(shared_data):
    folder = shared_data / "diffusion-curves"
    sunset = read_dcxml(folder / "sunset_illustration.xml")
    as_orzan = read_dcxml(folder / "test_curve.xml", convention="orzan")
    as_written = read_dcxml(folder / "test_curve.xml")
    np.testing.assert_array_equal(sunset.control_points, as_orzan.control_points)
    np.testing.assert_array_equal(sunset.control_points, as_written.control_points[..., ::-1])
    for f in ("left_s", "left", "right_s", "right"):
        np.testing.assert_array_equal(getattr(sunset.sides[0], f), getattr(as_orzan.sides[0], f))
    # SceneXML's 'left' is dfc's right: the sun's pale core colour (255, 253, 166) is inside, on dfc's right
    np.testing.assert_allclose(sunset.sides[0].right.max(0), np.array([255, 253, 166]) / 255)


XML_CURVE = """<curve nb_control_points="4"><control_points_set>
<control_point x="1" y="2"/><control_point x="3" y="4"/><control_point x="5" y="6"/><control_point x="7" y="8"/>
</control_points_set>
<left_colors_set><left_color R="255" G="0" B="0" globalID="0"/><left_color R="0" G="0" B="255" globalID="10"/></left_colors_set>
<right_colors_set><right_color r="0.5" g="0.5" b="0.5" globalID="5"/></right_colors_set>
</curve>"""
XML_BAD_COLOUR = XML_CURVE.replace('R="255"', 'R="300"')
XML_BAD_POINT = XML_CURVE.replace('x="3"', 'x="inf"')
XML_NO_RIGHT = XML_CURVE.replace("<right_color ", "<rightx ")
XML_WIDE_IDS = XML_CURVE.replace('globalID="10"', 'globalID="10000"')


def test_xml_scene_mapping(tmp_path):
    f = tmp_path / "s.xml"
    f.write_text(f'<!DOCTYPE SceneXML>\n<scene image_width="20" image_height="10"><curve_set nb_curves="1">{XML_CURVE}</curve_set></scene>')
    c = read_any(f)
    assert c.domain == (0, 0, 20, 10)
    np.testing.assert_array_equal(c.control_points[0], [(1, 2), (3, 4), (5, 6), (7, 8)])
    side = c.sides[0]
    np.testing.assert_array_equal(side.left_s, [0.5])  # the file's right side
    np.testing.assert_array_equal(side.left, [[0.5, 0.5, 0.5]])
    np.testing.assert_array_equal(side.right_s, [0, 1])
    np.testing.assert_array_equal(side.right, [[1, 0, 0], [0, 0, 1]])
    f.write_text(f'<curve_set image_width="20" image_height="10" nb_curves="1">{XML_CURVE}</curve_set>')
    c = read_any(f)
    np.testing.assert_array_equal(c.control_points[0], [(2, 1), (4, 3), (6, 5), (8, 7)])
    np.testing.assert_array_equal(c.sides[0].left, [[0, 0, 1], [1, 0, 0]])
    # globalIDs beyond 10 k (an exporter writing 0..10000) are scaled onto [0, k], per side
    f.write_text(f'<curve_set image_width="20" image_height="10">{XML_WIDE_IDS}</curve_set>')
    side = read_any(f).sides[0]
    np.testing.assert_array_equal(side.left_s, [0, 1])
    np.testing.assert_array_equal(side.right_s, [0.5])


def test_xml_without_curves_is_empty(tmp_path):
    f = tmp_path / "s.xml"
    f.write_text('<scene image_width="20" image_height="10"/>')
    c = read_any(f)
    assert len(c) == 0 and c.domain == (0, 0, 20, 10)


@pytest.mark.parametrize(
    "text, message",
    [
        ('<scene image_width="20" image_height="10">\n<curve_set>\n<curve', "line 3, column"),
        ('<curves image_width="20" image_height="10"/>', "neither <scene> nor <curve_set>"),
        ('<scene image_width="20"/>', "lacks the attribute image_height"),
        ('<scene image_width="-2" image_height="10"/>', "not a positive finite number"),
        ('<scene image_width="nan" image_height="10"/>', "not a positive finite number"),
        (f'<scene image_width="20" image_height="10"><curve_set nb_curves="2">{XML_CURVE}</curve_set></scene>', "nb_curves='2' but the file holds 1"),
        ('<scene image_width="20" image_height="10"><curve_set>\n<curve><control_points_set><control_point x="1" y="2"/>'
         '<control_point x="1" y="2"/></control_points_set></curve></curve_set></scene>', "line 2: curve 0: 2 control points"),
        (f'<scene image_width="20" image_height="10"><curve_set>{XML_NO_RIGHT}</curve_set></scene>',
         "curve 0: no <right_color> stops"),
        (f'<scene image_width="20" image_height="10"><curve_set>{XML_BAD_COLOUR}</curve_set></scene>',
         "R=300 outside [0, 255]"),
        (f'<scene image_width="20" image_height="10"><curve_set>{XML_BAD_POINT}</curve_set></scene>',
         "x='inf' is not finite"),
        ("", "empty file"),
    ],
)
def test_xml_errors(tmp_path, text, message):
    f = tmp_path / "d.xml"
    f.write_text(text)
    with pytest.raises(CurveError, match="d.xml") as e:
        read_any(f)
    assert message in str(e.value)


# ------------------------------------------------------------------------------------------- dispatch


def test_read_any_rejects_unknown_content_and_missing_file(tmp_path):
    (tmp_path / "c.txt").write_text("M 0 0 L 1 1")
    with pytest.raises(CurveError, match=r"c\.txt: unknown curves file extension '\.txt' and content that is neither"):
        read_any(tmp_path / "c.txt")
    with pytest.raises(CurveError, match="no such file"):
        read_any(tmp_path / "absent.txt")
    with pytest.raises(CurveError, match="no such file"):
        read_curves(tmp_path / "absent.json")


def test_read_any_by_content_when_the_extension_says_nothing(tmp_path):
    """Curves piped through standard input arrive without an extension: JSON, SVG and diffusion-curve XML are told
    apart by their content."""
    sample = read_any(SAMPLE_JSON)
    (tmp_path / "stdin").write_bytes(SAMPLE_JSON.read_bytes())
    got = read_any(tmp_path / "stdin")
    np.testing.assert_array_equal(got.control_points, sample.control_points)
    (tmp_path / "svg").write_text('<?xml version="1.0"?>\n<svg xmlns="http://www.w3.org/2000/svg" width="10" '
                                  'height="10"><path d="M 1 1 L 9 9"/></svg>')
    assert read_any(tmp_path / "svg").domain == (0.0, 0.0, 10.0, 10.0)
    (tmp_path / "xml").write_text("<curve_set/>")
    with pytest.raises(CurveError) as e:  # read as diffusion-curve XML, which refuses an empty set by its own rule
        read_any(tmp_path / "xml")
    assert "unknown curves file extension" not in str(e.value)
