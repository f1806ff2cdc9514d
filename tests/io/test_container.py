"""The .dfield reader/writer: round trip, info, atomic writes, and a fuzzer that every damaged or hostile
file must meet with exactly one FormatError (or, for mutations that keep the file valid, a valid result)."""

import json
import struct
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch

from dfc.errors import FormatError, MeshError
from dfc.field.layout import build_layout
from dfc.field.quantize import dequantize_weights, quantize_weights
from dfc.io.container import (
    CONTENT_VERSION,
    HEADER_DICTIONARY,
    DfieldContents,
    decode_dfield,
    encode_dfield,
    read_dfield,
    read_dfield_info,
    write_dfield,
)
from dfc.io.meshcodec import compress, roundtrip_mesh

from .test_meshcodec import make_mesh

GOLDEN = Path(__file__).parents[1] / "golden"


def make_contents(S=1, K=5, seed=0, **mesh_kw) -> DfieldContents:
    rng = np.random.default_rng(seed)
    mesh = roundtrip_mesh(make_mesh(seed=seed, **mesh_kw), 16)
    N = build_layout(mesh).n_features
    features = (rng.normal(size=(S, N, K)) * [0.1, 1, 2, 0.01, 5][:K]).astype(np.float32)
    mlp = {"layers.0.weight": rng.normal(size=(16, K)).astype(np.float32), "layers.0.bias": rng.normal(size=16).astype(np.float32),
           "layers.1.weight": rng.normal(size=(3, 16)).astype(np.float32), "layers.1.bias": np.zeros(3, np.float32)}
    header = {"domain": list(mesh.domain), "channels": ["r", "g", "b"], "value_transform": "identity",
              "times": None if S == 1 else [0.5 * i for i in range(S)],
              "model": {"dim": K, "hidden": 16, "layers": 1, "activation": "relu", "oneblob_bins": 0},
              "encoder": {"steps": 10, "seed": seed, "source": "test"}}
    return DfieldContents(header=header, mesh=mesh, features=features, mlp=mlp)


@pytest.fixture(scope="module")
def contents():
    return make_contents()


CODINGS = {"1.0": {"feature_coding": "plain", "compact": False},
           "1.1": {"feature_coding": "predicted", "weight_bits": 6, "compact": False},
           "1.5": {"feature_coding": "predicted", "weight_bits": 6}}
"""Chunk encodings: HEAD + TOPO + FEAT + MLPW (as a 1.0 writer), HEAD + TOPO + FEAC + MLPQ (1.1) or
HEAC + TOPC + FEAC + MLPC (1.5)."""
CHUNK_TYPES = {"1.0": ["HEAD", "TOPO", "FEAT", "MLPW"], "1.1": ["HEAD", "TOPO", "FEAC", "MLPQ"],
               "1.5": ["HEAC", "TOPC", "FEAC", "MLPC"]}


@pytest.fixture(scope="module", params=sorted(CODINGS))
def coding(request):
    return CODINGS[request.param]


@pytest.fixture(scope="module")
def blob(contents, coding):
    return encode_dfield(contents, **coding)[0]


# ----------------------------------------------------------------------------------------------- helpers
def split(data: bytes) -> list[list]:
    """[type, data] per chunk (test-side parser of a known-good file)."""
    out, pos = [], 16
    while pos < len(data):
        (n,) = struct.unpack_from("<I", data, pos)
        out.append([data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]])
        pos += 12 + n + (-n % 4)
    return out


def join(chunks, crc=True) -> bytes:
    """Re-frame chunks with correct padding, CRCs (unless crc=False) and file length: a hostile but
    well-framed file."""
    body = b"".join(struct.pack("<I", len(d)) + t + d + b"\0" * (-len(d) % 4)
                    + struct.pack("<I", zlib.crc32(t + d) if crc else 0) for t, d in chunks)
    return b"\x89DFL\r\n\x1a\n" + struct.pack("<HHI", 1, 0, 16 + len(body)) + body


def boundaries(data: bytes) -> list[int]:
    pos, out = 16, [0, 8, 12, 16]
    while pos < len(data):
        (n,) = struct.unpack_from("<I", data, pos)
        out += [pos + 4, pos + 8, pos + 8 + n, pos + 8 + n + (-n % 4)]
        pos += 12 + n + (-n % 4)
        out.append(pos)
    return out


def outcome(data: bytes) -> str:
    """'refused' for one FormatError, 'valid' for a fully valid result; anything else propagates."""
    try:
        c = decode_dfield(data)
    except FormatError as exc:
        assert "\n" not in str(exc)
        return "refused"
    c.mesh.validate()
    assert np.all(np.isfinite(c.features)) and c.features.ndim == 3
    return "valid"


