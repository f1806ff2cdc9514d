"""Mitsuba scene access (``dfc.io.mitsuba``): the exact zoom-window references and the missing-extra message.
The Mitsuba tests skip without the render extra (CI installs it)."""

import sys

import numpy as np
import pytest

from dfc.errors import ExtraError

from ..cli.test_cli import assert_one_line_error, run


@pytest.fixture
def mitsuba():
    return pytest.importorskip("mitsuba")


def scene_file(tmp_path):
    from ..geometry.test_scene_curves import BACKDROP, CUBE, write_scene

    lit = '<emitter type="point"><point name="position" x="2" y="4" z="3"/><rgb name="intensity" value="30"/></emitter>'
    return write_scene(tmp_path, '<integrator type="direct"/>' + lit + CUBE + BACKDROP, width=72, height=54,
                       crop=(6, 4, 50, 40))


def test_render_window_of_the_whole_film_is_the_plain_render(tmp_path, mitsuba):
    from dfc.io.mitsuba import load_scene, render_window

    path = scene_file(tmp_path)
    plain = np.array(mitsuba.render(load_scene(path), spp=4, seed=3))
    ours = render_window(path, (0, 0, 50, 40), 50, 40, 4, seed=3)
    assert ours.shape == plain.shape == (40, 50, 3) and ours.dtype == np.float32
    assert np.abs(ours - plain).max() < 1e-4
    assert plain.std() > 0.01  # a picture, not a blank


def test_window_sensor_maps_the_window_onto_its_film(tmp_path, mitsuba):
    from dfc.io.mitsuba import Camera, load_scene, perspective_sensor, window_sensor

    base = perspective_sensor(load_scene(scene_file(tmp_path)))
    camera = Camera.from_sensor(base)
    x0, y0, x1, y1 = 10.5, 7.25, 30.5, 22.25
    zoomed = Camera.from_sensor(window_sensor(base, (x0, y0, x1, y1), 400, 300))
    assert zoomed.size == (400, 300)
    points = np.random.default_rng(1).uniform(-1, 1, (40, 3))
    expected = (camera.project(points)[0] - (x0, y0)) * 20.0
    np.testing.assert_allclose(zoomed.project(points)[0], expected, atol=1e-3)


def test_render_window_refuses_non_square_pixels_and_bad_windows(tmp_path, mitsuba):
    from dfc.io.mitsuba import render_window

    path = scene_file(tmp_path)
    with pytest.raises(ValueError, match="square"):
        render_window(path, (0, 0, 10, 10), 20, 10, 1)
    with pytest.raises(ValueError, match="x1 > x0"):
        render_window(path, (5, 0, 5, 10), 10, 10, 1)


def test_missing_extra_names_the_pip_command(tmp_path, capsys, monkeypatch):
    from dfc.io.mitsuba import import_mitsuba

    monkeypatch.setitem(sys.modules, "mitsuba", None)  # `import mitsuba` now fails as if it were not installed
    with pytest.raises(ExtraError, match=r"pip install 'dfc\[render\]'"):
        import_mitsuba()
    (tmp_path / "s.xml").write_text('<scene version="3.0.0"/>')
    code, _, err = run(["curves", tmp_path / "s.xml", "-o", tmp_path / "c.json"], capsys)
    assert_one_line_error(code, err, "pip install 'dfc[render]'")
