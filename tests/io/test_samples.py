import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.errors import InputError
from dfc.io.samples import SampleSet, read_samples, write_samples


def _set(n=5, c=3, seed=0):
    rng = np.random.default_rng(seed)
    return SampleSet(rng.random((n, 2)) * [8.0, 4.0], rng.random((n, c)).astype(np.float32), (0.0, 0.0, 8.0, 4.0),
                     ["R", "G", "B"][:c] if c <= 3 else None)


@settings(max_examples=20, deadline=None)
@given(n=st.integers(1, 50), c=st.integers(1, 5), with_domain=st.booleans(), seed=st.integers(0, 1000))
def test_round_trip(tmp_path_factory, n, c, with_domain, seed):
    s = _set(n, c, seed)
    if not with_domain:
        s = SampleSet(s.xy, s.values, None, s.channels)
    path = tmp_path_factory.mktemp("rt") / "s.npz"
    write_samples(path, s)
    back = read_samples(path)
    assert back.xy.dtype == np.float64 and back.values.dtype == np.float32
    np.testing.assert_array_equal(back.xy, s.xy)
    np.testing.assert_array_equal(back.values, s.values)
    assert back.domain == s.domain and back.channels == s.channels


def test_write_keeps_the_name_and_leaves_nothing_behind(tmp_path):
    path = tmp_path / "samples.bin"  # no .npz suffix: numpy must not append one
    write_samples(path, _set())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["samples.bin"]
    assert len(read_samples(path)) == 5


def test_invalid_set_is_not_written(tmp_path):
    s = _set()
    bad = SampleSet(s.xy + 100.0, s.values, s.domain, s.channels)
    with pytest.raises(InputError, match="outside the domain"):
        write_samples(tmp_path / "s.npz", bad)
    assert list(tmp_path.iterdir()) == []


def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


GOOD = {"xy": np.zeros((3, 2)), "values": np.zeros((3, 1), dtype=np.float32)}


@pytest.mark.parametrize("arrays,message", [
    ({"values": GOOD["values"]}, r"missing required array \['xy'\]"),
    ({"xy": GOOD["xy"]}, r"missing required array \['values'\]"),
    ({**GOOD, "weights": np.ones(3)}, r"unknown arrays \['weights'\]"),
    ({**GOOD, "xy": np.zeros((3, 3))}, r"xy must have shape \(N, 2\)"),
    ({**GOOD, "values": np.zeros(3)}, r"values must have shape \(N, C\)"),
    ({**GOOD, "values": np.zeros((4, 1))}, "xy has 3 rows but values has 4"),
    ({**GOOD, "xy": np.zeros((3, 2), dtype=np.int64)}, "xy must be a floating-point array, got dtype int64"),
    ({**GOOD, "values": np.zeros((3, 1), dtype=bool)}, "values must be a floating-point array"),
    ({"xy": np.zeros((0, 2)), "values": np.zeros((0, 1))}, "no samples"),
    ({**GOOD, "xy": np.array([[0, 0], [np.nan, 1], [1, 1.0]])}, "xy has 1 rows with NaN/Inf, the first is row 1"),
    ({**GOOD, "values": np.array([[0], [1], [np.inf]])}, "values has 1 rows with NaN/Inf, the first is row 2"),
    ({**GOOD, "domain": np.array([0, 0, 1.0])}, "domain must be 4 numbers"),
    ({**GOOD, "domain": np.array([0, 0, -1, 1.0])}, "not a finite rectangle"),
    ({**GOOD, "xy": np.array([[0, 0], [2, 0.5], [1, 1.0]]), "domain": np.array([0, 0, 1, 1.0])},
     r"1 points lie outside the domain .* row 1 at \(2, 0.5\)"),
    ({**GOOD, "channels": np.array(["R", "G"])}, "channels must be 1 distinct non-empty names"),
    ({**GOOD, "channels": np.array([1.0])}, "channels must be an array of strings"),
    ({**GOOD, "values": np.zeros((3, 2)), "channels": np.array(["R", "R"])}, "distinct"),
])
def test_bad_arrays(tmp_path, arrays, message):
    path = _npz(tmp_path / "s.npz", **arrays)
    with pytest.raises(InputError, match=message) as e:
        read_samples(path)
    assert str(e.value).startswith(str(path)) and "\n" not in str(e.value)


