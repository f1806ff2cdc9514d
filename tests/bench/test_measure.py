"""What every method is measured with: box-filtered renders, stored rasters read as stored, the mixed pixels found
from the curves, PSNR on all pixels and without the mixed ones."""

import numpy as np
import pytest
import torch

from dfc.bench.baselines.upsample import PixelImage
from dfc.bench.measure import grid_points, image_render, image_scores, mixed_pixels, pixel_render
from dfc.bench.scenes import _pieces
from dfc.geometry.pixels import edge_pixels
from dfc.geometry.triangulate import triangulate
from dfc.metrics import QualityScale


class Linear(torch.nn.Module):
    """f(x, y) = x + 2 y, one channel."""

    def forward(self, xy):
        return (xy[:, :1] + 2 * xy[:, 1:]).float()


def test_the_1x_box_filter_of_a_linear_function_is_its_centre_value():
    domain = (0.0, 0.0, 8.0, 4.0)
    out = image_render(Linear(), domain, 8, 4, 4)
    x, y = np.meshgrid(np.arange(8) + 0.5, np.arange(4) + 0.5)
    np.testing.assert_allclose(out[..., 0], x + 2 * y, rtol=1e-6)
    assert out.shape == (4, 8, 1) and out.dtype == np.float32
    pts = grid_points(domain, 8, 4, 2, (1, 2))[:4]  # the first pixel of row 1: a centred 2 x 2 grid
    np.testing.assert_allclose(pts, [[0.25, 1.25], [0.75, 1.25], [0.25, 1.75], [0.75, 1.75]])
    windows = pixel_render(Linear(), domain, 8, 4, 1)  # the zoom windows' points: pixel centres at spp 1
    np.testing.assert_allclose(windows[..., 0], x + 2 * y, rtol=1e-6)


def test_a_stored_raster_of_the_same_size_is_read_as_stored():
    rng = np.random.default_rng(0)
    pixels = rng.random((6, 10, 3)).astype(np.float32)
    domain = (0.0, 0.0, 10.0, 6.0)
    model = PixelImage(pixels, domain, list("RGB"), n_bytes=1)
    assert np.array_equal(image_render(model, domain, 10, 6, 16), pixels)
    blurred = image_render(model, domain, 5, 3, 4)  # another size: box-filtered through the kernel
    assert blurred.shape == (3, 5, 3) and not np.allclose(blurred, pixels[::2, ::2])


def test_a_dfc_file_at_its_input_size_is_rendered_as_dfc_decode_renders_it():
    """A Gaussian-filtered raster fitted with that filter: the bench's 1× render is the file's decode at the input's
    size (the stored filter on the pixels a curve changes), not the box grid every other model gets; in the bench's
    own domain units too."""
    from dfc.bench.compare import _Remap
    from dfc.bench.pixel_filters import filtered_raster, polygon_scene
    from dfc.codec import EncodeSettings, encode_image, loads
    from dfc.render import render

    scene = polygon_scene(32.0)
    raster = filtered_raster(scene, 32, 32, "gaussian:0.5")
    blob, _ = encode_image(raster, scene.curves, EncodeSettings(steps=30, batch_size=1024, pixel_filter="gaussian:0.5"))
    model = loads(blob)
    decoded = render(model, 32, 32, pixel_filter=model.header["pixel_filter"])
    wrapped = _Remap(model, (0.0, 0.0, 2.0, 2.0), (0.0, 0.0, 32.0, 32.0), (32, 32))
    assert np.array_equal(image_render(wrapped, (0.0, 0.0, 2.0, 2.0), 32, 32, 4), decoded)
    boxed = image_render(_Remap(model, (0.0, 0.0, 2.0, 2.0), (0.0, 0.0, 32.0, 32.0)), (0.0, 0.0, 2.0, 2.0), 32, 32, 4)
    assert np.abs(boxed - decoded).max() > 1e-3  # the box grid is another filter


def test_mixed_pixels_come_from_the_curves_as_from_the_mesh():
    curves = _pieces([("line", [(1, [(2.5, 0.0), (2.5, 8.0)])]),
                      ("arc", [(3, [(4.0, 1.0), (8.0, 1.0), (8.0, 7.0), (4.0, 7.0)])])], (0.0, 0.0, 10.0, 8.0))
    mask = mixed_pixels(curves, 8, 10)
    assert mask[:, 2].all() and not mask[:, :2].any()
    assert np.array_equal(mask, edge_pixels(triangulate(curves), 8, 10))


def test_scores_on_all_pixels_and_without_the_mixed_ones():
    truth = np.zeros((4, 4, 1))
    test = truth.copy()
    test[0, 0] = 0.5
    mixed = np.zeros((4, 4), bool)
    mixed[0, 0] = True
    s = image_scores(truth, test, mixed, QualityScale(1.0))
    assert s["all"] == pytest.approx(10 * np.log10(16 / 0.25)) and s["unmixed"] == float("inf")
