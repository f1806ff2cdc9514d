"""The residual raster (spec/dfield.md §6.9, spec/field.md "Residual"): its payload round trip and damage checks,
bilinear interpolation through the pixel centres, the container's rESD chunk, and an encode that stores one."""

import struct
from dataclasses import replace

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.bench.pixel_filters import filtered_raster
from dfc.bench.scenes import sample_scene, shapes_scene
from dfc.codec import EncodeSettings, check_domain, encode_image, loads
from dfc.errors import FormatError, InputError
from dfc.field.residual import ResidualGrid
from dfc.io.container import decode_dfield, encode_dfield, with_residual
import dfc.codec
import dfc.io.residual as residual_module
from dfc.io.residual import (AVIF_MATRIX, RESIDUAL_BITS, decode_residual, encode_residual, payload_head,
                             payload_streams)
from dfc.metrics import noise_sigma, quality_scale
import dfc.rate
from dfc.rate import RESIDUAL_FIELD_BPP, RESIDUAL_MIN_BYTES, RESIDUAL_NOISE, RESIDUAL_SHARE, residual_choices
from dfc.render import render

from .reference_decoder import ReferenceField


def _smooth(h, w, c, seed=0):
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    rng = np.random.default_rng(seed)
    return np.stack([np.sin(3 * x + rng.uniform(0, 6)) * np.cos(2 * y + k) * 0.01 for k in range(c)],
                    axis=2).astype(np.float32)


@pytest.mark.parametrize("channels", [1, 2, 3])
def test_a_payload_fits_its_budget_and_decodes_to_its_values(channels):
    values = _smooth(24, 40, channels)
    payload = encode_residual(values, 4000)
    assert len(payload) <= 4000
    decoded = decode_residual(payload)
    assert decoded.shape == values.shape and decoded.dtype == np.float32
    span = float(values.max() - values.min())
    assert np.abs(decoded - values).max() < 0.02 * span  # 12-bit samples, high quality
    small = encode_residual(values, int(0.8 * len(payload)))
    assert len(small) < len(payload)
    assert np.abs(decode_residual(small) - values).mean() >= np.abs(decoded - values).mean()


def test_the_streams_code_their_planes_as_they_are_and_the_top_quality_decodes_exactly():
    values = _smooth(24, 40, 3)
    payload = encode_residual(values, 1 << 20)  # room for the top quality: lossless
    (stream,) = payload_streams(payload)
    colr = stream.index(b"colrnclx") + 8  # colour information: primaries, transfer, matrix (u16 each)
    assert int.from_bytes(stream[colr + 4:colr + 6], "big") == AVIF_MATRIX == 0  # identity: GBR, 4:4:4
    lo, hi = float(values.min()), float(values.max())
    step = (hi - lo) / ((1 << RESIDUAL_BITS) - 1)
    assert np.abs(decode_residual(payload) - values).max() <= 0.5 * step * (1 + 1e-4)  # only the 12-bit rounding


def test_a_raised_hi_spends_the_bytes_between_two_qualities_only_where_it_lowers_the_error(monkeypatch):
    rng = np.random.default_rng(3)
    values = (_smooth(48, 64, 3) + rng.normal(0.0, 0.002, (48, 64, 3))).astype(np.float32)

    def error(payload):
        return float(np.square(decode_residual(payload).astype(np.float64) - values).sum())

    raised = 0
    for budget in (2500, 3500, 5000, 7000, 10000):
        payload = encode_residual(values, budget)
        with monkeypatch.context() as m:
            m.setattr(residual_module, "GAIN_FILL", 0.0)  # the highest quality that fits, as it is
            plain = encode_residual(values, budget)
        assert len(payload) <= budget and len(plain) <= budget
        assert error(payload) <= error(plain)
        if payload != plain:
            assert payload_head(payload)["hi"] > float(values.max()) and error(payload) < error(plain)
            raised += 1
    assert raised >= 1