def test_object_arrays_are_refused_not_unpickled(tmp_path):
    path = _npz(tmp_path / "s.npz", **GOOD, channels=np.array(["R", None], dtype=object))
    with pytest.raises(InputError, match="'channels' holds Python objects"):
        read_samples(path)


def test_not_an_archive(tmp_path):
    text = tmp_path / "s.npz"
    text.write_text("xy,values\n1,2,3\n")
    with pytest.raises(InputError, match="not an npz archive"):
        read_samples(text)
    npy = tmp_path / "a.npz"
    with open(npy, "wb") as f:
        np.save(f, np.zeros(3))
    with pytest.raises(InputError, match="not an npz archive"):
        read_samples(npy)
    with pytest.raises(InputError, match="no such file"):
        read_samples(tmp_path / "missing.npz")


def test_corrupt_archives(tmp_path):
    path = _npz(tmp_path / "s.npz", **GOOD)
    data = path.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: len(data) // 2] + data[-22:])  # keeps the end record, loses members
    with pytest.raises(InputError, match="cut.npz"):
        read_samples(cut)
    # flip bytes inside the first member's data: the zip CRC check fails
    with zipfile.ZipFile(path) as z:
        info = z.infolist()[0]
    flipped = bytearray(data)
    start = info.header_offset + 30 + len(info.filename) + 80
    flipped[start : start + 8] = bytes(255 - b for b in flipped[start : start + 8])
    bad = tmp_path / "crc.npz"
    bad.write_bytes(bytes(flipped))
    with pytest.raises(InputError, match="crc.npz"):
        read_samples(bad)


def test_bytes_channel_names_are_decoded(tmp_path):
    path = _npz(tmp_path / "s.npz", **GOOD, channels=np.array([b"Y"]))
    assert read_samples(path).channels == ["Y"]


# -- fit_samples (dfc.train.fit) on noisy samples of a piecewise-constant scene --
A, B = np.array([0.2, 0.5, 0.8]), np.array([0.9, 0.3, 0.1])


def _truth(xy):
    return np.where((xy[:, 0] < 12 + xy[:, 1] / 4)[:, None], A, B)  # left of the line (12, 0)–(20, 32)


def test_fit_samples_denoises_a_piecewise_constant_scene():
    from dfc.geometry.curves import Curves, elevate
    from dfc.geometry.triangulate import triangulate
    from dfc.metrics import psnr
    from dfc.render import render
    from dfc.train.fit import fit_samples

    curves = Curves((0, 0, 32, 32), elevate(np.array([[[12.0, 0.0], [20.0, 32.0]]]), 1), [1], [0], [[0, 1]])
    mesh = triangulate(curves, max_triangles=200)
    rng = np.random.default_rng(0)
    xy = rng.random((10000, 2)) * 32
    xy[5000:] = xy[:5000]  # repeated positions with independent noise
    noisy = (_truth(xy) + rng.normal(0, 0.1, (10000, 3))).astype(np.float32)
    model = fit_samples(SampleSet(xy, noisy, (0, 0, 32, 32), ["R", "G", "B"]), mesh, steps=120, batch_size=2048)
    assert model.channels == ["R", "G", "B"]
    c = np.arange(32) + 0.5
    centres = np.stack([np.tile(c, 32), np.repeat(c, 32)], 1)
    assert psnr(_truth(xy), noisy, data_range=1.0) < 20.5  # the input: σ = 0.1
    assert psnr(_truth(centres).reshape(32, 32, 3), render(model, 32, 32), data_range=1.0) > 34.0


def test_fit_samples_refuses_points_outside_the_mesh():
    from dfc.geometry.curves import Curves
    from dfc.geometry.triangulate import triangulate
    from dfc.train.fit import fit_samples

    mesh = triangulate(Curves((0, 0, 4, 4), np.zeros((0, 4, 2)), [], [], np.zeros((0, 2))), max_triangles=8)
    s = SampleSet(np.array([[1.0, 1.0], [5.0, 1.0]]), np.zeros((2, 1), dtype=np.float32))
    with pytest.raises(InputError, match="1 points lie outside the mesh's domain"):
        fit_samples(s, mesh, steps=1)
