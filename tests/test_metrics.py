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
