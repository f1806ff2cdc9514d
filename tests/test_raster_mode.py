"""The raster mode (dfc.codec._raster_mode): a clean image the field does not model is stored as a constant field and
a residual raster holding the image, when that decodes closer to the input at the same size; never for noisy
images, with residual bytes given or with ``raster_mode=False``; a byte target too small for the curves' field gets
a raster-mode file instead of an error."""

import numpy as np
import pytest
import torch

import dfc.codec
from dfc.codec import EncodeSettings, encode_image, loads
from dfc.errors import TargetBytesError
from dfc.field.feature_field import FeatureField
from dfc.field.model import FieldModel
from dfc.geometry.curves import Curves
from dfc.metrics import psnr
from dfc.rate import RASTER_MARGIN_DB, RASTER_TRIANGLES, build_mesh
from dfc.render import render, values_at
from dfc.train.flat import constant_rows

SIZE = 48


def _blocks(seed: int = 0) -> np.ndarray:
    """(SIZE, SIZE, 3): 6 × 6-pixel blocks of random constant colours, a test chart no smooth field models."""
    rng = np.random.default_rng(seed)
    colours = rng.uniform(0.05, 0.95, (SIZE // 6, SIZE // 6, 3))
    return np.repeat(np.repeat(colours, 6, axis=0), 6, axis=1).astype(np.float32)


def _no_curves() -> Curves:
    return Curves((0.0, 0.0, float(SIZE), float(SIZE)), np.zeros((0, 4, 2)), [], [], np.zeros((0, 2)))


def _diagonals(n: int) -> Curves:
    """``n`` parallel line curves across the image: more triangles than a small target holds."""
    x = np.linspace(2.0, SIZE - 2.0, n)
    lines = np.stack([np.stack([x, np.zeros(n)], 1), np.stack([x + 1, np.full(n, SIZE / 3)], 1),
                      np.stack([x + 2, np.full(n, 2 * SIZE / 3)], 1), np.stack([x + 3, np.full(n, SIZE)], 1)], 1)
    lines[..., 0] = np.clip(lines[..., 0], 0, SIZE)
    return Curves((0.0, 0.0, float(SIZE), float(SIZE)), lines, [1] * n, list(range(n)), [[0.0, 1.0]] * n)


def test_constant_rows_make_the_field_one_value_everywhere_and_survive_the_file():
    curves = _diagonals(3)
    mesh = build_mesh(curves, EncodeSettings(max_triangles=60))
    model = FieldModel(FeatureField(mesh, dim=5, seed=1), ["R", "G", "B"], hidden=8)
    with torch.no_grad():
        model.field.bank.normal_(0.0, 1.0, generator=torch.Generator().manual_seed(2))
    xy = np.random.default_rng(3).uniform(0, SIZE, (3000, 2))
    assert np.ptp(values_at(model, xy), axis=0).max() > 1e-3  # random rows: the field varies
    assert constant_rows(model) == model.field.n_features
    values = values_at(model, xy)
    assert np.ptp(values, axis=0).max() <= 1e-6


def test_a_test_chart_is_stored_in_the_raster_mode_and_decodes_as_reported():
    pixels = _blocks()
    target = 2500
    blob, report = encode_image(pixels, _no_curves(), EncodeSettings(steps=200, target_bytes=target))
    assert report.raster_mode and report.field_psnr is not None
    assert report.psnr >= report.field_psnr + RASTER_MARGIN_DB  # a clear win: the field's curves stay sharp at zoom
    assert len(blob) <= target and report.total_bytes == len(blob) and "rESD" in report.chunk_bytes
    assert "raster_s" in report.seconds
    model = loads(blob)
    assert model.field.mesh.n_triangles == RASTER_TRIANGLES
    assert len(np.unique(model.field.bank.detach().numpy()[0], axis=0)) == 1  # one stored vector
    assert model.header["encoder"]["raster_mode"] is True and model.header["encoder"]["target_bytes"] == target
    assert psnr(pixels, render(model, SIZE, SIZE), data_range=1.0) == pytest.approx(report.psnr, abs=1e-6)


def test_without_a_target_the_raster_mode_takes_the_default_files_size():
    pixels = _blocks(1)
    plain, field = encode_image(pixels, _no_curves(), EncodeSettings(steps=200), raster_mode=False)
    blob, report = encode_image(pixels, _no_curves(), EncodeSettings(steps=200))
    assert not field.raster_mode and report.raster_mode
    assert len(blob) <= len(plain) and report.field_psnr == pytest.approx(field.psnr)


def test_the_raster_mode_is_not_tried_where_it_does_not_apply():
    pixels = _blocks(2)
    noisy = pixels + np.random.default_rng(4).normal(0, 0.01, pixels.shape).astype(np.float32)
    settings = EncodeSettings(steps=100, target_bytes=2500)
    for image, kw in ((pixels, {"raster_mode": False}), (noisy, {})):
        blob, report = encode_image(image, _no_curves(), settings, **kw)
        assert not report.raster_mode and "raster_s" not in report.seconds
        assert loads(blob).field.mesh.n_triangles > RASTER_TRIANGLES
    _, report = encode_image(pixels, _no_curves(), EncodeSettings(steps=100, target_bytes=2500, residual_bytes=1200))
    assert not report.raster_mode and "raster_s" not in report.seconds


def test_the_field_is_kept_when_it_decodes_closer(monkeypatch):
    pixels = _blocks(3)
    real = dfc.codec._with_residual

    def worse(blob, report, *args, **kw):  # the raster mode's residual made useless: its file must lose
        out = real(blob, report, *args, **kw)
        if loads(blob).field.mesh.n_triangles == RASTER_TRIANGLES:
            report.psnr = 0.0
        return out

    monkeypatch.setattr(dfc.codec, "_with_residual", worse)
    blob, report = encode_image(pixels, _no_curves(), EncodeSettings(steps=100, target_bytes=2500))
    assert not report.raster_mode and report.field_psnr is None and "raster_s" in report.seconds
    assert loads(blob).field.mesh.n_triangles > RASTER_TRIANGLES
    field = report.psnr
    monkeypatch.setattr(dfc.codec, "RASTER_MARGIN_DB", 1e9)  # a raster mode that must win by more than it can
    monkeypatch.setattr(dfc.codec, "_with_residual", real)
    blob, report = encode_image(pixels, _no_curves(), EncodeSettings(steps=100, target_bytes=2500))
    assert not report.raster_mode and report.psnr == pytest.approx(field)


def test_a_target_too_small_for_the_curves_gets_a_raster_mode_file():
    pixels, curves = _blocks(4), _diagonals(12)
    settings = EncodeSettings(steps=100, target_bytes=1500)
    with pytest.raises(TargetBytesError):
        encode_image(pixels, curves, settings, raster_mode=False)
    blob, report = encode_image(pixels, curves, settings)
    assert report.raster_mode and report.field_psnr is None and len(blob) <= 1500


def test_the_cli_says_so_and_no_raster_mode_keeps_the_field(tmp_path, capsys):
    from dfc.cli import main
    from dfc.geometry.sources.jsonfile import write_json
    from dfc.io.image import write_exr

    write_exr(tmp_path / "in.exr", _blocks(5), ["R", "G", "B"], half=False)
    write_json(_diagonals(2), tmp_path / "c.json")
    args = ["encode", str(tmp_path / "in.exr"), "--curves", str(tmp_path / "c.json"), "--steps", "100",
            "--target-bytes", "2500"]
    main([*args, "-o", str(tmp_path / "r.dfield")])
    out = capsys.readouterr().out
    assert any(line.startswith("raster mode: ") and "--no-raster-mode" in line for line in out.splitlines())
    assert loads((tmp_path / "r.dfield").read_bytes()).field.mesh.n_triangles == RASTER_TRIANGLES
    main([*args, "-o", str(tmp_path / "f.dfield"), "--no-raster-mode"])
    assert "raster mode" not in capsys.readouterr().out
    assert len(loads((tmp_path / "f.dfield").read_bytes()).field.mesh.disc_edges) > 0  # the curves are stored