def test_a_residual_that_would_add_error_is_refused(monkeypatch):
    values = _smooth(24, 40, 3)
    coded = decode_residual(encode_residual(values, 3000))
    monkeypatch.setattr(residual_module, "decode_residual", lambda payload: 2.0 * values - 0.5 * coded)
    assert encode_residual(values, 3000) is not None  # its error, (values − coded / 2)², is still the smaller
    monkeypatch.setattr(residual_module, "decode_residual", lambda payload: -coded)
    with pytest.raises(InputError, match="adds more error than it removes"):
        encode_residual(values, 3000)


def test_a_budget_below_the_smallest_stream_and_a_constant_residual():
    with pytest.raises(InputError, match="smallest stream takes"):
        encode_residual(_smooth(32, 32, 3), 30)
    assert encode_residual(np.full((8, 8, 3), 0.25, np.float32), 1000) is None


def test_damaged_payloads_are_refused():
    payload = encode_residual(_smooth(16, 16, 3), 3000)
    for damaged, why in [(payload[:10], "shorter than"), (b"\x02" + payload[1:], "unknown version"),
                         (payload[:4] + b"\x02" + payload[5:], "space 2"), (payload[:6] + b"\x01" + payload[7:],
                                                                             "reserved"),
                         (payload + b"\0", "after the last stream"), (payload[:-5], "runs past"),
                         (payload[:40] + payload[40:80][::-1] + payload[80:], "rESD")]:
        with pytest.raises(FormatError, match=why):
            decode_residual(damaged)
    huge = bytearray(payload)
    struct.pack_into("<II", huge, 8, 1 << 14, 1 << 13)  # 2^27 pixels: refused before any stream is decoded
    with pytest.raises(FormatError, match="invalid head"):
        decode_residual(bytes(huge))
    head = bytearray(payload)
    struct.pack_into("<I", head, 8, 17)  # the width the head declares differs from the stream's
    with pytest.raises(FormatError, match="the head says"):
        decode_residual(bytes(head))


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.floats(-3, 12), st.floats(-3, 12))
def test_the_grid_interpolates_through_the_pixel_centres_and_is_continuous(w, h, x, y):
    rng = np.random.default_rng(w * 7 + h)
    values = rng.normal(size=(h, w, 2)).astype(np.float32)
    domain = (-1.0, 2.0, -1.0 + 1.5 * w, 2.0 + 0.5 * h)  # pixels of 1.5 x 0.5
    grid = ResidualGrid(values, domain, b"")
    cx = -1.0 + 1.5 * (np.arange(w) + 0.5)
    cy = 2.0 + 0.5 * (np.arange(h) + 0.5)
    centres = torch.tensor([[a, b] for b in cy for a in cx], dtype=torch.float64)
    assert np.allclose(grid(centres).numpy(), values.reshape(-1, 2), atol=1e-12)
    p = torch.tensor([[x, y]], dtype=torch.float64)
    out = grid(p).numpy()[0]
    assert values.min(axis=(0, 1)).min() - 1e-9 <= out.min() and out.max() <= values.max() + 1e-9
    eps = torch.tensor([[1e-7, -1e-7]], dtype=torch.float64)
    assert np.allclose(grid(p + eps).numpy(), out, atol=1e-5)  # no jump anywhere: bilinear, clamped outside


@pytest.fixture(scope="module", params=["sdr", "hdr"])
def encoded(request):
    scene = sample_scene()
    image = scene.render(48, 48, window=None, spp=2) * (4.0 if request.param == "hdr" else 1.0)
    curves = check_domain(scene.curves, 48, 48, fit=True)
    plain, _ = encode_image(image, curves, EncodeSettings(steps=60, batch_size=2048, target_bytes=5000,
                                                          residual_bytes=0))
    blob, report = encode_image(image, curves, EncodeSettings(steps=60, batch_size=2048, target_bytes=5000,
                                                              residual_bytes=2000))
    return image, curves, plain, blob, report


