"""Property tests of ``dfc.geometry.cleanup.clean`` on fuzzed scenes: crossings, shared end points, T- and X-junctions,
lenses, "D"s, loops, duplicates, overlaps, pieces across or on the border, near-parallel and nearly straight
pieces. The checks are independent of the implementation: dense polylines and direct formulas."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from dfc.errors import CurveError
from dfc.geometry import bezier as bz
from dfc.geometry.cleanup import clean
from dfc.geometry.curves import Curves, elevate
from dfc.geometry.sources import read_curves
from dfc.geometry.tolerances import tol

DOMAIN = (0.0, 0.0, 100.0, 50.0)
DENSE = 64  # polyline segments per piece in the checks


# ------------------------------------------------------------------------------------------------ scenes


def _scene(seed: int, n_random: int, features: list[str]) -> Curves:
    """Random pieces plus the requested structured features; every piece is its own input curve."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array([-10.0, -10.0]), np.array([110.0, 60.0])
    pieces: list[tuple[np.ndarray, int]] = []

    def pt(k=1):
        return rng.uniform(lo, hi, size=(k, 2))

    def add(points, degree):
        pieces.append((elevate(np.asarray(points, dtype=np.float64)[None], degree)[0], degree))

    for _ in range(n_random):
        d = int(rng.integers(1, 4))
        add(pt(d + 1), d)
    for f in features:
        if f == "chain":  # pieces sharing end points
            p = pt()[0]
            for _ in range(3):
                q = pt(3)
                add([p, q[0], q[1], q[2]], 3)
                p = q[2]
        elif f == "t_junction":  # an end point exactly on another piece's interior
            c = pt(3)
            add(c, 2)
            p = bz.evaluate(elevate(c[None], 2), [rng.uniform(0.2, 0.8)])[0]
            add([p, pt()[0]], 1)
        elif f == "x_junction":  # four pieces meeting at one point
            c = pt()[0]
            for _ in range(4):
                add([c, pt()[0]], 1)
        elif f == "lens":  # two curves between the same end points
            a, b = pt(2)
            add([a, pt()[0], b], 2)
            add([a, *pt(2), b], 3)
        elif f == "d_shape":  # a line and a curve between the same end points
            a, b = pt(2)
            add([a, b], 1)
            add([a, *pt(2), b], 3)
        elif f == "loop":  # a self-crossing cubic
            a = pt()[0]
            s = rng.uniform(10.0, 30.0)
            add(a + s * np.array([[0, 0], [1.3, 1.3], [-0.3, 1.3], [1, 0]]), 3)
        elif f == "duplicate":  # the same piece twice, once reversed
            q = pt(4)
            add(q, 3)
            add(q[::-1], 3)
        elif f == "overlap":  # collinear lines overlapping in part
            a, b = pt(2)
            add([a, a + 0.6 * (b - a)], 1)
            add([a + 0.3 * (b - a), b], 1)
        elif f == "near_parallel":  # two nearly parallel lines crossing at a small angle
            a, b = pt(2)
            n = np.array([-(b - a)[1], (b - a)[0]]) * 1e-3
            add([a + n, b - n], 1)
            add([a - n, b + n], 1)
        elif f == "nearly_straight":  # a cubic almost on its chord, crossed by a line
            a, b = pt(2)
            n = np.array([-(b - a)[1], (b - a)[0]]) * 1e-9
            add([a, a + (b - a) / 3 + n, a + 2 * (b - a) / 3 - n, b], 3)
            add([a + 0.5 * (b - a) + 50 * n * 1e6, a + 0.5 * (b - a) - 50 * n * 1e6], 1)
        elif f == "on_border":  # a piece lying on the border and one ending on it
            x = rng.uniform(10.0, 90.0)
            add([[x, 0.0], [x + 5.0, 0.0]], 1)
            add([[x + 2.0, 0.0], [x + 2.0, 20.0]], 1)
        elif f == "fold":  # a cubic reversing along its own line, and a quadratic folding back (almost closed)
            a, b = pt(2)
            add([a, a + 2.0 * (b - a), a - (b - a), b], 3)
            q = pt(2)
            add([q[0], q[1], q[0] + [0.0, 1e-9]], 2)
        elif f == "cusp":
            a = pt()[0]
            add(a + rng.uniform(5.0, 20.0) * np.array([[0, 0], [1, 1], [0, 1], [1, 0]]), 3)
        elif f == "tangent":  # a line touching a parabola at its apex
            c = pt()[0]
            add([c + [-10, 10], c, c + [10, 10]], 2)
            add([c + [-10, 5], c + [10, 5]], 1)
            add([c + [-10, 10 + 1e-3], c + [0, 2e-3], c + [10, 10 + 1e-3]], 2)
    cp = np.array([c for c, _ in pieces]).reshape(-1, 4, 2)
    n = len(cp)
    return Curves(DOMAIN, cp, [d for _, d in pieces], np.arange(n), np.tile([0.0, 1.0], (n, 1)),
                  [f"c{i}" for i in range(n)], [None] * n)


