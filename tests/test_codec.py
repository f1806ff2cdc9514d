"""The codec glue: model <-> file contents, byte-target sizing, domain checks, and that an encode decodes to
exactly what it reports."""

import numpy as np
import pytest
import torch

from dfc.bench.scenes import sample_scene
from dfc.codec import EncodeSettings, check_domain, encode_image, loads
from dfc.errors import FormatError, InputError
from dfc.field.feature_field import FeatureField
from dfc.field.model import FieldModel
from dfc.io.container import decode_dfield, encode_dfield
from dfc.io.dfield import from_contents, to_contents
from dfc.rate import build_mesh
from dfc.render import render


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
    err = np.mean((render(model, 64, 64).astype(np.float64) - image) ** 2)
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


@pytest.mark.parametrize("target", [12_000, 30_000])
def test_target_bytes_sizes_the_file(scene, target):
    image = scene.render(64, 64, spp=1)
    curves = check_domain(scene.curves, 64, 64, fit=True)
    blob, report = encode_image(image, curves, EncodeSettings(steps=2, batch_size=512, target_bytes=target))
    assert len(blob) <= target * 1.05
    assert len(blob) >= target * 0.7


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
    blob, _ = encode_bands(ArrayBands(image, ["R", "G", "B"]), small, settings)
    assert len(calls) == 2
    loads(blob)  # a decoder validates what it reads
    assert len(calls) == 3
