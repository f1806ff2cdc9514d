"""Reader and writer of ``.dfield`` files (spec/dfield.md): PNG-style typed, length-prefixed, CRC-checked
chunks after a GLB-style 16-byte header.

``write_dfield`` / ``encode_dfield`` build a file from ``DfieldContents``; ``read_dfield`` /
``decode_dfield`` parse one back, checking every MUST of the spec before anything is allocated or
decompressed, and raise exactly one ``FormatError`` on any violation. ``read_dfield_info`` reads the
header and the chunks' fixed-size fields only (for ``dfc stats``). The mesh chunks live in
``dfc.io.meshcodec``, the predicted, range-coded feature bank (``FEAC``) in ``dfc.io.featcodec``.

Content 1.1 adds two critical chunks, each an alternative to a 1.0 chunk in the same place: ``FEAC`` for ``FEAT``
and ``MLPQ`` (integer weight matrices) for ``MLPW``; content 1.4 two more, for a smaller fixed part: ``HEAC`` (the
header JSON compressed against ``HEADER_DICTIONARY``) for ``HEAD`` and ``MLPC`` (``MLPQ`` without its tensor table,
which the header's model implies) for ``MLPQ``; content 1.5 ``TOPC`` (the discontinuities bit-packed, control points
on a coarser barycentric grid, no piece ids) for ``TOPO``. An older decoder refuses them as unknown critical chunks;
this one reads every version.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import zlib
from dataclasses import dataclass

import numpy as np
import torch
import zstandard

from ..errors import FormatError, MeshError
from ..field.quantize import (
    DEFAULT_FEATURE_BITS,
    MAX_FEATURE_BITS,
    MAX_WEIGHT_BITS,
    MIN_WEIGHT_BITS,
    dequantize_features,
    dequantize_weights,
    quantize_features,
    quantize_weights,
)
from ..geometry.mesh import Mesh
from .atomic import write_bytes_atomic
from .meshcodec import compress, decode_mesh, decompress, encode_roundtripped, mesh_info

__all__ = [
    "DfieldContents",
    "write_dfield",
    "read_dfield",
    "with_residual",
    "read_dfield_info",
    "encode_dfield",
    "decode_dfield",
    "SIGNATURE",
    "CONTAINER_VERSION",
    "CONTENT_VERSION",
    "HEADER_DICTIONARY",
]

SIGNATURE = b"\x89DFL\r\n\x1a\n"
CONTAINER_VERSION = (1, 1)
CONTENT_VERSION = (1, 5)
MAX_FILE_BYTES = 2**30
MAX_CHUNK = 2**30 - 1
MAX_HEADER_JSON = 2**20
MAX_JSON_DEPTH = 32
MAX_ROWS, MAX_K, MAX_S, MAX_FEATURE_ELEMENTS = 2**27, 256, 4096, 2**28
MAX_TENSORS, MAX_RANK, MAX_MLP_ELEMENTS = 256, 4, 2**24
MAX_CHANNELS = 64
CRITICAL_ORDER = ((b"HEAD", b"HEAC"), (b"MESH",), (b"TOPO", b"TOPC"), (b"FEAT", b"FEAC"), (b"MLPW", b"MLPQ", b"MLPC"),
                  (b"DEND",))
"""The critical chunks in file order; each position holds exactly one of its alternatives."""
ANCILLARY = (b"rESD",)
"""The ancillary chunks this version reads (at most one of each): the residual raster (§6.9)."""
RESIDUAL_MINOR = 2
"""The minor container version of a file with an ``rESD`` chunk (container 1.2); files without one stay 1.1."""
FEATURE_CODINGS = ("plain", "predicted")
"""``encode_dfield``'s feature codings: ``FEAT`` (zstd of the quantised bank) or ``FEAC`` (``dfc.io.featcodec``)."""

_FILE_HEAD = struct.Struct("<8sHHI")
_FEAT_HEAD = struct.Struct("<IIHBx")
_MLP_HEAD = struct.Struct("<II")
_MLP_RECORD = struct.Struct("<60sI4I")
_MLPC_HEAD = struct.Struct("<BBH")
HEADER_DICTIONARY = (
    b'{"format":"dfield","content_version":[1,4],"domain":[0.0,0.0,512.0,512.0],"channels":["u"],"channels":'
    b'["R","G","B"],"value_transform":"identity","value_transform":"log","times":null,"times":[0.0,"model":{"dim":'
    b'5,"hidden":16,"layers":2,"activation":"tanh","oneblob_bins":0},"encoder":{"software":"dfc 0.1.0","source":'
    b'"auto","refine":0,"steps":1000,"feature_bits":8,"weight_bits":8,"target_bytes":4096,"target_psnr":40.0,'
    b'"seed":1,"pixel_filter":"point","input":"samples ","samples":4096,"input":"FEM ","input":"frames ","input":'
    b'"image 512x512","pixels":262144,"hdr":true,"curves":{"extracted":"from the image (--curves auto)","extractor":'
    b'"dfc.geometry.sources.raster.image_curves","pixel_filter":"gaussian:0.5","curves":4,"pieces":74,"pruned":'
    b'{"curves":4,"dropped":0,"lambda":0.0,"bytes_kept":5482.0,"bytes":5482.0},"refined":{"pixels":1812,'
    b'"misfit_before":0.0,"misfit_after":0.0,"max_move_px":0.4}}},"value_transform":"affine","value_offset":'
    b'[0.0,0.0,0.0],"value_scale":[1.0,1.0,1.0],"times":null,"model":{"dim":5,"hidden":32,"layers":2,"activation":'
    b'"relu","oneblob_bins":0},"encoder":{"software":"dfc 0.1.0","source":"","refine":0,"steps":3000,"hidden":32,'
    b'"feature_bits":10,"pixel_filter":"box:4","input":"image 256x256","pixels":65536,"hdr":false},"pixel_size":'
    b'[1.0,1.0],"pixel_filter":"box","format":"dfield","content_version":[1,4]}'
)
"""Spec Appendix A: the raw-content zstd dictionary ``HEAC`` frames are compressed against (typical header JSON
text; its bytes are part of the format and never change)."""
_NAME = re.compile(r"[A-Za-z0-9_.]{1,60}")
_TRANSFORMS = ("identity", "log", "affine")
_VALUE_MAP_KEYS = ("value_offset", "value_scale")


