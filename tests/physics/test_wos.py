import sys

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.cli import cli, main
from dfc.errors import InputError
from dfc.geometry import bezier
from dfc.geometry.curves import Curves
from dfc.geometry.sources import read_curves
from dfc.io.samples import read_samples
from dfc.physics.reference import solve_reference
from dfc.physics.wos import GRID_CELLS, Scene, grid_size, reflect, sample_scene, walk_on_spheres

from ..conftest import SAMPLES
from ._laplace import OUTER_LEFT, X1, X2, sides, two_lines

SCENE = SAMPLES / "diffusion_small.json"


@pytest.fixture(scope="module")
def small():
    return Scene(read_curves(SCENE))


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-1e4, 1e4), y=st.floats(-1e4, 1e4))
def test_reflect_folds_into_the_domain(x, y):
    domain = (-2.0, 1.0, 5.0, 4.0)
    p = reflect(np.array([[x, y]]), domain)[0]
    assert -2.0 <= p[0] <= 5.0 and 1.0 <= p[1] <= 4.0
    if -2.0 <= x <= 5.0 and 1.0 <= y <= 4.0:
        np.testing.assert_allclose(p, [x, y], atol=1e-12)
    # the fold is its own mirror: reflecting across a side gives the same point
    np.testing.assert_allclose(reflect(np.array([[2 * -2.0 - x, y]]), domain)[0], p, atol=1e-8)


def test_reflection_keeps_walkers_in_their_region():
    # The region left of X1 touches three borders and no other curve: every walk started there must bounce
    # off the border until it ends on X1's right side, so every single estimate is exactly 0.7 — a walker
    # that left the canvas or crossed X1 would come back with another value.
    scene = Scene(two_lines())
    rng = np.random.default_rng(1)
    xy = np.concatenate([rng.uniform([0, 0], [1, 64], (300, 2)), rng.uniform([0, 0], [X1, 0.5], (300, 2))])
    values, capped = walk_on_spheres(scene, xy, seed=2)
    assert capped == 0
    np.testing.assert_array_equal(values, OUTER_LEFT)


def test_strip_touching_the_border_is_linear():
    # between the lines u is linear in x: its zero flux through the top and bottom borders needs the reflection
    scene = Scene(two_lines())
    pts = np.array([[20.0, 0.5], [30.0, 63.7], [44.0, 32.0]])
    m = 4000
    values, _ = walk_on_spheres(scene, np.repeat(pts, m, axis=0), seed=3)
    v = values.reshape(len(pts), m)
    exact = (pts[:, 0] - X1) / (X2 - X1)
    err = np.abs(v.mean(1) - exact)
    assert np.all(err < 4 * v.std(1) / np.sqrt(m) + 1e-3), err


def test_walks_are_unbiased_against_the_reference(small):
    pts = np.array([[4.0, 60.0], [30.0, 25.0], [50.0, 20.0], [56.0, 50.0], [62.5, 1.5]])
    m = 3000
    values, capped = walk_on_spheres(small, np.repeat(pts, m, axis=0), seed=0)
    assert capped == 0
    v = values.reshape(len(pts), m, -1)
    mean, se = v.mean(1), v.std(1) / np.sqrt(m)
    fine, coarse = solve_reference(small, 192, 192).at(pts), solve_reference(small, 96, 96).at(pts)
    tolerance = 4 * se + 2 * np.abs(fine - coarse) + 1e-4  # Monte Carlo error + the reference's own error
    assert np.all(np.abs(mean - fine) < tolerance), (mean - fine) / tolerance


def test_annulus_matches_the_exact_solution():
    def circle(r):
        a = np.linspace(0.0, 2.0 * np.pi, 9)
        k = 4.0 / 3.0 * np.tan(np.pi / 16)
        p, tan = np.stack([np.cos(a), np.sin(a)], 1), np.stack([-np.sin(a), np.cos(a)], 1)
        return 32.0 + r * np.stack([p[:-1], p[:-1] + k * tan[:-1], p[1:] - k * tan[1:], p[1:]], axis=1)

    cp = np.concatenate([circle(8.0), circle(20.0)])
    t = np.tile(np.arange(8), 2)
    one, zero = sides([1.0], [1.0]), sides([0.0], [0.0])
    scene = Scene(Curves((0, 0, 64, 64), cp, np.full(16, 3), np.repeat([0, 1], 8), np.stack([t, t + 1], 1),
                         ["inner", "outer"], [one, zero]))
    pts = np.array([[32.0 + 11.0, 32.0], [32.0, 32.0 - 16.0]])
    m = 3000
    values, _ = walk_on_spheres(scene, np.repeat(pts, m, axis=0), seed=4)
    v = values.reshape(2, m)
    exact = np.log(np.array([11.0, 16.0]) / 20.0) / np.log(8.0 / 20.0)
    assert np.all(np.abs(v.mean(1) - exact) < 4 * v.std(1) / np.sqrt(m) + 1e-3)