def with_header(blob, header: bytes | dict, level=3) -> bytes:
    """``blob`` with its header chunk (``HEAD`` or ``HEAC``) holding ``header``."""
    text = header if isinstance(header, bytes) else json.dumps(header).encode()
    ch = split(blob)
    ch[0][1] = compress(text, level, HEADER_DICTIONARY if ch[0][0] == b"HEAC" else None)
    return join(ch)


# ----------------------------------------------------------------------------------------------- round trip
def test_round_trip(tmp_path, contents, coding):
    path = tmp_path / "f.dfield"
    sizes = write_dfield(path, contents, **coding)
    assert sum(sizes.values()) + 16 == path.stat().st_size
    out = read_dfield(path)
    _, scale, _ = __import__("dfc.field.quantize", fromlist=["x"]).quantize_features(contents.features, 8)
    assert out.features.dtype == np.float32 and out.features.shape == contents.features.shape
    assert np.all(np.abs(out.features - contents.features) <= scale / 2 * (1 + 1e-5) + 1e-7)
    assert out.mlp.keys() == contents.mlp.keys()
    for k, w in contents.mlp.items():
        if w.ndim == 2 and "weight_bits" in coding:
            expected = dequantize_weights(*quantize_weights(torch.from_numpy(w), coding["weight_bits"])).numpy()
        else:
            expected = w.astype(np.float16).astype(np.float32)
        assert out.mlp[k].dtype == np.float32 and np.array_equal(out.mlp[k], expected)
    for f in ("vertices", "triangles", "disc_edges", "curved_triangles", "curve_endpoints", "curve_control_points",
              "curve_degree", "disc_edge_piece", "curve_piece"):
        assert np.array_equal(getattr(out.mesh, f), getattr(contents.mesh, f)), f
    assert out.mesh.domain == contents.mesh.domain
    assert {k: v for k, v in out.header.items() if k not in ("format", "content_version")} == contents.header
    assert out.header["content_version"] == list(CONTENT_VERSION)
    version = next(v for v, c in CODINGS.items() if c == coding)
    assert sorted(sizes) == sorted(["MESH", "DEND"] + CHUNK_TYPES[version])


@pytest.mark.parametrize("bits", [1, 4, 12, 16])
@pytest.mark.parametrize("feature_coding", ["plain", "predicted"])
def test_feature_bits(bits, feature_coding, contents):
    out = decode_dfield(encode_dfield(contents, feature_bits=bits, feature_coding=feature_coding)[0])
    span = contents.features.max(axis=(0, 1)) - contents.features.min(axis=(0, 1))
    assert np.all(np.abs(out.features - contents.features) <= span / (2**bits - 1) / 2 * (1 + 1e-4) + 1e-6)


def test_time_axis():
    c = make_contents(S=3)
    for feature_coding in ("plain", "predicted"):
        out = decode_dfield(encode_dfield(c, feature_coding=feature_coding)[0])
        assert out.features.shape[0] == 3 and out.header["times"] == [0.0, 0.5, 1.0]
        assert np.array_equal(out.features, decode_dfield(encode_dfield(c, feature_coding="plain")[0]).features)
    c.header["times"] = [0.0, 0.0, 1.0]
    with pytest.raises(FormatError, match="strictly increasing"):
        encode_dfield(c)
    c.header["times"] = None
    with pytest.raises(FormatError, match="slices"):
        encode_dfield(c)


def test_info_reads_counts_without_decoding(tmp_path, contents):
    path = tmp_path / "f.dfield"
    sizes = write_dfield(path, contents, feature_bits=10, weight_bits=7)
    info = read_dfield_info(path)
    assert info["chunks"] == sizes and info["container_version"] == [1, 1]
    assert info["content_version"] == list(CONTENT_VERSION)
    assert info["mesh"]["vertices"] == contents.mesh.n_vertices and info["mesh"]["bits"] == 16
    assert info["features"] == {"slices": 1, "rows": contents.features.shape[1], "width": 5, "bits": 10,
                                "coding": "predicted, range-coded"}
    assert info["mlp"]["parameters"] == sum(w.size for w in contents.mlp.values()) and info["mlp"]["weight_bits"] == [7]
    assert info["header"]["channels"] == ["r", "g", "b"]


