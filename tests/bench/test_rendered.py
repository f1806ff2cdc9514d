"""``dfc bench --scene SCENE.xml``: a Mitsuba scene as the comparison's input and its reference at every zoom (the
crop-window renders), the reference's own noise estimate, and the errors. Skipped without the render extra (CI
installs it)."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

mi = pytest.importorskip("mitsuba")

from dfc.bench.compare import HALVES_DB, BenchSettings, square_pixels  # noqa: E402
from dfc.bench.rendered import MitsubaReference, mitsuba_inputs  # noqa: E402
from dfc.cli import cli  # noqa: E402
from dfc.errors import InputError  # noqa: E402
from dfc.io.image import write_exr  # noqa: E402
from dfc.io.mitsuba import render_window  # noqa: E402
from dfc.metrics import quality_scale  # noqa: E402
from dfc.render import window_shape  # noqa: E402

from ..io.test_mitsuba import scene_file  # noqa: E402
from .test_bench import TINY  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_thread")

BOX = {"type": "box"}


def test_each_window_is_mitsuba_rendering_it_in_two_independent_halves(tmp_path):
    path = scene_file(tmp_path)  # a 50 x 40 film
    reference = MitsubaReference(path, path, spp=8)
    window = (10.0, 8.0, 20.0, 16.0)
    mean, (a, b) = reference.window(window, 20, 16)
    np.testing.assert_array_equal(a, render_window(path, window, 20, 16, 4, seed=1, rfilter=BOX))
    np.testing.assert_array_equal(b, render_window(path, window, 20, 16, 4, seed=2, rfilter=BOX))
    np.testing.assert_allclose(mean, 0.5 * (a + b), rtol=1e-6)
    assert np.abs(a - b).max() > 0  # independent samples
    assert reference.window(window, 20, 16)[1][0] is not a and reference.seed == 5  # each call draws new seeds


def test_the_noise_estimate_follows_the_sample_count(tmp_path):
    """A reference of 4× the samples has a quarter of the noise variance: its estimated PSNR rises by about 6 dB,
    and the estimate agrees with the measured distance to a much cleaner render."""
    path = scene_file(tmp_path)
    window, size = (0.0, 0.0, 50.0, 40.0), (50, 40)
    clean = render_window(path, window, *size, 1024, seed=99, rfilter=BOX)
    scale = quality_scale(clean)
    estimates, measured = [], []
    for spp in (16, 64):
        mean, halves = MitsubaReference(path, path, spp=spp).window(window, *size)
        estimates.append(scale.psnr(*halves) + HALVES_DB)
        measured.append(scale.psnr(clean, mean))
    assert 4.5 < estimates[1] - estimates[0] < 7.5
    assert abs(estimates[0] - measured[0]) < 1.5


def test_windows_get_square_pixels_inside_the_zoom_window():
    for window in [(0.0, 0.0, 50.0, 40.0), (3.0, 1.0, 8.0, 5.0), (0.0, 0.0, 30.0, 47.0)]:
        narrowed = square_pixels(window, 16)
        w, h = window_shape(narrowed, 16)
        kx, ky = w / (narrowed[2] - narrowed[0]), h / (narrowed[3] - narrowed[1])
        assert kx == pytest.approx(ky)
        assert narrowed[0] >= window[0] and narrowed[1] >= window[1] - 1e-12
        assert narrowed[2] <= window[2] and narrowed[3] <= window[3] + 1e-12
        assert np.allclose([narrowed[0] + narrowed[2], narrowed[1] + narrowed[3]],
                           [window[0] + window[2], window[1] + window[3]])  # same centre
        assert max(window[2] - window[0] - narrowed[2] + narrowed[0],
                   window[3] - window[1] - narrowed[3] + narrowed[1]) < max(window[2] - window[0],
                                                                            window[3] - window[1]) / 16


def test_bench_on_a_mitsuba_scene_measures_every_zoom_against_its_renders(tmp_path):
    path = scene_file(tmp_path)
    out = tmp_path / "bench"
    result = CliRunner().invoke(cli, ["bench", "--scene", str(path), "--methods", "dfc,raster", "--max-triangles",
                                      "200", *TINY[2:], "--size", "25", "--scene-spp", "8", "--zoom",
                                      "1", "--zoom", "10", "-o", str(out)])
    assert result.exit_code == 0, result.output
    res = json.loads((out / "results.json").read_text())
    assert res["zoom_truth"] is True and "Mitsuba" in res["reference"] and "8 spp" in res["reference"]
    assert res["image"]["width"] == 25 and res["image"]["height"] == 20  # the 50 x 40 film at --size 25
    assert "independent Mitsuba render" in res["image"]["truth"] and res["image"]["truth_psnr"] > 10
    kinds = res["probe_kinds"]
    assert "edge" in kinds and "smooth" in kinds  # probes from the curves extracted from the scene
    for m in ("dfc", "raster"):
        for z in ("1", "10"):
            assert all(v is not None and 0 < v < 100 for v in res["methods"][m]["psnr"][z])
    assert all(v is not None and v > 10 for z in ("1", "10") for v in res["reference_psnr"][z])
    sr = res["super_resolution"]  # the film at 2x the input's pixels, rendered by Mitsuba
    assert (sr["factor"], sr["width"], sr["height"]) == (2, 50, 40) and sr["reference_psnr"] > 10
    assert set(sr["methods"]) == {"dfc", "raster"} and all(0 < v < 100 for v in sr["methods"].values())
    assert set(sr["input"]) == {"bicubic", "lanczos"} and all(0 < v < 100 for v in sr["input"].values())
    table = (out / "results.md").read_text()
    assert "| reference itself (estimated) |" in table and "By probe kind" in table
    assert "2× super-resolution" in table and "| the input, bicubic |" in table


@pytest.mark.parametrize("name", ["mitsuba-glass-auto", "mitsuba-texture-auto"])
def test_the_corpus_renders_without_their_scene_render_with_visible_curves(name):
    from dfc.bench.corpus import CASES

    inputs = CASES[name].build(16, BenchSettings(), lambda m: None)
    pixels = inputs["pixels"]
    assert pixels.shape == (16, 16, 3) and np.isfinite(pixels).all() and pixels.min() >= 0
    assert inputs["curves"].n_curves >= 3 and len(inputs["probes"]) > 0  # silhouettes from the scene: the probes


def test_a_render_and_curves_given_are_used(tmp_path):
    path = scene_file(tmp_path)
    settings = BenchSettings(render=16, spp=1)
    render = render_window(path, (0, 0, 50, 40), 100, 80, 4, seed=7, rfilter=BOX)
    from dfc.geometry.sources.scene import read_scene

    curves = read_scene(path)
    inputs = mitsuba_inputs(path, settings, pixels=render, channels=["R", "G", "B"], curves=curves)
    assert inputs["pixels"] is render and inputs["curves"] is curves and inputs["truth"].shape == render.shape
    assert not np.array_equal(inputs["truth"], render)  # an independent render, not the input again
    with pytest.raises(InputError, match="not the film"):
        mitsuba_inputs(path, settings, pixels=render[:, :90], channels=["R", "G", "B"], curves=curves)
    with pytest.raises(InputError, match="domain"):
        mitsuba_inputs(path, settings, pixels=render, channels=["R", "G", "B"],
                       curves=read_scene(path).__class__((0.0, 0.0, 100.0, 80.0), curves.control_points * 2,
                                                         curves.degree, curves.curve, curves.t_range, curves.names,
                                                         curves.sides))


@pytest.mark.parametrize("args,match", [
    (["--scene-spp", "8"], "--scene-spp, --scene-filter and --sensor apply to a Mitsuba scene"),
])
def test_mitsuba_options_need_a_mitsuba_scene(tmp_path, args, match):
    result = CliRunner().invoke(cli, ["bench", "--scene", "shapes", *args, "-o", str(tmp_path)])
    assert result.exit_code == 2 and match in result.output


def test_bad_size_and_missing_scene_are_one_error_line(tmp_path):
    path = scene_file(tmp_path)
    result = CliRunner().invoke(cli, ["bench", "--scene", str(path), "--size", "32", "--methods", "raster",
                                      "--bytes", "900", "-o", str(tmp_path / "b")])
    assert result.exit_code == 1 and isinstance(result.exception, InputError)
    assert "multiples of 5" in str(result.exception) and not (tmp_path / "b").exists()
    result = CliRunner().invoke(cli, ["bench", "--scene", str(tmp_path / "gone.xml"), "-o", str(tmp_path / "b")])
    assert result.exit_code == 2 and "no such file" in result.output


def test_a_render_file_as_input(tmp_path):
    path = scene_file(tmp_path)
    write_exr(tmp_path / "render.exr", render_window(path, (0, 0, 50, 40), 50, 40, 4, rfilter=BOX), ["R", "G", "B"])
    out = tmp_path / "bench"
    result = CliRunner().invoke(cli, ["bench", str(tmp_path / "render.exr"), "--scene", str(path), "--methods",
                                      "raster", "--bytes", "1500", *TINY, "--scene-spp", "4", "--zoom", "10",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    res = json.loads((out / "results.json").read_text())
    assert res["image"]["width"] == 50 and all(v is not None for v in res["methods"]["raster"]["psnr"]["10"])