@dataclass
class DfieldContents:
    """Everything a ``.dfield`` file holds.

    header : dict, the header JSON (spec §5): domain, channels, value_transform, times, model, encoder
    mesh : Mesh, in decoder view (``dfc.io.meshcodec.roundtrip_mesh``)
    features : (S, N, K) float32, feature bank per time slice (S = 1 for a static field)
    mlp : dict name -> float32 array, the decoder's parameters (stored as float16)
    residual : the ``rESD`` chunk's payload (§6.9, ``dfc.io.residual``), or None
    """

    header: dict
    mesh: Mesh
    features: np.ndarray
    mlp: dict[str, np.ndarray]
    residual: bytes | None = None


# ----------------------------------------------------------------------------------------------- header
def _check_header(h, S: int) -> None:
    """Spec §5 checks of a parsed header for a bank of S slices; raise FormatError."""
    if not isinstance(h, dict):
        raise FormatError("header: JSON is not an object")
    missing = {"format", "content_version", "domain", "channels", "value_transform", "times", "model"} - set(h)
    if missing:
        raise FormatError(f"header: missing keys {sorted(missing)}")
    if h["format"] != "dfield":
        raise FormatError(f"header: format is {h['format']!r}, expected 'dfield'")
    cv = h["content_version"]
    if not (isinstance(cv, list) and len(cv) == 2 and all(type(v) is int and v >= 0 for v in cv)):
        raise FormatError("header: content_version must be [major, minor]")
    if cv[0] != CONTENT_VERSION[0]:
        raise FormatError(f"header: unsupported content version {cv[0]}.{cv[1]}")
    d = h["domain"]
    if not (isinstance(d, list) and len(d) == 4 and all(_is_number(v) for v in d) and d[0] < d[2] and d[1] < d[3]):
        raise FormatError("header: domain must be [x0, y0, x1, y1] with x0 < x1 and y0 < y1")
    ch = h["channels"]
    if not (isinstance(ch, list) and 1 <= len(ch) <= MAX_CHANNELS and all(isinstance(c, str) and c for c in ch)
            and len(set(ch)) == len(ch)):
        raise FormatError(f"header: channels must be 1..{MAX_CHANNELS} distinct non-empty strings")
    if h["value_transform"] not in _TRANSFORMS:
        raise FormatError(f"header: value_transform must be one of {_TRANSFORMS}")
    _check_value_map(h)
    times = h["times"]
    if times is None:
        if S != 1:
            raise FormatError(f"header: times is null but the feature bank has {S} slices")
    elif not (isinstance(times, list) and len(times) == S and all(_is_number(t) for t in times)
              and all(a < b for a, b in zip(times, times[1:]))):
        raise FormatError(f"header: times must be {S} finite numbers, strictly increasing")
    size = h.get("pixel_size")
    if size is not None and not (isinstance(size, list) and len(size) == 2 and all(_is_number(v) and v > 0
                                                                                  for v in size)):
        raise FormatError("header: pixel_size must be null or two positive finite numbers")
    if "pixel_filter" in h:
        _check_pixel_filter(h["pixel_filter"])
    if not isinstance(h["model"], dict) or not isinstance(h.get("encoder", {}), dict):
        raise FormatError("header: model and encoder must be objects")


def _check_pixel_filter(spec) -> None:
    """Spec §5: ``pixel_filter`` is a filter spec string (``dfc.pixel_filter.parse``)."""
    from ..errors import InputError
    from ..pixel_filter import parse

    try:
        parse(spec)
    except InputError as e:
        raise FormatError(f"header: pixel_filter: {e}") from None


def _check_value_map(h) -> None:
    """Spec §5: ``value_offset`` and ``value_scale`` (C finite numbers, scales > 0) with ``"affine"``, else absent."""
    present = [k for k in _VALUE_MAP_KEYS if k in h]
    if h["value_transform"] != "affine":
        if present:
            raise FormatError(f"header: {present[0]} is only allowed with value_transform 'affine'")
        return
    n = len(h["channels"])
    for key in _VALUE_MAP_KEYS:
        v = h.get(key)
        if not (isinstance(v, list) and len(v) == n and all(_is_number(x) for x in v)):
            raise FormatError(f"header: value_transform 'affine' needs {key}: {n} finite numbers, one per channel")
    if not all(x > 0 for x in h["value_scale"]):
        raise FormatError("header: value_scale must be > 0")


def _is_number(v) -> bool:
    return type(v) in (int, float) and math.isfinite(v)


def _no_duplicates(pairs):
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        raise FormatError("header: JSON repeats a key")
    return dict(pairs)


def _reject_constant(name):
    raise FormatError(f"header: JSON contains {name}, which is not JSON")