def test_compact_chunks_hold_the_same_contents_in_fewer_bytes(contents):
    """Content 1.4 and 1.5: HEAC, MLPC and TOPC decode to exactly what HEAD, MLPQ and TOPO decode to, and are
    smaller."""
    compact, sizes = encode_dfield(contents, weight_bits=6)
    plain, plain_sizes = encode_dfield(contents, weight_bits=6, compact=False)
    a, b = decode_dfield(compact), decode_dfield(plain)
    assert a.header == b.header and np.array_equal(a.features, b.features)
    assert a.mlp.keys() == b.mlp.keys() and all(np.array_equal(a.mlp[k], b.mlp[k]) for k in b.mlp)
    assert len(a.mesh.curved_triangles) and len(a.mesh.disc_edges)
    for name in ("vertices", "triangles", "disc_edges", "curved_triangles", "curve_endpoints", "curve_control_points",
                 "curve_degree", "disc_edge_piece", "curve_piece"):
        assert np.array_equal(getattr(a.mesh, name), getattr(b.mesh, name)), name
    assert sizes["HEAC"] < plain_sizes["HEAD"] and sizes["MLPC"] < plain_sizes["MLPQ"]
    assert sizes["TOPC"] < plain_sizes["TOPO"]
    assert read_dfield_info_bytes(compact)["mlp"] == read_dfield_info_bytes(plain)["mlp"]


def read_dfield_info_bytes(blob: bytes) -> dict:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.dfield"
        path.write_bytes(blob)
        return read_dfield_info(path)


def test_mlpc_takes_its_tensors_from_the_header_model(contents):
    blob = encode_dfield(contents, weight_bits=6)[0]
    ch, head = split(blob), decode_dfield(blob).header
    for change, match in (({"hidden": 15}, "payload size|declares"), ({"dim": 4}, "dim 4"),
                          ({"hidden": 2**23}, "parameters"), ({"layers": 200}, "tensors"),
                          ({"hidden": 0}, "integers"), ({"hidden": 16.0}, "integers")):
        with pytest.raises(FormatError, match=match):
            decode_dfield(with_header(blob, {**head, "model": {**head["model"], **change}}))
    coding = ch[4][1][1]
    for fixed, match in ((bytes([1, coding, 0, 0]), "weight bits"), (bytes([17, coding, 0, 0]), "weight bits"),
                         (bytes([6, 2, 0, 0]), "coding"), (bytes([6, coding, 1, 0]), "reserved")):
        bad = [list(c) for c in ch]
        bad[4][1] = fixed + ch[4][1][4:]
        with pytest.raises(FormatError, match=match):
            decode_dfield(join(bad))
    other = {**contents.header, "model": {**contents.header["model"], "hidden": 8}}
    with pytest.raises(FormatError, match="implies"):
        encode_dfield(DfieldContents(other, contents.mesh, contents.features, contents.mlp), weight_bits=6)


def test_mlpc_compresses_its_values_only_when_that_is_smaller(contents):
    plain = split(encode_dfield(contents, weight_bits=6)[0])[4][1]  # random weights: a frame would be larger
    flat = {k: np.full_like(w, 0.5) for k, w in contents.mlp.items()}  # one integer and one scale repeated
    blob = encode_dfield(DfieldContents(contents.header, contents.mesh, contents.features, flat), weight_bits=6)[0]
    coded = split(blob)[4][1]
    assert plain[1] == 0 and coded[1] == 1 and len(coded) < len(plain)
    assert all(np.allclose(w, flat[k], rtol=1e-3) for k, w in decode_dfield(blob).mlp.items())


def test_writing_is_deterministic_and_atomic(tmp_path, contents):
    a, b = encode_dfield(contents)[0], encode_dfield(contents)[0]
    assert a == b
    path = tmp_path / "f.dfield"
    path.write_bytes(b"old")
    bad = DfieldContents(contents.header, contents.mesh, contents.features, {"bad name!": np.zeros(2)})
    with pytest.raises(FormatError):
        write_dfield(path, bad)
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["f.dfield"]
    with pytest.raises(OSError):
        write_dfield(tmp_path / "missing" / "f.dfield", contents)


def test_writer_checks_its_inputs(contents):
    for mlp in ({"w": np.full(2, 1e6, np.float32)}, {}):
        with pytest.raises(FormatError):
            encode_dfield(DfieldContents(contents.header, contents.mesh, contents.features, mlp))
    with pytest.raises(FormatError, match="domain"):
        encode_dfield(DfieldContents({**contents.header, "domain": [0, 0, 1, 1]}, contents.mesh, contents.features, contents.mlp))
    with pytest.raises(FormatError, match="finite"):
        encode_dfield(DfieldContents(contents.header, contents.mesh, contents.features * np.nan, contents.mlp))
    bad = make_mesh()
    bad.triangles = bad.triangles[:, [0, 2, 1]]
    with pytest.raises(MeshError):
        encode_dfield(DfieldContents(contents.header, bad, contents.features, contents.mlp))


