"""Pixel filters (issue 26): the kernels and their specs, the detection of the filter that made a raster, the fit
and 1x decode with a filter, the header key, the decode rule and the CLI's errors."""

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.bench.pixel_filters import GENERATIONS, filtered_raster, polygon_scene
from dfc.codec import EncodeSettings, encode_image, encode_samples, loads
from dfc.errors import FormatError, InputError
from dfc.io.container import decode_dfield
from dfc.pixel_filter import parse
from dfc.pixel_model import detect, step_share
from dfc.render import default_pixel_filter, render

from .cli.test_cli import assert_one_line_error, run
from .reference_decoder import ReferenceField

SIZE = 64
GOLDEN = __import__("pathlib").Path(__file__).parent / "golden" / "valid"


@pytest.fixture(scope="module")
def scene():
    return polygon_scene(float(SIZE))


@pytest.fixture(scope="module")
def rasters(scene):
    return {g: filtered_raster(scene, SIZE, SIZE, g) for g in GENERATIONS}


@pytest.mark.parametrize("spec, name, param", [("point", "point", None), ("box", "box", None), ("box:4", "box", 4),
                                               ("gaussian", "gaussian", 0.5), ("gaussian:0.8", "gaussian", 0.8),
                                               ("tent", "tent", None), ("blackman-harris", "blackman-harris", 1.5),
                                               ("Mitchell", "mitchell", None)])
def test_parse_and_round_trip(spec, name, param):
    f = parse(spec)
    assert (f.name, f.param) == (name, param)
    assert parse(str(f)) == f


@pytest.mark.parametrize("spec", ["lanczos", "gaussian:-0.5", "blackman-harris:0", "box:2.5", "box:0", "tent:1",
                                  "gaussian:x", "gaussian:inf"])
def test_parse_refuses(spec):
    with pytest.raises(InputError):
        parse(spec)


@pytest.mark.parametrize("spec", ["box", "tent", "gaussian:0.5", "blackman-harris:1.5", "mitchell"])
def test_nodes_integrate_the_kernel(spec):
    f = parse(spec)
    off, w = f.nodes(4096)
    assert w.sum() == pytest.approx(1.0)
    assert np.abs(off).max() <= f.radius + 1e-12
    # the second moment along x matches the kernel's own (a straight integral of u² k(u) / ∫ k)
    u = np.linspace(-f.radius, f.radius, 20001)
    k = f.kernel(u)
    assert (w * off[:, 0] ** 2).sum() == pytest.approx((u**2 * k).sum() / k.sum(), abs=2e-3)


def test_box_subsamples_and_step_share():
    off, _ = parse("box:2").nodes(16)
    assert sorted(map(tuple, off)) == [(-0.25, -0.25), (-0.25, 0.25), (0.25, -0.25), (0.25, 0.25)]
    d = np.array([-0.3, -0.1, 0.1, 0.3])
    n = np.tile([[0.0, 1.0]], (4, 1))
    assert step_share(parse("point"), d, n).tolist() == [0, 0, 1, 1]
    assert step_share(parse("box:2"), d, n).tolist() == [0, 0.5, 0.5, 1]
    assert step_share(parse("box"), d, n) == pytest.approx(d + 0.5, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(spec=st.sampled_from(["box", "tent", "gaussian:0.5", "gaussian:1.1", "blackman-harris:1.5", "mitchell"]),
       d=st.floats(-2.5, 2.5), angle=st.floats(0.0, 2 * np.pi))
def test_continuous_step_share_is_the_kernel_on_the_edge_side(spec, d, angle):
    # against a 2000 x 2000 midpoint sum of the separable kernel (a cell row holds at most 1.6e-3 of its mass)
    f = parse(spec)
    n = np.array([[np.cos(angle), np.sin(angle)]])
    m = 2000
    u = ((np.arange(m) + 0.5) / m * 2 - 1) * f.radius
    k = f.kernel(u) / f.kernel(u).sum()
    side = (n[0, 0] * u[None, :] + n[0, 1] * u[:, None] + d) > 0
    dense = float((np.outer(k, k) * side).sum())
    share = step_share(f, np.array([d]), n)
    assert share[0] == pytest.approx(dense, abs=1.5e-3)
    assert share[0] + step_share(f, np.array([-d]), n)[0] == pytest.approx(1.0, abs=1e-9)


def test_raster_generation_matches_the_definition(scene):
    # a pixel of the Gaussian raster far from every curve equals the region's value; the point raster is the value
    r = filtered_raster(scene, SIZE, SIZE, "point")
    xy = np.stack(np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5), -1).reshape(-1, 2)
    assert np.array_equal(r.reshape(-1), scene.value(xy)[:, 0].astype(np.float32))
    g = filtered_raster(scene, SIZE, SIZE, "gaussian:0.5")
    assert g[1, 1, 0] == pytest.approx(r[1, 1, 0], abs=1e-6)
    assert 0.0 < np.abs(g - r).max() < 1.0