def _parse_header(ctype: bytes, data) -> dict:
    """The header JSON of a ``HEAD`` or ``HEAC`` chunk (spec §5), parsed but not checked (``_check_header``)."""
    chunk, dictionary, data = ctype.decode(), HEADER_DICTIONARY if ctype == b"HEAC" else None, bytes(data)
    text = decompress(data, _frame_size(data, MAX_HEADER_JSON, chunk), chunk, dictionary)
    # bound json.loads' recursion first; brackets inside strings only make this over-count
    if _bracket_depth(text) > MAX_JSON_DEPTH:
        raise FormatError(f"header: JSON nested deeper than {MAX_JSON_DEPTH}")
    try:
        h = json.loads(text.decode("utf-8"), object_pairs_hook=_no_duplicates, parse_constant=_reject_constant)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"header: not UTF-8 JSON ({exc})") from None
    return h


def _bracket_depth(text: bytes) -> int:
    """Maximum running depth of [ and { minus ] and } (ignores strings: an upper bound on the JSON depth)."""
    b = np.frombuffer(text, np.uint8)
    step = np.isin(b, (ord("["), ord("{"))).astype(np.int64) - np.isin(b, (ord("]"), ord("}"))).astype(np.int64)
    return int(np.cumsum(step).max(initial=0))


def _frame_size(frame: bytes, limit: int, chunk: str) -> int:
    """Declared content size of a zstd frame whose size is not known in advance, checked against ``limit``."""
    try:
        size = zstandard.get_frame_parameters(frame).content_size
    except zstandard.ZstdError:
        raise FormatError(f"{chunk}: zstd frame header is corrupt") from None
    if size > limit:
        raise FormatError(f"{chunk}: declared size {size} exceeds the limit {limit}")
    return size


# ----------------------------------------------------------------------------------------------- framing
def _chunk(ctype: bytes, data: bytes) -> bytes:
    pad = b"\0" * (-len(data) % 4)
    return struct.pack("<I", len(data)) + ctype + data + pad + struct.pack("<I", zlib.crc32(ctype + data))


def _split_chunks(buf: bytes) -> tuple[dict[bytes, memoryview], dict[str, int]]:
    """Check the file header and framing (spec §2, §3); return the data of the critical chunks and of the known
    ancillary ones (``ANCILLARY``), and bytes per chunk."""
    if len(buf) < _FILE_HEAD.size:
        raise FormatError("file is shorter than the 16-byte .dfield header")
    sig, major, minor, length = _FILE_HEAD.unpack_from(buf)
    if sig != SIGNATURE:
        raise FormatError("not a .dfield file (bad signature)")
    if major != CONTAINER_VERSION[0]:
        raise FormatError(f"unsupported container version {major}.{minor}")
    if length != len(buf):
        raise FormatError(f"file length field says {length} bytes, the file has {len(buf)} (truncated?)")
    view = memoryview(buf)
    pos, chunks, sizes, expect = _FILE_HEAD.size, {}, {}, 0
    while pos < len(buf):
        if len(buf) - pos < 12:
            raise FormatError(f"chunk at offset {pos} is truncated")
        (n,) = struct.unpack_from("<I", buf, pos)
        ctype = bytes(buf[pos + 4:pos + 8])
        name = ctype.decode("latin-1")
        if not all(65 <= c <= 90 or 97 <= c <= 122 for c in ctype):
            raise FormatError(f"chunk at offset {pos} has an invalid type {ctype!r}")
        padded = n + (-n % 4)
        if n > MAX_CHUNK or padded + 12 > len(buf) - pos:
            raise FormatError(f"{name}: length {n} runs past the end of the file")
        data = view[pos + 8:pos + 8 + n]
        if any(buf[pos + 8 + n:pos + 8 + padded]):
            raise FormatError(f"{name}: padding is not zero")
        (crc,) = struct.unpack_from("<I", buf, pos + 8 + padded)
        if zlib.crc32(data, zlib.crc32(ctype)) != crc:
            raise FormatError(f"{name}: CRC mismatch (corrupt file)")
        if expect == len(CRITICAL_ORDER):
            raise FormatError(f"{name}: chunk after DEND")
        if ctype[0] & 0x20:  # ancillary
            if expect == 0:
                raise FormatError(f"{name}: ancillary chunk before HEAD")
            if ctype in ANCILLARY:
                if ctype in chunks:
                    raise FormatError(f"{name}: more than one")
                chunks[ctype] = data
        elif ctype not in CRITICAL_ORDER[expect]:
            known = any(ctype in alternatives for alternatives in CRITICAL_ORDER)
            raise FormatError(f"{name}: {'critical chunk out of order' if known else 'unknown critical chunk'}"
                              f", expected {_names(CRITICAL_ORDER[expect])}")
        else:
            chunks[ctype] = data
            expect += 1
        sizes[name] = sizes.get(name, 0) + 12 + padded
        pos += 12 + padded
    if expect < len(CRITICAL_ORDER):
        raise FormatError(f"file ends before chunk {_names(CRITICAL_ORDER[expect])} (truncated?)")
    if len(chunks[b"DEND"]):
        raise FormatError("DEND: chunk is not empty")
    return chunks, sizes


def _names(alternatives: tuple[bytes, ...]) -> str:
    return " or ".join(t.decode() for t in alternatives)


def _one(chunks: dict, alternatives: tuple[bytes, ...]) -> tuple[bytes, memoryview]:
    """(type, data) of the chunk present among ``alternatives`` (``_split_chunks`` guarantees exactly one)."""
    ctype = next(t for t in alternatives if t in chunks)
    return ctype, chunks[ctype]