def test_wrong_feature_row_count_is_refused(contents):
    c = DfieldContents(contents.header, contents.mesh, contents.features[:, :-1], contents.mlp)
    with pytest.raises(FormatError, match="feature rows"):
        decode_dfield(encode_dfield(c, feature_coding="plain")[0])
    with pytest.raises(FormatError, match="feature rows"):  # the predicted coding needs the right layout to write
        encode_dfield(c)


def test_max_bytes(tmp_path, contents):
    path = tmp_path / "f.dfield"
    write_dfield(path, contents)
    with pytest.raises(FormatError, match="exceeds"):
        read_dfield(path, max_bytes=100)


# ----------------------------------------------------------------------------------------------- fuzzing
def test_truncation_everywhere_is_refused(blob):
    cuts = set(boundaries(blob)) | set(range(0, len(blob), 7))
    for n in sorted(cuts - {len(blob)}):
        with pytest.raises(FormatError):
            decode_dfield(blob[:n])


def test_random_bit_flips_and_overwrites_are_refused(blob):
    rng = np.random.default_rng(0)
    for i in range(2000):
        b = bytearray(blob)
        for _ in range(int(rng.integers(1, 4))):
            pos = int(rng.integers(len(b)))
            if i % 2:
                b[pos] ^= 1 << int(rng.integers(8))
            else:
                b[pos] = (b[pos] + int(rng.integers(1, 256))) % 256
        changed = {i for i in range(len(b)) if b[i] != blob[i]}
        # only the minor container version may change and keep the file valid
        assert outcome(bytes(b)) == ("valid" if changed <= {10, 11} else "refused")


@pytest.mark.slow
def test_hostile_chunk_data_with_valid_crcs(blob):
    """Overwrite bytes inside each chunk's data and re-frame with correct CRCs: the decoder's own checks
    must catch everything (or the result must be valid)."""
    rng = np.random.default_rng(1)
    chunks = split(blob)
    seen = {"refused": 0, "valid": 0}
    for i in range(1500):
        ch = [list(c) for c in chunks]
        k = i % 5
        d = bytearray(ch[k][1])
        for _ in range(int(rng.integers(1, 4))):
            pos = int(rng.integers(min(len(d), 64))) if rng.random() < 0.5 else int(rng.integers(len(d)))
            d[pos] = int(rng.integers(256))
        ch[k][1] = bytes(d)
        seen[outcome(join(ch))] += 1
    assert seen["refused"] > 1000


@pytest.mark.parametrize("value", [0xFFFFFFFF, 2**30, 2**30 - 1, 2**24 + 1, 2**20])
def test_huge_counts_are_refused_without_allocating(blob, value):
    """Every u32 count in every chunk's fixed fields, set huge (CRC fixed): refused, small peak memory."""
    chunks = split(blob)
    tracemalloc.start()
    # MLPQ compresses its tensor table; MLPC has none (its fixed fields: bit depth, coding, reserved)
    mlp_counts = {b"MLPW": [0, 4, 68, 72], b"MLPQ": [0, 4], b"MLPC": [0]}[chunks[4][0]]
    for k, offsets in ((1, [4, 8]), (2, [0, 4, 8]), (3, [0, 4]), (4, mlp_counts)):
        for off in offsets:
            ch = [list(c) for c in chunks]
            d = bytearray(ch[k][1])
            d[off:off + 4] = struct.pack("<I", value)
            ch[k][1] = bytes(d)
            with pytest.raises(FormatError):
                decode_dfield(join(ch))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 20 * len(blob) + 2**22


@pytest.mark.parametrize("value", [0xFFFFFFFF, 2**30, 12345])
def test_huge_chunk_lengths_are_refused(blob, value):
    for pos in boundaries(blob)[4::5]:  # each chunk's length field
        if pos + 4 <= len(blob):
            b = bytearray(blob)
            b[pos:pos + 4] = struct.pack("<I", value)
            with pytest.raises(FormatError):
                decode_dfield(bytes(b))


