"""Classical codecs at equal bytes: every configuration decodes to the input's shape and range, the bisection meets
the budget (or the next quality step provably does not fit), and the inputs a codec cannot take are refused."""

import numpy as np
import pytest

from dfc.bench import codecs
from dfc.bench.codecs import CODECS, LOSSLESS, configurations, decode, encode, encode_to_budget, stream_bytes
from dfc.bench.scenes import hdr_scene, shapes_scene
from dfc.errors import InputError
from dfc.io.residual import GAIN_MIN
from dfc.metrics import QualityScale, data_range, psnr, quality_scale

MID_QUALITY = {"jpegxl": 0.7, "avif": 80, "webp": 80.0, "jpeg2k": 45.0}
"""A knob value of each codec well inside its range."""


@pytest.fixture(autouse=True)
def fast_avif(monkeypatch):
    """libavif's fastest speed: the tests check sizes and decoding, not compression efficiency."""
    monkeypatch.setattr(codecs, "AVIF_SPEED", 8)


@pytest.fixture(scope="module")
def sdr():
    return shapes_scene().render(48, 40, spp=2)


@pytest.fixture(scope="module")
def hdr():
    return hdr_scene().render(48, 40, spp=2)


def _roundtrip(codec, pixels, config):
    q = LOSSLESS if config.get("lossless") else MID_QUALITY[codec]
    stream = encode(codec, pixels, config, q)
    out = decode(codec, stream, config, pixels.shape[2], (float(pixels.min()), float(pixels.max())))
    return stream, out


@pytest.mark.parametrize("codec", CODECS)
def test_every_configuration_decodes_to_the_input_shape_and_range(codec, sdr):
    for config in configurations(codec, sdr):
        stream, out = _roundtrip(codec, sdr, config)
        assert out.shape == sdr.shape and out.dtype == np.float32
        assert -0.02 <= out.min() and out.max() <= 1.02
        assert psnr(sdr, out, data_range=1.0) > 28, config
        assert stream_bytes(stream, config) == len(stream)  # SDR: no transfer range to store


@pytest.mark.parametrize("codec", ["jpegxl", "avif", "jpeg2k"])
def test_hdr_input_keeps_its_range(codec, hdr):
    span = data_range(hdr)
    configs = configurations(codec, hdr)
    assert {c["transfer"] for c in configs} >= {"linear", "log", "tonemap"}
    for config in configs:
        stream, out = _roundtrip(codec, hdr, config)
        assert out.shape == hdr.shape
        assert out.min() >= hdr.min() - 0.02 * span and out.max() <= hdr.max() + 0.02 * span
        if config["transfer"] == "tonemap":  # its codes spread evenly over the tone map, where PSNR is measured
            assert quality_scale(hdr).psnr(hdr, out) > 30, config
        else:
            assert psnr(hdr, out, data_range=span) > 30, config
        if config["input"] == "uint":
            assert stream_bytes(stream, config) == len(stream) + codecs.SIDE_BYTES


def test_the_tonemap_transfer_spans_the_code_range_and_inverts(hdr):
    lo, hi = float(hdr.min()), float(hdr.max())
    unit = codecs._forward(hdr.astype(np.float64), "tonemap", lo, hi)
    assert unit.min() == pytest.approx(0.0, abs=1e-12) and unit.max() == pytest.approx(1.0, abs=1e-12)
    back = codecs._inverse(unit, "tonemap", lo, hi)
    assert np.allclose(back, hdr, rtol=1e-9, atol=1e-9)
    coarse = codecs._inverse(np.round(unit * 4095) / 4095, "tonemap", lo, hi)  # 12-bit samples: uniform steps of
    t, t_coarse = hdr / (1 + np.abs(hdr)), coarse / (1 + np.abs(coarse))  # the tone map, where PSNR is measured
    assert np.abs(t_coarse - t).max() <= 0.5 / 4095 * (hi / (1 + hi) - lo / (1 + lo)) + 1e-9


