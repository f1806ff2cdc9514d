"""Flat regions made exact (dfc.train.flat): an image's constant region decodes to one value inside it, at any
zoom; images without one are encoded as before; the decoder of features is the model's own."""

import numpy as np
import pytest
import torch

import dfc.codec
from dfc.codec import EncodeSettings, encode_image, loads
from dfc.geometry.curves import Curves
from dfc.render import values_at
from dfc.train import flat

FLAT = (0.3, 0.5, 0.2)


def _half_flat(size: int = 48, seed: int = 0) -> tuple[np.ndarray, Curves]:
    """(pixels (size, size, 3): the left half exactly FLAT, the right half a smooth ramp with a little noise, the
    jump between them on a vertical line at size / 2 (a pixel boundary))."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) / size
    rng = np.random.default_rng(seed)
    ramp = np.stack([0.6 + 0.3 * x * y, 0.2 + 0.5 * y, 0.9 - 0.4 * x], axis=2) + rng.normal(0, 0.002, (size, size, 3))
    pixels = np.where((x < 0.5)[..., None], np.array(FLAT), ramp).astype(np.float32)
    half = size / 2
    line = np.array([[[half, 0.0], [half, size / 3], [half, 2 * size / 3], [half, float(size)]]])
    return pixels, Curves((0.0, 0.0, float(size), float(size)), line, [1], [0], [[0.0, 1.0]], names=["jump"])


def _encode(pixels, curves, monkeypatch=None, snap=True, **settings):
    if not snap:
        monkeypatch.setattr(dfc.codec, "_snap_flat", lambda *a, **k: 0)
    return encode_image(pixels, curves, EncodeSettings(steps=200, residual_bytes=0, **settings))


@pytest.mark.parametrize("bits", [6, 10])
def test_a_flat_region_decodes_to_one_value_inside_it_at_any_zoom(bits, monkeypatch):
    pixels, curves = _half_flat()
    blob, report = _encode(pixels, curves, feature_bits=bits)
    assert report.flat_rows > 0
    model = loads(blob)
    rng = np.random.default_rng(1)
    inside = np.stack([rng.uniform(0.0, 23.9, 4000), rng.uniform(0.0, 48.0, 4000)], axis=1)  # up to the jump
    values = values_at(model, inside)
    common, counts = np.unique(values, axis=0, return_counts=True)
    one = common[np.argmax(counts)]
    exact = (values == one).all(axis=1)
    assert exact.mean() >= 0.5  # one value over most of the region (not where it meets rows that are not flat)
    assert np.abs(one - FLAT).max() <= 2e-3  # the stored vector nearest the region's value
    _, before = _encode(pixels, curves, monkeypatch, snap=False, feature_bits=bits)
    plain = values_at(loads(_), inside)
    assert np.abs(plain[exact] - FLAT).mean() > np.abs(values[exact] - FLAT).mean()  # the fit alone: further off
    assert report.n_triangles == before.n_triangles and report.psnr >= before.psnr - 0.05


def test_the_summary_says_how_many_rows(tmp_path, capsys):
    from dfc.cli import main
    from dfc.geometry.sources.jsonfile import write_json
    from dfc.io.image import write_exr

    pixels, curves = _half_flat()
    write_exr(tmp_path / "in.exr", pixels, ["R", "G", "B"], half=False)
    write_json(curves, tmp_path / "c.json")
    out = tmp_path / "out.dfield"
    main(["encode", str(tmp_path / "in.exr"), "--curves", str(tmp_path / "c.json"), "-o", str(out), "--steps", "200",
          "--residual-bytes", "0"])
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("flat regions:"))
    rows = int(line.split()[2])
    assert rows > 0 and "flat_rows" not in loads(out.read_bytes()).header["encoder"]  # no header bytes spent


def test_an_image_without_a_flat_region_is_encoded_as_before(monkeypatch):
    pixels, curves = _half_flat()
    noisy = pixels + np.random.default_rng(2).normal(0, 0.002, pixels.shape).astype(np.float32)
    blob, report = _encode(noisy, curves)
    plain, _ = _encode(noisy, curves, monkeypatch, snap=False)
    assert report.flat_rows == 0 and blob == plain


def test_a_snap_that_would_raise_the_error_is_undone(monkeypatch):
    pixels, curves = _half_flat()
    errors = iter([0.0, 1.0])  # before and after the snap: it raises the error
    monkeypatch.setattr(flat, "_squared_error", lambda model, xy, values: next(errors))
    blob, report = _encode(pixels, curves)
    monkeypatch.undo()
    plain, _ = _encode(pixels, curves, monkeypatch, snap=False)
    assert report.flat_rows == 0 and blob == plain


def test_decode_is_the_models_forward_without_point_location():
    pixels, curves = _half_flat(24)
    model = loads(encode_image(pixels, curves, EncodeSettings(steps=20, residual_bytes=0))[0])
    xy = torch.from_numpy(np.random.default_rng(3).uniform(0, 24, (500, 2)))
    with torch.no_grad():
        assert torch.equal(model.decode(model.features(xy), xy), model(xy))


def test_a_snap_the_caller_refuses_is_undone(monkeypatch):
    pixels, curves = _half_flat()
    model = loads(_encode(pixels, curves, monkeypatch, snap=False, feature_bits=8)[0])  # a file's model, unsnapped
    bank = model.field.bank.detach().clone()
    seen = []
    refused = flat.snap_flat_rows(model, pixels, curves.domain, 8, 1.0, accept=lambda m: seen.append(m) or False)
    assert refused == 0 and seen == [model] and torch.equal(model.field.bank, bank)
    assert flat.snap_flat_rows(model, pixels, curves.domain, 8, 1.0) > 0
    assert not torch.equal(model.field.bank, bank)
