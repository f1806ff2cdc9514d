"""The independent decoder of ``tests/reference_decoder.py`` (written from spec/dfield.md and spec/field.md)
must agree with dfc on the same bytes: proof that the spec suffices to evaluate a field."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from dfc.bench.scenes import sample_scene
from dfc.codec import loads
from dfc.field.feature_field import FeatureField
from dfc.field.mlp import OneBlob
from dfc.field.model import FieldModel
from dfc.field.side import chord_frames, in_sliver
from dfc.geometry.curves import Curves, elevate
from dfc.geometry.triangulate import triangulate
from dfc.io.container import HEADER_DICTIONARY, decode_dfield, encode_dfield
from dfc.io.dfield import from_contents, to_contents
from dfc.io.meshcodec import roundtrip_mesh

from .reference_decoder import ReferenceField, header_dictionary, read_chunks

GOLDEN = Path(__file__).parent / "golden" / "valid"
ATOL = 1e-4
CODINGS = {"1.0": {"feature_coding": "plain", "compact": False},
           "1.1": {"feature_coding": "predicted", "weight_bits": 6, "compact": False},
           "1.5": {"feature_coding": "predicted", "weight_bits": 6}}
"""Chunk encodings of a version: HEAD + TOPO + FEAT + MLPW (1.0), HEAD + TOPO + FEAC + MLPQ (1.1) or
HEAC + TOPC + FEAC + MLPC (1.5)."""
CHUNKS = {"1.0": {b"HEAD", b"TOPO", b"FEAT", b"MLPW"}, "1.1": {b"HEAD", b"TOPO", b"FEAC", b"MLPQ"},
          "1.5": {b"HEAC", b"TOPC", b"FEAC", b"MLPC"}}


def _junction() -> Curves:
    """Two lines and a cubic meeting at (4, 4): a vertex with three discontinuous half-edges."""
    lines = elevate(np.array([[(4.0, 4.0), (0.5, 1.0)], [(4.0, 4.0), (7.5, 2.0)]]), 1)
    cubic = np.array([[(4.0, 4.0), (5.0, 5.5), (2.0, 6.0), (3.0, 7.5)]])
    return Curves((0.0, 0.0, 8.0, 8.0), np.concatenate([lines, cubic]), [1, 1, 3], [0, 1, 2], [(0, 1)] * 3,
                  names=["a", "b", "c"], sides=[None] * 3)


SCENES = {"sample": (lambda: sample_scene().curves, 300, 2), "junction": (_junction, 150, 3)}
"""name -> (curves, max_triangles, most discontinuous half-edges at one vertex)."""


@pytest.fixture(scope="module", params=sorted(SCENES))
def scene(request):
    return request.param


@pytest.fixture(scope="module")
def mesh(scene):
    curves, max_triangles, _ = SCENES[scene]
    return roundtrip_mesh(triangulate(curves(), max_triangles=max_triangles), 16)


def _encode(mesh, *, n_slices=1, times=None, seed=0, coding="1.5", **model_kw):
    """The bytes of a random field on ``mesh`` written with the ``CODINGS[coding]`` chunks, decoded by dfc (a model)
    and by the reference decoder."""
    field = FeatureField(mesh, dim=5, seed=seed, n_slices=n_slices, times=times)
    model = FieldModel(field, ["r", "g", "b"], hidden=16, layers=2, seed=seed, **model_kw)
    with torch.no_grad():
        field.bank.uniform_(-1.0, 1.0, generator=torch.Generator().manual_seed(seed))
        for lin in model.decoder.linears():
            lin.weight.mul_(2.0)
    blob, _ = encode_dfield(to_contents(model), feature_bits=8, **CODINGS[coding])
    return loads(blob), ReferenceField.from_bytes(blob), blob


def _dfc(model, xy, t=None):
    with torch.no_grad():
        xy = torch.from_numpy(np.ascontiguousarray(xy, np.float64))
        tt = None if t is None else torch.as_tensor(np.asarray(t, np.float64))
        return model(xy, tt).numpy().astype(np.float64), model.features(xy, tt).numpy().astype(np.float64)


def _agree(model, ref, xy, t=None):
    value, feat = _dfc(model, xy, t)
    np.testing.assert_allclose(ref.features(xy, t), feat, rtol=0, atol=ATOL)
    np.testing.assert_allclose(ref(xy, t), value, rtol=0, atol=ATOL)


def _random(ref, n, seed, margin=0.0):
    x0, y0, x1, y1 = ref.domain
    rng = np.random.default_rng(seed)
    span = np.array([x1 - x0, y1 - y0])
    lo = np.array([x0, y0]) - margin * span
    return lo + rng.random((n, 2)) * (1.0 + 2.0 * margin) * span


def _bezier(cp, t):
    s = (1.0 - t)[:, None]
    t = t[:, None]
    return s**3 * cp[:, 0] + 3 * s * s * t * cp[:, 1] + 3 * s * t * t * cp[:, 2] + t**3 * cp[:, 3]


def _curve_points(ref, fractions):
    """Points between each curve's chord and the curve (w = f·W(t)) for the given f, and their curves."""
    C = len(ref.curve_faces)
    t = np.tile(np.linspace(0.15, 0.85, 8), C)
    c = np.repeat(np.arange(C), 8)
    cp = ref.control_points[c]
    on_curve = _bezier(cp, t)
    u = np.einsum("nd,nd->n", on_curve - cp[:, 0], ref.ubar[c])
    on_chord = cp[:, 0] + u[:, None] * (cp[:, 3] - cp[:, 0])
    pts = [(1.0 - f) * on_chord + f * on_curve for f in fractions]
    return np.concatenate(pts), np.tile(c, len(fractions))