def _read(path, max_bytes: int) -> bytes:
    size = os.stat(path).st_size
    if size > max_bytes:
        raise FormatError(f"{os.fspath(path)}: {size} bytes exceeds the limit of {max_bytes}")
    with open(path, "rb") as f:
        return f.read(max_bytes + 1)


# ----------------------------------------------------------------------------------------------- FEAT / MLPW
def _feat_info(data, chunk: str = "FEAT") -> dict:
    if len(data) < _FEAT_HEAD.size:
        raise FormatError(f"{chunk}: chunk shorter than its fixed fields")
    S, N, K, bits = _FEAT_HEAD.unpack_from(data)
    if data[11]:
        raise FormatError(f"{chunk}: reserved field is not zero")
    if not (1 <= S <= MAX_S and 1 <= N <= MAX_ROWS and 1 <= K <= MAX_K and S * N * K <= MAX_FEATURE_ELEMENTS):
        raise FormatError(f"{chunk}: bank shape ({S}, {N}, {K}) outside the limits")
    if not 1 <= bits <= MAX_FEATURE_BITS:
        raise FormatError(f"{chunk}: {bits} bits, expected 1..{MAX_FEATURE_BITS}")
    if len(data) < _FEAT_HEAD.size + 8 * K:
        raise FormatError(f"{chunk}: chunk too short for its scales and offsets")
    return {"slices": S, "rows": N, "width": K, "bits": bits}


def _decode_features(data) -> np.ndarray:
    info = _feat_info(data)
    S, N, K, bits = info["slices"], info["rows"], info["width"], info["bits"]
    scale = np.frombuffer(data, "<f4", K, _FEAT_HEAD.size).astype(np.float32)
    offset = np.frombuffer(data, "<f4", K, _FEAT_HEAD.size + 4 * K).astype(np.float32)
    if not (np.all(np.isfinite(scale)) and np.all(scale > 0) and np.all(np.isfinite(offset))):
        raise FormatError("FEAT: scales must be finite and positive, offsets finite")
    dtype = "<u1" if bits <= 8 else "<u2"
    n = S * K * N * np.dtype(dtype).itemsize
    raw = decompress(bytes(data[_FEAT_HEAD.size + 8 * K:]), n, "FEAT")
    q = np.frombuffer(raw, dtype).reshape(S, K, N)
    if q.max() > 2**bits - 1:
        raise FormatError(f"FEAT: quantised value above 2**{bits} - 1")
    with np.errstate(over="ignore", invalid="ignore"):
        F = dequantize_features(q.transpose(0, 2, 1), scale, offset)
    if not np.all(np.isfinite(F)):
        raise FormatError("FEAT: a dequantised feature is not finite")
    return np.ascontiguousarray(F)


def _encode_features(F: np.ndarray, bits: int, level: int) -> bytes:
    q, scale, offset = quantize_features(F, bits)
    S, N, K = F.shape
    body = np.ascontiguousarray(q.transpose(0, 2, 1)).astype("<u1" if bits <= 8 else "<u2").tobytes()
    return (_FEAT_HEAD.pack(S, N, K, bits) + scale.astype("<f4").tobytes() + offset.astype("<f4").tobytes()
            + compress(body, level))


def _mlp_table(data, chunk: str = "MLPW") -> list[tuple[str, tuple[int, ...]]]:
    if len(data) < _MLP_HEAD.size:
        raise FormatError(f"{chunk}: chunk shorter than its fixed fields")
    n, total = _MLP_HEAD.unpack_from(data)
    if not 1 <= n <= MAX_TENSORS or total > MAX_MLP_ELEMENTS:
        raise FormatError(f"{chunk}: {n} tensors / {total} elements outside the limits")
    if len(data) < _MLP_HEAD.size + n * _MLP_RECORD.size:
        raise FormatError(f"{chunk}: chunk too short for its tensor table")
    table, count = [], 0
    for i in range(n):
        raw_name, rank, *dims = _MLP_RECORD.unpack_from(data, _MLP_HEAD.size + i * _MLP_RECORD.size)
        name = raw_name.rstrip(b"\0")
        if b"\0" in name or not _NAME.fullmatch(name.decode("latin-1")):
            raise FormatError(f"{chunk}: tensor {i} has an invalid name")
        if rank > MAX_RANK or any(d < 1 for d in dims[:rank]) or any(dims[rank:]):
            raise FormatError(f"{chunk}: tensor {name.decode()} has an invalid shape")
        shape = tuple(dims[:rank])
        count += math.prod(shape)
        if count > total:
            raise FormatError(f"{chunk}: tensor sizes exceed the declared element count")
        table.append((name.decode("ascii"), shape))
    if count != total or len({t[0] for t in table}) != n:
        raise FormatError(f"{chunk}: element count mismatch or repeated tensor name")
    return table


def _decode_mlp(data) -> dict[str, np.ndarray]:
    table = _mlp_table(data)
    total = sum(math.prod(s) for _, s in table)
    raw = decompress(bytes(data[_MLP_HEAD.size + len(table) * _MLP_RECORD.size:]), 2 * total, "MLPW")
    values = np.frombuffer(raw, "<f2")
    if not np.all(np.isfinite(values)):
        raise FormatError("MLPW: a weight is not finite")
    out, pos = {}, 0
    for name, shape in table:
        size = math.prod(shape)
        out[name] = values[pos:pos + size].astype(np.float32).reshape(shape)
        pos += size
    return out


def _encode_mlp(mlp: dict[str, np.ndarray], level: int) -> bytes:
    table, flat = _mlp_records(mlp)
    return table + compress(flat.tobytes(), level)


