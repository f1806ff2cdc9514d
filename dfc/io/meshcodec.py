"""Mesh encoding for ``.dfield`` files: the ``MESH`` and ``TOPO`` or ``TOPC`` chunk payloads (spec/dfield.md
§6.1–6.2).

Vertices are quantised to an integer grid over the domain rectangle (``M = 2**bits - 1`` steps per axis, so
border vertices stay exactly on the border) and the grid mesh is compressed with Draco's edgebreaker, or (the
derived encoding, content 1.3) stored as the grid points and the constraint edges TOPO does not imply, the decoder
rebuilding the triangles as their unique constrained Delaunay triangulation. Draco
reorders vertices and faces, so the decoder puts the mesh in a canonical order (vertices by ``(qx, qy)``, faces
rotated to start at their smallest index, then sorted); ``roundtrip_mesh`` returns that decoder view and the
encoder fits on it. The raw encoding stores float64 vertices losslessly and keeps the order. The discontinuities go to
``TOPO`` (zstd of fixed-width fields) or, since content 1.5, ``TOPC`` (bit-packed, control points on a barycentric
grid just fine enough for the vertex grid, no piece ids).

Every function that reads bytes raises ``FormatError`` (and nothing else) on any inconsistency.
"""

from __future__ import annotations

import struct
from dataclasses import replace
from fractions import Fraction
from typing import NamedTuple

import DracoPy
import numpy as np
import zstandard

from ..errors import FormatError, MeshError
from ..geometry.mesh import Mesh
from ..geometry.triangulate import constrained_delaunay, retriangulate
from ..geometry.plane import cross
from ..geometry.tolerances import tol

__all__ = [
    "DRACO",
    "RAW",
    "DERIVED",
    "MESH_CODINGS",
    "MAX_MESH_BITS",
    "encode_mesh",
    "decode_mesh",
    "roundtrip_mesh",
    "encode_roundtripped",
    "tolerance_bary_bits",
    "mesh_info",
    "check_mesh",
    "compress",
    "decompress",
]

DRACO, RAW, DERIVED = 0, 1, 2
MESH_CODINGS = ("derived", "draco")
"""What ``encode_roundtripped`` tries first: the derived encoding (then Draco), or Draco only (the 1.2 files)."""
MAX_MESH_BITS = 23
"""Draco quantises ``value + 0.5`` in float32, exact for grid integers below 2**23."""
MAX_VERTICES = 2**24
MAX_TRIANGLES = 2**25
MAX_DISC_EDGES = 2**25
DRACO_LEVEL = 10

_MESH_HEAD = struct.Struct("<BBHII")
_DERIVED_HEAD = struct.Struct("<IIBBH")
_DERIVED_ROUNDS = 32
"""Triangulations the derived encoder tries, each constraining more of the mesh's edges, before it gives up."""
_INCIRCLE_FILTER = 1e-12
"""Relative error bound (× the permanent) under which the float incircle test is redone exactly."""
_TOPO_HEAD = struct.Struct("<IIIB3x")
_TOPC_HEAD = struct.Struct("<IIIBBBB")
"""TOPC's fixed fields: E, C, C3, barycentric bits b (0: f64 control points), Rice parameters of the first
vertices, the second vertices and the control-point integers (spec §6.2.1)."""
_MAX_BARY_BITS = 24
_CP_I32, _CP_F64 = 0, 1
_MAX_WINDOW = 2**27
_BARY_ONE = 2.0**24
"""Barycentric control-point coordinates are stored as i32 multiples of 2**-24."""
_BARY_LIMIT = 127.0


# ----------------------------------------------------------------------------------------------- zstd
def compress(data: bytes, level: int, dictionary: bytes | None = None) -> bytes:
    """One zstd frame declaring its content size (spec §1, ``Z(n)``); with ``dictionary``, compressed against
    that raw-content dictionary and declaring no dictionary ID (spec §5, ``HEAC``)."""
    with_dictionary = {} if dictionary is None else {"dict_data": _raw_dictionary(dictionary), "write_dict_id": False}
    return zstandard.ZstdCompressor(level=level, write_content_size=True, **with_dictionary).compress(data)


def decompress(frame: bytes, size: int, chunk: str, dictionary: bytes | None = None) -> bytes:
    """Decode a ``Z(size)`` payload of chunk ``chunk``; ``FormatError`` unless it is exactly one frame of
    declared content size ``size`` (checked before decompressing, so nothing larger is ever allocated).
    ``dictionary``: the raw-content dictionary the frame was compressed with (it must declare no dictionary ID)."""
    try:
        params = zstandard.get_frame_parameters(frame)
    except zstandard.ZstdError:
        raise FormatError(f"{chunk}: zstd frame header is corrupt") from None
    if params.content_size != size:
        raise FormatError(f"{chunk}: zstd frame declares {params.content_size} bytes, expected {size}")
    if params.dict_id:
        raise FormatError(f"{chunk}: zstd frame declares dictionary {params.dict_id}, none is defined")
    try:
        dctx = zstandard.ZstdDecompressor(max_window_size=_MAX_WINDOW, **(
            {} if dictionary is None else {"dict_data": _raw_dictionary(dictionary)}))
        out = dctx.decompress(frame, max_output_size=size)
        # the one-shot call ignores trailing bytes; replay the (now known-good) frame to find them
        obj = dctx.decompressobj()
        obj.decompress(frame)
        trailing = obj.unused_data
    except zstandard.ZstdError as exc:
        raise FormatError(f"{chunk}: zstd data is corrupt ({exc})") from None
    if len(out) != size or trailing:
        raise FormatError(f"{chunk}: zstd payload has the wrong size or bytes after its frame")
    return out


def _raw_dictionary(content: bytes) -> zstandard.ZstdCompressionDict:
    return zstandard.ZstdCompressionDict(content, dict_type=zstandard.DICT_TYPE_RAWCONTENT)


# ----------------------------------------------------------------------------------------------- helpers
def _lerp(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """Normalised-coordinate decoding (spec §1): (1 - t) * a + t * b in float64, exact at t = 0 and 1."""
    t = np.asarray(t, dtype=np.float64)
    return (1.0 - t) * a + t * b


def _normalise(p: np.ndarray, domain) -> np.ndarray:
    """Domain coordinates (..., 2) -> normalised (..., 2) float64, 0 at (x0, y0) and 1 at (x1, y1)."""
    x0, y0, x1, y1 = domain
    return (p - np.array([x0, y0])) / np.array([x1 - x0, y1 - y0])


def _denormalise(t: np.ndarray, domain) -> np.ndarray:
    x0, y0, x1, y1 = domain
    return np.stack([_lerp(t[..., 0], x0, x1), _lerp(t[..., 1], y0, y1)], axis=-1)


def _inverse(perm: np.ndarray) -> np.ndarray:
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(perm), dtype=perm.dtype)
    return inv


