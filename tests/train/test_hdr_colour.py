"""Real HDR images without curves keep their colours (``../shared/data/exr``, skipped without it).

``SquaresSwirls.exr`` (values 0 … 1000, saturated primaries on grey, black squares) and ``WideColorGamut.exr``
(out-of-gamut values down to −1.3, up to 21) lost their colour when fitted: red decoded as grey after 200 steps and
as (0.50, 0.29, 0.00) after 1000, black squares as dark red. Two causes: the decoder's output bias started at
log1p of the mean value (2.97 for SquaresSwirls, whose typical pixel is 0.5: log1p 0.41), so the fit first spent its
steps, and Adam's second-moment estimates, pulling everything down; and the relative MSE is flat for a channel whose
target is 0 once the prediction is well above 0.01, so it traded colour for brightness. Measured on these images at
a quarter of their size, 300 steps (the fit alone, batch 16384): red patch (0.52, 0.44, 0.49) → (0.97, 0.02, −0.02),
black (0.50, −0.02, 0.15) → (−0.01, 0.00, −0.01), tone-mapped PSNR 17.6 → 23.4 dB (SquaresSwirls) and 15.8 →
31.7 dB (WideColorGamut).
"""

import numpy as np
import pytest

from dfc.codec import EncodeSettings, encode_image, loads
from dfc.geometry.curves import Curves
from dfc.io.image import read_image
from dfc.metrics import tonemap
from dfc.render import render

SETTINGS = EncodeSettings(steps=300, batch_size=8192)
SCALE = 4
"""The images are block-averaged by this factor (250 × 250 and 200 × 200): the colours are the same, the fit cheaper."""


def _fit(path):
    pixels = read_image(path).pixels
    h, w, c = pixels.shape
    pixels = pixels.reshape(h // SCALE, SCALE, w // SCALE, SCALE, c).mean(axis=(1, 3))
    h, w = h // SCALE, w // SCALE
    no_curves = Curves((0.0, 0.0, float(w), float(h)), np.zeros((0, 4, 2)), [], [], np.zeros((0, 2)))
    blob, report = encode_image(pixels, no_curves, SETTINGS)
    return pixels, render(loads(blob), w, h), report


def _patch(image, x, y, r=2):
    """Mean colour (C,) of the (2r + 1)² pixels around full-size pixel (x, y)."""
    i, j = x // SCALE, y // SCALE
    return image[j - r : j + r + 1, i - r : i + r + 1].reshape(-1, image.shape[2]).mean(axis=0)


@pytest.mark.shared
def test_squares_swirls_keeps_saturated_colours_and_black(shared_data):
    truth, decoded, report = _fit(shared_data / "exr" / "SquaresSwirls.exr")
    assert report.tonemapped
    # the row of saturated squares (red, yellow, green, cyan, blue, magenta, light grey, black) and the large black
    # square; within 0.1 of the input in tone-mapped units (grey for red is 0.26 off, dark red for black 0.2)
    centres = [(150 + 100 * k, 350) for k in range(8)] + [(650, 800)]
    for x, y in centres:
        want, got = tonemap(_patch(truth, x, y)), tonemap(_patch(decoded, x, y))
        # 300 steps: the blue patch (140, 740) was 0.092 off on the Draco mesh, 0.108 with the free vertices snapped
        # (mesh_coding "derived"); the worst patch of seeds 0, 1, 2 is 0.115, 0.116, 0.025 off with batches of
        # whole-epoch shuffles and 0.136, 0.115, 0.047 with batches of chunks (dfc.train.pixel_sampler): fit noise up
        # to about 0.14; a lost hue is off by several tenths
        assert np.abs(got - want).max() < 0.16, ((x, y), _patch(truth, x, y), _patch(decoded, x, y))
    assert report.psnr > 21.0


@pytest.mark.shared
def test_wide_colour_gamut_keeps_its_hues(shared_data):
    truth, decoded, report = _fit(shared_data / "exr" / "WideColorGamut.exr")
    assert report.tonemapped
    for x, y in [(700, 560), (140, 740), (300, 400), (20, 20)]:  # red, blue and the mixed middle, the grey border
        want, got = tonemap(_patch(truth, x, y)), tonemap(_patch(decoded, x, y))
        # 300 steps: the blue patch (140, 740) was 0.092 off on the Draco mesh, 0.108 with the free vertices snapped
        # (mesh_coding "derived"); the worst patch of seeds 0, 1, 2 is 0.115, 0.116, 0.025 off with batches of
        # whole-epoch shuffles and 0.136, 0.115, 0.047 with batches of chunks (dfc.train.pixel_sampler): fit noise up
        # to about 0.14; a lost hue is off by several tenths
        assert np.abs(got - want).max() < 0.16, ((x, y), _patch(truth, x, y), _patch(decoded, x, y))
    assert report.psnr > 28.0