def _mlp_records(mlp: dict[str, np.ndarray]) -> tuple[bytes, np.ndarray]:
    """(``MLPW``'s fixed fields and tensor table, spec §6.4; every value as float16, flattened) of ``mlp``, whose
    names, shapes, sizes and float16 finiteness are checked (``FormatError``)."""
    if not 1 <= len(mlp) <= MAX_TENSORS:
        raise FormatError(f"cannot write: the MLP needs 1..{MAX_TENSORS} tensors, got {len(mlp)}")
    records, values = [], []
    for name, w in mlp.items():
        w = np.asarray(w, dtype=np.float32)
        if not (isinstance(name, str) and _NAME.fullmatch(name)) or w.ndim > MAX_RANK or 0 in w.shape:
            raise FormatError(f"cannot write: MLP tensor {name!r} {w.shape} has an invalid name or shape")
        with np.errstate(over="ignore"):
            h = w.astype("<f2")
        if not np.all(np.isfinite(h)):
            raise FormatError(f"cannot write: MLP tensor {name!r} is not finite in float16")
        dims = list(w.shape) + [0] * (MAX_RANK - w.ndim)
        records.append(_MLP_RECORD.pack(name.encode("ascii"), w.ndim, *dims))
        values.append(h.ravel())
    flat = np.concatenate(values)
    if flat.size > MAX_MLP_ELEMENTS:
        raise FormatError(f"cannot write: the MLP has {flat.size} weights, the limit is {MAX_MLP_ELEMENTS}")
    return _MLP_HEAD.pack(len(mlp), flat.size) + b"".join(records), flat


def _mlpq_width(bits: int) -> int:
    """Bytes per stored value of an ``MLPQ`` tensor of ``bits`` (0: float16)."""
    return 2 if bits == 0 or bits > 8 else 1


def _mlpq_table(data) -> tuple[bytes, list[tuple[str, tuple[int, ...]]], list[int], int]:
    """(decompressed payload, tensor table, bits per tensor (0: float16), offset of the scales) of ``MLPQ`` data."""
    if len(data) < _MLP_HEAD.size:
        raise FormatError("MLPQ: chunk shorter than its fixed fields")
    n, total = _MLP_HEAD.unpack_from(data)
    if not 1 <= n <= MAX_TENSORS or total > MAX_MLP_ELEMENTS:
        raise FormatError(f"MLPQ: {n} tensors / {total} elements outside the limits")
    payload = bytes(data[_MLP_HEAD.size:])
    raw = decompress(payload, _frame_size(payload, (_MLP_RECORD.size + 1) * n + 4 * total, "MLPQ"), "MLPQ")
    table = _mlp_table(_MLP_HEAD.pack(n, total) + raw[:_MLP_RECORD.size * n], "MLPQ")
    pos = _MLP_RECORD.size * n
    if len(raw) < pos + n:
        raise FormatError("MLPQ: payload too short for its bit depths")
    bits = list(raw[pos:pos + n])
    for b, (name, shape) in zip(bits, table):
        if b and not (MIN_WEIGHT_BITS <= b <= MAX_WEIGHT_BITS and len(shape) == 2):
            raise FormatError(f"MLPQ: tensor {name} has {b} bits (integers need 2..16 bits and rank 2)")
    return raw, table, bits, pos + n


def _decode_mlpq(data) -> dict[str, np.ndarray]:
    raw, table, bits, pos = _mlpq_table(data)
    return _integer_tensors(raw, pos, table, bits, "MLPQ")


def _integer_tensors(raw: bytes, pos: int, table, bits: list[int], chunk: str) -> dict[str, np.ndarray]:
    """Name -> float32 array of the scales and values at ``raw[pos:]`` (spec §6.7, from the scales on; the rest of
    ``raw`` must be exactly these) of the tensors ``table`` with ``bits`` per tensor (0: float16)."""
    n_scales = sum(shape[0] for b, (_, shape) in zip(bits, table) if b)
    if len(raw) != pos + 2 * n_scales + sum(_mlpq_width(b) * math.prod(s) for b, (_, s) in zip(bits, table)):
        raise FormatError(f"{chunk}: payload size does not match its tensors")
    scales = np.frombuffer(raw, "<f2", n_scales, pos).astype(np.float32)
    if not (np.all(np.isfinite(scales)) and np.all(scales > 0)):
        raise FormatError(f"{chunk}: a scale is not finite and positive")
    pos += 2 * n_scales
    out, at_scale = {}, 0
    for b, (name, shape) in zip(bits, table):
        size = math.prod(shape)
        if b == 0:
            values = np.frombuffer(raw, "<f2", size, pos).astype(np.float32)
        else:
            q = np.frombuffer(raw, "<i1" if b <= 8 else "<i2", size, pos).astype(np.int32)
            if np.abs(q).max(initial=0) > 2 ** (b - 1) - 1:
                raise FormatError(f"{chunk}: tensor {name} holds an integer outside ±(2**{b - 1} - 1)")
            scale = scales[at_scale:at_scale + shape[0]]
            at_scale += shape[0]
            values = dequantize_weights(torch.from_numpy(q.reshape(shape)), torch.from_numpy(scale)).numpy()
        if not np.all(np.isfinite(values)):
            raise FormatError(f"{chunk}: tensor {name} has a value that is not finite")
        out[name] = values.reshape(shape)
        pos += _mlpq_width(b) * size
    return out