def test_an_encode_with_a_residual_keeps_the_target_and_reports_the_file(encoded):
    image, _, plain, blob, report = encoded
    assert len(blob) <= 5000 and report.total_bytes == len(blob)
    assert 0 < report.chunk_bytes["rESD"] <= 2000 and sum(report.chunk_bytes.values()) + 16 == len(blob)
    assert struct.unpack_from("<HH", blob, 8) == (1, 2) and struct.unpack_from("<HH", plain, 8) == (1, 1)
    model = loads(blob)
    assert model.header["encoder"]["target_bytes"] == 5000 and model.header["encoder"]["residual_bytes"] == 2000
    filt, scale = model.header["pixel_filter"], quality_scale(image)
    assert model.residual.space == ("tonemapped" if scale.tonemap else "values")
    with_residual_psnr = scale.psnr(image, render(model, 48, 48, pixel_filter=filt))
    assert report.psnr == pytest.approx(with_residual_psnr, abs=1e-6)
    model.residual = None  # the field alone: the residual must be what raises the file's PSNR
    assert with_residual_psnr > scale.psnr(image, render(model, 48, 48, pixel_filter=filt)) + 1.0


def test_the_rESD_chunk_leaves_the_critical_chunks_as_they_are(encoded):
    _, _, plain, blob, _ = encoded
    contents = decode_dfield(blob)
    assert contents.residual is not None
    again, chunk = with_residual(plain, contents.residual)
    assert again[16:len(plain) - 12] == plain[16:-12]  # every critical chunk byte for byte
    assert decode_dfield(again).residual == contents.residual
    assert chunk == len(again) - len(plain) == 12 + len(contents.residual) + (-len(contents.residual) % 4)
    rewritten, sizes = encode_dfield(contents)
    assert decode_dfield(rewritten).residual == contents.residual and "rESD" in sizes
    with pytest.raises(ValueError, match="without an rESD"):
        with_residual(blob, contents.residual)


def test_a_second_rESD_and_a_damaged_one_are_refused(encoded):
    _, _, plain, blob, _ = encoded
    payload = decode_dfield(blob).residual
    end = len(blob) - 12
    chunk = blob[end - (12 + len(payload) + (-len(payload) % 4)):end]
    doubled = bytearray(blob[:end] + chunk + blob[end:])
    struct.pack_into("<I", doubled, 12, len(doubled))
    with pytest.raises(FormatError, match="rESD: more than one"):
        decode_dfield(bytes(doubled))
    bad, _ = with_residual(plain, payload[:-40])
    with pytest.raises(FormatError, match="rESD"):
        loads(bad)


def test_residual_bytes_must_leave_the_field_something(encoded):
    image, curves, *_ = encoded
    with pytest.raises(InputError, match="leaves nothing of --target-bytes"):
        encode_image(image, curves, EncodeSettings(steps=10, target_bytes=3000, residual_bytes=3000))


def test_the_reference_decoder_adds_the_same_residual(encoded):
    *_, blob, _ = encoded
    model, reference = loads(blob), ReferenceField.from_bytes(blob)
    assert reference.residual is not None
    rng = np.random.default_rng(3)
    x0, y0, x1, y1 = model.header["domain"]
    xy = np.column_stack([rng.uniform(x0, x1, 400), rng.uniform(y0, y1, 400)])
    with torch.no_grad():
        ours = model(torch.from_numpy(xy)).double().numpy()
    assert np.abs(ours - reference(xy)).max() < 1e-4
    model.residual = None
    with torch.no_grad():
        alone = model(torch.from_numpy(xy)).double().numpy()
    assert np.abs(ours - alone).max() > 1e-3  # the residual is there to be agreed on


def test_without_imagecodecs_one_line_says_what_to_install(encoded, monkeypatch):
    *_, blob, _ = encoded
    monkeypatch.setitem(__import__("sys").modules, "imagecodecs", None)  # import imagecodecs raises ImportError
    with pytest.raises(InputError, match="needs imagecodecs, a dependency of dfc"):
        loads(blob)


def test_stats_describe_the_residual(encoded, tmp_path):
    from dfc.cli.stats import file_stats

    image, _, plain, blob, _ = encoded
    (tmp_path / "r.dfield").write_bytes(blob)
    (tmp_path / "p.dfield").write_bytes(plain)
    stats = file_stats(tmp_path / "r.dfield")
    hdr = quality_scale(image).tonemap
    assert stats["residual"] == {**stats["residual"], "width": 48, "height": 48, "channels": 3, "bits": 12,
                                 "space": "tonemapped" if hdr else "values"}
    assert stats["container_version"] == "1.2" and "rESD" in stats["chunk_bytes"]
    assert file_stats(tmp_path / "p.dfield")["residual"] is None


