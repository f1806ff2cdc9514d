"""MESH/TOPO/TOPC chunk encoding: quantisation, canonical order, fallback ladder, hostile payloads."""

import hashlib
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from dfc.errors import FormatError, MeshError
from dfc.geometry.mesh import Mesh
from dfc.geometry.triangulate import triangulate
from dfc.io.meshcodec import (
    MAX_MESH_BITS,
    compress,
    decode_mesh,
    decompress,
    encode_mesh,
    encode_roundtripped,
    mesh_info,
    roundtrip_mesh,
)
from tests.geometry.test_triangulate import curve_sets, make_curves


def make_mesh(n_interior=60, n_side=6, n_disc=8, n_curves=10, domain=(0.0, 0.0, 64.0, 32.0), seed=0) -> Mesh:
    """A valid Mesh: Delaunay of random points with exact border points, random discontinuous edges and
    curves bulging slightly into their triangle from one edge (the chord)."""
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = domain
    s = rng.random((4, n_side))
    border = np.concatenate([
        np.stack([x0 + s[0] * (x1 - x0), np.full(n_side, y0)], 1), np.stack([x0 + s[1] * (x1 - x0), np.full(n_side, y1)], 1),
        np.stack([np.full(n_side, x0), y0 + s[2] * (y1 - y0)], 1), np.stack([np.full(n_side, x1), y0 + s[3] * (y1 - y0)], 1),
        np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]),
    ])
    inner = np.array([x0, y0]) + (0.05 + 0.9 * rng.random((n_interior, 2))) * np.array([x1 - x0, y1 - y0])
    v = np.concatenate([border, inner])
    t = Delaunay(v).simplices.astype(np.int64)
    p = v[t]
    cw = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]) < 0
    t[cw] = t[cw][:, [0, 2, 1]]
    # curves: chord = edge k -> k+1 of a triangle with acute base angles (so the curve is a graph over it),
    # one curve per triangle and per chord; control points on the edges towards the apex keep it inside
    cand_t, cand_k = np.repeat(np.arange(len(t)), 3), np.tile(np.arange(3), len(t))
    A, B, Cx = v[t[cand_t, cand_k]], v[t[cand_t, (cand_k + 1) % 3]], v[t[cand_t, (cand_k + 2) % 3]]
    proj = np.sum((Cx - A) * (B - A), axis=1) / np.sum((B - A) ** 2, axis=1)
    chosen, chords, used = [], set(), set()
    for i in rng.permutation(np.flatnonzero((proj > 0.05) & (proj < 0.95))):
        ti, k = int(cand_t[i]), int(cand_k[i])
        key = tuple(sorted((t[ti, k], t[ti, (k + 1) % 3])))
        if key not in chords and ti not in used:
            chords.add(key)
            used.add(ti)
            chosen.append((ti, k))
        if len(chosen) == n_curves:
            break
    ct = np.array([c[0] for c in chosen], np.int64)
    k = np.array([c[1] for c in chosen], np.int64)
    a, b, c = t[ct, k], t[ct, (k + 1) % 3], t[ct, (k + 2) % 3]
    A, B, Cx = v[a], v[b], v[c]
    deg = (2 + (np.arange(len(ct)) % 2)).astype(np.int8)
    Q = (A + B + Cx) / 3
    P1 = np.where(deg[:, None] == 3, A + 0.3 * (Cx - A), (A + 2 * Q) / 3)
    P2 = np.where(deg[:, None] == 3, B + 0.2 * (Cx - B), (2 * Q + B) / 3)
    cp = np.stack([A, P1, P2, B], axis=1)
    # discontinuous edges: mesh edges that are no chord
    edges = np.unique(np.sort(t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    edges = np.array([e for e in edges if tuple(e) not in chords])
    disc = edges[rng.choice(len(edges), n_disc, replace=False)]
    return Mesh(domain=tuple(domain), vertices=v, triangles=t, disc_edges=disc, curved_triangles=ct,
                curve_endpoints=np.stack([a, b], 1), curve_control_points=cp, curve_degree=deg,
                disc_edge_piece=np.arange(n_disc, dtype=np.int64), curve_piece=np.arange(len(ct), dtype=np.int64) + 100)


@pytest.fixture(scope="module")
def mesh():
    m = make_mesh()
    m.validate()
    return m


def _edge_set(edges, verts):
    return {tuple(sorted(map(tuple, verts[e].round(9).tolist()))) for e in edges}


def test_roundtrip_keeps_topology_and_bounds_error(mesh):
    bits = 14
    out = roundtrip_mesh(mesh, bits)
    assert out.n_vertices == mesh.n_vertices and out.n_triangles == mesh.n_triangles
    x0, y0, x1, y1 = mesh.domain
    step = np.array([x1 - x0, y1 - y0]) / (2**bits - 1)
    # match vertices by nearest grid point: each moves at most half a grid step per axis
    order_in = np.lexsort((mesh.vertices[:, 1], mesh.vertices[:, 0]))
    moved = np.abs(out.vertices - mesh.vertices[order_in])
    assert np.all(moved <= step / 2 * (1 + 1e-9))
    # same discontinuous edges and curves up to the vertex renumbering
    vmap = np.empty(mesh.n_vertices, np.int64)
    vmap[order_in] = np.arange(mesh.n_vertices)
    assert {tuple(sorted(e)) for e in vmap[mesh.disc_edges].tolist()} == {tuple(sorted(e)) for e in out.disc_edges.tolist()}
    # curves in canonical order (TOPC), matched by their directed endpoints; no piece ids (TOPC stores none)
    source = {tuple(e): c for c, e in enumerate(vmap[mesh.curve_endpoints].tolist())}
    match = np.array([source[tuple(e)] for e in out.curve_endpoints.tolist()])
    assert sorted(match.tolist()) == list(range(len(match)))
    assert np.all(np.diff(np.sort(out.curve_endpoints, axis=1) @ [mesh.n_vertices, 1]) > 0)
    assert np.all(out.curve_piece == -1) and np.all(out.disc_edge_piece == -1)
    assert np.array_equal(out.curve_degree, mesh.curve_degree[match])
    # inner control points move with their triangle's corners (at most half a step each) plus half a step of rounding
    moved_cp = np.abs(out.curve_control_points - mesh.curve_control_points[match])
    assert np.all(moved_cp <= 2 * step.max())
    # curves stay in their triangles, ends coincide with vertices bit for bit
    assert np.array_equal(out.curve_control_points[:, 0], out.vertices[out.curve_endpoints[:, 0]])
    assert np.array_equal(out.curve_control_points[:, 3], out.vertices[out.curve_endpoints[:, 1]])
    assert set(out.curve_endpoints[0]) <= set(out.triangles[out.curved_triangles[0]].tolist())
    out.validate()


def test_border_vertices_stay_exactly_on_border(mesh):
    out = roundtrip_mesh(mesh, 9)
    x0, y0, x1, y1 = mesh.domain
    for coord, value in ((0, x0), (0, x1), (1, y0), (1, y1)):
        assert np.count_nonzero(out.vertices[:, coord] == value) == np.count_nonzero(mesh.vertices[:, coord] == value)


def test_quadratics_stay_exact_elevations(mesh):
    out = roundtrip_mesh(mesh, 12)
    quad = out.curve_degree == 2
    cp = out.curve_control_points[quad]
    q1, q2 = (3 * cp[:, 1] - cp[:, 0]) / 2, (3 * cp[:, 2] - cp[:, 3]) / 2
    assert np.allclose(q1, q2, rtol=0, atol=1e-12)


def test_canonical_order_is_a_fixed_point(mesh):
    out = roundtrip_mesh(mesh, 12)
    again = roundtrip_mesh(out, 12)
    for f in ("vertices", "triangles", "disc_edges", "curved_triangles", "curve_endpoints", "curve_control_points"):
        assert np.array_equal(getattr(out, f), getattr(again, f)), f
    assert np.all(np.diff(out.vertices[:, 0]) >= 0)
    m, t = encode_roundtripped(out, coding="draco")
    assert mesh_info(m, t)["encoding"] == "draco" and mesh_info(m, t)["bits"] == 12


def test_writer_finds_the_grid_of_a_decoder_view(mesh):
    out = roundtrip_mesh(mesh, 10)
    for coding, encoding in (("draco", "draco"), ("derived", "derived")):
        m, t = encode_roundtripped(out, coding=coding)
        assert mesh_info(m, t)["encoding"] == encoding and 10 <= mesh_info(m, t)["bits"] < 16
        again = decode_mesh(m, t, mesh.domain)
        assert np.array_equal(again.vertices, out.vertices) and np.array_equal(again.triangles, out.triangles)


def test_a_mesh_that_is_not_a_decoder_view_is_written_losslessly(mesh):
    m, t = encode_roundtripped(mesh)
    assert mesh_info(m, t)["encoding"] == "raw"
    assert np.array_equal(decode_mesh(m, t, mesh.domain).vertices, mesh.vertices)
    bad = make_mesh()
    bad.disc_edges = np.array([[0, 0]])
    bad.disc_edge_piece = np.array([0])
    with pytest.raises(MeshError, match="invalid"):
        encode_roundtripped(bad)


def test_low_bits_fall_back_until_valid(mesh):
    out = roundtrip_mesh(mesh, 2)  # a 4 x 4 grid cannot hold 100 distinct vertices
    m, t = encode_roundtripped(out)
    info = mesh_info(m, t)
    assert info["encoding"] == "raw" or info["bits"] > 2
    out.validate()


def test_raw_encoding_is_lossless(mesh):
    m, t = encode_mesh(mesh, None)
    out = decode_mesh(m, t, mesh.domain)
    for f in ("vertices", "triangles", "disc_edges", "curve_control_points", "curve_endpoints"):
        assert np.array_equal(getattr(out, f), getattr(mesh, f)), f


def test_invalid_mesh_is_refused_even_losslessly(mesh):
    bad = make_mesh()
    bad.triangles = bad.triangles[:, [0, 2, 1]]
    with pytest.raises(MeshError):
        roundtrip_mesh(bad, 12)


def test_bits_out_of_range(mesh):
    with pytest.raises(ValueError):
        encode_mesh(mesh, MAX_MESH_BITS + 1)


def test_draco_header_counts_must_match(mesh):
    m, t = encode_mesh(mesh, 12)
    lying = bytearray(m)
    lying[4:8] = (mesh.n_vertices + 1).to_bytes(4, "little")
    with pytest.raises(FormatError, match="declares"):
        decode_mesh(bytes(lying), t, mesh.domain)


def test_hostile_draco_payloads_raise_format_error(mesh):
    m, t = encode_mesh(mesh, 12)
    rng = np.random.default_rng(1)
    outcomes = set()
    for _ in range(300):
        b = bytearray(m)
        i = int(rng.integers(12, len(b)))
        b[i] = int(rng.integers(256))
        try:
            out = decode_mesh(bytes(b), t, mesh.domain)
            out.validate()
            outcomes.add("valid")
        except FormatError:
            outcomes.add("refused")
    assert "refused" in outcomes


def test_zstd_frames_are_checked_before_decompressing():
    frame = compress(b"x" * 1000, 3)
    assert decompress(frame, 1000, "T") == b"x" * 1000
    with pytest.raises(FormatError, match="declares"):
        decompress(frame, 999, "T")
    with pytest.raises(FormatError, match="after its frame"):
        decompress(frame + b"\0", 1000, "T")
    with pytest.raises(FormatError):
        decompress(zstandard.ZstdCompressor(write_content_size=False).compress(b"abc"), 3, "T")
    with pytest.raises(FormatError):
        decompress(frame[:-3], 1000, "T")
    with pytest.raises(FormatError):
        decompress(b"", 0, "T")


# ----------------------------------------------------------------------------------------------- derived encoding
def _derived(mesh: Mesh, bits: int):
    """(MESH, TOPO) of ``mesh`` in the derived encoding (asserted chosen) and the mesh they decode to."""
    m, t = encode_roundtripped(mesh)
    assert mesh_info(m, t)["encoding"] == "derived"
    return m, t, decode_mesh(m, t, mesh.domain)


def _assert_same_mesh(a: Mesh, b: Mesh):
    for f in ("vertices", "triangles", "disc_edges", "curved_triangles", "curve_endpoints", "curve_control_points",
              "curve_degree", "disc_edge_piece", "curve_piece"):
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert x.shape == y.shape and np.array_equal(x, y), f


@pytest.fixture(scope="module")
def lattice_mesh():
    """A triangulated curve set with its free vertices on the lattice of a 16-bit grid, as the encoder fits on it."""
    curves = make_curves([(3, [(0.2, 0.2), (1.0, 2.9), (3.0, -1.0), (3.9, 2.8)]), (1, [(0.5, 2.5), (3.5, 0.4)]),
                          (2, [(0.3, 0.5), (2.0, 1.2), (3.8, 0.3)])])
    return roundtrip_mesh(triangulate(curves, max_triangles=160, lattice_bits=16), 16)


def test_derived_encoding_decodes_to_the_encoders_mesh_and_is_smaller(lattice_mesh):
    m, t, out = _derived(lattice_mesh, 16)
    _assert_same_mesh(out, lattice_mesh)
    info = mesh_info(m, t)
    assert info["bits"] == 16 and 1 <= info["shift"] < 16
    assert len(m) < 0.6 * len(encode_mesh(lattice_mesh, 16)[0])  # Draco of the same mesh
    again = decode_mesh(m, t, lattice_mesh.domain)
    _assert_same_mesh(again, out)


def test_derived_decoding_is_the_same_in_a_fresh_process(lattice_mesh, tmp_path):
    m, t, out = _derived(lattice_mesh, 16)
    (tmp_path / "mesh.bin").write_bytes(m)
    (tmp_path / "topo.bin").write_bytes(t)
    code = ("import hashlib, sys, numpy as np; from dfc.io.meshcodec import decode_mesh; "
            f"d = decode_mesh(open(sys.argv[1], 'rb').read(), open(sys.argv[2], 'rb').read(), {tuple(out.domain)}); "
            "print(hashlib.sha256(np.ascontiguousarray(d.vertices).tobytes() + d.triangles.astype('<i8').tobytes())"
            ".hexdigest())")
    root = Path(__file__).parents[2]
    res = subprocess.run([sys.executable, "-c", code, str(tmp_path / "mesh.bin"), str(tmp_path / "topo.bin")],
                         capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": str(root)})
    here = hashlib.sha256(np.ascontiguousarray(out.vertices).tobytes() + out.triangles.astype("<i8").tobytes())
    assert res.stdout.strip() == here.hexdigest()


def test_lattice_snaps_only_the_free_vertices(lattice_mesh):
    curves = make_curves([(1, [(0.5, 2.5), (3.5, 0.4)])])
    plain = roundtrip_mesh(triangulate(curves, max_triangles=160), 16)
    snapped = roundtrip_mesh(triangulate(curves, max_triangles=160, lattice_bits=16), 16)
    q = np.rint(snapped.vertices / np.array([4.0, 3.0]) * 65535).astype(np.int64)
    on_curve = np.zeros(snapped.n_vertices, bool)
    on_curve[snapped.disc_edges.ravel()] = True
    lattice = np.all((q % 2 ** mesh_info(*encode_roundtripped(snapped))["shift"] == 0) | (q == 65535), axis=1)
    assert lattice[~on_curve].all() and not lattice[on_curve].all()
    assert abs(snapped.n_triangles - plain.n_triangles) <= 0.1 * plain.n_triangles
    snapped.validate()


def test_cocircular_vertices_are_resolved_by_stored_edges():
    """A regular grid: every square's four corners lie on one circle, so a CDT could take either diagonal; the
    encoder stores the mesh's diagonals as constraint edges and the decoder reproduces them."""
    n = 6
    g = np.linspace(0.0, 1.0, n)
    v = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2) * [5.0, 5.0]
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()
    alt = (np.add.outer(np.arange(n - 1), np.arange(n - 1)) % 2 == 0).ravel()  # both diagonal directions
    t = np.concatenate([np.where(alt[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1)),
                        np.where(alt[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))])
    z = np.zeros((0, 2), np.int64)
    mesh = Mesh((0.0, 0.0, 5.0, 5.0), v, t, z, np.zeros(0, np.int64), z, np.zeros((0, 4, 2)), np.zeros(0, np.int8),
                np.zeros(0, np.int64), np.zeros(0, np.int64))
    mesh = roundtrip_mesh(mesh, 12)
    m, _, out = _derived(mesh, 12)
    _assert_same_mesh(out, mesh)
    assert struct.unpack_from("<I", m, 16)[0] >= (n - 1) ** 2  # a stored edge per square at least


def test_hostile_derived_payloads_raise_format_error(lattice_mesh):
    m, t, _ = _derived(lattice_mesh, 16)
    domain = lattice_mesh.domain
    bad = [m[:-1], m + b"\0", m[:12] + m[12:20] + b"\x40\0\0\0" + m[24:], m[:2] + b"\0\0" + m[4:],
           m[:2] + bytes([16, 0]) + m[4:], m[:12] + struct.pack("<I", lattice_mesh.n_vertices + 1) + m[16:],
           m[:12] + m[12:20] + bytes([25]) + m[21:], m[:8] + struct.pack("<I", lattice_mesh.n_triangles + 1)]
    rng = np.random.default_rng(0)
    for _ in range(40):
        flipped = bytearray(m)
        flipped[int(rng.integers(24, len(m)))] ^= 1 << int(rng.integers(8))
        bad.append(bytes(flipped))
    for data in bad:
        try:
            out = decode_mesh(data, t, domain)
        except FormatError:
            continue
        out.validate()  # a flip that still decodes gives a valid mesh (another one)


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(curves=curve_sets(), density=st.sampled_from([None, 0.5]))
def test_fuzzed_curves_derived_mesh_is_the_encoders(curves, density):
    try:
        mesh = triangulate(curves, max_area=density, max_triangles=300, lattice_bits=16)
    except MeshError as e:  # the known limits of test_fuzzed_curves_mesh_validate_and_keep_every_piece
        assume(not re.search("tangent at their shared endpoint|cannot separate|would be split|need", str(e)))
        raise
    view = roundtrip_mesh(mesh, 16)
    m, t = encode_roundtripped(view)
    out = decode_mesh(m, t, view.domain)
    _assert_same_mesh(out, view)
    out.validate()
    assert mesh_info(m, t)["encoding"] in ("derived", "raw")  # raw: the 16-bit grid could not hold the mesh


def test_curve_vertices_finer_than_the_grid_keep_the_mesh_on_it():
    """Scene curves as ``dfc curves`` writes them: end points 7.5e-5 px apart (closer than one step of the 20-bit
    grid over 256 px) and chains of short line pieces bent by less than a step, whose thin triangles turn over when
    rounded. The encoder's mesh is still on the 20-bit grid and stored derived (such meshes were stored raw, in
    float64, at 5-10 times the bytes), and it still draws the curves."""
    from dfc.rate import build_mesh
    from dfc.settings import EncodeSettings
    from tests.geometry.test_triangulate import assert_same_drawing

    rng = np.random.default_rng(0)
    pieces = [(1, [(10.0, 250.0), (60.0, 240.0)]), (1, [(60.0 + 7.5e-5, 240.0), (120.0, 250.0)])]
    for k in range(30):
        a = np.array([20.0 + 40.0 * (k % 6), 20.0 + 40.0 * (k // 6)])
        d = rng.normal(size=2)
        d /= np.hypot(*d)
        mid = a + 10.0 * d + np.array([-d[1], d[0]]) * rng.uniform(-1e-6, 1e-6)
        pieces += [(1, [tuple(a), tuple(mid)]), (1, [tuple(mid), tuple(a + 20.0 * d)])]
    curves = make_curves(pieces, domain=(0.0, 0.0, 256.0, 256.0))
    mesh = build_mesh(curves, EncodeSettings(max_triangles=600))
    q = np.rint(mesh.vertices / 256.0 * (2**20 - 1))
    np.testing.assert_array_equal(q / (2**20 - 1) * 256.0, mesh.vertices)
    m, t = encode_roundtripped(mesh)
    assert mesh_info(m, t)["encoding"] == "derived"
    _assert_same_mesh(decode_mesh(m, t, mesh.domain), mesh)
    assert_same_drawing(curves, mesh, 1e-3)


def test_a_triangle_that_rounding_flattens_is_triangulated_again():
    """A chain of two discontinuous edges C-A-B bent by 0.3 grid steps: its thin triangle C-B-A becomes flat on the
    20-bit grid, so Draco's view of the mesh is invalid. ``roundtrip_mesh`` rounds the vertices and triangulates
    again (``retriangulate``) instead of falling back to the raw float64 encoding."""
    M = 2**20 - 1
    g = 256.0 / M
    xc, yc = 400_000, 400_000
    corners = [(0.0, 0.0), (256.0, 0.0), (256.0, 256.0), (0.0, 256.0)]
    v = np.array(corners + [(xc * g, yc * g), ((xc + 1000.3) * g, (yc + 0.3) * g), ((xc + 2000) * g, yc * g)])
    tri = np.array([[4, 6, 5], [0, 1, 6], [0, 6, 4], [1, 2, 6], [6, 2, 5], [5, 2, 3], [5, 3, 4], [4, 3, 0]])
    mesh = Mesh(domain=(0.0, 0.0, 256.0, 256.0), vertices=v, triangles=tri, disc_edges=np.array([[4, 5], [5, 6]]),
                curved_triangles=np.zeros(0, np.int64), curve_endpoints=np.zeros((0, 2), np.int64),
                curve_control_points=np.zeros((0, 4, 2)), curve_degree=np.zeros(0, np.int8),
                disc_edge_piece=np.array([0, 1]), curve_piece=np.zeros(0, np.int64))
    mesh.validate()
    with pytest.raises(FormatError, match="counter-clockwise"):
        decode_mesh(*encode_mesh(mesh, 20), mesh.domain)
    out = roundtrip_mesh(mesh, 20)
    out.validate()
    rounded = np.rint(v / g) * g
    np.testing.assert_array_equal(np.unique(out.vertices, axis=0), np.unique(rounded, axis=0))
    edges = np.sort(out.vertices[out.disc_edges].reshape(-1, 4), axis=0)
    np.testing.assert_array_equal(edges, np.sort(rounded[[[4, 5], [5, 6]]].reshape(-1, 4), axis=0))
    assert mesh_info(*encode_roundtripped(out))["encoding"] in ("derived", "draco")


def test_retriangulate_in_place_keeps_every_curve(mesh):
    from dfc.geometry.triangulate import retriangulate

    out = retriangulate(mesh, mesh.vertices)
    out.validate()
    np.testing.assert_array_equal(out.curve_control_points, mesh.curve_control_points)
    np.testing.assert_array_equal(np.sort(out.triangles[out.curved_triangles], axis=1),
                                  np.sort(mesh.triangles[mesh.curved_triangles], axis=1))  # the same holders


# ----------------------------------------------------------------------------------------------- TOPC (content 1.5)
def _reordered(mesh: Mesh, seed: int) -> Mesh:
    """``mesh`` with its edges and curves shuffled and half its edges turned around."""
    from dataclasses import replace

    rng = np.random.default_rng(seed)
    eo, co = rng.permutation(len(mesh.disc_edges)), rng.permutation(len(mesh.curved_triangles))
    edges = np.array(mesh.disc_edges)[eo]
    turn = rng.random(len(edges)) < 0.5
    edges[turn] = edges[turn][:, ::-1]
    return replace(mesh, disc_edges=edges, disc_edge_piece=np.array(mesh.disc_edge_piece)[eo],
                   curved_triangles=np.array(mesh.curved_triangles)[co], curve_endpoints=np.array(mesh.curve_endpoints)[co],
                   curve_control_points=np.array(mesh.curve_control_points)[co],
                   curve_degree=np.array(mesh.curve_degree)[co], curve_piece=np.array(mesh.curve_piece)[co])


@pytest.mark.parametrize("coding", ["derived", "draco"])
@pytest.mark.parametrize("seed", [0, 1])
def test_topc_keeps_any_order_bit_for_bit(mesh, coding, seed):
    """TOPC stores edges and curves in any order and orientation; the decoded mesh is the stored one bit for bit,
    with -1 for every piece id, and TOPO of the same mesh decodes to the same geometry."""
    view = _reordered(roundtrip_mesh(mesh, 16), seed)
    m, t = encode_roundtripped(view, coding=coding, compact=True)
    assert mesh_info(m, t, "TOPC")["topology"] == "TOPC"
    out = decode_mesh(m, t, view.domain, topology="TOPC")
    _assert_same_mesh(out, view)
    assert np.all(out.disc_edge_piece == -1) and np.all(out.curve_piece == -1)
    plain = decode_mesh(*encode_roundtripped(view, coding=coding), view.domain)
    np.testing.assert_array_equal(plain.curve_control_points, out.curve_control_points)
    assert len(t) < len(encode_roundtripped(view, coding=coding)[1])


@given(seed=st.integers(0, 10_000), bits=st.integers(8, 22))
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_control_points_move_at_most_half_a_vertex_step(seed, bits):
    """``roundtrip_mesh`` puts the control points on the barycentric grid ``tolerance_bary_bits`` picks: on a mesh whose
    vertices are already on the grid, each inner control point moves by at most half a step of the vertex grid."""
    from dfc.io.meshcodec import tolerance_bary_bits

    on_grid = encode_roundtripped(roundtrip_mesh(make_mesh(n_interior=30, n_curves=8, seed=seed), 22), compact=False)
    exact = decode_mesh(*on_grid, (0.0, 0.0, 64.0, 32.0))
    b = tolerance_bary_bits(exact, bits)
    encoded = encode_mesh(exact, 22, compact=True, bary_bits=b)
    if encoded is None:  # encode_mesh's documented refusal: two vertices on one grid point (a random mesh can)
        x0, y0, x1, y1 = exact.domain
        q = np.rint((exact.vertices - [x0, y0]) / [x1 - x0, y1 - y0] * (2**22 - 1))  # the 22-bit vertex grid
        assert len(np.unique(q, axis=0)) < len(q)
        return
    m, t = encoded
    assert mesh_info(m, t, "TOPC")["bary_bits"] == b
    out = decode_mesh(m, t, exact.domain, topology="TOPC", full_validate=False)
    half_step = 64.0 / (2**bits - 1) / 2
    moved = np.hypot(*(out.curve_control_points - exact.curve_control_points).reshape(-1, 2).T)
    assert moved.max() <= half_step * (1 + 1e-9)


def test_hostile_topc_payloads_raise_format_error(mesh):
    """Every byte of a TOPC chunk changed at random, cut short or lengthened: a FormatError naming the chunk or a
    mesh that passes every check, nothing else."""
    view = roundtrip_mesh(mesh, 16)
    m, t = encode_roundtripped(view, compact=True)
    rng = np.random.default_rng(2)
    outcomes = set()
    cases = [t[:-1], t + b"\0", t[:12] + bytes([25]) + t[13:], t[:8] + struct.pack("<I", 99) + t[12:],
             t[:4] + struct.pack("<I", 2**20) + t[8:]]
    for _ in range(300):
        b = bytearray(t)
        i = int(rng.integers(0, len(b)))
        b[i] = int(rng.integers(256))
        cases.append(bytes(b))
    for data in cases:
        try:
            decode_mesh(m, data, view.domain, topology="TOPC")
            outcomes.add("valid")
        except FormatError as exc:
            assert re.match(r"(TOPC|MESH)", str(exc)), exc
            outcomes.add("refused")
    assert "refused" in outcomes
    for data in cases[:5]:
        with pytest.raises(FormatError, match="^TOPC"):
            decode_mesh(m, data, view.domain, topology="TOPC")