def _encode_mlpq(mlp: dict[str, np.ndarray], weight_bits: int, level: int) -> bytes:
    """``MLPQ`` data: rank-2 tensors as ``weight_bits``-bit integers per row, the others as float16."""
    table, _ = _mlp_records(mlp)
    bits, body = _integer_body(mlp, weight_bits)
    return table[:_MLP_HEAD.size] + compress(table[_MLP_HEAD.size:] + bytes(bits) + body, level)


def _integer_body(mlp: dict[str, np.ndarray], weight_bits: int) -> tuple[list[int], bytes]:
    """(bits per tensor, scales then values, spec §6.7) of ``mlp``: rank-2 tensors as ``weight_bits``-bit integers
    per row, the others as float16."""
    bits, scales, values = [], [], []
    for w in mlp.values():
        w = np.asarray(w, dtype=np.float32)
        if w.ndim == 2:
            q, scale = quantize_weights(torch.from_numpy(w), weight_bits)
            bits.append(weight_bits)
            scales.append(scale.numpy().astype("<f2").tobytes())
            values.append(q.numpy().astype("<i1" if weight_bits <= 8 else "<i2").tobytes())
        else:
            bits.append(0)
            values.append(w.astype("<f2").tobytes())
    return bits, b"".join(scales) + b"".join(values)


# ----------------------------------------------------------------------------------------------- MLPC
def _mlpc_table(header: dict, width: int) -> list[tuple[str, tuple[int, ...]]]:
    """The decoder tensors (name, shape) that the header's ``model`` and ``channels`` imply (field spec §7), in file
    order, for a feature bank ``width`` wide; ``FormatError`` when the model is malformed or outside the limits."""
    m = header["model"]
    dims = [m.get(k) for k in ("dim", "hidden", "layers", "oneblob_bins")]
    if not (all(type(v) is int for v in dims) and dims[0] >= 1 and dims[1] >= 1 and dims[2] >= 0 and dims[3] >= 0):
        raise FormatError("header: model needs integers dim >= 1, hidden >= 1, layers >= 0, oneblob_bins >= 0")
    dim, hidden, layers, bins = dims
    if dim != width:
        raise FormatError(f"header: model dim {dim}, the feature bank is {width} wide")
    if 2 * (layers + 1) > MAX_TENSORS:
        raise FormatError(f"MLPC: {2 * (layers + 1)} tensors, the limit is {MAX_TENSORS}")
    sizes = [dim + 2 * bins] + [hidden] * layers + [len(header["channels"])]
    if sum(o * (i + 1) for i, o in zip(sizes, sizes[1:])) > MAX_MLP_ELEMENTS:
        raise FormatError(f"MLPC: the model has more than {MAX_MLP_ELEMENTS} parameters")
    return [entry for i, (n_in, n_out) in enumerate(zip(sizes, sizes[1:]))
            for entry in ((f"layers.{i}.weight", (n_out, n_in)), (f"layers.{i}.bias", (n_out,)))]


def _mlpc_head(data) -> int:
    """The weight bits of ``MLPC`` data, its fixed fields checked."""
    if len(data) < _MLPC_HEAD.size:
        raise FormatError("MLPC: chunk shorter than its fixed fields")
    bits, coding, reserved = _MLPC_HEAD.unpack_from(data)
    if not MIN_WEIGHT_BITS <= bits <= MAX_WEIGHT_BITS:
        raise FormatError(f"MLPC: {bits} weight bits, expected {MIN_WEIGHT_BITS}..{MAX_WEIGHT_BITS}")
    if coding > 1 or reserved:
        raise FormatError("MLPC: unknown value coding or reserved field not zero")
    return bits


def _decode_mlpc(data, table) -> dict[str, np.ndarray]:
    """``MLPC`` data -> name -> float32 array of the tensors ``table`` (``_mlpc_table``)."""
    weight_bits = _mlpc_head(data)
    bits = [weight_bits if len(shape) == 2 else 0 for _, shape in table]
    size = sum(2 * shape[0] * (b > 0) + _mlpq_width(b) * math.prod(shape) for b, (_, shape) in zip(bits, table))
    payload = bytes(data[_MLPC_HEAD.size:])
    raw = decompress(payload, size, "MLPC") if data[1] else payload
    return _integer_tensors(raw, 0, table, bits, "MLPC")


def _encode_mlpc(mlp: dict[str, np.ndarray], table, weight_bits: int, level: int) -> bytes:
    """``MLPC`` data for the tensors ``table`` the header implies: ``MLPQ``'s scales and values, zstd-compressed
    only when that is smaller."""
    _mlp_records(mlp)  # checks names, shapes and finiteness
    if {name: tuple(np.shape(w)) for name, w in mlp.items()} != dict(table):
        raise FormatError(f"cannot write: MLP tensors {sorted(mlp)} are not the ones the header's model implies")
    _, body = _integer_body({name: mlp[name] for name, _ in table}, weight_bits)
    packed = compress(body, level)
    coded = len(packed) < len(body)
    return _MLPC_HEAD.pack(weight_bits, int(coded), 0) + (packed if coded else body)