def test_avif_tries_colour_images_with_the_identity_matrix_too(sdr):
    identity = [c for c in configurations("avif", sdr) if c.get("matrix") == "identity"]
    assert {(c["bits"], c["transfer"]) for c in identity} == {(10, "identity"), (12, "identity")}
    stream = encode("avif", sdr, identity[1], 100)  # 12 bits, top quality: lossless in GBR
    colr = stream.index(b"colrnclx") + 8  # colour information: primaries, transfer, matrix (u16 each)
    assert int.from_bytes(stream[colr + 4:colr + 6], "big") == 0
    out = decode("avif", stream, identity[1], 3, (float(sdr.min()), float(sdr.max())))
    assert np.abs(out - sdr).max() <= 0.5 / 4095 + 1e-6  # only the 12-bit rounding
    assert all("matrix" not in c for c in configurations("avif", np.ascontiguousarray(sdr[..., :1])))


@pytest.mark.parametrize("channels", [1, 2])
def test_grey_and_other_channel_counts(channels, sdr):
    pixels = np.ascontiguousarray(sdr[..., :channels])
    for codec in CODECS:
        config = configurations(codec, pixels)[0]
        _, out = _roundtrip(codec, pixels, config)
        assert out.shape == pixels.shape
        assert psnr(pixels, out, data_range=1.0) > 28


@pytest.mark.parametrize("codec,budget", [("jpegxl", 1200), ("jpeg2k", 1200), ("webp", 600), ("avif", 1200),
                                          ("avif", 2500), ("webp", 1200)])
def test_streams_fill_the_budget_or_the_next_step_overflows(codec, budget, sdr):
    coded = encode_to_budget(codec, sdr, budget, QualityScale(1.0))
    assert coded.n_bytes <= budget and coded.decoded.shape == sdr.shape
    assert coded.score == pytest.approx(psnr(sdr, coded.decoded, data_range=1.0))
    assert coded.score == max(c["score"] for c in coded.candidates)
    if codec in ("jpegxl", "jpeg2k") or (codec == "webp" and budget == 600):  # continuous knobs below saturation
        assert coded.n_bytes >= 0.97 * budget
    if coded.saturated:  # the top quality (or the lossless stream) fits: the codec cannot spend more
        assert codec == "webp" and budget == 1200
    else:
        assert coded.next_bytes > budget


def test_avif_fills_the_gap_between_two_qualities_with_a_gain_only_where_it_scores_higher(sdr, monkeypatch):
    gains = 0
    for budget in (1500, 2500, 4000, 6000):
        coded = encode_to_budget("avif", sdr, budget, QualityScale(1.0))
        with monkeypatch.context() as m:
            m.setattr(codecs, "GAIN_FILL", 0.0)  # every configuration's highest quality that fits, as it is
            plain = encode_to_budget("avif", sdr, budget, QualityScale(1.0))
        assert coded.n_bytes <= budget and coded.score >= plain.score
        gained = [c for c in coded.candidates if "gain" in c["config"]]
        for c in gained:
            assert GAIN_MIN <= c["config"]["gain"] < 1.0 and c["bytes"] <= budget
        gains += len(gained)
        if "gain" in coded.config:
            assert coded.score > plain.score
            assert stream_bytes(encode("avif", sdr, coded.config, coded.config["quality"]), coded.config) == \
                coded.n_bytes  # a gain's two numbers are counted
    assert gains >= 1


def test_budget_too_small_and_hdr_webp_are_refused(sdr, hdr):
    with pytest.raises(InputError, match="too small for jpeg2k"):
        encode_to_budget("jpeg2k", sdr, 50, QualityScale(1.0))
    with pytest.raises(InputError, match="SDR"):
        encode_to_budget("webp", hdr, 5000, quality_scale(hdr))


def test_missing_imagecodecs_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "imagecodecs", None)
    with pytest.raises(InputError, match=r"pip install imagecodecs"):
        codecs.require_imagecodecs()


def test_hdr_streams_are_chosen_on_the_tone_mapped_scale(hdr):
    scale = quality_scale(hdr)
    assert scale.tonemap
    coded = encode_to_budget("jpeg2k", hdr, 3000, scale)
    assert coded.score == pytest.approx(scale.psnr(hdr, coded.decoded))
    assert coded.score != pytest.approx(psnr(hdr, coded.decoded, data_range=data_range(hdr)))
    assert coded.score == max(c["score"] for c in coded.candidates) and len(coded.candidates) >= 2