FEATURES = ["chain", "t_junction", "x_junction", "lens", "d_shape", "loop", "duplicate", "overlap",
            "near_parallel", "nearly_straight", "on_border", "tangent", "fold", "cusp"]
scenes = st.builds(_scene, st.integers(0, 2**31 - 1), st.integers(0, 8),
                   st.lists(st.sampled_from(FEATURES), max_size=6))


# ------------------------------------------------------------------------------------------------ checks


def _proper_crossings(p, q):
    """Whether segments p = (K, 2, 2) and q = (K, 2, 2) cross at a point interior to both: (K,) bool."""
    def orient(a, b, c):
        u, v = b - a, c - a
        return np.sign(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])

    a, b, c, d = p[:, 0], p[:, 1], q[:, 0], q[:, 1]
    return (orient(a, b, c) * orient(a, b, d) < 0) & (orient(c, d, a) * orient(c, d, b) < 0)


def assert_meet_only_at_end_points(out: Curves):
    poly = bz.flatten(out.control_points, DENSE)
    box_lo, box_hi = poly.min(axis=1), poly.max(axis=1)
    i, j = np.triu_indices(len(poly), k=1)
    overlap = (box_lo[i] <= box_hi[j]).all(1) & (box_lo[j] <= box_hi[i]).all(1)
    i, j = i[overlap], j[overlap]
    seg = np.stack([poly[:, :-1], poly[:, 1:]], axis=2)  # (P, DENSE, 2, 2)
    a, b = np.meshgrid(np.arange(DENSE), np.arange(DENSE), indexing="ij")
    for start in range(0, len(i), 2000):
        ii, jj = i[start:start + 2000], j[start:start + 2000]
        hit = _proper_crossings(seg[ii][:, a.ravel()].reshape(-1, 2, 2), seg[jj][:, b.ravel()].reshape(-1, 2, 2))
        hit = hit.reshape(len(ii), -1)
        # polylines of pieces sharing an end point may cross right next to it: allow that only
        k, m = np.nonzero(hit)
        for pk, cell in zip(k, m):
            pa, pb = ii[pk], jj[pk]
            ends_a = out.control_points[pa, [0, 3]]
            ends_b = out.control_points[pb, [0, 3]]
            shared = [e for e in ends_a if (np.all(e == ends_b, axis=1)).any()]
            x = seg[pa, a.ravel()[cell], 0]
            near = any(np.hypot(*(x - e)) < 1e-3 * out.diagonal for e in shared)
            assert near, f"pieces {pa} and {pb} cross away from a shared end point near {x}"
    # an end point of one piece on another's interior is a missed T-junction
    ends = out.control_points[:, [0, 3]].reshape(-1, 2)
    tree = cKDTree(poly[:, 1:-1].reshape(-1, 2))
    owner = np.repeat(np.arange(len(poly)), DENSE - 1)
    for e, pe in zip(ends, np.repeat(np.arange(len(poly)), 2)):
        for k in tree.query_ball_point(e, 1e-9 * out.diagonal):
            other = owner[k]
            assert other == pe or (out.control_points[other, [0, 3]] == e).all(1).any(), \
                f"end point {e} lies on the interior of piece {other}"


def assert_graphs_over_chords(out: Curves):
    curved = out.control_points[out.degree > 1]
    t = np.broadcast_to(np.linspace(0.0, 1.0, 257), (len(curved), 257))
    x = bz.to_chord_frame(curved, bz.evaluate(curved, t))[..., 0]
    assert (np.diff(x, axis=1) > 0).all(), "a curved piece is not a graph over its chord"
    d = bz.derivative(curved, t[:, 1:-1])
    angle = np.unwrap(np.arctan2(d[..., 1], d[..., 0]), axis=1)
    assert (angle.max(axis=1) - angle.min(axis=1) <= np.pi / 2 + 1e-6).all(), "a curved piece turns by more than 90°"
    turn = np.diff(angle, axis=1)
    assert ((turn >= -1e-12).all(axis=1) | (turn <= 1e-12).all(axis=1)).all(), "a curved piece has an inflection"


