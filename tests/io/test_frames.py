"""Time-varying input: frame sequences (.npz or image lists) encoded as one time-sliced file, blending between
slices, ``dfc decode --time`` / ``--frames``, ``dfc stats``' time axis, and the error cases."""

import json

import numpy as np
import pytest
import torch

from dfc.codec import load
from dfc.errors import InputError
from dfc.field.feature_field import FeatureField
from dfc.geometry.sources import read_curves
from dfc.geometry.triangulate import triangulate
from dfc.io.frames import FrameSequence, npz_kind, read_frames, write_frames
from dfc.io.image import read_image, write_exr
from dfc.render import EDGE_SPP

from ..cli.test_cli import assert_one_line_error, run

SIZE = 24
TIMES = [1.0, 3.0]


def two_frames() -> np.ndarray:
    """(2, 24, 24, 1): a jump at x = 12 whose sides swap brightness between the frames, plus a gentle ramp."""
    x = (np.arange(SIZE) + 0.5)[None, :].repeat(SIZE, 0)
    y = x.T
    left = x < SIZE / 2
    f0 = np.where(left, 0.2, 0.8) + 0.004 * y
    f1 = np.where(left, 0.7, 0.1) + 0.004 * x
    return np.stack([f0, f1])[..., None].astype(np.float32)


@pytest.fixture(scope="module")
def wall(tmp_path_factory):
    path = tmp_path_factory.mktemp("curves") / "wall.json"
    path.write_text(json.dumps({"format": "dfc-curves/1", "domain": [0, 0, SIZE, SIZE], "curves": [
        {"name": "wall", "pieces": [{"type": "line", "points": [[SIZE / 2, 0], [SIZE / 2, SIZE]]}]}]}))
    return path


@pytest.fixture(scope="module")
def encoded(tmp_path_factory, wall):
    d = tmp_path_factory.mktemp("frames")
    seq = d / "seq.npz"
    write_frames(seq, FrameSequence(two_frames(), np.array(TIMES), ["u"]))
    out = d / "seq.dfield"
    from dfc.cli import main

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        main(["encode", str(seq), "--curves", str(wall), "-o", str(out), "--steps", "250", "--batch-size", "2048",
              "--max-triangles", "120", "-q"])
    except SystemExit as e:
        assert e.code in (0, None)
    finally:
        torch.set_num_threads(threads)
    return out


def test_features_between_slices_are_their_blend(wall):
    mesh = triangulate(read_curves(wall), max_triangles=60)
    field = FeatureField(mesh, dim=3, n_slices=2, times=[0.0, 2.0], seed=1)
    with torch.no_grad():
        field.bank.uniform_(-1, 1)
    xy = torch.rand(200, 2, dtype=torch.float64) * SIZE
    with torch.no_grad():
        f0, f1, mid = field.features(xy, 0.0), field.features(xy, 2.0), field.features(xy, 0.5)
    torch.testing.assert_close(mid, 0.75 * f0 + 0.25 * f1, rtol=0, atol=1e-6)
    assert (f0 - f1).abs().max() > 0.1  # the slices differ, so the blend is not trivially equal


def test_sequence_decodes_each_frame_and_blends_between(encoded):
    model = load(encoded)
    assert model.config()["times"] == TIMES and model.channels == ["u"]
    frames = two_frames()
    for k, t in enumerate(TIMES):
        err = np.abs(model.render(SIZE, SIZE, t=t) - frames[k])
        assert np.median(err) < 0.02 and err.max() < 0.2, (k, float(np.median(err)), float(err.max()))
    xy = torch.rand(300, 2, dtype=torch.float64) * SIZE
    with torch.no_grad():
        f0, f1, mid = (model.features(xy, t) for t in (TIMES[0], TIMES[1], 2.5))
        torch.testing.assert_close(mid, 0.25 * f0 + 0.75 * f1, rtol=0, atol=1e-6)
        # the decoder's output in the units the file stores (value_transform "affine")
        torch.testing.assert_close(model(xy, 2.5), model.value_map.apply(model.decoder(mid)), rtol=0, atol=1e-6)


def test_decode_time_and_frames(encoded, tmp_path, capsys):
    model = load(encoded)
    size = ["--size", f"{SIZE}x{SIZE}", "--float", "-q"]
    aa = {"edge_spp": EDGE_SPP}  # the input's resolution: pixels a discontinuity crosses are averaged
    code, _, err = run(["decode", encoded, "-o", tmp_path / "mid.exr", "--time", "2.0", *size], capsys)
    assert code == 0, err
    np.testing.assert_allclose(read_image(tmp_path / "mid.exr").pixels, model.render(SIZE, SIZE, t=2.0, **aa),
                               atol=1e-6)
    code, out, err = run(["decode", encoded, "-o", tmp_path / "f_%03d.exr", "--frames", "3", *size], capsys)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.glob("f_*.exr")) == ["f_000.exr", "f_001.exr", "f_002.exr"]
    for k, t in enumerate([1.0, 2.0, 3.0]):  # evenly spaced over the time axis, ends included
        np.testing.assert_allclose(read_image(tmp_path / f"f_{k:03d}.exr").pixels, model.render(SIZE, SIZE, t=t, **aa),
                                   atol=1e-6)
    code, out, _ = run(["stats", encoded], capsys)
    assert "2 slices, t = 1 .. 3" in out


def test_image_list_with_times(tmp_path, wall, capsys):
    frames = two_frames()
    paths = []
    for k in range(2):
        paths.append(tmp_path / f"in{k}.exr")
        write_exr(paths[-1], frames[k], ["Y"], half=False)
    out = tmp_path / "imgs.dfield"
    code, _, err = run(["encode", *paths, "--times", "0,0.5", "--curves", wall, "-o", out, "--steps", "5",
                        "--max-triangles", "60", "-q"], capsys)
    assert code == 0, err
    assert load(out).config()["times"] == [0.0, 0.5]


def test_errors(encoded, tmp_path, wall, capsys):
    static = tmp_path / "static.dfield"
    frames = two_frames()
    write_exr(tmp_path / "one.exr", frames[0], ["Y"], half=False)
    code, _, err = run(["encode", tmp_path / "one.exr", "--curves", wall, "-o", static, "--steps", "2",
                        "--max-triangles", "60", "-q"], capsys)
    assert code == 0, err
    for argv, match in (
        (["decode", encoded, "-o", tmp_path / "f.exr", "--frames", "2"], "one integer field"),
        (["decode", encoded, "-o", tmp_path / "f_%s.exr", "--frames", "2"], "one integer field"),
        (["decode", static, "-o", tmp_path / "f_%d.exr", "--frames", "2"], "no time axis"),
        (["encode", tmp_path / "one.exr", tmp_path / "one.exr", "--times", "0", "--curves", wall,
          "-o", tmp_path / "x.dfield"], "one time per image"),
    ):
        code, _, err = run(argv, capsys)
        assert_one_line_error(code, err, match)
    assert not list(tmp_path.glob("f*.exr")) and not (tmp_path / "x.dfield").exists()
    np.savez(tmp_path / "other.npz", grid=np.zeros(3))
    code, _, err = run(["encode", tmp_path / "other.npz", "--curves", wall, "-o", tmp_path / "x.dfield"], capsys)
    assert_one_line_error(code, err, "neither a frame sequence")
    bad = tmp_path / "bad.npz"
    np.savez(bad, frames=frames, times=np.array([1.0, 1.0]))
    assert npz_kind(bad) == "frames"
    with pytest.raises(InputError, match="strictly increasing"):
        read_frames(bad)