def test_side_selection_and_interpolation_along_the_curve(small):
    curves = read_curves(SCENE)
    cp = curves.control_points
    eps = 1e-3
    for piece in range(len(cp)):  # every piece of both curves, at several parameters
        t = np.array([0.2, 0.5, 0.8])
        on = bezier.evaluate(cp[[piece] * 3], t)
        d = bezier.derivative(cp[[piece] * 3], t)
        left_normal = np.stack([d[:, 1], -d[:, 0]], 1) / np.linalg.norm(d, axis=1)[:, None]
        s = curves.t_range[piece, 0] + t
        sides = curves.sides[curves.curve[piece]]
        for sign, side in ((1.0, "left"), (-1.0, "right")):
            got, _ = walk_on_spheres(small, on + sign * 0.3 * eps * left_normal, eps=eps)
            np.testing.assert_allclose(got, sides.at(s, side), atol=1e-6)


def test_far_point_does_not_stop_at_the_first_step(small):
    pts = np.array([[24.0, 30.0]])  # the disc's centre: 12 units from every curve
    values, _ = walk_on_spheres(small, np.repeat(pts, 2000, axis=0), seed=5)
    # the mean value property of the disc's right-side values (piecewise linear in s around the circle)
    np.testing.assert_allclose(values.mean(0), [0.9, 0.325, 0.1], atol=4 * values.std(0).max() / np.sqrt(2000) + 1e-3)


def test_sample_scene_is_stratified_and_deterministic(small):
    a = sample_scene(small, 6, 3, seed=7)
    b = sample_scene(small, 6, 3, seed=7)
    assert len(a) == 3 * 36 and a.values.dtype == np.float32 and a.channels == ["R", "G", "B"]
    np.testing.assert_array_equal(a.values, b.values)
    cell = 64.0 / 6
    for k in range(3):
        ij = np.floor(a.xy[36 * k : 36 * (k + 1)] / cell).astype(int)
        np.testing.assert_array_equal(ij[:, 1] * 6 + ij[:, 0], np.arange(36))
    assert grid_size((0, 0, 8, 4), 10) == (10, 5) and grid_size((0, 0, 3, 9), 10) == (3, 10)


def test_step_cap_is_counted(small):
    values, capped = walk_on_spheres(small, np.array([[24.0, 30.0], [8.0, 8.0]]), max_steps=1)
    assert capped == 2 and np.isfinite(values).all()


def test_bad_scenes_and_points():
    c = two_lines()
    with pytest.raises(InputError, match="x2: no side values"):
        Scene(Curves(c.domain, c.control_points, c.degree, c.curve, c.t_range, c.names, [c.sides[0], None]))
    with pytest.raises(InputError, match="no curves"):
        Scene(Curves((0, 0, 1, 1), np.zeros((0, 4, 2)), [], [], np.zeros((0, 2))))
    with pytest.raises(InputError, match="inside the domain"):
        walk_on_spheres(c, np.array([[70.0, 1.0]]))
    with pytest.raises(ValueError, match="eps"):
        walk_on_spheres(c, np.array([[1.0, 1.0]]), eps=0.0)


def test_cli_writes_samples_and_reference(tmp_path):
    out, ref = tmp_path / "s.npz", tmp_path / "ref.npz"
    result = CliRunner().invoke(cli, ["wos", str(SCENE), "-o", str(out), "--resolution", "8", "--spp", "2",
                                      "--reference", str(ref)])
    assert result.exit_code == 0, result.output
    assert "walks that hit the step cap: 0" in result.output
    s = read_samples(out)
    assert len(s) == 128 and s.domain == (0.0, 0.0, 64.0, 64.0) and s.channels == ["R", "G", "B"]
    assert ((s.values >= 0) & (s.values <= 1)).all()
    with np.load(ref, allow_pickle=False) as z:
        assert z["image"].shape == (8, 8, 3) and list(z["channels"]) == ["R", "G", "B"]


