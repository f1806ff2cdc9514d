"""Regenerate the golden files: ``python tests/golden/make_golden.py`` (from the repository root).

valid/tiny.dfield is a file of version 1.0 (FEAT, MLPW) and valid/tiny_coded.dfield one of version 1.1 with the same
contents in the 1.1 chunks (FEAC, MLPQ); both stay as they were written: they prove that old files keep decoding, so
this script only reads them (and writes them when missing). valid/tiny_filter.dfield adds the
1.2 header keys pixel_size and pixel_filter. Each valid file has a .json with
the values a decoder must reproduce. invalid/<rule>.dfield each break the rule their name gives. Regenerate only on
a deliberate format change (update the spec's change log)."""

import json
import struct
from dataclasses import replace
import sys
from pathlib import Path

import numpy as np
import zstandard

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parents[1]))

from dfc.io.container import decode_dfield, encode_dfield  # noqa: E402
from dfc.io.meshcodec import compress  # noqa: E402
from tests.io.test_container import join, make_contents, split  # noqa: E402


def _write_valid(name: str, blob: bytes) -> None:
    decoded = decode_dfield(blob)
    (HERE / "valid" / f"{name}.dfield").write_bytes(blob)
    (HERE / "valid" / f"{name}.json").write_text(json.dumps({
        "vertices": decoded.mesh.n_vertices, "features_shape": list(decoded.features.shape),
        "features_sum": float(np.asarray(decoded.features, np.float64).sum()),
        **({"pixel_filter": decoded.header["pixel_filter"]} if "pixel_filter" in decoded.header else {}),
    }, indent=1) + "\n")


def main():
    c = make_contents(n_interior=6, n_side=1, n_disc=2, n_curves=2, seed=0)
    frozen = HERE / "valid" / "tiny.dfield"
    if not frozen.exists():
        _write_valid("tiny", encode_dfield(c, compression_level=19, feature_coding="plain")[0])
    blob = frozen.read_bytes()
    frozen_coded = HERE / "valid" / "tiny_coded.dfield"  # content 1.1: kept as written, like tiny (1.0)
    if not frozen_coded.exists():
        _write_valid("tiny_coded", encode_dfield(c, compression_level=19, feature_coding="predicted", weight_bits=6)[0])
    coded = frozen_coded.read_bytes()
    x0, y0, x1, y1 = c.header["domain"]
    filtered = replace(c, header={**c.header, "pixel_size": [(x1 - x0) / 16, (y1 - y0) / 16],
                                  "pixel_filter": "gaussian:0.5"})
    _write_valid("tiny_filter", encode_dfield(filtered, compression_level=19, weight_bits=6)[0])
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
        "pixel_filter_unknown": join(unknown),
    }
    for name, data in invalid.items():
        (HERE / "invalid" / f"{name}.dfield").write_bytes(data)


if __name__ == "__main__":
    main()
