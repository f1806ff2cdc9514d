"""Regenerate the golden files: ``python tests/golden/make_golden.py`` (from the repository root).

valid/tiny.dfield is a file of version 1.0 (FEAT, MLPW) and stays as it was written: it proves that old files keep
decoding, so this script only reads it (and writes it, from the 1.0 chunk encodings, when it is missing).
valid/tiny_coded.dfield holds the same contents with the 1.1 chunks (FEAC, MLPQ) and is frozen the same way (a
file of content version 1.1). valid/tiny_units.dfield (content 1.2) holds them with value_transform "affine": an
offset and scale per channel (``VALUE_MAP``); valid/tiny_filter.dfield (content 1.2) adds the header keys
pixel_size and pixel_filter; both are frozen the same way. valid/tiny_derived.dfield (content 1.3) stores the mesh
with the derived encoding (MESH encoding 2: the triangles rebuilt by the decoder), frozen too.
valid/tiny_compact.dfield (content 1.4) holds the header as HEAC (compressed against the spec's header dictionary)
and the weights as MLPC (no tensor table), frozen too. valid/tiny_topc.dfield (content 1.5) is what the encoder writes
now: HEAC, MLPC and the discontinuities as TOPC (bit-packed); valid/tiny_residual.dfield (container 1.2) adds an rESD
chunk (a residual raster, AVIF-coded), frozen. Each valid file has a .json with
the values a decoder must reproduce. invalid/<rule>.dfield each break the rule their name gives. Regenerate only on
a deliberate format change (update the spec's change log)."""

import json
import struct
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import zstandard

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parents[1]))

from dfc.io.container import decode_dfield, encode_dfield  # noqa: E402
from dfc.io.meshcodec import compress  # noqa: E402
from dfc.io.residual import decode_residual, encode_residual  # noqa: E402
from tests.io.test_container import join, make_contents, split  # noqa: E402

VALUE_MAP = {"value_offset": [1e6, -3e-5, 0.5], "value_scale": [1e-3, 2e-9, 4.0]}
"""The tiny_units file's map: a huge offset on a small scale, a tiny scale, and an ordinary one."""


def _write_valid(name: str, blob: bytes) -> None:
    decoded = decode_dfield(blob)
    (HERE / "valid" / f"{name}.dfield").write_bytes(blob)
    (HERE / "valid" / f"{name}.json").write_text(json.dumps({
        "vertices": decoded.mesh.n_vertices, "features_shape": list(decoded.features.shape),
        "features_sum": float(np.asarray(decoded.features, np.float64).sum()),
        **({"pixel_filter": decoded.header["pixel_filter"]} if "pixel_filter" in decoded.header else {}),
        **({"residual_sum": float(decode_residual(decoded.residual).astype(np.float64).sum())}
           if decoded.residual is not None else {}),
    }, indent=1) + "\n")