def test_cli_errors(tmp_path, monkeypatch, capsys):
    bad = tmp_path / "plain.json"
    bad.write_text('{"domain": [0, 0, 4, 4], "pieces": [{"type": "line", "points": [[0, 0], [4, 4]]}]}')
    out = tmp_path / "s.npz"
    monkeypatch.setattr(sys, "argv", ["dfc", "wos", str(bad), "-o", str(out), "--resolution", "4"])
    with pytest.raises(SystemExit) as e:
        main()
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 1 and err[-1].startswith("dfc: error:") and "no side values" in err[-1]
    assert not out.exists()
    result = CliRunner().invoke(cli, ["wos", str(SCENE), "-o", str(out), "--reference", str(tmp_path / "r.png")])
    assert result.exit_code == 2 and "--reference" in result.output and not out.exists()


@pytest.mark.shared
@pytest.mark.parametrize("name", ["poivron_orzan.xml", "sunset_illustration.xml", "test_curve.xml"])
def test_shipped_scenes_run(shared_data, tmp_path, name):
    out = tmp_path / "s.npz"
    result = CliRunner().invoke(cli, ["wos", str(shared_data / "diffusion-curves" / name), "-o", str(out),
                                      "--resolution", "4", "--spp", "1"])
    assert result.exit_code == 0, result.output
    s = read_samples(out)
    assert len(s) == 16 and s.domain == (0.0, 0.0, 512.0, 512.0)
    assert ((s.values >= 0) & (s.values <= 1)).all()


def test_distance_is_a_tight_lower_bound(small):
    # brute force: distance to a dense sampling of the exact pieces
    cp = small.curves.control_points
    t = np.linspace(0.0, 1.0, 4001)
    dense = bezier.evaluate(cp, np.broadcast_to(t, (len(cp), len(t)))).reshape(-1, 2)
    rng = np.random.default_rng(8)
    on = dense[rng.integers(0, len(dense), 300)]
    pts = np.concatenate([rng.uniform(0, 64, (300, 2)), np.clip(on + rng.normal(0, 0.03, on.shape), 0, 64)])
    exact = np.concatenate([np.linalg.norm(pts[i : i + 50, None, :] - dense[None], axis=2).min(axis=1)
                            for i in range(0, len(pts), 50)])
    got = small.distance(pts)
    gap = np.linalg.norm(np.diff(dense.reshape(len(cp), -1, 2), axis=1), axis=2).max()
    slack = gap / 2  # the dense sampling's own error
    assert np.all(got <= exact + slack)
    segment = small.lines.max_segment
    near = exact < 2 * segment
    assert near.sum() > 100 and np.all(exact[near] - got[near] < 1e-3 + slack)
    cell = 64.0 / GRID_CELLS * np.sqrt(2)
    assert np.all(exact - got <= cell + segment / 2 + slack)  # far away: the precomputed grid's bound


def test_split_pieces_keeps_geometry_and_parameters():
    from dfc.geometry.curves import split_pieces
    from dfc.geometry.sources import read_curves

    curves = read_curves(SCENE)
    cut = split_pieces(curves, 3.0)
    assert len(cut) > len(curves)
    polygon = np.linalg.norm(np.diff(cut.control_points, axis=1), axis=2).sum(axis=1)
    assert np.all(polygon[cut.degree != 1] <= 3.0 + 1e-9)
    # every cut piece's points are the original's at the same curve parameter s
    for k in range(len(cut)):
        orig = np.flatnonzero((curves.curve == cut.curve[k]) & (curves.t_range[:, 0] <= cut.t_range[k, 0])
                              & (curves.t_range[:, 1] >= cut.t_range[k, 1]))[0]
        s = np.linspace(*cut.t_range[k], 5)
        a = bezier.evaluate(cut.control_points[[k]], ((s - cut.t_range[k, 0]) / np.ptp(cut.t_range[k]))[None])
        b = bezier.evaluate(curves.control_points[[orig]], (s - curves.t_range[orig, 0])[None])
        np.testing.assert_allclose(a, b, atol=1e-9)