def assert_no_shared_chords(out: Curves):
    a, b = out.control_points[:, 0], out.control_points[:, 3]
    assert not (a == b).all(axis=1).any(), "a closed piece is left"
    pairs = {tuple(sorted([tuple(p), tuple(q)])) for p, q in zip(a, b)}
    assert len(pairs) == len(out), "two pieces share a chord"


def assert_vertices_exact(out: Curves):
    ends = np.unique(out.control_points[:, [0, 3]].reshape(-1, 2), axis=0)
    if len(ends) > 1:
        d, _ = cKDTree(ends).query(ends, k=2)
        assert d[:, 1].min() > 0.5 * tol.snap_rel * out.diagonal, "end points closer than the snap"


def assert_maps_back(inp: Curves, out: Curves):
    t = np.broadcast_to(np.linspace(0.0, 1.0, 9), (len(out), 9))
    s = out.t_range[:, :1] + t * (out.t_range[:, 1:] - out.t_range[:, :1])
    # input piece k of a curve covers s in [k, k + 1]; an output piece lies within one input piece
    k = np.floor(out.t_range.mean(axis=1)).astype(int)
    index = {(c, int(r)): i for i, (c, r) in enumerate(zip(inp.curve, inp.t_range[:, 0]))}
    src = inp.control_points[[index[(c, kk)] for c, kk in zip(out.curve, k)]].reshape(-1, 4, 2)
    mapped = bz.evaluate(src, s - k[:, None])
    err = np.hypot(*(mapped - bz.evaluate(out.control_points, t)).transpose(2, 0, 1))
    # a curved piece demoted to a line keeps its geometry, not its parametrisation: compare its interior
    # points with the line instead
    demoted = out.degree < inp.degree[[index[(c, kk)] for c, kk in zip(out.curve, k)]]
    a, b = out.control_points[demoted, :1], out.control_points[demoted, 3:]
    u = np.clip(((mapped[demoted] - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0.0, 1.0)
    err[demoted] = np.hypot(*(a + u[..., None] * (b - a) - mapped[demoted]).transpose(2, 0, 1))
    assert err.max(initial=0.0) < 1e-5 * out.diagonal, f"t_range maps back with error {err.max()}"


def assert_same_union(inp: Curves, out: Curves):
    x0, y0, x1, y1 = out.domain
    n = 400
    pin = bz.flatten(inp.control_points, n).reshape(-1, 2)
    pout = bz.flatten(out.control_points, n).reshape(-1, 2)
    margin = 1e-3 * out.diagonal
    inside = ((pin > np.array([x0, y0]) + margin) & (pin < np.array([x1, y1]) - margin)).all(axis=1)
    step_in = np.hypot(*np.diff(bz.flatten(inp.control_points, n), axis=1).transpose(2, 0, 1)).max(initial=0)
    step_out = np.hypot(*np.diff(bz.flatten(out.control_points, n), axis=1).transpose(2, 0, 1)).max(initial=0)
    if inside.any():
        d, _ = cKDTree(pout).query(pin[inside])
        assert d.max() < step_out + 1e-5 * out.diagonal, "part of an input curve inside the domain is missing"
    if len(pout):
        d, _ = cKDTree(pin).query(pout)
        assert d.max() < step_in + 1e-5 * out.diagonal, "an output piece is not on any input curve"
        assert (pout >= np.array([x0, y0]) - 1e-9).all() and (pout <= np.array([x1, y1]) + 1e-9).all()


# ------------------------------------------------------------------------------------------------- tests


def assert_clean_invariants(curves, out):
    """Everything ``clean`` promises about its output ``out`` for the input ``curves``."""
    assert_vertices_exact(out)
    assert_no_shared_chords(out)
    assert_graphs_over_chords(out)
    assert_maps_back(curves, out)
    assert_same_union(curves, out)
    assert_meet_only_at_end_points(out)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes)
def test_clean_properties(curves):
    out = clean(curves)
    assert out.domain == curves.domain and out.names == curves.names and out.source == curves.source
    assert set(np.unique(out.degree)) <= {1, 2, 3}
    assert ((out.degree == 1) | (curves.degree[out.curve] == out.degree)).all()
    assert (out.t_range[:, 0] < out.t_range[:, 1]).all()
    assert_clean_invariants(curves, out)


def test_cusp_branches_meet_only_at_the_cusp():
    """A cusp is cut at a rounded root, so its branches' end control points coincide only up to rounding; read as
    a backward step, that once had the branch halved towards the cusp into lines whose new end points lay on the
    other branch (found by hypothesis)."""
    curves = _scene(238, 4, ["x_junction", "x_junction", "overlap", "overlap", "cusp"])
    assert_clean_invariants(curves, clean(curves))


@pytest.mark.shared
@pytest.mark.parametrize("name", ["svg/engine_geometry.svg", "diffusion-curves/poivron_orzan.xml"])
def test_clean_shared_data(shared_data, name):
    curves = read_curves(shared_data / name)
    out = clean(curves)
    assert len(out) >= 1
    assert_clean_invariants(curves, out)


def _single(points, degree, domain=DOMAIN):
    cp = elevate(np.asarray(points, dtype=np.float64), degree)
    n = len(cp)
    return Curves(domain, cp, [degree] * n, np.arange(n), np.tile([0.0, 1.0], (n, 1)),
                  [f"c{i}" for i in range(n)], [None] * n)


def test_x_crossing_splits_both_lines_at_one_vertex():
    out = clean(_single([[[10, 10], [90, 40]], [[10, 40], [90, 10]]], 1))
    assert len(out) == 4
    centre = np.array([50.0, 25.0])
    ends = out.control_points[:, [0, 3]].reshape(-1, 2)
    at_centre = ends[np.hypot(*(ends - centre).T) < 1e-9]
    assert len(at_centre) == 4 and (at_centre == at_centre[0]).all()
    np.testing.assert_allclose(np.sort(out.t_range.ravel()), np.sort([0, 0.5, 0.5, 1, 0, 0.5, 0.5, 1]), atol=1e-12)


def test_clip_at_border_and_drop_piece_on_border():
    out = clean(_single([[[-10, 25], [50, 25]], [[20, 0], [80, 0]]], 1))
    assert len(out) == 1 and out.curve[0] == 0
    assert out.control_points[0, 0, 0] == 0.0  # exactly on the border
    np.testing.assert_allclose(out.control_points[0, 0, 1], 25.0, rtol=1e-14)
    np.testing.assert_allclose(out.t_range[0], [1 / 6, 1.0], atol=1e-12)


def test_a_piece_running_inside_the_snap_band_goes_where_it_hugs_the_border():
    """A quadratic along the bottom border, closer than the merge distance over most of its length: the part cut at
    the band's edge (reaching the edge only up to a rounding) lies on the border and goes; what leaves the band
    stays."""
    snap = tol.snap_rel * np.hypot(100.0, 50.0)
    quad = [[[87.5, 0.0], [0.0, 0.0], [0.0, 3.5 * snap]]]
    out = clean(_single(quad, 2))
    depth = np.minimum(bz.flatten(out.control_points, 8)[..., 1], 100.0 - bz.flatten(out.control_points, 8)[..., 0])
    assert len(out) >= 1 and (depth.max(axis=1) > 1.5 * snap).all()
    assert out.control_points[:, :, 0].max() < 0.5 * 87.5  # the hugging part is gone


def test_lens_and_d_are_split_until_no_chord_is_shared():
    a, b = [10.0, 10.0], [60.0, 10.0]
    lens = clean(_single([[a, [35, 30], b], [a, [35, -5], b]], 2))
    assert len(lens) >= 4
    assert_no_shared_chords(lens)
    d = clean(Curves(DOMAIN, np.concatenate([elevate(np.array([[a, b]]), 1), elevate(np.array([[a, [35, 30], b]]), 2)]),
                     [1, 2], [0, 1], [[0, 1], [0, 1]], ["line", "arc"], [None, None]))
    assert ((d.curve == 0) & (d.degree == 1)).sum() == 1  # the line stays one piece
    assert_no_shared_chords(d)


def test_loop_is_split_at_its_crossing():
    loop = _single([[[20, 10], [46, 36], [14, 36], [40, 10]]], 3)
    out = clean(loop)
    x = bz.evaluate(loop.control_points, bz.self_intersections(loop.control_points)[:, 0])[0]
    ends = out.control_points[:, [0, 3]].reshape(-1, 2)
    assert (np.hypot(*(ends - x).T) < 1e-9).sum() == 4  # four pieces meet at the crossing
    assert_graphs_over_chords(out)


def test_duplicates_collapse_to_one():
    q = np.array([[10.0, 10.0], [30.0, 40.0], [60.0, 40.0], [90.0, 10.0]])
    out = clean(_single([q, q[::-1]], 3))
    assert len(np.unique(out.curve)) == 1


def test_rejects_non_curves():
    with pytest.raises(CurveError, match="expected a Curves"):
        clean(np.zeros((1, 4, 2)))
