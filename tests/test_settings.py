"""Encode settings (``dfc.settings``): each group refuses a value that breaks its rule with one line naming the
setting, ``EncodeSettings`` keeps its flat keywords and attributes, and ``dfc encode`` refuses what the API refuses."""

import dataclasses

import pytest

import dfc

from dfc.errors import SettingsError
from dfc.settings import EncodeSettings, FitSettings, MeshSettings, RunSettings, StorageSettings
from .cli.test_cli import assert_one_line_error, run

from .conftest import SAMPLES

BAD = {
    MeshSettings: [dict(max_triangles=1), dict(max_triangles=2.5), dict(max_area=0.0), dict(max_area=float("nan")),
                   dict(edge_length=-1.0), dict(target_bytes=0), dict(target_psnr=0.0), dict(refine=17),
                   dict(refine=-1), dict(refine_steps=0), dict(refine_fraction=0.0), dict(refine_fraction=1.5),
                   dict(max_area=1.0, edge_length=2.0), dict(edge_length=2.0, target_bytes=500),
                   dict(target_bytes=500, target_psnr=40.0)],
    FitSettings: [dict(steps=0), dict(steps=1.5), dict(batch_size=0), dict(dim=0), dict(dim=65), dict(hidden=0),
                  dict(layers=0), dict(qat_steps=-1), dict(loss="l1"), dict(seed="1"), dict(seed=True),
                  dict(device="")],
    StorageSettings: [dict(feature_bits=0), dict(feature_bits=17), dict(feature_coding="zip"), dict(weight_bits=1),
                      dict(weight_bits=0), dict(weight_bits=17), dict(mesh_bits=0), dict(mesh_bits=24)],
    RunSettings: [dict(epoch_pixels=0), dict(workers=0)],
}


@pytest.mark.parametrize("cls", list(BAD))
def test_each_group_refuses_bad_values_with_one_line_naming_the_setting(cls):
    for kw in BAD[cls]:
        with pytest.raises(SettingsError) as caught:
            cls(**kw)
        message = str(caught.value)
        assert "\n" not in message
        assert any(name in message for name in kw), (kw, message)
        assert isinstance(caught.value, ValueError) and isinstance(caught.value, dfc.DfcError)
        with pytest.raises(SettingsError):  # the same through EncodeSettings' flat keywords
            EncodeSettings(**kw)


def test_each_group_accepts_its_edge_values():
    MeshSettings(max_triangles=2, target_bytes=1, refine=16, refine_fraction=1.0)
    MeshSettings(max_area=1e-9, max_triangles=5)
    FitSettings(steps=1, batch_size=1, dim=64, qat_steps=0, loss="logmse", seed=-3, device="cuda:1")
    StorageSettings(feature_bits=1, weight_bits=None, mesh_bits=23, feature_coding="plain")
    StorageSettings(feature_bits=16, weight_bits=2, mesh_bits=1)
    RunSettings(epoch_pixels=1, workers=3)


def test_flat_keywords_attributes_and_replace():
    s = EncodeSettings(steps=1000, epoch_pixels=1 << 24, target_bytes=8000, weight_bits=None)
    assert (s.steps, s.epoch_pixels, s.target_bytes, s.weight_bits) == (1000, 1 << 24, 8000, None)
    assert s.fit == FitSettings(steps=1000) and s.run == RunSettings(epoch_pixels=1 << 24)
    assert s.mesh == MeshSettings(target_bytes=8000) and s.storage == StorageSettings(weight_bits=None)
    changed = dataclasses.replace(s, steps=5, feature_bits=8)
    assert (changed.steps, changed.feature_bits, changed.target_bytes) == (5, 8, 8000)
    assert s.steps == 1000  # unchanged
    assert EncodeSettings(fit=FitSettings(steps=7), seed=3).fit == FitSettings(steps=7, seed=3)
    assert EncodeSettings() == EncodeSettings(mesh=MeshSettings(), fit=FitSettings())
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.steps = 3
    with pytest.raises(SettingsError):
        dataclasses.replace(s, max_area=2.0)  # with target_bytes: two mesh sizes
    with pytest.raises(TypeError, match="stepz"):
        EncodeSettings(stepz=3)
    with pytest.raises(SettingsError, match="fit must be a FitSettings"):
        EncodeSettings(fit=MeshSettings())
    assert list(s.to_dict())[:3] == ["max_triangles", "max_area", "edge_length"]
    assert set(s.to_dict()) == set(EncodeSettings.names())