def _canonical_faces(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate each face (T, 3) to start at its smallest index, sort faces; return (faces, old -> new rank)."""
    k = np.argmin(tri, axis=1)
    rot = np.take_along_axis(tri, (k[:, None] + np.arange(3)) % 3, axis=1)
    order = np.lexsort((rot[:, 2], rot[:, 1], rot[:, 0]))
    return rot[order], _inverse(order)


def _vertex_order(q: np.ndarray) -> np.ndarray | None:
    """Canonical vertex order of grid points q (V, 2) int64, or None if two points coincide."""
    order = np.lexsort((q[:, 1], q[:, 0]))
    s = q[order]
    if len(s) > 1 and np.any(np.all(s[1:] == s[:-1], axis=1)):
        return None
    return order


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    value = 0
    for shift in range(0, 35, 7):
        if pos >= len(buf):
            raise FormatError("MESH: Draco header truncated")
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
    raise FormatError("MESH: Draco header varint longer than 5 bytes")


def _check_draco_header(blob: bytes, V: int, T: int) -> None:
    """Spec §6.1: accept only Draco 2.2 edgebreaker meshes without metadata whose counts match V and T."""
    if len(blob) < 12 or blob[:5] != b"DRACO":
        raise FormatError("MESH: payload is not a Draco bitstream")
    if blob[5:7] != b"\x02\x02" or blob[7] != 1 or blob[8] != 1 or blob[9:11] != b"\0\0" or blob[11] > 2:
        raise FormatError("MESH: unsupported Draco version, type, method, flags or traversal")
    nv, pos = _varint(blob, 12)
    nf, _ = _varint(blob, pos)
    if (nv, nf) != (V, T):
        raise FormatError(f"MESH: Draco stream declares {nv} vertices / {nf} faces, chunk declares {V} / {T}")


# ----------------------------------------------------------------------------------------------- encoding
def _quantise(vertices: np.ndarray, domain, bits: int) -> np.ndarray:
    M = 2**bits - 1
    return np.clip(np.rint(_normalise(vertices, domain) * M), 0, M).astype(np.int64)


def _barycentric(mesh: Mesh) -> np.ndarray | None:
    """Barycentric (u, w) (C + C3, 2) float64 of the stored inner control points (P1, P2 of a cubic, Q of a
    quadratic, curve by curve) in their curve's frame (spec §6.2), or None when one is not below ``_BARY_LIMIT`` in
    magnitude (a degenerate frame included)."""
    C = len(mesh.curved_triangles)
    deg = np.asarray(mesh.curve_degree, np.int64)
    cp = np.asarray(mesh.curve_control_points, np.float64).reshape(C, 4, 2)
    # quadratic: Q from the elevated control points (mean of both estimates)
    q = 0.25 * ((3.0 * cp[:, 1] - cp[:, 0]) + (3.0 * cp[:, 2] - cp[:, 3]))
    inner = np.where((deg == 3)[:, None, None], cp[:, 1:3], q[:, None, :])
    keep = np.ones((C, 2), bool)
    keep[:, 1] = deg == 3
    A, B, X = _curve_frame(mesh.vertices, mesh.triangles, mesh.curved_triangles, mesh.curve_endpoints)
    rows = np.repeat(np.arange(C), 2).reshape(C, 2)[keep]
    d, e, p = (B - A)[rows], (X - A)[rows], inner[keep] - A[rows]
    with np.errstate(divide="ignore", invalid="ignore"):  # degenerate triangles fail validation later
        det = cross(d, e)
        uw = np.stack([cross(p, e) / det, cross(d, p) / det], axis=-1)
    return uw if np.all(np.abs(uw) < _BARY_LIMIT) else None  # the comparison also catches NaN


def _from_barycentric(uw: np.ndarray, deg: np.ndarray, A: np.ndarray, B: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Inner control points P1, P2 (C, 2, 2) float64 from barycentric rows ``uw`` (C + C3, 2) in the frames A, B, X
    (C, 2) of curves of degree ``deg`` (C,), evaluated exactly as spec §6.2 orders the operations."""
    C = len(deg)
    cubic = deg == 3
    rows = np.repeat(np.arange(C), np.where(cubic, 2, 1))
    with np.errstate(over="ignore", invalid="ignore"):
        pts = A[rows] + uw[:, :1] * (B - A)[rows] + uw[:, 1:] * (X - A)[rows]
        first = np.cumsum(np.where(cubic, 2, 1)) - np.where(cubic, 2, 1)
        inner = np.empty((C, 2, 2))
        inner[cubic, 0], inner[cubic, 1] = pts[first[cubic]], pts[first[cubic] + 1]
        two_q = 2.0 * pts[first[~cubic]]
        inner[~cubic, 0], inner[~cubic, 1] = (A[~cubic] + two_q) / 3.0, (two_q + B[~cubic]) / 3.0
    return inner


def _encode_topology(mesh: Mesh, vmap: np.ndarray, tmap: np.ndarray, cp_format: int, level: int) -> bytes | None:
    """TOPO chunk data, or None when a control point is not representable in ``cp_format``."""
    E, C = len(mesh.disc_edges), len(mesh.curved_triangles)
    deg = np.asarray(mesh.curve_degree, np.uint8)
    parts = [
        vmap[np.asarray(mesh.disc_edges, np.int64)].astype("<u4"),
        np.asarray(mesh.disc_edge_piece).astype("<i4"),
        tmap[np.asarray(mesh.curved_triangles, np.int64)].astype("<u4"),
        vmap[np.asarray(mesh.curve_endpoints, np.int64)].astype("<u4"),
        np.asarray(mesh.curve_piece).astype("<i4"),
        deg,
    ]
    if cp_format == _CP_F64:
        parts.append(np.asarray(mesh.curve_control_points, np.float64)[:, 1:3].astype("<f8"))
    else:
        # barycentric, so the curve moves with its triangle when vertices are quantised
        uw = _barycentric(mesh)
        if uw is None:
            return None
        parts.append(np.rint(uw * _BARY_ONE).astype("<i4"))
    payload = b"".join(np.ascontiguousarray(p).tobytes() for p in parts)
    head = _TOPO_HEAD.pack(E, C, int(np.count_nonzero(deg == 3)), cp_format)
    return head + compress(payload, level)


# ----------------------------------------------------------------------------------------------- TOPC
def _zigzag(d: np.ndarray) -> np.ndarray:
    """Signed integers -> non-negative: 0, -1, 1, -2, ... -> 0, 1, 2, 3, ..."""
    d = np.asarray(d, np.int64)
    return np.where(d >= 0, 2 * d, -2 * d - 1)


def _unzigzag(z: int) -> int:
    return -(z >> 1) - 1 if z & 1 else z >> 1


def _exact_bary_bits(mesh: Mesh, uw: np.ndarray) -> int:
    """The coarsest barycentric grid 2**-b, b in 1..24, on which ``mesh``'s inner control points decode to themselves
    bit for bit (spec §6.2.1), else 24."""
    deg = np.asarray(mesh.curve_degree, np.int64)
    target = np.asarray(mesh.curve_control_points, np.float64)[:, 1:3]
    A, B, X = _curve_frame(mesh.vertices, mesh.triangles, mesh.curved_triangles, mesh.curve_endpoints)
    for b in range(1, _MAX_BARY_BITS + 1):
        if np.array_equal(_from_barycentric(np.rint(uw * 2.0**b) / 2.0**b, deg, A, B, X), target):
            return b
    return _MAX_BARY_BITS


def tolerance_bary_bits(mesh: Mesh, bits: int) -> int:
    """The coarsest barycentric grid 2**-b, b in 1..24, whose rounding moves no inner control point of ``mesh`` by
    more than half a step of the ``bits`` vertex grid (the precision the curves' vertices are stored with)."""
    if not len(mesh.curved_triangles):
        return 1
    A, B, X = _curve_frame(mesh.vertices, mesh.triangles, mesh.curved_triangles, mesh.curve_endpoints)
    # rounding u and w by at most 2**-(b+1) each moves a point by at most 2**-(b+1) * (|B - A| + |X - A|)
    span = float(np.max(np.hypot(*(B - A).T) + np.hypot(*(X - A).T)))
    x0, y0, x1, y1 = mesh.domain
    step = max(x1 - x0, y1 - y0) / (2**bits - 1)
    return int(np.clip(np.ceil(np.log2(max(span / step, 1.0))), 1, _MAX_BARY_BITS))


def _encode_topc(mesh: Mesh, vmap: np.ndarray, bary_bits: int | None) -> bytes | None:
    """TOPC chunk data (spec §6.2.1) with the inner control points on the 2**-``bary_bits`` barycentric grid (0: as
    f64; None: the coarsest grid that holds them exactly, else 2**-24), or None when one is too far from its
    triangle for the barycentric grid."""
    E, C = len(mesh.disc_edges), len(mesh.curved_triangles)
    deg = np.asarray(mesh.curve_degree, np.int64)
    ends = np.asarray(mesh.curve_endpoints, np.int64).reshape(C, 2)
    tri = np.asarray(mesh.triangles, np.int64)[np.asarray(mesh.curved_triangles, np.int64)].reshape(C, 3)
    # side 0: the curve's triangle holds the directed edge A -> B (counter-clockwise, so its apex is left of A -> B)
    side = ~np.any((tri == ends[:, :1]) & (np.roll(tri, -1, axis=1) == ends[:, 1:]), axis=1)
    pairs = vmap[np.concatenate([np.asarray(mesh.disc_edges, np.int64).reshape(E, 2), ends])]
    first = _zigzag(np.diff(pairs[:, 0], prepend=0))
    second = _zigzag(pairs[:, 1] - pairs[:, 0]) - 1
    tail, codes = b"", np.zeros(0, np.int64)
    if bary_bits == 0:
        tail = np.asarray(mesh.curve_control_points, "<f8")[:, 1:3].tobytes()
    else:
        uw = _barycentric(mesh)
        if uw is None:
            return None
        bary_bits = _exact_bary_bits(mesh, uw) if bary_bits is None else bary_bits
        codes = _zigzag(np.rint(uw * 2.0**bary_bits).astype(np.int64).reshape(-1))
    r_first, _ = _rice_cost(first)
    r_second, _ = _rice_cost(second)
    r_cp, _ = _rice_cost(codes)
    w = _BitWriter()
    for i, (a, b) in enumerate(zip(first.tolist(), second.tolist())):
        w.rice(a, r_first)
        w.rice(b, r_second)
        if i >= E:
            w.fixed(int(side[i - E]), 1)
            w.fixed(int(deg[i - E] == 3), 1)
    for z in codes.tolist():
        w.rice(z, r_cp)
    head = _TOPC_HEAD.pack(E, C, int(np.count_nonzero(deg == 3)), bary_bits, r_first, r_second, r_cp)
    return head + w.to_bytes() + tail


def _read_topc(topo_data: bytes, info: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """TOPC chunk data -> vertex pairs (E + C, 2) int64 (the discontinuous edges, then each curve's A, B), side (C,)
    bool, degree (C,) int64 and the inner control points' codes: barycentric integers (C + C3, 2) int64, or the f64
    pairs (C, 2, 2) when the control points are stored as f64 (spec §6.2.1)."""
    E, C, C3, V, b = info["disc_edges"], info["curves"], info["cubic_curves"], info["vertices"], info["bary_bits"]
    r_first, r_second, r_cp = info["rice"]
    payload = topo_data[_TOPC_HEAD.size:]
    n_tail = 32 * C if b == 0 else 0
    n_codes = 0 if b == 0 else 2 * (C + C3)
    # every pair takes at least 2 bits, every curve 2 more, every code 1: bounds the work before any is read
    if len(payload) < n_tail or 8 * (len(payload) - n_tail) < 2 * (E + C) + 2 * C + n_codes:
        raise FormatError("TOPC: stream truncated")
    reader = _BitReader(payload[:len(payload) - n_tail], "TOPC: stream")
    pairs = np.empty((E + C, 2), np.int64)
    flags = np.empty((C, 2), np.int64)
    a = 0
    for i in range(E + C):
        a += _unzigzag(reader.rice(r_first))
        s = _unzigzag(reader.rice(r_second) + 1)
        if not (0 <= a < V and 0 <= a + s < V):
            raise FormatError("TOPC: a vertex index is out of range")
        pairs[i] = a, a + s
        if i >= E:
            flags[i - E] = reader.fixed(1), reader.fixed(1)
    codes = [_unzigzag(reader.rice(r_cp)) for _ in range(n_codes)]
    reader.finish()
    if np.count_nonzero(flags[:, 1]) != C3:
        raise FormatError("TOPC: the curves' degree bits do not match the cubic count")
    if b:
        limit = int(_BARY_LIMIT) << b
        if codes and max(abs(k) for k in codes) >= limit:
            raise FormatError(f"TOPC: a barycentric coordinate is not below {int(_BARY_LIMIT)} in magnitude")
        inner = np.array(codes, np.int64).reshape(C + C3, 2)
    else:
        inner = np.frombuffer(payload, "<f8", 4 * C, len(payload) - n_tail).reshape(C, 2, 2).astype(np.float64)
    return pairs, flags[:, 0].astype(bool), np.where(flags[:, 1] == 1, 3, 2), inner


def _curve_frame(vertices, triangles, curved_triangles, endpoints):
    """Endpoints A, B and apex X (the third corner), each (C, 2) float64, of every curved triangle."""
    tri = np.asarray(triangles, np.int64)[np.asarray(curved_triangles, np.int64)]
    ends = np.asarray(endpoints, np.int64)
    apex = tri.sum(axis=1) - ends.sum(axis=1)
    v = np.asarray(vertices, np.float64)
    return v[ends[:, 0]], v[ends[:, 1]], v[apex]


def encode_mesh(mesh: Mesh, bits: int | None, *, level: int = 19, derived: bool = False, compact: bool = False,
                bary_bits: int | None = None) -> tuple[bytes, bytes] | None:
    """Encode ``mesh`` as (MESH, TOPO) chunk data with one fixed encoding, no fallback; (MESH, TOPC) with ``compact``.

    Parameters
    ----------
    mesh : Mesh
    bits : int in 1..23 for Draco-quantised vertices, or None for the lossless raw encoding
    level : zstd level of the TOPO (and raw MESH) payloads
    derived : the derived encoding (vertices on the ``bits`` grid, 2..23, triangles rebuilt by the decoder)
    compact : the topology as TOPC (spec §6.2.1, content 1.5): packed, no piece ids
    bary_bits : TOPC's barycentric grid 2**-b for the control points, 1..24, or None for the coarsest that holds
        them exactly (else 24); the raw encoding (``bits`` None) stores them as f64

    Returns
    -------
    (mesh_data, topo_data) bytes, or None when ``bits`` puts two vertices on one grid point, a control
    point is too far from its triangle for the fixed-point barycentric format, or (``derived``) the mesh is not on
    the grid or cannot be made the unique constrained Delaunay triangulation of its vertices.
    """
    if derived:
        mesh_data = _encode_derived(mesh, bits)
        if mesh_data is None:
            return None
        q = _quantise(np.asarray(mesh.vertices, np.float64), mesh.domain, bits)
        vmap = _inverse(_vertex_order(q))
        _, tmap = _canonical_faces(vmap[np.asarray(mesh.triangles, np.int64)])
        topo_data = _topology(mesh, vmap, tmap, level, compact, bary_bits)
        return None if topo_data is None else (mesh_data, topo_data)
    V, T = mesh.n_vertices, mesh.n_triangles
    tri = np.asarray(mesh.triangles, np.int64)
    if bits is None:
        raw = np.asarray(mesh.vertices, "<f8").tobytes() + tri.astype("<u4").tobytes()
        mesh_data = _MESH_HEAD.pack(RAW, 0, 0, V, T) + compress(raw, level)
        ident_v, ident_t = np.arange(V), np.arange(T)
        return mesh_data, (_encode_topc(mesh, ident_v, 0) if compact
                           else _encode_topology(mesh, ident_v, ident_t, _CP_F64, level))
    if not 1 <= bits <= MAX_MESH_BITS:
        raise ValueError(f"mesh bits must be in 1..{MAX_MESH_BITS}, got {bits}")
    q = _quantise(np.asarray(mesh.vertices, np.float64), mesh.domain, bits)
    order = _vertex_order(q)
    if order is None:
        return None
    vmap = _inverse(order)
    faces, tmap = _canonical_faces(vmap[tri])
    points = np.zeros((V, 3), np.float32)
    points[:, :2] = q[order]
    M = 2**bits - 1
    blob = DracoPy.encode(
        points, faces.astype(np.uint32), quantization_bits=bits, quantization_range=float(M),
        quantization_origin=[0.0, 0.0, 0.0], compression_level=DRACO_LEVEL, preserve_order=False,
    )
    topo_data = _topology(mesh, vmap, tmap, level, compact, bary_bits)
    return None if topo_data is None else (_MESH_HEAD.pack(DRACO, bits, 0, V, T) + blob, topo_data)


def _topology(mesh: Mesh, vmap: np.ndarray, tmap: np.ndarray, level: int, compact: bool,
              bary_bits: int | None) -> bytes | None:
    """The topology chunk's data of a quantised mesh: TOPC (``compact``) or TOPO with i32 barycentric points."""
    return _encode_topc(mesh, vmap, bary_bits) if compact else _encode_topology(mesh, vmap, tmap, _CP_I32, level)


# ----------------------------------------------------------------------------------------------- derived encoding
class _BitWriter:
    """MSB-first bit string (spec §6.1, encoding 2)."""

    def __init__(self):
        self.parts: list[str] = []

    def fixed(self, value: int, width: int) -> None:
        if width:
            self.parts.append(format(value, f"0{width}b"))

    def rice(self, value: int, r: int) -> None:
        self.parts.append("1" * (value >> r) + "0")
        self.fixed(value & ((1 << r) - 1), r)

    def truncated(self, value: int, n: int) -> None:
        k = n.bit_length() - 1
        u = (1 << (k + 1)) - n
        if value < u:
            self.fixed(value, k)
        else:
            self.fixed(value + u, k + 1)

    def to_bytes(self) -> bytes:
        bits = "".join(self.parts)
        bits += "0" * (-len(bits) % 8)
        return int(bits, 2).to_bytes(len(bits) // 8, "big") if bits else b""


class _BitReader:
    """Reads what ``_BitWriter`` wrote; ``FormatError`` naming ``stream`` past the end."""

    def __init__(self, data: bytes, stream: str = "MESH: derived vertex stream"):
        self.bits = "".join(format(b, "08b") for b in data)
        self.pos = 0
        self.stream = stream

    def fixed(self, width: int) -> int:
        if not width:
            return 0
        end = self.pos + width
        if end > len(self.bits):
            raise FormatError(f"{self.stream} truncated")
        value = int(self.bits[self.pos:end], 2)
        self.pos = end
        return value

    def rice(self, r: int) -> int:
        stop = self.bits.find("0", self.pos)
        if stop < 0:
            raise FormatError(f"{self.stream} truncated")
        high = stop - self.pos
        self.pos = stop + 1
        return (high << r) | self.fixed(r)

    def truncated(self, n: int) -> int:
        k = n.bit_length() - 1
        u = (1 << (k + 1)) - n
        value = self.fixed(k)
        return value if value < u else ((value << 1) | self.fixed(1)) - u

    def finish(self) -> None:
        rest = self.bits[self.pos:]
        if len(rest) >= 8 or "1" in rest:
            raise FormatError(f"{self.stream}: bytes or non-zero padding after it")


def _lattice(q: np.ndarray, bits: int, shift: int) -> np.ndarray:
    """Whether each grid coordinate pair (N, 2) is a lattice point: both coordinates multiples of ``2**shift`` or M."""
    return np.all((q % (1 << shift) == 0) | (q == 2**bits - 1), axis=1)


def _rice_cost(gaps: np.ndarray) -> tuple[int, int]:
    """(best Rice parameter, its bits) for non-negative gaps (N,) int64."""
    costs = [int((gaps >> r).sum()) + len(gaps) * (r + 1) for r in range(_MAX_RICE + 1)]
    r = int(np.argmin(costs))
    return r, costs[r]


def _truncated_cost(values: np.ndarray, n: int) -> int:
    k = n.bit_length() - 1
    return int(len(values) * k + np.count_nonzero(values >= (1 << (k + 1)) - n))


def _sorted_points(p: np.ndarray) -> np.ndarray:
    return p[np.lexsort((p[:, 1], p[:, 0]))]


def _point_set_cost(p: np.ndarray, n: int) -> tuple[int, int]:
    """(Rice parameter, bits) of the sorted points (N, 2) with coordinates in [0, n)."""
    if not len(p):
        return 0, 0
    p = _sorted_points(p)
    r, bits = _rice_cost(np.diff(p[:, 0], prepend=0))
    return r, bits + _truncated_cost(p[:, 1], n)


def _write_points(w: _BitWriter, p: np.ndarray, n: int, r: int) -> None:
    x_prev = 0
    for x, y in _sorted_points(p).tolist():
        w.rice(x - x_prev, r)
        w.truncated(y, n)
        x_prev = x


def _read_points(reader: _BitReader, count: int, n: int, r: int) -> np.ndarray:
    out = np.empty((count, 2), np.int64)
    x = 0
    for i in range(count):
        x += reader.rice(r)
        if x >= n:
            raise FormatError("MESH: derived vertex coordinate out of range")
        out[i] = x, reader.truncated(n)
    return out


_MAX_RICE = 24


def _edge_keys(edges: np.ndarray, V: int) -> np.ndarray:
    e = np.sort(np.asarray(edges, np.int64).reshape(-1, 2), axis=1)
    return e[:, 0] * V + e[:, 1]


def _interior_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges of CCW faces (T, 3): (K, 4) int64 rows (u, v, w, z), faces (u, v, w) and (v, u, z)."""
    V = int(faces.max()) + 1
    u = faces.reshape(-1)
    v = np.roll(faces, -1, axis=1).reshape(-1)
    w = np.roll(faces, -2, axis=1).reshape(-1)
    at, there = _find_keys(u * V + v, v * V + u)
    found = there & (u < v)
    return np.stack([u[found], v[found], w[found], w[at[found]]], axis=1)


def _find_keys(keys: np.ndarray, want: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each of ``want`` (K,) int64 is in the distinct ``keys`` (N,) int64, N >= 1: its index (K,) int64 (any
    index when absent) and whether it is there (K,) bool."""
    order = np.argsort(keys)
    pos = np.minimum(np.searchsorted(keys[order], want), len(keys) - 1)
    return order[pos], keys[order][pos] == want


def _incircle_sign(p: np.ndarray) -> np.ndarray:
    """Exact sign of the incircle determinant of points (K, 4, 2) float64 (a, b, c counter-clockwise, d): > 0 when
    d is strictly inside the circle through a, b, c. Float evaluation, redone in rationals where it is not certain."""
    d = p[:, :3] - p[:, 3:4]
    lift = (d ** 2).sum(axis=2)
    c01 = d[:, 1, 0] * d[:, 2, 1] - d[:, 2, 0] * d[:, 1, 1]
    c12 = d[:, 2, 0] * d[:, 0, 1] - d[:, 0, 0] * d[:, 2, 1]
    c20 = d[:, 0, 0] * d[:, 1, 1] - d[:, 1, 0] * d[:, 0, 1]
    det = lift[:, 0] * c01 + lift[:, 1] * c12 + lift[:, 2] * c20
    a = np.abs(d)
    perm = (lift[:, 0] * (a[:, 1, 0] * a[:, 2, 1] + a[:, 2, 0] * a[:, 1, 1])
            + lift[:, 1] * (a[:, 2, 0] * a[:, 0, 1] + a[:, 0, 0] * a[:, 2, 1])
            + lift[:, 2] * (a[:, 0, 0] * a[:, 1, 1] + a[:, 1, 0] * a[:, 0, 1]))
    sign = np.sign(det).astype(np.int64)
    for k in np.flatnonzero(np.abs(det) <= _INCIRCLE_FILTER * perm):
        (ax, ay), (bx, by), (cx, cy), (dx, dy) = ([Fraction(float(c)) for c in xy] for xy in p[k])
        ax, ay, bx, by, cx, cy = ax - dx, ay - dy, bx - dx, by - dy, cx - dx, cy - dy
        exact = ((ax * ax + ay * ay) * (bx * cy - cx * by) + (bx * bx + by * by) * (cx * ay - ax * cy)
                 + (cx * cx + cy * cy) * (ax * by - bx * ay))
        sign[k] = (exact > 0) - (exact < 0)
    return sign


def _not_strictly_delaunay(vertices: np.ndarray, faces: np.ndarray, constrained: np.ndarray) -> np.ndarray:
    """Interior edges (K, 2) of ``faces`` not in ``constrained`` (keys, ``_edge_keys``) whose opposite vertex is on or
    inside the circumcircle of the other face: the edges that make a constrained Delaunay triangulation not unique
    (cocircular) or not Delaunay."""
    quad = _interior_edges(faces)
    quad = quad[~np.isin(_edge_keys(quad[:, :2], len(vertices)), constrained)]
    if not len(quad):
        return np.zeros((0, 2), np.int64)
    return quad[_incircle_sign(vertices[quad]) >= 0][:, :2]


def _derived_faces(vertices: np.ndarray, constraints: np.ndarray, domain) -> np.ndarray:
    """Canonical faces (T, 3) of the constrained Delaunay triangulation of canonical ``vertices`` with
    ``constraints`` (K, 2); ``MeshError`` when constraints cross or a vertex lies on one."""
    return _canonical_faces(constrained_delaunay(vertices, constraints, domain))[0]


def _derived_constraints(vertices, faces, implied, domain) -> np.ndarray | None:
    """The edges (K, 2) beyond ``implied`` (J, 2) whose constraint makes ``faces`` (canonical, over canonical
    ``vertices``) the unique constrained Delaunay triangulation, or None when none is found."""
    V = len(vertices)
    target = _edge_keys(faces[:, [0, 1, 1, 2, 2, 0]], V)
    extra = np.zeros((0, 2), np.int64)
    for _ in range(_DERIVED_ROUNDS):
        constraints = np.concatenate([implied, extra])
        try:
            derived = _derived_faces(vertices, constraints, domain)
        except MeshError:
            return None
        if len(derived) == len(faces) and np.array_equal(derived, faces):
            add = _not_strictly_delaunay(vertices, faces, _edge_keys(constraints, V))
        else:
            keys = np.setdiff1d(target, _edge_keys(derived[:, [0, 1, 1, 2, 2, 0]], V))
            add = np.stack([keys // V, keys % V], axis=1)
        if not len(add):
            return extra
        keys = np.unique(_edge_keys(np.concatenate([extra, add]), V))
        extra = np.stack([keys // V, keys % V], axis=1)
    return None


def _encode_derived(mesh: Mesh, bits: int) -> bytes | None:
    """MESH chunk data of the derived encoding, or None when ``mesh`` is not on the ``bits`` grid or no set of
    constraint edges makes it the unique constrained Delaunay triangulation of its vertices."""
    if not 2 <= bits <= MAX_MESH_BITS or not _on_grid(mesh, bits):
        return None
    V, T = mesh.n_vertices, mesh.n_triangles
    q = _quantise(np.asarray(mesh.vertices, np.float64), mesh.domain, bits)
    order = _vertex_order(q)
    if order is None:
        return None
    vmap, q = _inverse(order), q[order]
    faces, _ = _canonical_faces(vmap[np.asarray(mesh.triangles, np.int64)])
    vertices = np.asarray(mesh.vertices, np.float64)[order]
    implied = np.concatenate([vmap[np.asarray(mesh.disc_edges, np.int64).reshape(-1, 2)],
                              vmap[np.asarray(mesh.curve_endpoints, np.int64).reshape(-1, 2)]])
    extra = _derived_constraints(vertices, faces, implied, mesh.domain)
    if extra is None:
        return None
    M = 2**bits - 1
    best = None
    for shift in range(1, bits):
        on = _lattice(q, bits, shift)
        coarse = (q[on] + (1 << shift) - 1) >> shift  # M -> 2**(bits - shift), multiples of 2**shift -> themselves
        rf, cost_f = _point_set_cost(q[~on], M + 1)
        rc, cost_c = _point_set_cost(coarse, (1 << (bits - shift)) + 1)
        if best is None or cost_f + cost_c < best[0]:
            best = cost_f + cost_c, shift, on, coarse, rf, rc
    _, shift, on, coarse, rf, rc = best
    w = _BitWriter()
    _write_points(w, q[~on], M + 1, rf)
    _write_points(w, coarse, (1 << (bits - shift)) + 1, rc)
    for i, j in extra.tolist():
        w.truncated(i, V)
        w.truncated(j, V)
    head = _MESH_HEAD.pack(DERIVED, bits, shift, V, T) + _DERIVED_HEAD.pack(int((~on).sum()), len(extra), rf, rc, 0)
    return head + w.to_bytes()


def _decode_derived(payload: bytes, info: dict, implied: np.ndarray, domain) -> tuple[np.ndarray, np.ndarray]:
    """Derived payload -> canonical grid points (V, 2) int64 and faces (T, 3) int64 (spec §6.1, encoding 2);
    ``implied``: the constraint edges the topology chunk implies (E + C, 2) int64, its discontinuous edges and curve
    chords."""
    V, T, bits, shift = info["vertices"], info["triangles"], info["bits"], info["shift"]
    if len(payload) < _DERIVED_HEAD.size:
        raise FormatError("MESH: derived payload shorter than its fixed fields")
    n_fine, K, rf, rc, reserved = _DERIVED_HEAD.unpack_from(payload)
    if reserved or n_fine > V or rf > _MAX_RICE or rc > _MAX_RICE or K > 3 * V:
        raise FormatError(f"MESH: derived counts or parameters out of range ({n_fine} fine vertices, {K} edges, "
                          f"Rice {rf}/{rc})")
    if len(payload) - _DERIVED_HEAD.size < (V + 7) // 8:  # every vertex takes at least a bit: bounds the work
        raise FormatError("MESH: derived vertex stream truncated")
    M = 2**bits - 1
    reader = _BitReader(payload[_DERIVED_HEAD.size:])
    fine = _read_points(reader, n_fine, M + 1, rf)
    coarse = np.minimum(_read_points(reader, V - n_fine, (1 << (bits - shift)) + 1, rc) << shift, M)
    extra = np.array([[reader.truncated(V), reader.truncated(V)] for _ in range(K)], np.int64).reshape(K, 2)
    reader.finish()
    q = np.concatenate([fine, coarse])
    order = _vertex_order(q)
    if order is None:
        raise FormatError("MESH: two vertices coincide")
    q = q[order]
    constraints = np.concatenate([implied, extra])
    if len(constraints) and (constraints.max() >= V or np.any(constraints[:, 0] == constraints[:, 1])):
        raise FormatError("MESH/TOPO: a constraint edge has an invalid or repeated vertex")
    vertices = _denormalise(q / float(M), domain)
    try:
        faces = _derived_faces(vertices, constraints, domain)
    except MeshError as exc:
        raise FormatError(f"MESH: the derived triangulation fails ({exc})") from None
    if len(faces) != T:
        raise FormatError(f"MESH: the derived triangulation has {len(faces)} triangles, the chunk declares {T}")
    if len(_not_strictly_delaunay(vertices, faces, _edge_keys(constraints, V))):
        raise FormatError("MESH: the derived triangulation is not unique (four points on one circle)")
    return q, faces


# ----------------------------------------------------------------------------------------------- decoding
def mesh_info(mesh_data: bytes, topo_data: bytes, topology: str = "TOPO") -> dict:
    """Counts and encodings from the fixed-size prefixes of MESH and the ``topology`` chunk's data ("TOPO" or "TOPC";
    nothing decoded)."""
    if len(mesh_data) < _MESH_HEAD.size or len(topo_data) < _TOPO_HEAD.size:
        raise FormatError(f"MESH/{topology}: chunk shorter than its fixed fields")
    enc, bits, shift, V, T = _MESH_HEAD.unpack_from(mesh_data)
    if topology == "TOPC":
        E, C, C3, bary_bits, *rice = _TOPC_HEAD.unpack_from(topo_data)
        if bary_bits > _MAX_BARY_BITS or max(rice) > _MAX_RICE:
            raise FormatError(f"TOPC: invalid barycentric bits {bary_bits} or Rice parameters {rice}")
        extra = {"control_points": f"barycentric, {bary_bits} bits" if bary_bits else "f64",
                 "bary_bits": bary_bits, "rice": tuple(rice)}
    else:
        E, C, C3, cp_format = _TOPO_HEAD.unpack_from(topo_data)
        if topo_data[13:16] != b"\0\0\0":
            raise FormatError("MESH/TOPO: reserved field is not zero")
        if cp_format not in (_CP_I32, _CP_F64):
            raise FormatError(f"TOPO: invalid control-point format {cp_format}")
        extra = {"control_points": "i32-barycentric" if cp_format == _CP_I32 else "f64"}
    if shift and enc != DERIVED:
        raise FormatError("MESH: reserved field is not zero")
    if (enc == DRACO and not 1 <= bits <= MAX_MESH_BITS or enc == RAW and bits != 0
            or enc == DERIVED and not 1 <= shift < bits <= MAX_MESH_BITS or enc not in (DRACO, RAW, DERIVED)):
        raise FormatError(f"MESH: invalid encoding {enc} with {bits} bits" + (f", lattice shift {shift}" if shift else ""))
    if not (3 <= V <= MAX_VERTICES and 1 <= T <= MAX_TRIANGLES):
        raise FormatError(f"MESH: {V} vertices / {T} triangles outside the limits")
    if E > MAX_DISC_EDGES or C > T or C3 > C:
        raise FormatError(f"{topology}: invalid counts E={E} C={C} C3={C3}")
    return {"encoding": ("draco", "raw", "derived")[enc], "bits": bits, "shift": shift, "vertices": V, "triangles": T,
            "topology": topology, "disc_edges": E, "curves": C, "cubic_curves": C3, **extra}


def _decode_draco(blob: bytes, V: int, T: int, bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Draco payload -> canonical grid points (V, 2) int64 and faces (T, 3) int64."""
    _check_draco_header(blob, V, T)
    try:
        decoded = DracoPy.decode(blob)
        points = np.asarray(decoded.points)
        faces = np.asarray(decoded.faces)
    except Exception as exc:  # DracoPy raises its own exception types on corrupt input
        raise FormatError(f"MESH: Draco decoding failed ({type(exc).__name__})") from None
    if points.shape != (V, 3) or faces.shape != (T, 3):
        raise FormatError(f"MESH: Draco decoded {points.shape} points / {faces.shape} faces, expected {V} / {T}")
    M = 2**bits - 1
    points = points.astype(np.float64)
    if not (np.all(np.isfinite(points)) and np.all(points == np.rint(points)) and np.all(points[:, 2] == 0)
            and points[:, :2].min() >= 0 and points[:, :2].max() <= M):
        raise FormatError(f"MESH: Draco points are not integers in [0, {M}] with z = 0")
    faces = faces.astype(np.int64)
    if faces.size and (faces.min() < 0 or faces.max() >= V):
        raise FormatError("MESH: Draco face index out of range")
    q = points[:, :2].astype(np.int64)
    order = _vertex_order(q)
    if order is None:
        raise FormatError("MESH: two vertices coincide")
    faces, _ = _canonical_faces(_inverse(order)[faces])
    return q[order], faces


def check_mesh(vertices: np.ndarray, triangles: np.ndarray, domain) -> None:
    """Cheap exact checks of spec §6.1 on decoded (V, 2) float64 vertices and (T, 3) int64 faces."""
    x0, y0, x1, y1 = domain
    V = len(vertices)
    if not np.all(np.isfinite(vertices)):
        raise FormatError("MESH: non-finite vertex coordinate")
    x, y = vertices[:, 0], vertices[:, 1]
    if x.min() < x0 or x.max() > x1 or y.min() < y0 or y.max() > y1:
        raise FormatError("MESH: vertex outside the domain")
    if triangles.min() < 0 or triangles.max() >= V:
        raise FormatError("MESH: triangle index out of range")
    a, b, c = (triangles[:, i] for i in range(3))
    if np.any((a == b) | (b == c) | (c == a)):
        raise FormatError("MESH: triangle with a repeated vertex")
    p = vertices[triangles]
    doubled = cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    if not np.all(doubled > 0):
        raise FormatError("MESH: triangle not counter-clockwise with positive area")
    directed = np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=-1).reshape(-1, 2)
    key = directed[:, 0] * V + directed[:, 1]
    if len(np.unique(key)) != len(key):
        raise FormatError("MESH: a directed edge is used twice (overlapping or flipped triangles)")
    boundary = directed[~np.isin(directed[:, 1] * V + directed[:, 0], key)]
    e = vertices[boundary]
    on_side = ((e[:, 0, 0] == x0) & (e[:, 1, 0] == x0)) | ((e[:, 0, 0] == x1) & (e[:, 1, 0] == x1)) | \
              ((e[:, 0, 1] == y0) & (e[:, 1, 1] == y0)) | ((e[:, 0, 1] == y1) & (e[:, 1, 1] == y1))
    if not np.all(on_side):
        raise FormatError("MESH: a boundary edge is not on the domain border (hole)")
    area = (x1 - x0) * (y1 - y0)
    if abs(0.5 * doubled.sum() - area) > tol.area_rel * area:
        raise FormatError("MESH: triangle areas do not sum to the domain area")
    if len(np.unique(triangles)) != V:
        raise FormatError("MESH: a vertex is used by no triangle")


class _Topology(NamedTuple):
    """A topology chunk's fields that need no faces (spec §6.2, §6.2.1)."""

    edges: np.ndarray  # (E, 2) int64, discontinuous edges
    edge_piece: np.ndarray  # (E,) int64, -1 from TOPC
    ends: np.ndarray  # (C, 2) int64, each curve's A, B
    curve_piece: np.ndarray  # (C,) int64, -1 from TOPC
    degree: np.ndarray  # (C,) int64
    ctri: np.ndarray | None  # (C,) int64, TOPO's curved triangles
    side: np.ndarray | None  # (C,) bool, TOPC's side bits
    inner: np.ndarray  # (C, 2, 2) float64 inner control points, or barycentric (u, w) rows (C + C3, 2) float64


def _read_topology(topo: bytes, info: dict) -> _Topology:
    """TOPO or TOPC chunk data -> its fields, read once (a derived mesh needs the edges before its faces)."""
    E, C, C3 = info["disc_edges"], info["curves"], info["cubic_curves"]
    if info["topology"] == "TOPC":
        pairs, side, deg, inner = _read_topc(topo, info)
        b = info["bary_bits"]
        return _Topology(pairs[:E], np.full(E, -1, np.int64), pairs[E:], np.full(C, -1, np.int64), deg, None, side,
                         inner / 2.0**b if b else inner)
    f64 = info["control_points"] == "f64"
    n = 12 * E + 17 * C + (32 * C if f64 else 8 * (C + C3))
    raw = decompress(topo[_TOPO_HEAD.size:], n, "TOPO")
    offs = np.cumsum([0, 8 * E, 4 * E, 4 * C, 8 * C, 4 * C, C])
    inner = (np.frombuffer(raw, "<f8", 4 * C, offs[6]).reshape(C, 2, 2).astype(np.float64) if f64
             else np.frombuffer(raw, "<i4", 2 * (C + C3), offs[6]).reshape(-1, 2) / _BARY_ONE)
    return _Topology(np.frombuffer(raw, "<u4", 2 * E, offs[0]).reshape(E, 2).astype(np.int64),
                     np.frombuffer(raw, "<i4", E, offs[1]).astype(np.int64),
                     np.frombuffer(raw, "<u4", 2 * C, offs[3]).reshape(C, 2).astype(np.int64),
                     np.frombuffer(raw, "<i4", C, offs[4]).astype(np.int64),
                     np.frombuffer(raw, np.uint8, C, offs[5]).astype(np.int64),
                     np.frombuffer(raw, "<u4", C, offs[2]).astype(np.int64), None, inner)


def _decode_topology(topo: _Topology, info: dict, vertices: np.ndarray, triangles: np.ndarray):
    """The fields of a topology chunk checked against the faces -> disc edges (E, 2), their pieces (E,), curved
    triangles (C,), endpoints (C, 2), control points (C, 4, 2), degrees (C,), curve pieces (C,)."""
    E, C, C3 = info["disc_edges"], info["curves"], info["cubic_curves"]
    V, T = len(vertices), len(triangles)
    chunk = info["topology"]
    edges, edge_piece, ends, curve_piece, deg, ctri, side, inner = topo
    if side is not None:
        # the triangle holding the directed chord A -> B (side 0) or B -> A (side 1)
        directed = triangles.reshape(-1) * V + np.roll(triangles, -1, axis=1).reshape(-1)
        at, there = _find_keys(directed, np.where(side, ends[:, 1] * V + ends[:, 0], ends[:, 0] * V + ends[:, 1]))
        if not np.all(there):
            raise FormatError("TOPC: a curve's chord is not an edge of a triangle on its side")
        ctri = at // 3
    if E and (edges.max() >= V or np.any(edges[:, 0] == edges[:, 1])):
        raise FormatError(f"{chunk}: discontinuous edge with an invalid or repeated vertex")
    if E:
        und = np.sort(np.stack([triangles, np.roll(triangles, -1, axis=1)], -1).reshape(-1, 2), axis=1)
        es = np.sort(edges, axis=1)
        if not np.all(np.isin(es[:, 0] * V + es[:, 1], und[:, 0] * V + und[:, 1])):
            raise FormatError(f"{chunk}: a discontinuous edge is not a mesh edge")
        if len(np.unique(es[:, 0] * V + es[:, 1])) != E:
            raise FormatError(f"{chunk}: a discontinuous edge is listed twice")
    if np.any(edge_piece < -1) or np.any(curve_piece < -1):
        raise FormatError(f"{chunk}: piece id below -1")
    if C and (ctri.max() >= T or len(np.unique(ctri)) != C):
        raise FormatError(f"{chunk}: curved triangle index out of range or repeated")
    if C and (ends.max() >= V or np.any(ends[:, 0] == ends[:, 1])
              or not np.all(np.any(triangles[ctri][:, :, None] == ends[:, None, :], axis=1))):
        raise FormatError(f"{chunk}: curve endpoints are not two distinct corners of their triangle")
    if np.any((deg != 2) & (deg != 3)) or np.count_nonzero(deg == 3) != C3:
        raise FormatError(f"{chunk}: curve degree not in {{2, 3}} or cubic count mismatch")
    A, B = vertices[ends[:, 0]], vertices[ends[:, 1]]
    if inner.ndim == 2:  # barycentric (u, w) rows
        _, _, X = _curve_frame(vertices, triangles, ctri, ends)
        inner = _from_barycentric(inner, deg, A, B, X)
    if not np.all(np.isfinite(inner)):
        raise FormatError(f"{chunk}: non-finite control point")
    cp = np.concatenate([A[:, None], inner, B[:, None]], axis=1)
    return edges, edge_piece, ctri, ends, cp, deg.astype(np.int8), curve_piece


def decode_mesh(mesh_data: bytes, topo_data: bytes, domain, *, full_validate: bool = True,
                topology: str = "TOPO") -> Mesh:
    """Decode MESH and topology chunk data into the canonical ``Mesh``; raise ``FormatError`` on any violation.

    ``domain`` is (x0, y0, x1, y1) from the header. ``full_validate`` also runs ``Mesh.validate``. ``topology``: the
    chunk type ``topo_data`` came from, "TOPO" or "TOPC".
    """
    info = mesh_info(mesh_data, topo_data, topology)
    topo = _read_topology(topo_data, info)
    V, T, bits = info["vertices"], info["triangles"], info["bits"]
    payload = mesh_data[_MESH_HEAD.size:]
    if info["encoding"] in ("draco", "derived"):
        q, triangles = (_decode_draco(payload, V, T, bits) if info["encoding"] == "draco"
                        else _decode_derived(payload, info, np.concatenate([topo.edges, topo.ends]), domain))
        vertices = _denormalise(q / float(2**bits - 1), domain)
    else:
        raw = decompress(payload, 16 * V + 12 * T, "MESH")
        vertices = np.frombuffer(raw, "<f8", 2 * V).reshape(V, 2).astype(np.float64)
        triangles = np.frombuffer(raw, "<u4", 3 * T, 16 * V).reshape(T, 3).astype(np.int64)
    check_mesh(vertices, triangles, domain)
    edges, edge_piece, ctri, ends, cp, deg, curve_piece = _decode_topology(topo, info, vertices, triangles)
    mesh = Mesh(domain=tuple(float(v) for v in domain), vertices=vertices, triangles=triangles,
                disc_edges=edges, curved_triangles=ctri, curve_endpoints=ends, curve_control_points=cp,
                curve_degree=deg, disc_edge_piece=edge_piece, curve_piece=curve_piece)
    if full_validate:
        try:
            mesh.validate()
        except MeshError as exc:
            raise FormatError(f"MESH: decoded mesh is invalid: {exc}") from None
    return mesh


# ----------------------------------------------------------------------------------------------- ladder
def _ladder(bits: int) -> list[int | None]:
    if not 1 <= bits <= MAX_MESH_BITS:
        raise ValueError(f"mesh bits must be in 1..{MAX_MESH_BITS}, got {bits}")
    return [*range(bits, MAX_MESH_BITS + 1, 2), None]


def _same(a: Mesh, b: Mesh) -> bool:
    """Whether two meshes are equal bit for bit, order included, except for the informative piece ids."""
    fields = ("vertices", "triangles", "disc_edges", "curved_triangles", "curve_endpoints", "curve_control_points")
    return tuple(a.domain) == tuple(b.domain) and all(
        np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))) for f in fields
    ) and np.array_equal(np.asarray(a.curve_degree, np.int64), np.asarray(b.curve_degree, np.int64))


def _try(mesh: Mesh, step: int | None, level: int, validate: bool = True, derived: bool = False,
         compact: bool = False, bary_bits: int | None = None) -> tuple[tuple[bytes, bytes], Mesh] | None:
    enc = encode_mesh(mesh, step, level=level, derived=derived, compact=compact, bary_bits=bary_bits)
    if enc is None:
        return None
    try:
        return enc, decode_mesh(*enc, mesh.domain, full_validate=validate, topology="TOPC" if compact else "TOPO")
    except FormatError:
        return None


def _try_view(mesh: Mesh, step: int | None):
    """``_try`` as ``roundtrip_mesh`` stores: TOPC with the control points on the grid ``tolerance_bary_bits`` gives
    for ``step`` (on 2**-24 when that fails a check, f64 with the raw encoding)."""
    for b in [0] if step is None else sorted({tolerance_bary_bits(mesh, step), _MAX_BARY_BITS}):
        res = _try(mesh, step, level=1, compact=True, bary_bits=b)
        if res is not None:
            return res
    return None


def _canonical_topology(mesh: Mesh) -> Mesh:
    """``mesh`` with its discontinuous edges as sorted (low, high) vertex pairs and its curves sorted by their
    endpoints' (low, high) pair: the order TOPC stores in the fewest bits (it keeps any order)."""
    edges = np.sort(np.asarray(mesh.disc_edges, np.int64).reshape(-1, 2), axis=1)
    eo = np.lexsort((edges[:, 1], edges[:, 0]))
    ends = np.asarray(mesh.curve_endpoints, np.int64).reshape(-1, 2)
    co = np.lexsort((ends.max(axis=1), ends.min(axis=1)))
    return replace(mesh, disc_edges=edges[eo], disc_edge_piece=np.asarray(mesh.disc_edge_piece)[eo],
                   curved_triangles=np.asarray(mesh.curved_triangles)[co], curve_endpoints=ends[co],
                   curve_control_points=np.asarray(mesh.curve_control_points)[co],
                   curve_degree=np.asarray(mesh.curve_degree)[co], curve_piece=np.asarray(mesh.curve_piece)[co])


def roundtrip_mesh(mesh: Mesh, bits: int) -> Mesh:
    """The mesh exactly as a decoder of a file written from it sees it (Draco with ``bits`` if valid).

    Tries Draco with ``bits, bits + 2, ... <= 23`` and then the lossless raw encoding, returning the first
    decoded mesh that passes every check (spec §6.1, ``Mesh.validate``), its topology as TOPC stores it: control
    points rounded to the barycentric grid that keeps them within half a vertex grid step
    (``tolerance_bary_bits``), no piece ids (-1), edges and curves in canonical order (``_canonical_topology``).
    Where rounding to a grid turns a thin triangle over, the mesh rounded to that grid and triangulated again
    (``dfc.geometry.triangulate.retriangulate``) is tried before the next grid. Raises ``MeshError`` if even the raw
    encoding fails, i.e. ``mesh`` itself is invalid.
    """
    valid = None  # whether ``mesh`` itself is valid, checked once, when a grid first fails: an invalid one is refused
    for step in _ladder(bits):
        res = _try_view(mesh, step)
        if res is None and step is not None:
            valid = _is_valid(mesh) if valid is None else valid
            res = _try_on_grid(mesh, step) if valid else None
        if res is not None:
            return _canonical_topology(res[1])
    raise MeshError("mesh cannot be stored: it fails validation even when stored losslessly")


def _is_valid(mesh: Mesh) -> bool:
    try:
        mesh.validate()
    except MeshError:
        return False
    return True


def _try_on_grid(mesh: Mesh, bits: int):
    """``_try`` on the valid ``mesh`` rounded to the ``bits`` grid and triangulated again, or None (two vertices on
    one grid point, constraints that cross once rounded, or a mesh that fails a check)."""
    q = _quantise(np.asarray(mesh.vertices, np.float64), mesh.domain, bits)
    if _vertex_order(q) is None:
        return None
    try:
        moved = retriangulate(mesh, _denormalise(q / float(2**bits - 1), mesh.domain))
    except MeshError:
        return None
    return _try_view(moved, bits)


def _on_grid(mesh: Mesh, bits: int) -> bool:
    """Whether every vertex is exactly a ``bits`` grid point (as a Draco decode at ``bits`` produces)."""
    q = _quantise(np.asarray(mesh.vertices, np.float64), mesh.domain, bits)
    return np.array_equal(_denormalise(q / float(2**bits - 1), mesh.domain), mesh.vertices)


def encode_roundtripped(mesh: Mesh, *, level: int = 19, validated: bool = False,
                        coding: str = "derived", compact: bool = False) -> tuple[bytes, bytes]:
    """(MESH, TOPO) chunk data that decode to ``mesh`` bit for bit, order included (the piece ids aside with
    ``compact``, which writes (MESH, TOPC): TOPC stores none).

    ``mesh`` should be ``roundtrip_mesh(m, bits)``: the file then reproduces exactly the geometry and order
    the features were fitted on. ``coding`` "derived" (``MESH_CODINGS``) first tries the derived encoding on the
    coarsest grid (2 bits or more) that holds every vertex, taking it when it is no larger than Draco's and decodes to
    ``mesh``.
    Otherwise tries, smallest first, the Draco precisions whose grid holds every vertex
    exactly (grids nest: 10 bits lie on the 20-bit grid) and takes the first under which ``mesh`` decodes to
    itself; any other valid mesh is stored with the lossless raw encoding. Raises ``MeshError`` when
    ``mesh`` is invalid. ``validated``: ``mesh`` passed ``Mesh.validate`` already (``roundtrip_mesh`` checked it),
    so an encoding that decodes to exactly ``mesh`` needs no second check.
    """
    if coding not in MESH_CODINGS:
        raise ValueError(f"mesh coding must be one of {MESH_CODINGS}, got {coding!r}")
    grids = [b for b in range(1, MAX_MESH_BITS + 1) if _on_grid(mesh, b)]
    derived = None
    coarsest = next((b for b in grids if b >= 2), None)
    if coding == "derived" and coarsest is not None:
        res = _try(mesh, coarsest, level, validate=not validated, derived=True, compact=compact)
        # The derived encoding is kept only when decoding it gives back ``mesh`` bit for bit. It cannot when the
        # mesh is off the grid, when a vertex lies on (or within the CDT's tolerance of) a constraint edge so the
        # triangulation would split it, or when no set of extra edges makes ``mesh`` the unique CDT within
        # _DERIVED_ROUNDS tries: then Draco (or raw) below, which store the connectivity itself.
        derived = res[0] if res is not None and _same(res[1], mesh) else None
    for step in grids + [None]:
        res = _try(mesh, step, level, validate=not validated, compact=compact)
        if res is not None and _same(res[1], mesh):
            if derived is not None and len(derived[0]) <= len(res[0][0]):
                return derived
            return res[0]
    raise MeshError("mesh cannot be stored: it is invalid (see Mesh.validate)")
