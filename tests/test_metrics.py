import math

import numpy as np
import pytest

from dfc.metrics import mse, psnr


def test_psnr_pinned_value():
    # independent computation: mse = 0.1² / 4 = 0.0025, PSNR = 10 log10(1 / 0.0025) = 10 log10(400)
    a = np.zeros((2, 2))
    b = np.array([[0.0, 0.0], [0.0, 0.1]])
    assert mse(a, b) == pytest.approx(0.0025, rel=1e-12)
    assert psnr(a, b, data_range=1.0) == pytest.approx(26.020599913279625, abs=1e-9)
    assert psnr(a, b, data_range=2.0) == pytest.approx(26.020599913279625 + 20 * math.log10(2), abs=1e-9)


def test_psnr_uint8_infers_range_and_identical_is_inf():
    a = np.zeros((4, 4), np.uint8)
    b = a.copy()
    b[0, 0] = 16  # mse = 256 / 16 = 16
    assert psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 16))
    assert psnr(a, a) == math.inf


def test_psnr_float_requires_data_range():
    with pytest.raises(ValueError, match="data_range=1.0"):
        psnr(np.zeros(3), np.ones(3))
    with pytest.raises(ValueError, match="positive"):
        psnr(np.zeros(3), np.ones(3), data_range=0)


def test_shape_mismatch():
    with pytest.raises(ValueError, match="same shape"):
        mse(np.zeros((2, 3)), np.zeros((3, 2)))


def test_tonemap_pinned_and_clipped():
    from dfc.metrics import tonemap

    np.testing.assert_allclose(tonemap(np.array([-2.0, 0.0, 1.0, 3.0, 999.0])), [0.0, 0.0, 0.5, 0.75, 0.999])
    import torch

    torch.testing.assert_close(tonemap(torch.tensor([-1.0, 1.0, 3.0])), torch.tensor([0.0, 0.5, 0.75]))


def test_quality_scale_ldr_hdr_physical():
    from dfc.metrics import QualityScale, quality_scale

    assert quality_scale(np.array([0.0, 0.4, 1.0])) == QualityScale(1.0, tonemap=False)
    assert quality_scale(np.array([0.0, 0.5, 0.2, 0.3, 0.1, 0.4, 0.3, 0.2, 0.1, 1000.0])) == QualityScale(1.0, tonemap=True)
    # above 1 without a peak far above the mean (an LDR image in other units): the span, not tone-mapped
    assert quality_scale(np.array([0.0, 500.0, 1000.0])) == QualityScale(1000.0, tonemap=False)
    assert quality_scale(np.array([1e-3, 3e-3]), physical=True) == QualityScale(pytest.approx(2e-3), tonemap=False)
    assert quality_scale(np.array([-5.0, 20.0]), physical=True).data_range == 25.0


def test_measure_space_follows_the_image_it_is_told():
    from dfc.metrics import measure_space

    hdr = np.array([0.0, 0.5, 0.2, 0.3, 0.1, 0.4, 0.3, 0.2, 0.1, 1000.0])
    # HDR light: signed tone map, whatever the brightest value
    np.testing.assert_allclose(measure_space(np.array([-1.0, 0.0, 1.0, 3.0]), hdr), [-0.5, 0.0, 0.5, 0.75])
    # other values: over the image's range (an LDR image in counts measures like the same image in [0, 1])
    counts = np.array([100.0, 300.0, 500.0])
    np.testing.assert_allclose(measure_space(counts), [0.0, 0.5, 1.0])
    np.testing.assert_allclose(measure_space(np.array([200.0]), counts), [0.25])
    assert not measure_space(np.full(4, 7.0)).any()
    from dfc.metrics import step_size  # a step's size there: 0 → 3 is 0.75 beside HDR light, 100 → 300 a half in counts

    np.testing.assert_allclose(step_size(np.array([[3.0, 0.0]]), np.zeros((1, 2)), hdr), [0.75])
    np.testing.assert_allclose(step_size(np.array([[300.0]]), np.array([[100.0]]), counts), [0.5])


def test_hdr_psnr_sees_colour_that_the_value_span_hides():
    """Red (1, 0, 0) decoded as grey (0.35, 0.35, 0.35) beside a few pixels at 1000: on the linear values with the
    span as data range that is 55 dB; tone-mapped it is 16.2 dB (pinned by hand below)."""
    from dfc.metrics import quality_scale

    truth = np.zeros((100, 3))
    truth[:, 0] = 1.0
    truth[:2] = 1000.0
    test = truth.copy()
    test[2:] = 0.35
    linear = psnr(truth, test, data_range=1000.0)
    assert linear > 50
    scale = quality_scale(truth)
    # tone-mapped: red -> (0.5, 0, 0), grey -> 0.35 / 1.35 in each channel
    g = 0.35 / 1.35
    mse_tm = 98 * ((0.5 - g) ** 2 + 2 * g**2) / 300
    assert scale.psnr(truth, test) == pytest.approx(10 * math.log10(1 / mse_tm), abs=1e-9)
    assert scale.psnr(truth, test) < 17
    assert scale.describe() == "tone-mapped x/(1+x), data range 1"