@pytest.mark.parametrize("generation", GENERATIONS)
def test_auto_picks_the_generating_filter(scene, rasters, generation):
    found = detect(rasters[generation], scene.curves)
    assert str(found.filter) == generation, found.evidence()
    assert found.pixels > 100 and next(iter(found.misfit)) == generation


def test_detect_counts_the_edges_beside_hdr_light(scene, rasters):
    """One polygon made an emitter a thousand times brighter than the others' jumps: their edges still count
    (a jump is measured tone-mapped, as the file's PSNR is, not as a share of the emitter's span)."""
    def value(xy):
        v = scene.value(xy)
        return np.where(v == 0.05, 50.0, v)

    raster = filtered_raster(replace(scene, value=value), SIZE, SIZE, "gaussian:0.5")
    found = detect(raster, scene.curves)
    assert str(found.filter) == "gaussian:0.5", found.evidence()
    assert found.pixels >= 0.9 * detect(rasters["gaussian:0.5"], scene.curves).pixels


def test_detect_keeps_box_when_noise_alone_favours_a_wider_filter():
    """A box-filtered raster with noise (σ 0.06 of a 0.05-0.85 scene): the Gaussian fits a little better by chance,
    by about one standard error, not the three a switch from box asks; a Gaussian raster with less noise (σ 0.01)
    switches."""
    from dfc.pixel_model import MIN_EVIDENCE

    scene64 = polygon_scene(64.0)
    noise = np.random.default_rng(1).normal(0.0, 0.06, (64, 64, 1)).astype(np.float32)
    found = detect(filtered_raster(scene64, 64, 64, "box:16") + noise, scene64.curves)
    assert next(iter(found.misfit)) == "gaussian:0.5" and found.t < MIN_EVIDENCE
    assert str(found.filter) == "box" and "box kept" in found.evidence()
    found = detect(filtered_raster(scene64, 64, 64, "gaussian:0.5") + noise / 6, scene64.curves)
    assert str(found.filter) == "gaussian:0.5" and found.t >= MIN_EVIDENCE


def test_an_incumbent_filter_is_kept_unless_another_fits_better_by_the_evidence_asked():
    """``incumbent``: the noisy box raster above keeps whichever filter it is given among those within noise of each
    other; a clean 4 x 4 box raster overturns a 16 x 16 incumbent."""
    from dfc.pixel_model import MIN_EVIDENCE

    scene64 = polygon_scene(64.0)
    noise = np.random.default_rng(1).normal(0.0, 0.06, (64, 64, 1)).astype(np.float32)
    noisy = filtered_raster(scene64, 64, 64, "box:16") + noise
    for incumbent in ("box:6", "box", "gaussian:0.5"):
        found = detect(noisy, scene64.curves, incumbent=incumbent)
        assert str(found.filter) == incumbent, found.evidence()
        assert next(iter(found.misfit)) == incumbent or (found.t < MIN_EVIDENCE and f"{incumbent} kept" in found.evidence())
    found = detect(filtered_raster(scene64, 64, 64, "box:4"), scene64.curves, incumbent="box:16")
    assert str(found.filter) == "box:4" and found.t >= MIN_EVIDENCE