def main():
    c = make_contents(n_interior=6, n_side=1, n_disc=2, n_curves=2, seed=0)
    frozen = HERE / "valid" / "tiny.dfield"
    if not frozen.exists():
        _write_valid("tiny", encode_dfield(c, compression_level=19, feature_coding="plain")[0])
    blob = frozen.read_bytes()
    frozen_coded = HERE / "valid" / "tiny_coded.dfield"
    if not frozen_coded.exists():
        _write_valid("tiny_coded", encode_dfield(c, compression_level=19, feature_coding="predicted", weight_bits=6)[0])
    coded = frozen_coded.read_bytes()
    units = replace(c, header={**c.header, "value_transform": "affine", **VALUE_MAP})
    frozen_units = HERE / "valid" / "tiny_units.dfield"
    if not frozen_units.exists():
        _write_valid("tiny_units", encode_dfield(units, compression_level=19, feature_coding="predicted",
                                                 weight_bits=6, mesh_coding="draco")[0])
    units_blob = frozen_units.read_bytes()
    zero_scale = split(units_blob)
    head = json.loads(zstandard.ZstdDecompressor().decompress(zero_scale[0][1]))
    zero_scale[0][1] = compress(json.dumps({**head, "value_scale": [1e-3, 0.0, 4.0]}).encode(), 19)
    x0, y0, x1, y1 = c.header["domain"]
    filtered = replace(c, header={**c.header, "pixel_size": [(x1 - x0) / 16, (y1 - y0) / 16],
                                  "pixel_filter": "gaussian:0.5"})
    if not (HERE / "valid" / "tiny_filter.dfield").exists():
        _write_valid("tiny_filter", encode_dfield(filtered, compression_level=19, weight_bits=6, mesh_coding="draco")[0])
    if not (HERE / "valid" / "tiny_derived.dfield").exists():
        _write_valid("tiny_derived", encode_dfield(c, compression_level=19, weight_bits=6, mesh_coding="derived",
                                                   compact=False)[0])
    derived = (HERE / "valid" / "tiny_derived.dfield").read_bytes()
    assert split(derived)[1][1][0] == 2, "the tiny mesh is no longer stored with the derived encoding"
    compact = (HERE / "valid" / "tiny_compact.dfield").read_bytes()
    assert [t for t, _ in split(compact)] == [b"HEAC", b"MESH", b"TOPO", b"FEAC", b"MLPC", b"DEND"]
    topc = encode_dfield(c, compression_level=19, weight_bits=6)[0]
    assert [t for t, _ in split(topc)] == [b"HEAC", b"MESH", b"TOPC", b"FEAC", b"MLPC", b"DEND"]
    _write_valid("tiny_topc", topc)
    if not (HERE / "valid" / "tiny_residual.dfield").exists():
        ramp = np.linspace(-0.01, 0.02, 6 * 8 * len(c.header["channels"]), dtype=np.float32)
        payload = encode_residual(ramp.reshape(6, 8, -1), 4000)
        _write_valid("tiny_residual", encode_dfield(replace(c, residual=payload), compression_level=19,
                                                    weight_bits=6)[0])
    residual = [list(x) for x in split((HERE / "valid" / "tiny_residual.dfield").read_bytes())]
    assert [t for t, _ in residual] == [b"HEAC", b"MESH", b"TOPC", b"FEAC", b"MLPC", b"rESD", b"DEND"]
    resd_short = [list(x) for x in residual]
    resd_short[5][1] = resd_short[5][1][:-1]
    resd_twice = residual[:6] + residual[5:]
    truncated_topc = [list(x) for x in split(topc)]
    truncated_topc[2][1] = truncated_topc[2][1][:-1]
    short_mlpc = [list(x) for x in split(compact)]
    mlpc = short_mlpc[4][1]
    body = zstandard.ZstdDecompressor().decompress(mlpc[4:]) if mlpc[1] else mlpc[4:]
    short_mlpc[4][1] = mlpc[:1] + b"\0" + mlpc[2:4] + body[:-1]
    dict_id = [list(x) for x in split(compact)]
    dict_id[0][1] = _declare_dictionary_id(dict_id[0][1], 7)
    truncated_mesh = [list(x) for x in split(derived)]
    truncated_mesh[1][1] = truncated_mesh[1][1][:-2]
    unknown = [list(x) for x in split(coded)]
    head = {**decode_dfield(coded).header, "pixel_filter": "lanczos"}
    unknown[0][1] = compress(json.dumps(head, separators=(",", ":")).encode(), 19)
    ch = split(blob)
    cc = split(coded)
    mlpq = cc[4][1]
    raw = bytearray(zstandard.ZstdDecompressor().decompress(mlpq[8:]))
    raw[-7] = 0x80  # the last integer of layers.1.weight (6 bits; three float16 biases follow): -128 is not in ±31
    out_of_range = [list(x) for x in cc]
    out_of_range[4][1] = mlpq[:8] + compress(bytes(raw), 19)
    flip = bytearray(blob)
    flip[40] ^= 0x10
    bad_counts = [list(x) for x in ch]
    bad_counts[1][1] = bad_counts[1][1][:4] + struct.pack("<I", 2**31) + bad_counts[1][1][8:]
    bomb = [list(x) for x in ch]
    bomb[0][1] = compress(b" " * (2**20 + 1), 19)
    invalid = {
        "truncated": blob[:-7],
        "bad_signature": b"\x89PNG" + blob[4:],
        "crc_mismatch": bytes(flip),
        "unknown_critical_chunk": join(ch[:2] + [[b"ZZZZ", b"x"]] + ch[2:]),
        "chunks_out_of_order": join([ch[0], ch[2], ch[1]] + ch[3:]),
        "vertex_count_over_limit": join(bad_counts),
        "header_over_1MiB": join(bomb),
        "container_major_2": blob[:8] + b"\x02\x00" + blob[10:],
        "length_past_end": blob[:16] + struct.pack("<I", 0xFFFFFFF0) + blob[20:],
        "feat_and_feac": join(cc[:4] + [ch[3]] + cc[4:]),
        "mlpq_integer_out_of_range": join(out_of_range),
        "value_scale_not_positive": join(zero_scale),
        "pixel_filter_unknown": join(unknown),
        "derived_mesh_truncated": join(truncated_mesh),
        "mlpc_payload_short": join(short_mlpc),
        "heac_declares_dictionary_id": join(dict_id),
        "topc_stream_truncated": join(truncated_topc),
        "resd_stream_truncated": join(resd_short),
        "resd_twice": join(resd_twice),
    }
    for name, data in invalid.items():
        (HERE / "invalid" / f"{name}.dfield").write_bytes(data)


def _declare_dictionary_id(frame: bytes, dict_id: int) -> bytes:
    """``frame`` (a zstd frame without a dictionary ID) declaring the one-byte ``dict_id`` (RFC 8878 §3.1.1.1)."""
    descriptor = frame[4]
    assert descriptor & 0x03 == 0, "the frame already declares a dictionary ID"
    at = 5 if descriptor & 0x20 else 6  # the ID follows the window descriptor, absent in single-segment frames
    out = frame[:4] + bytes([descriptor | 0x01]) + frame[5:at] + bytes([dict_id]) + frame[at:]
    assert zstandard.get_frame_parameters(out).dict_id == dict_id
    return out


if __name__ == "__main__":
    main()