def _apex_side_points(ref):
    C = len(ref.curve_faces)
    t = np.tile(np.linspace(0.2, 0.8, 5), C)
    c = np.repeat(np.arange(C), 5)
    on_curve = _bezier(ref.control_points[c], t)
    apex = ref.vertices[ref.faces[ref.curve_faces[c], ref.corner_x[c]]]
    return np.concatenate([on_curve + g * (apex - on_curve) for g in (0.3, 0.6)]), np.tile(c, 2)


def _edges(ref):
    """Undirected mesh edges (M, 2) and the faces on each side (M, 2), -1 on the border."""
    f = ref.faces
    directed = np.stack([f, np.roll(f, -1, axis=1)], -1).reshape(-1, 2)
    owner = np.repeat(np.arange(len(f)), 3)
    key = {(a, b): o for (a, b), o in zip(directed.tolist(), owner.tolist())}
    und = np.unique(np.sort(directed, axis=1), axis=0)
    sides = np.array([[key.get((a, b), -1), key.get((b, a), -1)] for a, b in und.tolist()])
    return und, sides


def test_geometry_and_layout_match_dfc(scene, mesh):
    model, ref, blob = _encode(mesh)
    assert read_chunks(blob)[b"MESH"][0] == 2  # derived: the reference rebuilds the triangles itself (D §6.1)
    m = model.field.mesh
    assert np.array_equal(ref.vertices, m.vertices) and np.array_equal(ref.faces, m.triangles)
    assert np.array_equal(ref.vertices, mesh.vertices) and np.array_equal(ref.faces, mesh.triangles)
    assert np.array_equal(ref.control_points, m.curve_control_points)
    lay = model.field.layout
    assert ref.n_rows == lay.n_features and np.array_equal(ref.offset, lay.vertex_offset)
    assert np.array_equal(ref.c_start, lay.corner_start) and np.array_equal(ref.c_end, lay.corner_end)
    rc = np.arange(len(ref.far_a))
    assert np.array_equal(lay.curve_sliver_rows[rc, ref.corner_a], ref.far_a)
    assert np.array_equal(lay.curve_sliver_rows[rc, ref.corner_b], ref.far_b)
    assert np.array_equal(lay.curve_apex, ref.corner_x)
    r = ref.c_radial
    np.testing.assert_allclose(ref.c_alpha[r], lay.corner_alpha[r], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref.c_theta[r], lay.corner_theta[r], rtol=0, atol=1e-12)
    assert len(ref.curve_faces) >= 2 and (ref.k == 1).any() and ref.k.max() == SCENES[scene][2]