@pytest.mark.parametrize("generation", ["box:2", "gaussian:0.5"])
def test_detect_reads_round_edges(generation):
    """A disc of radius 20 px (a diffusion-curve drawing's rounded shapes): the curve bends 0.76 px from its tangent
    over the side samples' 5.5 px but stays straight over the filter's support, so its edge pixels count."""
    from dfc.bench.scenes import AnalyticScene, _circle, _pieces

    curves = _pieces([("disc", _circle(32.0, 32.0, 20.0))], (0.0, 0.0, 64.0, 64.0))
    disc = AnalyticScene("disc", curves, ["Y"],
                         lambda xy: np.where(np.hypot(xy[:, 0] - 32.0, xy[:, 1] - 32.0) < 20.0, 0.8, 0.2)[:, None])
    found = detect(filtered_raster(disc, 64, 64, generation), curves)
    assert str(found.filter) == generation, found.evidence()
    assert found.pixels > 200


def test_detect_without_evidence_falls_back_to_box(scene):
    flat = np.full((SIZE, SIZE, 1), 0.3, np.float32)
    found = detect(flat, scene.curves)
    assert str(found.filter) == "box" and found.pixels == 0 and "no clean" in found.evidence()


@pytest.mark.parametrize("generation", ["point", "gaussian:0.5"])
def test_auto_encode_equals_the_true_model_and_beats_box(scene, rasters, generation):
    settings = EncodeSettings(steps=120, batch_size=4096)
    raster = rasters[generation]
    blob, auto = encode_image(raster, scene.curves, replace(settings, pixel_filter="auto"), raster_mode=False)
    told_blob, told = encode_image(raster, scene.curves, replace(settings, pixel_filter=generation), raster_mode=False)
    _, box = encode_image(raster, scene.curves, replace(settings, pixel_filter="box"), raster_mode=False)  # the field
    assert auto.pixel_filter == generation and generation in auto.pixel_evidence
    assert abs(auto.psnr - told.psnr) <= 0.5
    assert auto.psnr > box.psnr + 5.0
    model = loads(blob)
    assert model.header["pixel_filter"] == generation
    assert model.header["encoder"]["pixel_filter"] == generation
    assert blob == told_blob  # the choice is recorded as resolved; its evidence only in the report
    # the 1x decode on the input's grid applies the stored filter and reproduces the report's PSNR
    assert default_pixel_filter(model, SIZE, SIZE) == (generation, "the file's, on the input's grid")
    from dfc.metrics import psnr
    assert psnr(raster, render(model, SIZE, SIZE, pixel_filter=generation), 1.0) == pytest.approx(auto.psnr, abs=0.05)