# ----------------------------------------------------------------------------------------------- public API
def encode_dfield(contents: DfieldContents, *, feature_bits: int = DEFAULT_FEATURE_BITS,
                  compression_level: int = 19, feature_coding: str = "predicted", weight_bits: int | None = None,
                  mesh_validated: bool = False, mesh_coding: str = "derived",
                  compact: bool = True) -> tuple[bytes, dict[str, int]]:
    """Serialise ``contents``; return (file bytes, bytes per chunk type incl. framing; the file adds 16).

    ``contents.mesh`` should be ``roundtrip_mesh(mesh, bits)``, the view the features were fitted on: it is
    stored with Draco at the precision it came from, and any other valid mesh losslessly (raw), so the file
    always decodes to exactly ``contents.mesh``. ``feature_bits`` in 1..16; ``compression_level`` is the
    zstd level. ``feature_coding``: "predicted" writes ``FEAC`` (``dfc.io.featcodec``), "plain" the 1.0 ``FEAT``.
    ``weight_bits``: None writes every MLP tensor as float16 (``MLPW``), 2..16 the weight matrices as integers of
    that many bits per row (``MLPQ``; ``dfc.field.quantize.quantize_weights``). Raises ``FormatError`` when the
    contents would make an invalid file and ``MeshError`` when the mesh is invalid. ``mesh_validated``: the mesh
    came from ``roundtrip_mesh`` (validated there), so it is not validated again (``encode_roundtripped``).
    ``mesh_coding``: "derived" stores the mesh with the derived encoding when that is smaller and exact (content
    1.3), "draco" never (``dfc.io.meshcodec.encode_roundtripped``). ``compact``: the header as ``HEAC``, integer
    weights as ``MLPC`` (content 1.4) and the topology as ``TOPC`` (content 1.5); False writes ``HEAD``, ``MLPQ`` and
    ``TOPO``, as content 1.3 did.
    """
    F = np.asarray(contents.features)
    if F.ndim != 3 or not np.issubdtype(F.dtype, np.floating) or not np.all(np.isfinite(F)):
        raise FormatError(f"cannot write: features must be a finite (S, N, K) float array, got {F.dtype} {F.shape}")
    header = {**contents.header, "format": "dfield", "content_version": list(CONTENT_VERSION)}
    _check_header(header, F.shape[0])
    if tuple(float(v) for v in header["domain"]) != tuple(float(v) for v in contents.mesh.domain):
        raise FormatError(f"cannot write: header domain {header['domain']} differs from the mesh's")
    if not 1 <= feature_bits <= MAX_FEATURE_BITS:
        raise FormatError(f"cannot write: feature_bits must be in 1..{MAX_FEATURE_BITS}, got {feature_bits}")
    if feature_coding not in FEATURE_CODINGS:
        raise FormatError(f"cannot write: feature_coding must be one of {FEATURE_CODINGS}, got {feature_coding!r}")
    if weight_bits is not None and not MIN_WEIGHT_BITS <= weight_bits <= MAX_WEIGHT_BITS:
        raise FormatError(f"cannot write: weight_bits must be None or in {MIN_WEIGHT_BITS}..{MAX_WEIGHT_BITS}, "
                          f"got {weight_bits}")
    try:
        text = json.dumps(header, allow_nan=False, ensure_ascii=False, separators=(",", ":")).encode("utf-8")
    except (TypeError, ValueError) as exc:
        raise FormatError(f"cannot write: header is not JSON-serialisable ({exc})") from None
    mesh_data, topo_data = encode_roundtripped(contents.mesh, level=compression_level, validated=mesh_validated,
                                               coding=mesh_coding, compact=compact)
    if feature_coding == "predicted":
        from .featcodec import encode_feac

        features = (b"FEAC", encode_feac(F.astype(np.float32), feature_bits, _layout(contents.mesh)))
    else:
        features = (b"FEAT", _encode_features(F.astype(np.float32), feature_bits, compression_level))
    if weight_bits is None:
        mlp = (b"MLPW", _encode_mlp(contents.mlp, compression_level))
    elif compact:
        mlp = (b"MLPC", _encode_mlpc(contents.mlp, _mlpc_table(header, F.shape[2]), weight_bits, compression_level))
    else:
        mlp = (b"MLPQ", _encode_mlpq(contents.mlp, weight_bits, compression_level))
    head = ((b"HEAC", compress(text, compression_level, HEADER_DICTIONARY)) if compact
            else (b"HEAD", compress(text, compression_level)))
    parts = [head, (b"MESH", mesh_data), (b"TOPC" if compact else b"TOPO", topo_data), features, mlp,
             *([(b"rESD", bytes(contents.residual))] if contents.residual is not None else []), (b"DEND", b"")]
    body = b"".join(_chunk(t, d) for t, d in parts)
    sizes = {t.decode(): 12 + len(d) + (-len(d) % 4) for t, d in parts}
    minor = CONTAINER_VERSION[1] if contents.residual is None else RESIDUAL_MINOR
    return _file(body, minor), sizes


def _file(body: bytes, minor: int) -> bytes:
    if _FILE_HEAD.size + len(body) > MAX_FILE_BYTES:
        raise FormatError("cannot write: the file would exceed 1 GiB")
    return _FILE_HEAD.pack(SIGNATURE, CONTAINER_VERSION[0], minor, _FILE_HEAD.size + len(body)) + body


def with_residual(buf: bytes, payload: bytes) -> tuple[bytes, int]:
    """(the file ``buf`` with an ``rESD`` chunk holding ``payload`` before its ``DEND``, the chunk's bytes): the
    critical chunks stay as they are, byte for byte. ``buf`` is a whole file ``encode_dfield`` wrote without one."""
    end = len(buf) - 12
    if buf[end + 4:end + 8] != b"DEND" or "rESD" in _split_chunks(buf)[1]:
        raise ValueError("with_residual takes a whole .dfield file without an rESD chunk")
    chunk = _chunk(b"rESD", payload)
    return _file(buf[_FILE_HEAD.size:end] + chunk + buf[end:], RESIDUAL_MINOR), len(chunk)


