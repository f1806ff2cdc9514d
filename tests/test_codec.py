"""The codec glue: model <-> file contents, byte-target sizing, domain checks, and that an encode decodes to
exactly what it reports."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from dfc.bench.scenes import sample_scene
from dfc.codec import EncodeSettings, check_domain, encode_image, loads
from dfc.errors import FormatError, InputError
from dfc.field.feature_field import FeatureField
from dfc.field.model import FieldModel
from dfc.geometry import bezier
from dfc.io.container import decode_dfield, encode_dfield
from dfc.io.dfield import from_contents, to_contents
from dfc.rate import build_mesh
from dfc.render import EDGE_SPP, default_edge_spp, render


@pytest.fixture(scope="module")
def scene():
    return sample_scene()


@pytest.fixture(scope="module")
def small_mesh(scene):
    return build_mesh(scene.curves, EncodeSettings(max_triangles=400))


def _random_model(mesh, **kw):
    model = FieldModel(FeatureField(mesh, dim=4, seed=1), ["R", "G", "B"], hidden=16, **kw)
    with torch.no_grad():
        model.field.bank.uniform_(-1, 1, generator=torch.Generator().manual_seed(2))
    return model


@pytest.mark.parametrize("kw", [{}, {"activation": "tanh", "oneblob_bins": 4, "transform": "log"}])
def test_quantised_model_round_trips_exactly(small_mesh, kw):
    model = _random_model(small_mesh, **kw)
    model.quantization = {"feature_bits": 8}
    blob, _ = encode_dfield(to_contents(model, {"note": "test"}), feature_bits=8)
    back = loads(blob)
    assert back.config() == model.config()
    xy = torch.rand(5000, 2, dtype=torch.float64) * 256
    with torch.no_grad():
        np.testing.assert_allclose(back(xy).numpy(), model(xy).numpy(), rtol=1e-6, atol=1e-6)
    assert back.header["encoder"] == {"note": "test"}


def test_the_header_records_only_the_settings_that_differ_and_is_compact(small_mesh):
    """The ``encoder`` record names the software, the curves' source, the settings that differ from that version's
    defaults and what the encoder adds; the header JSON carries no whitespace (its bytes count in a small file)."""
    import zstandard

    from dfc import __version__
    from dfc.codec import encoder_info
    from dfc.io.container import HEADER_DICTIONARY, _split_chunks

    info = encoder_info(replace(EncodeSettings(), seed=3, steps=200), "c.json", {"input": "image 8x8"})
    assert info == {"software": f"dfc {__version__}", "source": "c.json", "seed": 3, "steps": 200,
                    "input": "image 8x8"}
    blob, _ = encode_dfield(to_contents(_random_model(small_mesh), info))
    text = zstandard.ZstdDecompressor(dict_data=zstandard.ZstdCompressionDict(
        HEADER_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT)).decompress(bytes(_split_chunks(blob)[0][b"HEAC"]))
    assert b'"seed":3,' in text and b", " not in text and b": " not in text
    assert loads(blob).header["encoder"] == info


def test_from_contents_refuses_mismatched_weights(small_mesh):
    contents = decode_dfield(encode_dfield(to_contents(_random_model(small_mesh)))[0])
    contents.mlp.pop("layers.2.bias")
    with pytest.raises(FormatError, match="MLPW"):
        from_contents(contents)
    contents = decode_dfield(encode_dfield(to_contents(_random_model(small_mesh)))[0])
    contents.header["model"]["hidden"] = 32
    with pytest.raises(FormatError):
        from_contents(contents)


def test_build_mesh_is_the_decoder_view(scene):
    mesh = build_mesh(scene.curves, EncodeSettings(max_triangles=300))
    contents = to_contents(_random_model(mesh))
    decoded = decode_dfield(encode_dfield(contents)[0]).mesh
    np.testing.assert_array_equal(decoded.vertices, mesh.vertices)
    np.testing.assert_array_equal(decoded.triangles, mesh.triangles)


def test_domain_check(scene):
    assert check_domain(scene.curves, 256, 256, fit=False) is scene.curves
    with pytest.raises(InputError, match="fit-curves-to-image"):
        check_domain(scene.curves, 128, 64, fit=False)
    scaled = check_domain(scene.curves, 128, 64, fit=True)
    assert scaled.domain == (0.0, 0.0, 128.0, 64.0)
    np.testing.assert_allclose(scaled.control_points, scene.curves.control_points * [0.5, 0.25])


@pytest.fixture(scope="module")
def small_encode(scene):
    image = scene.render(64, 64, window=None, spp=2)
    curves = check_domain(scene.curves, 64, 64, fit=True)
    blob, report = encode_image(image, curves, EncodeSettings(steps=60, batch_size=2048, max_triangles=300))
    return image, blob, report


def test_encode_reports_what_the_file_decodes_to(small_encode):
    image, blob, report = small_encode
    model = loads(blob)
    assert model.header["pixel_size"] == [1.0, 1.0] and default_edge_spp(model, 64, 64) == EDGE_SPP
    assert model.header["pixel_filter"] == report.pixel_filter == "box:2"  # the raster's 2 x 2 sub-samples, found
    err = np.mean((render(model, 64, 64, pixel_filter="box:2").astype(np.float64) - image) ** 2)
    assert report.psnr == pytest.approx(10 * np.log10(1.0 / err), abs=1e-6)
    assert report.total_bytes == len(blob)
    assert sum(report.chunk_bytes.values()) + 16 == len(blob)
    assert report.bits_per_pixel == pytest.approx(8 * len(blob) / 64**2)
    assert report.n_triangles == model.field.mesh.n_triangles
    assert report.psnr > 20


def test_encode_is_deterministic(scene, small_encode):
    image, blob, _ = small_encode
    curves = check_domain(scene.curves, 64, 64, fit=True)
    again, _ = encode_image(image, curves, EncodeSettings(steps=60, batch_size=2048, max_triangles=300))
    assert again == blob


def test_refinement_splits_where_the_error_is_and_reports_the_refined_file(scene, small_encode):
    image, blob, report = small_encode
    curves = check_domain(scene.curves, 64, 64, fit=True)
    settings = EncodeSettings(steps=60, batch_size=2048, max_triangles=300, refine=1, refine_steps=60)
    refined_blob, refined = encode_image(image, curves, settings)
    model, coarse = loads(refined_blob), loads(blob)
    assert coarse.field.mesh.n_triangles < refined.n_triangles == model.field.mesh.n_triangles
    assert refined.n_triangles <= coarse.field.mesh.n_triangles * (1 + 3 * settings.refine_fraction)
    err = np.mean((render(model, 64, 64, pixel_filter=model.header["pixel_filter"]).astype(np.float64) - image) ** 2)
    assert refined.psnr == pytest.approx(10 * np.log10(1.0 / err), abs=1e-6)
    assert refined.psnr > report.psnr  # 60 more steps on a finer mesh, started from the first fit
    assert "refine_s" in refined.seconds
    # the curves draw as they did: the straight discontinuities stay, curved pieces are at most halved
    assert len(model.field.mesh.disc_edges) == len(coarse.field.mesh.disc_edges)
    fine, before = model.field.mesh.curve_control_points, coarse.field.mesh.curve_control_points
    assert len(fine) >= len(before)
    t = np.linspace(0.0, 1.0, 513)

    def drawn(cp):
        return bezier.evaluate(np.repeat(cp, len(t), axis=0), np.tile(t, len(cp)))

    assert cKDTree(drawn(before)).query(drawn(fine))[0].max() < 0.05
    assert cKDTree(drawn(fine)).query(drawn(before))[0].max() < 0.05


@pytest.mark.parametrize("target", [9_000, 12_000])
def test_target_bytes_sizes_the_file(scene, target):
    """The sizing probe (a random bank) leaves room that the default refinement round fills: the file lands within
    a few per cent below the target; without refinement it stays below it. (The field alone: a residual raster's
    AVIF may reach its top quality below its share of a small image's target.)"""
    image = scene.render(64, 64, spp=1)
    curves = check_domain(scene.curves, 64, 64, fit=True)
    settings = EncodeSettings(steps=2, batch_size=512, target_bytes=target, residual_bytes=0)
    blob, report = encode_image(image, curves, settings)
    assert 0.9 * target <= len(blob) <= target
    assert loads(blob).header["encoder"]["refine"] == 1 and "refine_s" in report.seconds
    probe_only, _ = encode_image(image, curves, replace(settings, refine=0))
    assert 0.7 * target <= len(probe_only) <= target


def test_target_bytes_stays_a_cap_when_the_fill_overshoots(scene, monkeypatch):
    """A fill that prices too many points (the refit's features cost more than the carried-over ones) is refitted
    with fewer until the file is within the target; more refinement than the probe's mesh is still kept."""
    import dfc.rate

    image = scene.render(64, 64, spp=1)
    curves = check_domain(scene.curves, 64, 64, fit=True)
    settings = EncodeSettings(steps=2, batch_size=512, target_bytes=9_000)
    real = dfc.rate.fill_points
    calls = []

    def greedy(model, *args, **kw):  # every triangle split: far over the target
        calls.append(real(model, *args, **kw))
        return dfc.rate.refinement_points(model.field.mesh, args[3], args[4], share=1.0,
                                          most=model.field.mesh.n_triangles)

    monkeypatch.setattr(dfc.rate, "fill_points", greedy)
    blob, report = encode_image(image, curves, settings, raster_mode=False)  # two steps: the field's fill, kept
    probe_only, probe = encode_image(image, curves, replace(settings, refine=0), raster_mode=False)
    assert calls and len(blob) <= 9_000
    assert report.n_triangles > probe.n_triangles


class _Fill:
    """A stand-in model for ``_fill_within``: its fill points ``n`` and the feature bits its file stores."""

    def __init__(self, n: int, bits: int = 10):
        self.n, self.quantization = n, {"feature_bits": bits}

    def key(self) -> tuple[int, int]:
        return self.n, self.quantization["feature_bits"]


def test_fill_within_cuts_the_points_in_proportion_and_gives_up():
    from dfc.codec import _fill_within

    points = np.arange(100.0).reshape(50, 2)
    tried = []

    def refit(p, bits):
        tried.append((len(p), bits))
        return _Fill(len(p), bits)

    def size_of(m):  # 1,000 bytes without fill points, 100 bytes per point
        return 1_000 + 100 * m.n

    model = _Fill(0)
    refined, used = _fill_within(model, points, refit, size_of, target=3_000, bits=10)
    assert tried[0] == (50, 10) and refined.n == len(used) <= 20 and tried[-1] == (len(used), 10) and len(tried) == 2
    np.testing.assert_array_equal(used, points[:len(used)])  # the points with the largest error first
    tried.clear()
    refined, used = _fill_within(model, points, refit, size_of, target=900, bits=10)  # over it before any point
    assert refined is None and used.shape == (0, 2) and tried == [(50, 10)]


def test_a_file_stores_the_feature_bits_its_model_was_fitted_for(small_encode):
    from dfc.io.dfield import encode_model, storage

    model = loads(small_encode[1])
    settings = EncodeSettings(feature_bits=10)
    assert model.quantization is None and storage(settings, model)["feature_bits"] == 10
    ten = encode_model(model, settings)[0]
    model.quantization = {"feature_bits": 9}
    assert storage(settings, model)["feature_bits"] == 9
    nine = encode_model(model, settings)[0]
    assert len(nine) < len(ten)
    step = float(loads(ten).field.bank.detach().abs().max()) / 2 ** 8  # a 9-bit step over the features' range
    assert np.abs(loads(nine).field.bank.detach().numpy() - loads(ten).field.bank.detach().numpy()).max() <= step


def test_the_report_and_the_encoder_record_say_the_bits_the_file_stores(small_encode):
    from dfc.codec import _finish
    from dfc.io.dfield import encoder_info
    from dfc.metrics import quality_scale

    image, blob, _ = small_encode
    model = loads(blob)
    model.quantization = {"feature_bits": 9}  # as a fill's last retry leaves it
    settings = EncodeSettings(feature_bits=10)
    info = encoder_info(settings, "test", {})
    out, report = _finish(model, settings, info, {}, 64 * 64, lambda m: (image, render(m, 64, 64)),
                          quality_scale(image))
    assert report.feature_bits == 9 and loads(out).header["encoder"]["feature_bits"] == 9 and info["feature_bits"] == 10


def test_fill_within_cuts_along_the_refits_and_stores_a_bit_fewer_when_no_cut_fits():
    """A refit costs more than its points (its features are less smooth than the carried-over ones): after the first
    proportional cut, a cut follows the line through the last two refits; when that line says no count fits, the
    points are kept at one feature bit fewer if the encoder chose the bits, and nothing is refitted if not."""
    from dfc.codec import _fill_within

    points = np.arange(100.0).reshape(50, 2)
    tried = []

    def refit(p, bits):
        tried.append((len(p), bits))
        return _Fill(len(p), bits)

    def size_of(m):  # the first fit 1,000 bytes; a refit 300 more, then 100 a point; bytes in proportion to the bits
        n, bits = m.key()
        return (1_000 + (300 + 100 * n if n else 0)) * bits // 10

    first = _Fill(0, 10)
    for fewer_bits in (True, False):  # a cut fits: the bits are kept either way
        tried.clear()
        refined, used = _fill_within(first, points, refit, size_of, target=2_200, bits=10, fewer_bits=fewer_bits)
        assert tried == [(50, 10), (10, 10), (8, 10)] and refined.key() == (8, 10) and len(used) == 8
    tried.clear()
    # a fill at fewer bits than the first fit's (dfc.rate.COARSE_FEATURE_BITS): the first file is priced at them too
    # (800 bytes, not 1,000), so the first cut keeps 16 points, not 14
    refined, used = _fill_within(first, points, refit, size_of, target=2_200, bits=8)
    assert tried == [(50, 8), (16, 8), (13, 8)] and refined.key() == (13, 8) and first.key() == (0, 10)

    def costly(m):  # a refit 1,150 bytes over the first fit at 10 bits, 800 at 9, plus 10 a point: no cut fits at 10
        n, bits = m.key()
        return 1_000 + ((1_150 if bits == 10 else 800) + 10 * n if n else 0)

    tried.clear()
    refined, used = _fill_within(first, points, refit, costly, target=2_200, bits=10, fewer_bits=True)
    assert tried == [(50, 10), (35, 10), (35, 9)] and refined.key() == (35, 9) and len(used) == 35
    tried.clear()
    refined, used = _fill_within(first, points, refit, costly, target=2_200, bits=10)
    assert refined is None and used.shape == (0, 2) and tried == [(50, 10), (35, 10)]


def test_a_byte_targets_refit_runs_as_many_steps_as_the_fit():
    """Under a byte target the refit is the file (CHANGELOG.md, "A byte target's refit runs the fit's steps");
    other refinement rounds refit for half the steps; ``refine_steps`` overrides both."""
    from dfc.codec import refit_steps

    assert refit_steps(EncodeSettings(steps=3000, target_bytes=4096)) == 3000
    assert refit_steps(EncodeSettings(steps=3000, refine=2)) == 1500
    assert refit_steps(EncodeSettings(steps=3000, target_psnr=40.0)) == 1500
    assert refit_steps(EncodeSettings(steps=1, target_psnr=40.0)) == 1
    assert refit_steps(EncodeSettings(steps=3000, target_bytes=4096, refine_steps=7)) == 7


def test_target_psnr_refines_until_the_fit_reaches_it(scene):
    """A PSNR target the first fit already reaches refines nothing; one it cannot reach runs every round, each on a
    finer mesh, and the report says what the file reached."""
    from dfc.codec import TARGET_PSNR_ROUNDS

    image = scene.render(48, 48, spp=1)
    curves = check_domain(scene.curves, 48, 48, fit=True)
    base = EncodeSettings(steps=30, batch_size=512, max_triangles=150, refine_steps=10)
    _, easy = encode_image(image, curves, replace(base, target_psnr=1.0))
    assert "refine_s" in easy.seconds and easy.psnr >= 1.0
    _, plain = encode_image(image, curves, base)
    assert (easy.n_triangles, easy.psnr) == (plain.n_triangles, plain.psnr)  # reached before any round: the plain fit
    assert easy.chunk_bytes["FEAC"] == plain.chunk_bytes["FEAC"]
    hard_blob, hard = encode_image(image, curves, replace(base, target_psnr=200.0))
    assert hard.psnr < 200.0 and hard.n_triangles > plain.n_triangles
    assert loads(hard_blob).header["encoder"]["refine"] == TARGET_PSNR_ROUNDS


def test_target_bytes_too_small(scene):
    image = scene.render(64, 64, spp=1)
    curves = check_domain(scene.curves, 64, 64, fit=True)
    with pytest.raises(InputError, match="too small"):
        encode_image(image, curves, EncodeSettings(steps=2, target_bytes=500))


def test_nan_image_is_refused(scene):
    image = scene.render(64, 64, spp=1)
    image[5, 6, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        encode_image(image, check_domain(scene.curves, 64, 64, fit=True), EncodeSettings(steps=2))


# ------------------------------------------------------------------------------------------- what the summary says
def _last_batch_psnr(history: list, n: int = 10) -> float:
    return float(np.mean(history[-n:]))


def test_hdr_report_is_tone_mapped_and_the_progress_agrees(scene, one_thread):
    """HDR images are measured on x / (1 + x) with data range 1, by the summary and by the fit's progress alike."""
    from dfc.metrics import QualityScale

    from dfc.bench.scenes import get_scene

    hdr = get_scene("hdr")  # light up to about 80, peaks far above the mean (times 40 would only be another unit)
    image = hdr.render(48, 48)
    curves = check_domain(hdr.curves, 48, 48, fit=True)
    seen = []
    blob, report = encode_image(image, curves, EncodeSettings(steps=120, batch_size=2048, max_triangles=300),
                                callback=lambda step, loss, psnr: seen.append(float(psnr)))
    assert report.tonemapped and report.data_range == 1.0
    model = loads(blob)  # measured as dfc decode renders it at the input's size: anti-aliased
    assert default_edge_spp(model, 48, 48) == EDGE_SPP
    decoded = render(model, 48, 48, pixel_filter=model.header["pixel_filter"]).astype(np.float64)
    tm = image / (1 + image), np.maximum(decoded, 0) / (1 + np.maximum(decoded, 0))
    assert report.psnr == pytest.approx(10 * np.log10(1.0 / np.mean((tm[0] - tm[1]) ** 2)), abs=1e-6)
    assert report.psnr == pytest.approx(QualityScale(1.0, tonemap=True).psnr(image, decoded), abs=1e-9)
    # the batch PSNR of the last steps (pixels no curve crosses) and the file's PSNR (every pixel) on one scale;
    # with the value span (about 80) as the bar's data range they would differ by 20 log10(80) = 38 dB
    assert abs(_last_batch_psnr(seen) - report.psnr) < 6.0


def test_fem_progress_and_summary_agree_for_small_values(tmp_path, one_thread):
    """A FEM solution of values about 1e-3: the progress bar's batch PSNR and the summary's use the values' span."""
    import meshio

    from dfc.codec import encode_fem
    from dfc.geometry.sources import read_curves
    from dfc.io.fem import from_meshio

    from .physics.test_fem import grid_mesh, write_curves

    pts, tris = grid_mesh(16)
    u = 1e-3 * (np.where(pts[:, 0] < 0.5, 0.2, 0.7) + 0.3 * pts[:, 1])
    solution = from_meshio(meshio.Mesh(pts, [("triangle", tris)], point_data={"u": u}))
    wall = read_curves(write_curves(tmp_path / "wall.json", [[[0.5, 0.0], [0.5, 1.0]]]))
    seen = []
    _, report = encode_fem(solution, wall, EncodeSettings(max_triangles=200, steps=100, batch_size=2048),
                           callback=lambda step, loss, psnr: seen.append(float(psnr)))
    assert report.data_range == pytest.approx(float(np.ptp(u)), rel=1e-6) and not report.tonemapped
    assert abs(_last_batch_psnr(seen) - report.psnr) < 6.0  # with data range 1 the bar would read ~60 dB more


def test_sample_set_report_uses_held_out_samples_and_the_reference(scene, monkeypatch, one_thread):
    import dfc.codec as codec
    from dfc.io.samples import SampleSet
    from dfc.metrics import psnr
    from dfc.render import values_at

    rng = np.random.default_rng(3)
    xy = rng.random((6000, 2)) * 256
    noisy = (scene.value(xy) + rng.normal(0, 0.05, (len(xy), 3))).clip(0, 1).astype(np.float32)
    fitted_on = []
    real = codec._mesh_and_fit
    monkeypatch.setattr(codec, "_mesh_and_fit", lambda fn, signal, *a, **k: (fitted_on.append(signal), real(
        fn, signal, *a, **k))[1])
    reference = scene.render(32, 32, spp=1)
    blob, report = codec.encode_samples(SampleSet(xy, noisy, scene.curves.domain, ["R", "G", "B"]), scene.curves,
                                        EncodeSettings(steps=40, batch_size=2048, seed=5), reference=reference)
    fitted, held = codec.heldout_split(len(xy), 5)
    assert report.heldout == len(held) == 600 and len(fitted) + len(held) == len(xy)
    assert not set(fitted) & set(held)
    assert len(fitted_on[0].xy) == 5400  # the held-out samples never reach the fit
    np.testing.assert_array_equal(fitted_on[0].xy, xy[fitted])
    model = loads(blob)
    assert report.psnr == pytest.approx(psnr(noisy[held], values_at(model, xy[held]), data_range=1.0), abs=1e-6)
    assert report.psnr_reference == pytest.approx(psnr(reference, render(model, 32, 32), data_range=1.0), abs=1e-6)
    with pytest.raises(InputError, match="reference"):
        codec.encode_samples(SampleSet(xy, noisy), scene.curves, EncodeSettings(steps=1), reference=reference[..., :1])


def test_heldout_split_sizes():
    from dfc.codec import HOLDOUT_MAX, heldout_split

    assert [len(heldout_split(n, 0)[1]) for n in (10, 99, 100, 1000)] == [0, 0, 10, 100]
    assert len(heldout_split(10 * HOLDOUT_MAX, 0)[1]) == HOLDOUT_MAX
    a, b = heldout_split(1000, 1)
    np.testing.assert_array_equal(np.sort(np.concatenate([a, b])), np.arange(1000))


def test_small_images_get_a_mesh_and_decoder_sized_to_them(scene, one_thread):
    from dfc.geometry.curves import Curves

    empty = Curves((0.0, 0.0, 1.0, 1.0), np.zeros((0, 4, 2)), [], [], np.zeros((0, 2)))
    blob, report = encode_image(np.full((1, 1, 3), 0.5, np.float32), empty, EncodeSettings(steps=5, batch_size=16))
    assert report.n_triangles == 2 and loads(blob).config()["hidden"] == 8
    assert len(blob) < 2000  # was 18 KB with the 2,000-triangle mesh and the 64-wide decoder
    image = scene.render(64, 64, spp=1)
    curves = check_domain(scene.curves, 64, 64, fit=True)
    # the field alone: a clean image without a target otherwise shares one with a residual, its decoder sized to it
    blob, report = encode_image(image, curves, EncodeSettings(steps=5, batch_size=512, residual_bytes=0))
    assert loads(blob).config()["hidden"] == 32
    assert report.n_triangles < 300 and len(blob) < 64 * 64 * 3  # smaller than the 8-bit pixels
    explicit, _ = encode_image(image, curves, EncodeSettings(steps=5, batch_size=512, max_triangles=1000))
    assert len(loads(explicit).field.mesh.triangles) > 600  # an explicit size is kept


def test_an_encode_validates_its_mesh_once(scene, monkeypatch):
    from dataclasses import replace

    from dfc.codec import encode_bands
    from dfc.geometry.mesh import Mesh
    from dfc.io.bands import ArrayBands

    calls = []
    validate = Mesh.validate
    monkeypatch.setattr(Mesh, "validate", lambda mesh: (calls.append(mesh.n_triangles), validate(mesh))[1])
    image = scene.render(64, 64, spp=1)
    small = replace(scene.curves, domain=(0.0, 0.0, 64.0, 64.0), control_points=scene.curves.control_points / 4.0)
    settings = EncodeSettings(steps=2, batch_size=256, max_triangles=400)
    encode_image(image, small, settings)
    assert len(calls) == 1
    blob, report = encode_bands(ArrayBands(image, ["R", "G", "B"]), small, settings)
    assert len(calls) == 2
    assert {"HEAC", "FEAC", "MLPC"} <= set(report.chunk_bytes)  # out of core, the same 1.4 chunks are written
    model = loads(blob)  # a decoder validates what it reads
    assert len(calls) == 3
    assert model.header["pixel_size"] == [1.0, 1.0]