def test_decode_rule_and_legacy_files(scene, rasters):
    blob, _ = encode_image(rasters["point"], scene.curves, EncodeSettings(steps=20, batch_size=4096,
                                                                          pixel_filter="gaussian:0.5"))
    model = loads(blob)
    assert default_pixel_filter(model, SIZE // 2, SIZE // 2)[0] == "box"
    assert default_pixel_filter(model, SIZE * 4, SIZE * 4)[0] == "point"
    assert default_pixel_filter(model, SIZE, SIZE, (0.5, 0.0, SIZE + 0.5, SIZE))[0] == "box"  # off the grid
    # a file without the key (content 1.1) renders as before: box = EDGE_SPP points in the crossed pixels
    del model.header["pixel_filter"]
    assert default_pixel_filter(model, SIZE, SIZE)[0] == "box"
    np.testing.assert_allclose(render(model, SIZE, SIZE, pixel_filter="box"), render(model, SIZE, SIZE, edge_spp=64),
                               atol=1e-6)


def test_golden_filter_file_and_reference_decoder():
    blob = (GOLDEN / "tiny_filter.dfield").read_bytes()
    expect = json.loads((GOLDEN / "tiny_filter.json").read_text())
    model = loads(blob)
    ref = ReferenceField.from_bytes(blob)
    assert model.header["pixel_filter"] == expect["pixel_filter"] == "gaussian:0.5"
    # the integral of spec §5.1, by dfc's quadrature with many points and by the reference's midpoint rule
    import torch

    off, weight = parse(model.header["pixel_filter"]).nodes(1 << 14)
    pw, ph = model.header["pixel_size"]
    for r, c in [(0, 0), (3, 7), (8, 8), (15, 2), (11, 13)]:
        centre = np.array([(c + 0.5) * pw, (r + 0.5) * ph])
        xy = np.clip(centre + off * [pw, ph], ref.domain[:2], ref.domain[2:])
        with torch.no_grad():
            ours = weight @ model(torch.from_numpy(xy)).double().numpy()
        want = ref.pixel(*centre, n=256)
        np.testing.assert_allclose(ours, want, rtol=0.01, atol=0.01 * np.abs(want).max())
    with pytest.raises(FormatError, match="pixel_filter"):
        decode_dfield((GOLDEN.parent / "invalid" / "pixel_filter_unknown.dfield").read_bytes())


def test_library_refuses_a_filter_for_samples(scene):
    from dfc.io.samples import SampleSet

    xy = np.random.default_rng(0).random((500, 2)) * SIZE
    samples = SampleSet(xy, scene.value(xy).astype(np.float32), scene.domain, ["Y"])
    with pytest.raises(InputError, match="pixel filter"):
        encode_samples(samples, scene.curves, EncodeSettings(steps=5, pixel_filter="point"))


def test_cli_pixel_filter_errors(tmp_path, capsys, scene, rasters):
    from dfc.geometry.sources.jsonfile import write_json
    from dfc.io.image import write_exr
    from dfc.io.samples import SampleSet, write_samples

    image, curves = tmp_path / "p.exr", tmp_path / "p.json"
    write_exr(image, np.repeat(rasters["point"], 3, axis=2), ["R", "G", "B"])
    write_json(scene.curves, curves)
    out = tmp_path / "o.dfield"
    for spec, match in (("lanczos", "unknown pixel filter"), ("gaussian:-1", "stddev"),
                        ("blackman-harris:-2", "width")):
        code, _, err = run(["encode", image, "--curves", curves, "-o", out, "--pixel-filter", spec], capsys)
        assert_one_line_error(code, err, match)
        assert not out.exists()
    xy = np.random.default_rng(0).random((500, 2)) * SIZE
    write_samples(tmp_path / "s.npz", SampleSet(xy, scene.value(xy).astype(np.float32), scene.domain, ["Y"]))
    code, _, err = run(["encode", tmp_path / "s.npz", "--curves", curves, "-o", out, "--pixel-filter", "point"],
                       capsys)
    assert_one_line_error(code, err, "--pixel-filter applies to images")
    code, stdout, err = run(["encode", image, "--curves", curves, "-o", out, "--pixel-filter", "point", "--steps",
                             "20", "--batch-size", "4096", "-q"], capsys)
    assert code == 0, err
    assert "pixel filter: point (as given" in stdout
    code, stdout, err = run(["decode", out, "-o", tmp_path / "d.exr", "--pixel-filter", "tent:3"], capsys)
    assert_one_line_error(code, err, "takes no parameter")
    code, stdout, err = run(["zoom", out, "--center", "20,20", "--zoom", "4", "-o", tmp_path / "z.exr"], capsys)
    assert code == 0 and "pixel filter point (enlarging" in stdout + err


def test_mitsuba_filters_state_their_kernel():
    from dfc.io.mitsuba import rfilter_plugin, rfilter_spec

    assert rfilter_plugin("box") == {"type": "box"}
    assert rfilter_plugin("gaussian") == {"type": "gaussian", "stddev": 0.5}
    assert rfilter_spec(rfilter_plugin("gaussian:0.8")) == "gaussian:0.8"
    assert rfilter_spec({"type": "lanczos"}) == "unknown"
    for spec in ("point", "box:4", "blackman-harris"):
        with pytest.raises(InputError):
            rfilter_plugin(spec)