def write_dfield(path: str | os.PathLike, contents: DfieldContents, **options) -> dict[str, int]:
    """Write ``contents`` to ``path`` atomically; return bytes per chunk type (``options`` and sizes: see
    ``encode_dfield``)."""
    data, sizes = encode_dfield(contents, **options)
    write_bytes_atomic(path, data)
    return sizes


def decode_dfield(buf: bytes, *, validate_mesh: bool = True) -> DfieldContents:
    """Parse a whole ``.dfield`` file held in memory; raise ``FormatError`` on any violation of the spec.
    ``validate_mesh=False`` skips ``Mesh.validate`` (only for bytes just written from a validated mesh)."""
    chunks, _ = _split_chunks(buf)
    feat_type, feat = _one(chunks, CRITICAL_ORDER[3])
    info = _feat_info(feat, feat_type.decode())
    header = _parse_header(*_one(chunks, CRITICAL_ORDER[0]))
    _check_header(header, info["slices"])
    topo_type, topo = _one(chunks, CRITICAL_ORDER[2])
    mesh = decode_mesh(bytes(chunks[b"MESH"]), bytes(topo), header["domain"], full_validate=validate_mesh,
                       topology=topo_type.decode())
    layout = _layout(mesh)
    if layout.n_features != info["rows"]:
        raise FormatError(f"{feat_type.decode()}: {info['rows']} feature rows, the mesh's layout has "
                          f"{layout.n_features}")
    if feat_type == b"FEAC":
        from .featcodec import decode_feac

        features = decode_feac(feat, info, layout)
    else:
        features = _decode_features(feat)
    mlp_type, mlp = _one(chunks, CRITICAL_ORDER[4])
    if mlp_type == b"MLPC":
        weights = _decode_mlpc(mlp, _mlpc_table(header, info["width"]))
    else:
        weights = _decode_mlp(mlp) if mlp_type == b"MLPW" else _decode_mlpq(mlp)
    residual = chunks.get(b"rESD")
    if residual is not None:  # its framing; the AVIF streams decode where the field is built (dfc.io.dfield)
        from .residual import payload_streams

        payload_streams(bytes(residual))
    return DfieldContents(header=header, mesh=mesh, features=features, mlp=weights,
                          residual=None if residual is None else bytes(residual))


def _layout(mesh: Mesh):
    """The feature layout of a decoded mesh (spec §6.3: it fixes the bank's rows); ``FormatError`` when none exists."""
    from ..field.layout import build_layout

    try:
        return build_layout(mesh)
    except MeshError as exc:
        raise FormatError(f"MESH: no feature layout for the decoded mesh: {exc}") from None


def read_dfield(path: str | os.PathLike, *, max_bytes: int = MAX_FILE_BYTES) -> DfieldContents:
    """Read and fully check a ``.dfield`` file. Raises ``FormatError`` for any damaged or hostile content
    (``OSError`` only when the file cannot be opened); files above ``max_bytes`` are refused unread."""
    return decode_dfield(_read(path, max_bytes))


def read_dfield_info(path: str | os.PathLike, *, max_bytes: int = MAX_FILE_BYTES, with_mesh: bool = False) -> dict:
    """Versions, header, bytes per chunk and the counts/encodings of every chunk, without decoding the
    features or weights (framing, CRCs and the header are still checked).

    Returns dict with keys container_version, content_version, file_bytes, chunks, header, mesh,
    features, mlp, residual (the ``rESD`` payload's head, ``dfc.io.residual.payload_head``, or None); with
    ``with_mesh`` also ``decoded_mesh``, the ``Mesh`` (decoded and range-checked, not run through ``Mesh.validate``).
    """
    buf = _read(path, max_bytes)
    chunks, sizes = _split_chunks(buf)
    feat_type, feat_data = _one(chunks, CRITICAL_ORDER[3])
    feat = {**_feat_info(feat_data, feat_type.decode()), "coding": "predicted, range-coded" if feat_type == b"FEAC" else "zstd"}
    header = _parse_header(*_one(chunks, CRITICAL_ORDER[0]))
    _check_header(header, feat["slices"])
    mlp_type, mlp_data = _one(chunks, CRITICAL_ORDER[4])
    if mlp_type == b"MLPQ":  # its table is compressed with the weights
        _, table, bits, _ = _mlpq_table(mlp_data)
        weight_bits = sorted({b for b in bits if b})
    elif mlp_type == b"MLPC":  # the header implies its table
        table, weight_bits = _mlpc_table(header, feat["width"]), [_mlpc_head(mlp_data)]
    else:
        table, weight_bits = _mlp_table(mlp_data), []
    topo_type, topo = _one(chunks, CRITICAL_ORDER[2])
    extra = {}
    if b"rESD" in chunks:
        from .residual import payload_head

        extra["residual"] = payload_head(bytes(chunks[b"rESD"]))
    if with_mesh:
        extra["decoded_mesh"] = decode_mesh(bytes(chunks[b"MESH"]), bytes(topo), header["domain"],
                                            full_validate=False, topology=topo_type.decode())
    return {
        "container_version": list(_FILE_HEAD.unpack_from(buf)[1:3]),
        "content_version": header["content_version"],
        "file_bytes": len(buf),
        "chunks": sizes,
        "header": header,
        "mesh": mesh_info(chunks[b"MESH"], topo, topo_type.decode()),
        "features": feat,
        "mlp": {"tensors": {name: list(shape) for name, shape in table},
                "parameters": sum(math.prod(s) for _, s in table), "weight_bits": weight_bits},
        "residual": None,
        **extra,
    }
