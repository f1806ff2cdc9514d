"""Regenerate the golden files: ``python tests/golden/make_golden.py`` (from the repository root).

valid/tiny.dfield (+ .json with the values a decoder must reproduce) and invalid/<rule>.dfield, each
breaking the rule its name gives. Regenerate only on a deliberate format change (update spec change log)."""

import json
import struct
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parents[1]))

from dfc.io.container import decode_dfield, encode_dfield  # noqa: E402
from dfc.io.meshcodec import compress  # noqa: E402
from tests.io.test_container import join, make_contents, split  # noqa: E402


def main():
    c = make_contents(n_interior=6, n_side=1, n_disc=2, n_curves=2, seed=0)
    blob, _ = encode_dfield(c, compression_level=19)
    (HERE / "valid" / "tiny.dfield").write_bytes(blob)
    (HERE / "valid" / "tiny.json").write_text(json.dumps({
        "vertices": c.mesh.n_vertices, "features_shape": list(c.features.shape),
        "features_sum": float(np.asarray(decode_dfield(blob).features, np.float64).sum()),
    }, indent=1) + "\n")
    ch = split(blob)
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
    }
    for name, data in invalid.items():
        (HERE / "invalid" / f"{name}.dfield").write_bytes(data)


if __name__ == "__main__":
    main()