@pytest.mark.parametrize("sigma", [0.003, 0.01, 0.03])
def test_noise_sigma_reads_white_noise_and_not_smooth_content_or_edges(sigma):
    raster = filtered_raster(shapes_scene(), 64, 64, "box:4")
    assert noise_sigma(raster) < 1e-6  # smooth regions and edges (few 2 x 2 blocks)
    noisy = raster + np.random.default_rng(1).normal(0.0, sigma, raster.shape).astype(np.float32)
    span = float(noisy.max() - noisy.min())  # measured as a share of the range
    assert noise_sigma(noisy) == pytest.approx(sigma / span, rel=0.2)  # edges add a little at 64²


def test_auto_gives_a_clean_image_a_share_of_the_target_and_a_noisy_one_none():
    raster = filtered_raster(shapes_scene(), 64, 64, "box:4")
    noisy = raster + np.random.default_rng(1).normal(0.0, 0.01, raster.shape).astype(np.float32)
    assert noise_sigma(noisy) > RESIDUAL_NOISE
    assert residual_choices(noisy, 4000) == [] and residual_choices(raster, None) == []
    cap = round(RESIDUAL_FIELD_BPP * 64 * 64 / 8)  # the field's most at 64²
    share = round(RESIDUAL_SHARE * 4000)
    assert cap < 4000 - share  # the cap bites first, the plain share follows
    assert residual_choices(raster, 4000) == [4000 - cap, share]
    small = int(RESIDUAL_MIN_BYTES / RESIDUAL_SHARE) - 2  # the share is under the least a residual gets ...
    assert residual_choices(raster, small) == ([small - cap] if small - cap >= RESIDUAL_MIN_BYTES else [])
    assert residual_choices(raster, RESIDUAL_MIN_BYTES - 1) == []  # ... and so is everything
    large = np.repeat(np.repeat(raster, 4, axis=0), 4, axis=1)  # 256²: the field's cap is over half of 4000 bytes
    assert residual_choices(large, 4000) == [share]


@pytest.fixture(scope="module")
def shapes_64():
    scene = shapes_scene()
    return filtered_raster(scene, 64, 64, "box:4"), check_domain(scene.curves, 64, 64, fit=True)


def test_auto_stores_a_residual_for_a_clean_image_under_a_target(shapes_64):
    raster, curves = shapes_64
    blob, report = encode_image(raster, curves, EncodeSettings(steps=60, batch_size=2048, target_bytes=4000),
                                raster_mode=False)  # the residual's share, not the raster mode (test_raster_mode)
    assert len(blob) <= 4000 and 0 < report.chunk_bytes["rESD"] <= 2000
    assert "residual_bytes" not in loads(blob).header["encoder"]  # auto is the default: not recorded
    no_target, _ = encode_image(raster, curves, EncodeSettings(steps=60, batch_size=2048, max_triangles=200))
    assert decode_dfield(no_target).residual is None


