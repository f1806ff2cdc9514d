"""The whole encode → decode on every device this machine has: the CPU always (CI), CUDA when a GPU is present
(skipped otherwise). The same code paths run on both: in-memory and out-of-core fits, quantisation-aware steps,
tiled decode. Plus the device-independent pieces the GPU path relies on: quantisation computed on the tensor's
device equals the file's, and generators live on the model's device."""

import numpy as np
import pytest
import torch

from dfc.codec import EncodeSettings, encode_bands, encode_image, loads
from dfc.field.quantize import dequantize_features, fake_quantize, quantize_features
from dfc.geometry.sources import read_any
from dfc.io.bands import ExrBands
from dfc.io.image import read_image
from dfc.render import render
from dfc.render_file import write_render

from .conftest import SAMPLES

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU"))]


@pytest.mark.parametrize("device", DEVICES)
def test_encode_and_decode_on_the_device(device, tmp_path, one_thread):
    curves = read_any(SAMPLES / "sample.json")
    # the field alone: without it the clean sample gets a byte target of its own, and a decoder sized to it
    settings = EncodeSettings(steps=100, batch_size=4096, device=device, epoch_pixels=30000, residual_bytes=0)
    blob, report = encode_image(read_image(SAMPLES / "sample.exr"), curves, settings)
    assert report.psnr > 30.0
    blob_bands, report_bands = encode_bands(ExrBands(SAMPLES / "sample.exr"), curves, settings)
    assert report_bands.psnr > 28.5  # at the held-out pixels, 100 steps: 29.1 dB at seed 0, 29-41 dB over seeds 0-5
    assert loads(blob_bands).config()["hidden"] == loads(blob).config()["hidden"]  # one width rule
    model = loads(blob, device=device)
    assert model.field.bank.device.type == device
    image = render(model, 256, 256)
    assert np.isfinite(image).all()
    out = tmp_path / "out.exr"
    write_render(model, out, (256, 256), model.field.mesh.domain, half=False, tiled=True)
    np.testing.assert_array_equal(read_image(out).pixels, image)


@pytest.mark.parametrize("device", DEVICES)
def test_quantisation_on_the_device_is_the_files(device):
    F = torch.randn(2, 500, 5, generator=torch.Generator().manual_seed(0)) * 3
    F[..., 1] = 0.25  # a constant channel
    for bits in (1, 8, 16):
        q, scale, offset = quantize_features(F.numpy(), bits)
        stored = torch.from_numpy(dequantize_features(q, scale, offset))
        got = fake_quantize(F.to(device), bits).cpu()
        assert torch.allclose(got, stored, rtol=0, atol=1e-6 * float(F.abs().max()))  # F + (Fq - F) rounds


@pytest.mark.parametrize("device", DEVICES)
def test_the_loop_draws_with_a_generator_on_the_models_device(device):
    from dfc.train.loop import Schedule, train

    model = torch.nn.Linear(2, 1).to(device)
    seen = []

    def sampler(step, generator):
        seen.append(generator.device.type)
        return (torch.rand(8, 2, generator=generator, device=generator.device),)

    def loss(net, batch):
        value = net(batch[0]).square().mean()
        return value, {"loss": value.detach()}

    train(model, loss, sampler, Schedule(3))
    assert seen == [device] * 3