def test_fit_functions_take_the_fit_settings_or_keywords():
    from dfc.train.fit import BATCH_SIZE, fit_settings

    settings, model_kw = fit_settings(FitSettings(steps=10, hidden=8), {"seed": 4, "activation": "sine"}, 3000)
    assert settings == FitSettings(steps=10, hidden=8, seed=4, batch_size=BATCH_SIZE)
    assert model_kw == {"hidden": 8, "layers": 2, "activation": "sine"}
    assert fit_settings(None, {}, 3000)[0].steps == 3000
    with pytest.raises(SettingsError, match="batch_size"):
        fit_settings(None, {"batch_size": 0}, 3000)


def test_image_fits_default_to_batches_of_their_pixels_over_256():
    from dfc.train.fit import fit_settings, image_batch_size

    sides = (4, 256, 1024, 1448, 1500, 2048, 4096)
    assert [image_batch_size(s * s) for s in sides] == [4096, 4096, 4096, 4096, 8192, 16384, 16384]
    assert fit_settings(None, {}, 3000, image_batch_size(256 * 256))[0].batch_size == 4096
    assert fit_settings(FitSettings(batch_size=300), {}, 3000, 4096)[0].batch_size == 300
    from dfc.io.dfield import encoder_info

    assert EncodeSettings().batch_size is None and "batch_size" not in encoder_info(EncodeSettings(), "json", {})


# (dfc encode options, the EncodeSettings keywords they map to): impossible combinations the CLI and the API refuse
REFUSED = [
    (["--max-area", "1", "--target-bytes", "3000"], dict(max_area=1.0, target_bytes=3000)),
    (["--edge-length", "4", "--max-area", "1"], dict(edge_length=4.0, max_area=1.0)),
    (["--target-psnr", "40", "--target-bytes", "9000"], dict(target_psnr=40.0, target_bytes=9000)),
    (["--max-triangles", "1"], dict(max_triangles=1)),
    (["--steps", "0"], dict(steps=0)),
    (["--dim", "65"], dict(dim=65)),
    (["--weight-bits", "1"], dict(weight_bits=1)),
    (["--feature-bits", "17"], dict(feature_bits=17)),
    (["--mesh-bits", "0"], dict(mesh_bits=0)),
    (["--refine", "17"], dict(refine=17)),
    (["--workers", "0"], dict(workers=0)),
    (["--epoch-pixels", "0"], dict(epoch_pixels=0)),
    (["--batch-size", "0"], dict(batch_size=0)),
]


@pytest.mark.parametrize("argv, keywords", REFUSED, ids=[" ".join(a) for a, _ in REFUSED])
def test_cli_and_api_refuse_the_same_settings(argv, keywords, tmp_path, capsys):
    with pytest.raises(SettingsError):
        EncodeSettings(**keywords)
    out = tmp_path / "o.dfield"
    code, _, err = run(["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", out, *argv],
                       capsys)
    assert_one_line_error(code, err, argv[0])
    assert not out.exists()


def test_cli_accepts_what_the_api_accepts(tmp_path, capsys):
    EncodeSettings(max_triangles=400, weight_bits=None, refine=0, mesh_bits=23)
    out = tmp_path / "o.dfield"
    code, _, err = run(["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", out,
                        "--max-triangles", "400", "--weight-bits", "0", "--refine", "0", "--mesh-bits", "23",
                        "--steps", "2", "--batch-size", "256", "-q", "--json", tmp_path / "r.json"], capsys)
    assert code == 0, err
    assert dfc.load(out).field.mesh.n_triangles <= 400