@pytest.mark.parametrize("coding", sorted(CODINGS))
def test_static_relu_field_agrees_everywhere_continuous(mesh, coding):
    model, ref, blob = _encode(mesh, activation="relu", coding=coding)
    assert CHUNKS[coding] <= set(read_chunks(blob))
    edges, sides = _edges(ref)
    disc = {tuple(e) for e in np.sort(mesh.disc_edges, axis=1).tolist()}
    cont = np.array([tuple(e) not in disc for e in edges.tolist()])
    a, b = ref.vertices[edges[cont, 0]], ref.vertices[edges[cont, 1]]
    on_edges = np.concatenate([a + f * (b - a) for f in (0.25, 0.5, 0.75)])
    two = np.tile(sides[cont], (3, 1))
    shared, two = on_edges[(two >= 0).all(1)], two[(two >= 0).all(1)]
    chords = {tuple(e) for e in np.sort(ref.curve_ends, axis=1).tolist()}
    assert sum(tuple(e) in chords for e in edges[cont].tolist()) == len(chords)
    # spec: the same value from both faces of a continuous edge, chords included
    np.testing.assert_allclose(ref(shared, face=two[:, 0]), ref(shared, face=two[:, 1]), atol=1e-9)
    sliver, c = _curve_points(ref, (0.2, 0.5, 0.8))
    apex_side, c_apex = _apex_side_points(ref)
    assert ref.in_sliver(sliver, c).all() and not ref.in_sliver(apex_side, c_apex).any()
    assert np.array_equal(ref.locate(sliver), ref.curve_faces[c])
    parts = [_random(ref, 3000, 1), _random(ref, 300, 2, margin=0.2), ref.vertices[ref.k == 0], on_edges,
             sliver, apex_side]
    _agree(model, ref, np.concatenate(parts))


def test_discontinuities_take_a_one_sided_value(mesh):
    model, ref, _ = _encode(mesh, seed=3)
    edges, sides = _edges(ref)
    disc = {tuple(e) for e in np.sort(mesh.disc_edges, axis=1).tolist()}
    pick = np.array([tuple(e) in disc for e in edges.tolist()]) & (sides >= 0).all(1)
    mid = 0.5 * (ref.vertices[edges[pick, 0]] + ref.vertices[edges[pick, 1]])
    got, _ = _dfc(model, mid)
    one = [ref(mid, face=sides[pick, s]) for s in (0, 1)]
    err = np.minimum(*(np.abs(o - got).max(1) for o in one))
    assert err.max() < ATOL
    assert np.mean(np.abs(one[0] - one[1]).max(1) > 1e-3) > 0.9      # a real jump: the choice matters
    # a vertex with discontinuities: dfc's value is that of one of its faces (F §5.1, ties)
    face = np.repeat(np.arange(len(ref.faces)), 3)
    vert = ref.faces.ravel()
    keep = ref.k[vert] > 0
    face, vert = face[keep], vert[keep]
    got, _ = _dfc(model, ref.vertices[vert])
    err = np.abs(ref(ref.vertices[vert], face=face) - got).max(1)
    best = np.full(len(ref.vertices), np.inf)
    np.minimum.at(best, vert, err)
    assert best[ref.k > 0].max() < ATOL


def test_tanh_oneblob_log_field_agrees(mesh):
    model, ref, _ = _encode(mesh, seed=1, activation="tanh", oneblob_bins=4, transform="log")
    assert ref.mlp["layers.0.weight"].shape[1] == 5 + 8
    sliver, _ = _curve_points(ref, (0.3, 0.7))
    _agree(model, ref, np.concatenate([_random(ref, 3000, 4), sliver, ref.vertices[ref.k == 0]]))


def test_time_slices_agree(mesh):
    model, ref, _ = _encode(mesh, seed=2, n_slices=2, times=[0.0, 2.0])
    xy = np.concatenate([_random(ref, 2000, 5), _curve_points(ref, (0.5,))[0]])
    t = np.random.default_rng(6).uniform(-0.5, 2.5, len(xy))
    t[:3] = [0.0, 2.0, 1.0]
    _agree(model, ref, xy, t)
    lo, hi = ref.features(xy, 0.0), ref.features(xy, 2.0)
    np.testing.assert_allclose(ref.features(xy, 1.0), 0.5 * (lo + hi), atol=1e-12)
    assert np.abs(lo - hi).max() > 0.1