def test_chunk_order_rules(blob):
    ch = split(blob)
    assert outcome(join(ch)) == "valid"
    anc = [b"xTRA", b"some ancillary data"]
    assert outcome(join(ch[:3] + [anc] + ch[3:])) == "valid"
    assert outcome(join(ch[:-1] + [[b"xTRa", b""]] + ch[-1:])) == "valid"  # reserved bit set, ancillary
    bad = {
        "unknown critical": ch[:3] + [[b"XTRA", b"x"]] + ch[3:],
        "ancillary before HEAD": [anc] + ch,
        "duplicate": ch[:2] + ch[1:],
        "swapped": [ch[0], ch[2], ch[1]] + ch[3:],
        "missing": ch[:3] + ch[4:],
        "after DEND": ch + [anc],
        "DEND not empty": ch[:-1] + [[b"DEND", b"x"]],
        "bad type": ch[:3] + [[b"x1RA", b""]] + ch[3:],
    }
    for name, chunks in bad.items():
        with pytest.raises(FormatError):
            decode_dfield(join(chunks))
    with pytest.raises(FormatError, match="CRC"):
        decode_dfield(join(ch[:3] + [anc] + ch[3:], crc=False))


def test_file_header_rules(blob):
    for pos, value in ((0, b"\x88"), (8, b"\x02\x00"), (12, struct.pack("<I", len(blob) + 4))):
        b = bytearray(blob)
        b[pos:pos + len(value)] = value
        with pytest.raises(FormatError):
            decode_dfield(bytes(b))
    assert outcome(blob[:10] + b"\x07\x00" + blob[12:]) == "valid"  # newer minor container version
    ch = split(blob)
    ch.insert(1, [b"xTRA", b"abcde"])  # 5 data bytes, 3 padding bytes
    b = bytearray(join(ch))
    b[16 + 12 + len(ch[0][1]) + (-len(ch[0][1]) % 4) + 8 + 5] = 1
    with pytest.raises(FormatError, match="padding"):
        decode_dfield(bytes(b))


def test_hostile_headers(blob, contents):
    base = decode_dfield(blob).header
    bad = [
        {**base, "format": "png"}, {**base, "content_version": [2, 0]}, {**base, "domain": [0, 0, 0, 1]},
        {**base, "channels": []}, {**base, "channels": ["a", "a"]}, {**base, "value_transform": "sqrt"},
        {**base, "times": [1.0, 2.0]}, {**base, "model": []}, {k: v for k, v in base.items() if k != "domain"},
        [1, 2], {**base, "domain": [0, 0, True, 32]}, {**base, "channels": "rgb"}, {**base, "encoder": 3},
        {**base, "value_transform": "affine"}, {**base, "value_offset": [0, 0, 0], "value_scale": [1, 1, 1]},
        {**base, "value_transform": "affine", "value_offset": [0, 0], "value_scale": [1, 1, 1]},
        {**base, "value_transform": "affine", "value_offset": [0, 0, 0], "value_scale": [1, -1, 1]},
        {**base, "value_transform": "affine", "value_offset": [0, 0, "0"], "value_scale": [1, 1, 1]},
    ]
    for h in bad:  # messages name the header, not HEAD: a 1.4 file stores it in HEAC
        with pytest.raises(FormatError, match="^header: "):
            decode_dfield(with_header(blob, h))
    affine = {**base, "value_transform": "affine", "value_offset": [1e6, 0, -2], "value_scale": [1e-9, 1, 3]}
    assert decode_dfield(with_header(blob, affine)).header["value_offset"] == [1e6, 0, -2]
    text = json.dumps(base).encode()
    for raw in (text.replace(b'"identity"', b"NaN"), b"\xff" + text, text[:-1], b'{"a": 1, "a": 2}',
                b"[" * 100000 + b"]" * 100000, b'{"x": ' + b"[" * 40 + b"]" * 40 + b"}", b" " * (2**20 + 1)):
        with pytest.raises(FormatError):
            decode_dfield(with_header(blob, raw))
    assert decode_dfield(with_header(blob, {**base, "future_key": {"a": 1}})).header["future_key"] == {"a": 1}


def test_golden_files():
    valid = sorted((GOLDEN / "valid").glob("*.dfield"))
    invalid = sorted((GOLDEN / "invalid").glob("*.dfield"))
    assert valid and invalid
    for path in valid:
        expected = json.loads(path.with_suffix(".json").read_text())
        c = read_dfield(path)
        assert c.mesh.n_vertices == expected["vertices"] and c.features.shape == tuple(expected["features_shape"])
        assert np.isclose(float(c.features.sum()), expected["features_sum"], rtol=1e-6)
        assert (c.residual is None) == ("residual_sum" not in expected)
        if c.residual is not None:  # the AVIF streams decode exactly: the sum is the spec's, to rounding
            from dfc.io.residual import decode_residual

            assert np.isclose(decode_residual(c.residual).astype(np.float64).sum(), expected["residual_sum"],
                              rtol=1e-6)
    for path in invalid:
        with pytest.raises(FormatError):
            read_dfield(path)
