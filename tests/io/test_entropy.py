"""Range coding under two-slope geometric models (spec/dfield.md §6.6) and the predicted feature bank (§6.5)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.errors import FormatError
from dfc.field.layout import build_layout
from dfc.field.quantize import quantize_features
from dfc.io.container import _encode_features
from dfc.io.entropy import PRECISION, GroupModel, counts, decode_groups, encode_groups, fit_model
from dfc.io.featcodec import decode_feac, encode_feac, prediction_graph
from dfc.io.meshcodec import roundtrip_mesh

from .test_meshcodec import make_mesh


@given(lo=st.integers(-300, 0), hi=st.integers(0, 300), d1=st.integers(0, 65535), d2=st.integers(0, 65535),
       m=st.integers(0, 65535))
@settings(max_examples=60, deadline=None)
def test_counts_fill_the_precision_exactly(lo, hi, d1, d2, m):
    c = counts(GroupModel(lo, hi, d1, d2, m))
    assert len(c) == hi - lo + 1 and c.min() >= 0 and c.sum() + len(c) == 2**PRECISION


def test_counts_follow_the_two_slopes():
    c = counts(GroupModel(-20, 20, 32768, 65000, 3)).astype(float)
    mid = 20
    assert c[mid + 1] / c[mid] == pytest.approx(0.5, rel=1e-4) and c[mid - 1] == c[mid + 1]  # symmetric
    assert c[mid + 10] / c[mid + 9] == pytest.approx(65000 / 65536, rel=1e-3)


def test_the_coder_uses_the_stated_frequencies():
    """A symbol of count c costs log2(2**24 / (c + 1)) bits: 255 + 1 out of 2**24 is 16 bits per symbol."""
    model = GroupModel(0, 1, 1, 1, 0)
    assert counts(model)[1] == 255
    blob = encode_groups([(model, np.ones(4000, np.int64))])
    assert 8 * len(blob) / 4000 == pytest.approx(16.0, abs=0.05)


def test_groups_round_trip_and_the_fit_approaches_the_entropy():
    rng = np.random.default_rng(0)
    a = np.rint(rng.laplace(0, 5, 3000)).astype(np.int64)
    b = np.zeros(10, np.int64)
    c = rng.integers(-3, 40, 500)
    models = [fit_model(a), fit_model(b), fit_model(c)]
    assert models[1].size == 1
    blob = encode_groups(list(zip(models, [a, b, c])))
    out = decode_groups(blob, [(m, len(v)) for m, v in zip(models, [a, b, c])], "TEST")
    assert all(np.array_equal(x, y) for x, y in zip(out, [a, b, c]))
    _, n = np.unique(a, return_counts=True)
    entropy = -(n * np.log2(n / n.sum())).sum() / 8
    assert len(encode_groups([(models[0], a)])) < 1.05 * entropy + 8


@given(scale=st.floats(0.3, 40.0), tail=st.floats(1.0, 4.0), seed=st.integers(0, 10**6))
@settings(max_examples=25, deadline=None)
@pytest.mark.slow
def test_the_coarse_to_fine_search_is_near_the_full_grid(scale, tail, seed):
    """``fit_model`` searches a coarse grid and then around its best; on two-slope Laplacian values it codes within
    1 % (and 2 bytes) of the best model of the full grid."""
    from dfc.io.entropy import _D_GRID, _M_GRID, _Search

    rng = np.random.default_rng(seed)
    v = np.rint(rng.laplace(0, scale, 3000) * np.where(rng.random(3000) < 0.1, tail, 1.0)).astype(np.int64)
    model = fit_model(v)
    d1, d2, m = (g.ravel() for g in np.meshgrid(_D_GRID, _D_GRID, np.array(_M_GRID, np.int64), indexing="ij"))
    lo = min(0, int(v.min()))
    hist = np.bincount(v - lo, minlength=max(0, int(v.max())) - lo + 1).astype(np.float64)
    best = GroupModel(lo, model.hi, *_Search(hist, lo).best(d1, d2, m))

    def bits(g):
        return -np.log2((counts(g)[v - g.lo] + 1.0) / 2**PRECISION).sum()

    assert bits(model) <= bits(best) * 1.01 + 16


def test_decoding_refuses_broken_streams():
    model = fit_model(np.arange(-5, 6))
    with pytest.raises(FormatError, match="whole number"):
        decode_groups(b"abc", [(model, 3)], "TEST")


@pytest.mark.parametrize("S", [1, 3])
@pytest.mark.parametrize("bits", [1, 8, 12])
def test_predicted_bank_round_trips_exactly(S, bits):
    mesh = roundtrip_mesh(make_mesh(seed=2), 16)
    layout = build_layout(mesh)
    rng = np.random.default_rng(bits)
    F = np.cumsum(rng.normal(size=(S, layout.n_features, 4)), axis=1).astype(np.float32)  # correlated rows
    data = encode_feac(F, bits, layout)
    info = {"slices": S, "rows": layout.n_features, "width": 4, "bits": bits}
    q, scale, offset = quantize_features(F, bits)
    assert np.array_equal(decode_feac(data, info, layout), offset + q.astype(np.float32) * scale)


def test_prediction_uses_only_earlier_neighbours_and_pays():
    mesh = roundtrip_mesh(make_mesh(n_interior=1000, seed=3), 16)
    layout = build_layout(mesh)
    P, classes = prediction_graph(layout)
    rows, cols = P.nonzero()
    assert np.all(cols < rows) and set(np.unique(classes)) == {0, 1, 2}
    assert np.all(classes[layout.n_vertex_features:] == 2)
    # a smooth bank (a function of the rows' vertex positions) codes in fewer bytes than the raw integers and their
    # zstd stream (the 1.0 FEAT)
    vertex = np.repeat(np.arange(mesh.n_vertices), np.where(layout.vertex_sectors > 0, 2 * layout.vertex_sectors, 1))
    xy = np.concatenate([mesh.vertices[vertex], mesh.vertices[mesh.curve_endpoints[:, 0]]])
    F = np.stack([np.sin(xy[:, 0] / 30), np.cos(xy[:, 1] / 20)], axis=1)[None].astype(np.float32)
    assert len(encode_feac(F, 8, layout)) < min(0.65 * F.size, 0.85 * len(_encode_features(F, 8, 19)))