def test_raw_mesh_encoding_agrees():
    mesh = triangulate(_junction(), max_triangles=150)       # off any grid: stored raw, control points as f64
    model, ref, blob = _encode(mesh, seed=4)
    assert read_chunks(blob)[b"MESH"][0] == 1 and read_chunks(blob)[b"TOPC"][12] == 0
    assert np.array_equal(ref.vertices, mesh.vertices)
    _agree(model, ref, np.concatenate([_random(ref, 1000, 8), _curve_points(ref, (0.5,))[0]]))


@pytest.mark.parametrize("name", ["tiny", "tiny_coded", "tiny_units", "tiny_derived", "tiny_compact", "tiny_topc",
                                  "tiny_residual"])
def test_golden_tiny_file_agrees(name):
    blob = (GOLDEN / f"{name}.dfield").read_bytes()
    model = from_contents(decode_dfield(blob))
    ref = ReferenceField.from_bytes(blob)
    expect = json.loads((GOLDEN / f"{name}.json").read_text())
    assert ref.bank.shape == tuple(expect["features_shape"])
    assert ref.bank.sum() == pytest.approx(expect["features_sum"], rel=1e-9)
    xy = np.concatenate([_random(ref, 2000, 7), _curve_points(ref, (0.4,))[0]])
    _agree(model, ref, xy)


def test_golden_units_file_maps_values():
    """content 1.2: value_transform "affine" returns offset + scale · y per channel, in binary64, where y is what
    the same chunks decode to with the identity transform."""
    units = (GOLDEN / "tiny_units.dfield").read_bytes()
    ref, ref_plain = ReferenceField.from_bytes(units), ReferenceField.from_bytes(units)
    ref_plain.header = {**ref_plain.header, "value_transform": "identity"}
    xy = _random(ref, 500, 3)
    y = ref_plain(xy)
    np.testing.assert_array_equal(ref(xy), np.array([1e6, -3e-5, 0.5]) + np.array([1e-3, 2e-9, 4.0]) * y)
    model = from_contents(decode_dfield(units))
    with torch.no_grad():
        got = model(torch.from_numpy(xy)).numpy()
    assert got.dtype == np.float64 and np.ptp(got[:, 0]) > 1e-4  # the variation survives the offset
    assert np.all(np.abs(got - ref(xy)) <= ATOL * np.array([1e-3, 2e-9, 4.0]))


def test_spec_oneblob_example():
    out = OneBlob(4, (0.0, 0.0, 256.0, 256.0))(torch.tensor([[64.0, 0.0]], dtype=torch.float64))
    np.testing.assert_allclose(out[0, :4].numpy(), [0.88250, 0.88250, 0.32465, 0.04394], atol=5e-6)


def test_spec_sliver_example():
    cp = torch.tensor([[[0.0, 0.0], [2 / 3, 2 / 3], [4 / 3, 2 / 3], [2.0, 0.0]]], dtype=torch.float64)
    origin, u_axis, v_axis, local = chord_frames(cp, torch.tensor([[1.0, 2.0]], dtype=torch.float64))
    np.testing.assert_allclose(local[0].numpy(), [[0, 0], [1 / 3, 1 / 3], [2 / 3, 1 / 3], [1, 0]], atol=1e-15)
    xy = torch.tensor([[1.0, 0.4], [1.0, 0.6]], dtype=torch.float64)
    got = in_sliver(xy, origin.expand(2, 2), u_axis.expand(2, 2), v_axis.expand(2, 2), local.expand(2, 4, 2))
    assert got.tolist() == [True, False]


def test_the_header_dictionary_is_the_spec_s():
    """dfc compresses HEAC against exactly the bytes spec Appendix A lists (its stated length and SHA-256 hold)."""
    assert header_dictionary() == HEADER_DICTIONARY