def test_auto_falls_back_to_the_field_alone_when_the_field_cannot_fit_its_share(shapes_64):
    raster, curves = shapes_64
    settings = EncodeSettings(steps=30, batch_size=2048, feature_bits=10)
    smallest = None
    for target in (1100, 1500, 2000, 2600, 3400):  # the smallest target the field alone fits
        try:
            encode_image(raster, curves, replace(settings, target_bytes=target, residual_bytes=0))
        except InputError:
            continue
        smallest = target
        break
    assert smallest is not None
    with pytest.raises(InputError, match="too small"):  # the field gets half: it does not fit
        encode_image(raster, curves, replace(settings, target_bytes=smallest, residual_bytes=smallest // 2))
    blob, report = encode_image(raster, curves, replace(settings, target_bytes=smallest), raster_mode=False)  # auto
    assert len(blob) <= smallest and "rESD" not in report.chunk_bytes


def test_auto_gives_the_residual_what_the_field_s_cap_leaves_when_the_field_fits_it(shapes_64, monkeypatch):
    raster, curves = shapes_64
    settings = EncodeSettings(steps=30, batch_size=2048, feature_bits=10)
    field = len(encode_image(raster, curves, replace(settings, max_triangles=80, target_bytes=None))[0])
    monkeypatch.setattr(dfc.rate, "RESIDUAL_FIELD_BPP", (field + 200) * 8 / (64 * 64))  # a cap the field fits
    target = 2 * field + 1200  # the plain share would leave the field more than its cap
    blob, report = encode_image(raster, curves, replace(settings, target_bytes=target), raster_mode=False)
    assert len(blob) <= target and report.chunk_bytes["rESD"] > target - (field + 200) - 400
    assert report.chunk_bytes["rESD"] > round(RESIDUAL_SHARE * target)


def test_without_a_target_a_clean_image_shares_its_default_mesh_s_bytes_with_a_residual(shapes_64):
    raster, curves = shapes_64
    settings = EncodeSettings(steps=40, batch_size=2048)
    blob, report = encode_image(raster, curves, settings, raster_mode=False)
    assert report.default_target is not None and len(blob) <= report.default_target
    assert report.chunk_bytes["rESD"] >= RESIDUAL_MIN_BYTES and decode_dfield(blob).residual is not None
    info = loads(blob).header["encoder"]
    assert info["target_bytes"] == report.default_target and info["default_target"] is True
    alone, alone_report = encode_image(raster, curves, replace(settings, residual_bytes=0))
    assert alone_report.default_target is None and decode_dfield(alone).residual is None
    assert "target_bytes" not in loads(alone).header["encoder"]
    noisy = raster + np.random.default_rng(1).normal(0.0, 0.01, raster.shape).astype(np.float32)
    blob, report = encode_image(noisy, curves, settings)  # a residual would code the noise: the field alone
    assert report.default_target is None and decode_dfield(blob).residual is None


def test_without_a_target_a_mesh_size_or_curves_too_costly_for_a_share_keep_the_field_alone(shapes_64, monkeypatch):
    raster, curves = shapes_64
    settings = EncodeSettings(steps=40, batch_size=2048)
    sized, report = encode_image(raster, curves, replace(settings, max_triangles=150))
    assert report.default_target is None and decode_dfield(sized).residual is None
    alone = encode_image(raster, curves, replace(settings, residual_bytes=0))[1]
    monkeypatch.setattr(dfc.codec, "smallest_bytes", lambda *a, **k: 1 << 30)  # no share leaves the field enough
    blob, report = encode_image(raster, curves, settings, raster_mode=False)
    assert report.default_target is None and decode_dfield(blob).residual is None
    fields = {k: v for k, v in report.chunk_bytes.items() if k != "HEAC"}  # the header records residual_bytes 0
    assert fields == {k: v for k, v in alone.chunk_bytes.items() if k != "HEAC"} and report.psnr == alone.psnr


def test_smallest_bytes_is_the_mesh_the_curves_force_at_the_fewest_feature_bits(shapes_64):
    from dfc.errors import TriangleBudgetError
    from dfc.rate import FEATURE_BITS_FALLBACK, build_mesh, forced_mesh, mesh_bytes, smallest_bytes

    _, curves = shapes_64
    settings = EncodeSettings(feature_bits=10)
    least = smallest_bytes(forced_mesh(curves, settings), settings, ["R", "G", "B"])
    cap, forced = 2, None
    while forced is None:  # the fewest triangles the curves allow
        try:
            forced = build_mesh(curves, replace(settings, max_triangles=cap))
        except TriangleBudgetError as e:
            cap = max(e.needed, cap + 1)
    assert least == mesh_bytes(forced, replace(settings, feature_bits=FEATURE_BITS_FALLBACK[-1]), ["R", "G", "B"])
    larger = build_mesh(curves, replace(settings, max_triangles=4 * cap))
    assert least < mesh_bytes(larger, replace(settings, feature_bits=FEATURE_BITS_FALLBACK[-1]), ["R", "G", "B"])
