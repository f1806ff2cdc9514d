"""An independent ``.dfield`` decoder written from ``spec/dfield.md`` and ``spec/field.md`` alone.

It exists to prove that the two documents suffice to evaluate a field (the header dictionary of ``HEAC`` is read
from dfield.md itself): it imports nothing from dfc
(only numpy, zstandard, DracoPy, constriction and pythoncdt, the libraries the spec names), skips CRCs and most validation, and evaluates ``f(x, t)`` in
float64 throughout. Section numbers below are those of the spec documents ("D" = dfield.md,
"F" = field.md).

Usage::

    field = ReferenceField.from_bytes(blob)
    values = field(xy)              # (N, C) float64, xy (N, 2) in domain units
    values = field(xy, t=0.5)       # fields with several time slices
    pixel = field.pixel(cx, cy)     # (C,) the pixel centred there, filtered as header pixel_filter says (D §5.1)
"""

from __future__ import annotations

import hashlib
import json
import re
import struct
from fractions import Fraction
from pathlib import Path

import constriction
import DracoPy
import numpy as np
import pythoncdt
import zstandard

__all__ = ["ReferenceField", "read_chunks"]

SIGNATURE = b"\x89DFL\r\n\x1a\n"
TWO_PI = 2.0 * np.pi
BISECTION_STEPS = 80
"""Bisection halvings of [0, 1] when solving U(t) = u (F §5.4); 53 already reach binary64 resolution."""


def _unzstd(data: bytes, dictionary: bytes | None = None) -> bytes:
    raw = {} if dictionary is None else {
        "dict_data": zstandard.ZstdCompressionDict(dictionary, dict_type=zstandard.DICT_TYPE_RAWCONTENT)}
    return zstandard.ZstdDecompressor(**raw).decompress(bytes(data))


def header_dictionary(spec: Path = Path(__file__).parents[1] / "spec" / "dfield.md") -> bytes:
    """The header dictionary of D Appendix A, read from the spec itself (its lines joined; length and SHA-256
    checked against the ones the appendix states)."""
    appendix = spec.read_text(encoding="utf-8").split("## Appendix A.", 1)[1]
    size, digest = re.search(r"(\d+) bytes of ASCII whose SHA-256 is\s+`([0-9a-f]{64})`", appendix).groups()
    block = appendix.split("```text\n", 1)[1].split("```", 1)[0]
    dictionary = "".join(block.splitlines()).encode("ascii")
    if len(dictionary) != int(size) or hashlib.sha256(dictionary).hexdigest() != digest:
        raise ValueError("the spec's header dictionary does not match its stated length and SHA-256")
    return dictionary


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _angle(d: np.ndarray) -> np.ndarray:
    return np.arctan2(d[..., 1], d[..., 0])


def read_chunks(blob: bytes) -> dict[bytes, bytes]:
    """Chunk type -> data (D §2; CRCs not checked, ancillary chunks other than rESD dropped)."""
    if blob[:8] != SIGNATURE:
        raise ValueError("not a .dfield file")
    pos, chunks = 16, {}
    while pos < len(blob):
        length, ctype = struct.unpack_from("<I4s", blob, pos)
        if not ctype[0] & 0x20 or ctype == b"rESD":
            chunks[ctype] = blob[pos + 8:pos + 8 + length]
        pos += 8 + length + (-length) % 4 + 4
    return chunks


def _canonical(faces: np.ndarray) -> np.ndarray:
    shift = np.argmin(faces, axis=1)[:, None]          # rotate: smallest index first
    faces = np.take_along_axis(faces, (shift + np.arange(3)) % 3, axis=1)
    return faces[np.lexsort((faces[:, 2], faces[:, 1], faces[:, 0]))]


class _Bits:
    """The MSB-first bit stream of MESH encoding 2 (D §6.1)."""

    def __init__(self, data: bytes):
        self.bits, self.pos = "".join(f"{b:08b}" for b in data), 0

    def take(self, k: int) -> int:
        self.pos += k
        return int(self.bits[self.pos - k:self.pos] or "0", 2)

    def rice(self, r: int) -> int:
        ones = self.bits.index("0", self.pos) - self.pos
        self.pos += ones + 1
        return ones * 2**r + self.take(r)

    def truncated(self, n: int) -> int:
        k = n.bit_length() - 1
        u = 2 ** (k + 1) - n
        v = self.take(k)
        return v if v < u else 2 * v + self.take(1) - u

    def points(self, count: int, n: int, r: int) -> list[tuple[int, int]]:
        out, x = [], 0
        for _ in range(count):
            x += self.rice(r)
            out.append((x, self.truncated(n)))
        return out


def _locally_delaunay(vertices: np.ndarray, faces: np.ndarray, constraints: set) -> bool:
    """Every interior edge not in ``constraints`` has its opposite vertex strictly outside the other face's
    circumcircle, in exact rational arithmetic: the condition under which the CDT is unique (D §6.1)."""
    opposite = {}
    for f in faces.tolist():
        for k in range(3):
            opposite[(f[k], f[(k + 1) % 3])] = f[(k + 2) % 3]
    for (a, b), c in opposite.items():
        if a > b or (b, a) not in opposite or (a, b) in constraints:
            continue
        d = opposite[(b, a)]
        (ax, ay), (bx, by), (cx, cy), (dx, dy) = ([Fraction(float(t)) for t in vertices[i]] for i in (a, b, c, d))
        ax, ay, bx, by, cx, cy = ax - dx, ay - dy, bx - dx, by - dy, cx - dx, cy - dy
        det = ((ax * ax + ay * ay) * (bx * cy - cx * by) + (bx * bx + by * by) * (cx * ay - ax * cy)
               + (cx * cx + cy * cy) * (ax * by - bx * ay))
        if det >= 0:
            return False
    return True


def _derived_faces(vertices: np.ndarray, edges: np.ndarray, domain) -> np.ndarray:
    """The constrained Delaunay triangulation of D §6.1 encoding 2, with pythoncdt, checked to be the unique one."""
    x0, y0, x1, y1 = domain
    border = []
    for axis, value in ((1, y0), (0, x1), (1, y1), (0, x0)):
        on = np.flatnonzero(vertices[:, axis] == value)
        on = on[np.argsort(vertices[on, 1 - axis])]
        border += list(zip(on[:-1].tolist(), on[1:].tolist()))
    constraints = border + [tuple(e) for e in edges.tolist()]
    t = pythoncdt.Triangulation(pythoncdt.VertexInsertionOrder.AS_PROVIDED,
                                pythoncdt.IntersectingConstraintEdges.NOT_ALLOWED, 0.0)
    t.insert_vertices(np.ascontiguousarray(vertices))
    t.insert_edges(np.array(constraints, np.uint32).reshape(-1, 2))
    t.erase_outer_triangles()
    if t.vertices_count() != len(vertices):
        raise ValueError("MESH: the constraint edges cross")
    faces = t.triangles_array()["vertices"].astype(np.int64)
    p = vertices[faces]
    cw = _cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) < 0
    faces[cw] = faces[cw][:, ::-1]
    if not _locally_delaunay(vertices, faces, {tuple(sorted(e)) for e in constraints}):
        raise ValueError("MESH: the derived triangulation is not unique")
    return _canonical(faces)


def _unzigzag(z: int) -> int:
    return z // 2 if z % 2 == 0 else -(z + 1) // 2


def _read_topc(topo: bytes):
    """TOPC -> vertex pairs (E + C, 2), side bits (C,), degrees (C,), barycentric integers (C + C3, 2) or, with b = 0,
    the f64 inner points (C, 2, 2), and b (D §6.2.1)."""
    E, C, C3, b, r1, r2, r3 = struct.unpack_from("<IIIBBBB", topo)
    tail = 32 * C if b == 0 else 0
    stream = _Bits(topo[16:len(topo) - tail])
    pairs, side, degree, a = [], [], [], 0
    for i in range(E + C):
        a += _unzigzag(stream.rice(r1))
        pairs.append((a, a + _unzigzag(stream.rice(r2) + 1)))
        if i >= E:
            side.append(stream.take(1))
            degree.append(3 if stream.take(1) else 2)
    if b:
        inner = np.array([_unzigzag(stream.rice(r3)) for _ in range(2 * (C + C3))], np.int64).reshape(-1, 2)
    else:
        inner = np.frombuffer(topo, "<f8", 4 * C, len(topo) - tail).reshape(C, 2, 2)
    return np.array(pairs, np.int64).reshape(-1, 2), np.array(side), np.array(degree, np.int64), inner, b


def _topology_edges(topo: bytes, kind: bytes = b"TOPO") -> np.ndarray:
    """The topology chunk's disc_edges and curve_endpoints, (E + C, 2) (D §6.2, §6.2.1), the constraints it implies
    (D §6.1)."""
    if kind == b"TOPC":
        return _read_topc(topo)[0]
    E, C = struct.unpack_from("<II", topo)
    raw = _unzstd(topo[16:])
    edges = np.frombuffer(raw, "<u4", 2 * E).reshape(E, 2)
    ends = np.frombuffer(raw, "<u4", 2 * C, 12 * E + 4 * C).reshape(C, 2)
    return np.concatenate([edges, ends]).astype(np.int64)


def _decode_mesh(data: bytes, domain, topo: bytes, kind: bytes = b"TOPO") -> tuple[np.ndarray, np.ndarray]:
    """MESH chunk -> vertices (V, 2) float64, faces (T, 3) int64 in canonical order (D §6.1)."""
    encoding, bits, shift, V, T = struct.unpack_from("<BBHII", data)
    payload = data[12:]
    if encoding == 1:
        raw = _unzstd(payload)
        vertices = np.frombuffer(raw, "<f8", 2 * V).reshape(V, 2).copy()
        return vertices, np.frombuffer(raw, "<u4", 3 * T, 16 * V).reshape(T, 3).astype(np.int64)
    M = 2**bits - 1
    if encoding == 2:
        n_full, K, rf, rc, _ = struct.unpack_from("<IIBBH", payload)
        bits_in = _Bits(payload[12:])
        q = bits_in.points(n_full, M + 1, rf)
        q += [(min(i * 2**shift, M), min(j * 2**shift, M)) for i, j in bits_in.points(V - n_full, 2 ** (bits - shift) + 1, rc)]
        extra = [(bits_in.truncated(V), bits_in.truncated(V)) for _ in range(K)]
        q = np.array(sorted(q), np.int64)                # by qx, ties by qy
    else:
        mesh = DracoPy.decode(bytes(payload))
        q = np.rint(np.asarray(mesh.points, np.float64)[:, :2]).astype(np.int64)
        order = np.lexsort((q[:, 1], q[:, 0]))           # by qx, ties by qy
        rank = np.empty(V, np.int64)
        rank[order] = np.arange(V)
        faces = _canonical(rank[np.asarray(mesh.faces, np.int64)])
        q = q[order]
    t = q / float(M)
    x0, y0, x1, y1 = domain
    vertices = np.stack([(1.0 - t[:, 0]) * x0 + t[:, 0] * x1, (1.0 - t[:, 1]) * y0 + t[:, 1] * y1], axis=1)
    if encoding == 2:
        faces = _derived_faces(vertices, np.concatenate([_topology_edges(topo, kind),
                                                         np.array(extra, np.int64).reshape(-1, 2)]), domain)
    return vertices, faces


def _decode_topology(data: bytes, vertices: np.ndarray, faces: np.ndarray):
    """TOPO chunk -> disc edges (E, 2), curve faces (C,), endpoints (C, 2), control points (C, 4, 2) (D §6.2)."""
    E, C, C3, cp_format = struct.unpack_from("<IIIB", data)
    raw = _unzstd(data[16:])
    pos = 0

    def take(dtype, count):
        nonlocal pos
        out = np.frombuffer(raw, dtype, count, pos)
        pos += out.nbytes
        return out.astype(np.int64) if dtype != "<f8" else out

    edges = take("<u4", 2 * E).reshape(E, 2)
    take("<i4", E)
    ctri = take("<u4", C)
    ends = take("<u4", 2 * C).reshape(C, 2)
    take("<i4", C)
    degree = take("u1", C)
    if cp_format == 1:
        return edges, ctri, ends, _control_points(vertices, faces, ctri, ends, degree, take("<f8", 4 * C).reshape(C, 2, 2))
    uw = take("<i4", 2 * (C + C3)).reshape(-1, 2) / 2.0**24
    return edges, ctri, ends, _control_points(vertices, faces, ctri, ends, degree, uw)


def _decode_topc(data: bytes, vertices: np.ndarray, faces: np.ndarray):
    """TOPC chunk -> the same as ``_decode_topology`` (D §6.2.1)."""
    E = struct.unpack_from("<I", data)[0]
    pairs, side, degree, inner, b = _read_topc(data)
    ends = pairs[E:]
    owner = {(int(f[k]), int(f[(k + 1) % 3])): i for i, f in enumerate(faces) for k in range(3)}
    ctri = np.array([owner[(a, c) if s == 0 else (c, a)] for (a, c), s in zip(ends.tolist(), side)], np.int64)
    return pairs[:E], ctri, ends, _control_points(vertices, faces, ctri, ends, degree, inner / 2.0**b if b else inner)


def _control_points(vertices, faces, ctri, ends, degree, inner) -> np.ndarray:
    """Control points (C, 4, 2) from the inner points (C, 2, 2), or from barycentric (u, w) rows (C + C3, 2): P1, P2
    of a cubic, Q of a quadratic, in the frame A, B, apex X of the curve's face (D §6.2, cp_format 0)."""
    A, B = vertices[ends[:, 0]], vertices[ends[:, 1]]
    if inner.ndim == 2:
        C, uw = len(ends), inner
        X = vertices[faces[ctri].sum(1) - ends.sum(1)]
        owner = np.repeat(np.arange(C), np.where(degree == 3, 2, 1))
        pts = (A[owner] + uw[:, :1] * (B - A)[owner]) + uw[:, 1:] * (X - A)[owner]
        inner = np.empty((C, 2, 2))
        start = np.cumsum(np.where(degree == 3, 2, 1)) - np.where(degree == 3, 2, 1)
        cubic = degree == 3
        inner[cubic] = np.stack([pts[start[cubic]], pts[start[cubic] + 1]], axis=1)
        two_q = 2.0 * pts[start[~cubic]]
        inner[~cubic] = np.stack([(A[~cubic] + two_q) / 3.0, (two_q + B[~cubic]) / 3.0], axis=1)
    return np.concatenate([A[:, None], inner, B[:, None]], axis=1)


def _decode_features(data: bytes) -> np.ndarray:
    """FEAT chunk -> bank (S, N, K) float32 (D §6.3)."""
    S, N, K, bits = struct.unpack_from("<IIHB", data)
    scale = np.frombuffer(data, "<f4", K, 12)
    offset = np.frombuffer(data, "<f4", K, 12 + 4 * K)
    q = np.frombuffer(_unzstd(data[12 + 8 * K:]), "<u1" if bits <= 8 else "<u2").reshape(S, K, N)
    return (offset[None, :, None] + q.astype(np.float32) * scale[None, :, None]).transpose(0, 2, 1)


def _feac_header(data: bytes):
    """FEAC chunk -> (S, N, K, bits, scale, offset, class models [(lo, hi, d1, d2, m)] * 3, stream words) (D §6.5)."""
    S, N, K, bits = struct.unpack_from("<IIHB", data)
    scale = np.frombuffer(data, "<f4", K, 12)
    offset = np.frombuffer(data, "<f4", K, 12 + 4 * K)
    pos = 12 + 8 * K
    models = [struct.unpack_from("<iiHHH", data, pos + 16 * c) for c in range(3)]
    words = np.frombuffer(data[pos + 48:], "<u4").astype(np.uint32)
    return S, N, K, bits, scale, offset, models, words


def _model_frequencies(lo: int, hi: int, d1: int, d2: int, m: int) -> list[int]:
    """Frequencies (out of 2**24) of the symbols v - lo, v = lo .. hi (D §6.6), in Python integers."""
    a = [1 << 30]
    for j in range(max(-lo, hi)):
        a.append(a[-1] * (d1 if j < m else d2) // 65536)
    w = {v: a[abs(v)] for v in range(lo, hi + 1)}
    n, G = hi - lo + 1, sum(w.values())
    T = (1 << 24) - n
    c = {v: w[v] * T // G for v in w if v != 0}
    c[0] = T - sum(c.values())
    return [c[v] + 1 for v in range(lo, hi + 1)]


def _decode_feac(data: bytes, neighbours: list[list[int]], classes: np.ndarray) -> np.ndarray:
    """FEAC chunk -> bank (S, N, K) float32 (D §6.5, §6.6), rows rebuilt one by one in row order.
    neighbours[r]: every neighbour row of r; classes (N,): the row classes."""
    S, N, K, bits, scale, offset, models, words = _feac_header(data)
    decoder = constriction.stream.queue.RangeDecoder(words)
    e = np.zeros((S, N, K), np.int64)
    for s in range(S):
        for c in range(3):
            rows = np.flatnonzero(classes == c)
            lo, hi, d1, d2, m = models[c]
            for k in range(K):
                if hi == lo or not len(rows):
                    continue
                freq = np.array(_model_frequencies(lo, hi, d1, d2, m), np.float64)
                # counts summing to 2**24 - n: constriction's fast quantiser adds one to each (D §6.6)
                model = constriction.stream.model.Categorical(freq - 1.0, perfect=False)
                e[s, rows, k] = np.asarray(decoder.decode(model, len(rows)), np.int64) + lo
    q = np.zeros((S, N, K), np.int64)
    for r in range(N):
        earlier = [j for j in neighbours[r] if j < r]
        if earlier:
            total = q[:, earlier].sum(axis=1)
            q[:, r] = (total + len(earlier) // 2) // len(earlier) + e[:, r]
        else:
            q[:, r] = (1 << (bits - 1)) + e[:, r]
    return offset[None, None, :] + q.astype(np.float32) * scale[None, None, :]


def _decode_mlpq(data: bytes) -> dict[str, np.ndarray]:
    """MLPQ chunk -> name -> float64 array (D §6.7)."""
    n, _ = struct.unpack_from("<II", data)
    raw = _unzstd(data[8:])
    records = [struct.unpack_from("<60sI4I", raw, 80 * i) for i in range(n)]
    names = [name.rstrip(b"\0").decode("ascii") for name, *_ in records]
    shapes = [tuple(dims[:rank]) for _, rank, *dims in records]
    return _integer_tensors(raw, 81 * n, names, shapes, list(raw[80 * n:81 * n]))


def _decode_mlpc(data: bytes, header: dict) -> dict[str, np.ndarray]:
    """MLPC chunk -> name -> float64 array (D §6.8): the tensors F §7 implies, MLPQ's scales and values."""
    bits, coding = data[0], data[1]
    m = header["model"]
    sizes = [m["dim"] + 2 * m["oneblob_bins"]] + [m["hidden"]] * m["layers"] + [len(header["channels"])]
    names, shapes = [], []
    for i, (n_in, n_out) in enumerate(zip(sizes, sizes[1:])):
        names += [f"layers.{i}.weight", f"layers.{i}.bias"]
        shapes += [(n_out, n_in), (n_out,)]
    raw = _unzstd(data[4:]) if coding else bytes(data[4:])
    return _integer_tensors(raw, 0, names, shapes, [bits if len(s) == 2 else 0 for s in shapes])


def _integer_tensors(raw: bytes, pos: int, names: list[str], shapes: list[tuple], bits: list[int]):
    """D §6.7 from the scales on: name -> float64 array."""
    n_scales = sum(shape[0] for b, shape in zip(bits, shapes) if b)
    scales = np.frombuffer(raw, "<f2", n_scales, pos).astype(np.float32)
    pos += 2 * n_scales
    out, at = {}, 0
    for name, b, shape in zip(names, bits, shapes):
        size = int(np.prod(shape))
        if b == 0:
            values = np.frombuffer(raw, "<f2", size, pos).astype(np.float64)
            pos += 2 * size
        else:
            dtype = "<i1" if b <= 8 else "<i2"
            q = np.frombuffer(raw, dtype, size, pos).reshape(shape).astype(np.float32)
            pos += np.dtype(dtype).itemsize * size
            values = (q * scales[at:at + shape[0], None]).astype(np.float64)  # binary32 product
            at += shape[0]
        out[name] = values.reshape(shape)
    return out


def _decode_mlp(data: bytes) -> dict[str, np.ndarray]:
    """MLPW chunk -> name -> float64 array (D §6.4)."""
    n, total = struct.unpack_from("<II", data)
    values = np.frombuffer(_unzstd(data[8 + 80 * n:]), "<f2").astype(np.float64)
    out, pos = {}, 0
    for i in range(n):
        name, rank, *dims = struct.unpack_from("<60sI4I", data, 8 + 80 * i)
        shape = tuple(dims[:rank])
        size = int(np.prod(shape))
        out[name.rstrip(b"\0").decode("ascii")] = values[pos:pos + size].reshape(shape)
        pos += size
    return out


class ReferenceField:
    """A decoded field: geometry tables (F §§2–4) plus the bank and the network."""

    def __init__(self, header: dict, vertices, faces, disc_edges, curve_faces, curve_ends, control_points, mlp):
        self.header, self.vertices, self.faces = header, vertices, faces
        self.domain = np.asarray(header["domain"], np.float64)
        self.mlp = mlp
        self.curve_faces, self.curve_ends, self.control_points = curve_faces, curve_ends, control_points
        self.residual = None
        self._build_layout(disc_edges)

    @classmethod
    def from_bytes(cls, blob: bytes) -> ReferenceField:
        ch = read_chunks(blob)
        header = json.loads(_unzstd(ch[b"HEAD"]) if b"HEAD" in ch else _unzstd(ch[b"HEAC"], header_dictionary()))
        kind = b"TOPC" if b"TOPC" in ch else b"TOPO"
        vertices, faces = _decode_mesh(ch[b"MESH"], header["domain"], ch[kind], kind)
        decode = _decode_topc if kind == b"TOPC" else _decode_topology
        edges, ctri, ends, cp = decode(ch[kind], vertices, faces)
        if b"MLPC" in ch:
            mlp = _decode_mlpc(ch[b"MLPC"], header)
        else:
            mlp = _decode_mlp(ch[b"MLPW"]) if b"MLPW" in ch else _decode_mlpq(ch[b"MLPQ"])
        field = cls(header, vertices, faces, edges, ctri, ends, cp, mlp)
        bank = _decode_features(ch[b"FEAT"]) if b"FEAT" in ch else _decode_feac(ch[b"FEAC"], *field.row_graph())
        if bank.shape[1] != field.n_rows:
            raise ValueError(f"the bank has {bank.shape[1]} rows, the layout needs {field.n_rows}")
        field.bank = bank.astype(np.float64)
        field.pixel_filter = _pixel_filter(header.get("pixel_filter", "box"))
        field.residual = _decode_resd(ch[b"rESD"]) if b"rESD" in ch else None
        return field

    def pixel(self, cx: float, cy: float, n: int = 64) -> np.ndarray:
        """(C,) the pixel centred at (cx, cy) under the header's pixel filter (D §5.1), the integral taken by the
        midpoint rule on n × n points over the support (``box:N``: its N × N points; ``point``: the centre)."""
        name, param, kernel, radius = self.pixel_filter
        pw, ph = self.header["pixel_size"]
        if name == "point":
            return self(np.array([[cx, cy]]))[0]
        if name == "box" and param is not None:
            n = int(param)
        u = (np.arange(n) + 0.5) / n * 2 * radius - radius
        w = np.ones(n) if name == "box" else kernel(u)
        X, Y = np.meshgrid(cx + u * pw, cy + u * ph)
        values = self(self.clamp(np.stack([X.ravel(), Y.ravel()], axis=1)))
        weights = np.outer(w, w).ravel()
        return weights @ values / weights.sum()

    def row_graph(self) -> tuple[list[list[int]], np.ndarray]:
        """Neighbour rows of every row and the row classes (D §6.5)."""
        groups = [np.concatenate([self.c_start, self.c_end], axis=1)]
        if len(self.curve_faces):
            groups.append(np.stack([self.far_a, self.far_b, self.n_vertex_rows + np.arange(len(self.curve_faces))], 1))
        neighbours = [set() for _ in range(self.n_rows)]
        for group in groups:
            for rows in group.tolist():
                for r in rows:
                    neighbours[r].update(j for j in rows if j != r)
        classes = np.full(self.n_rows, 2)
        classes[:self.n_vertex_rows] = np.repeat((self.k > 0).astype(int), np.maximum(1, 2 * self.k))
        return [sorted(n) for n in neighbours], classes

    # ------------------------------------------------------------------------------------- layout
    def _build_layout(self, disc_edges: np.ndarray) -> None:
        verts, faces, V = self.vertices, self.faces, len(self.vertices)
        pairs = np.unique(np.sort(np.concatenate([disc_edges, self.curve_ends]), axis=1), axis=0)
        frm = np.concatenate([pairs[:, 0], pairs[:, 1]])
        to = np.concatenate([pairs[:, 1], pairs[:, 0]])
        ang = _angle(verts[to] - verts[frm])
        order = np.lexsort((to, ang, frm))                            # F §2: by vertex, angle, far vertex
        frm, to, ang = frm[order], to[order], ang[order]
        k = np.bincount(frm, minlength=V)
        first = np.cumsum(k) - k
        self.k = k
        self.offset = np.cumsum(np.maximum(1, 2 * k)) - np.maximum(1, 2 * k)   # F §3
        self.n_vertex_rows = int(np.maximum(1, 2 * k).sum())
        kmax = max(int(k.max()), 1)
        slot = np.arange(len(frm)) - first[frm]
        angles = np.full((V, kmax), np.inf)                          # padded per-vertex half-edge tables
        angles[frm, slot] = ang
        far = np.full((V, kmax), -1)
        far[frm, slot] = to
        self._far = far

        # Corner tables (F §4), shape (T, 3).
        v, n, p = faces, np.roll(faces, -1, axis=1), np.roll(faces, 1, axis=1)
        e_n, e_p = verts[n] - verts[v], verts[p] - verts[v]
        ang_n = _angle(e_n)
        beta = np.arctan2(_cross(e_n, e_p), np.sum(e_n * e_p, axis=-1))
        kv = k[v]
        count = (angles[v] <= ang_n[..., None]).sum(-1)              # half-edges at or before v -> n
        j = np.where(kv > 0, (count - 1) % np.maximum(kv, 1), 0)
        a_j = np.where(kv > 0, angles[v, j], 0.0)                   # vertices without half-edges: unused
        a_next = np.where(kv > 0, angles[v, (j + 1) % np.maximum(kv, 1)], 0.0)
        theta = np.where(kv == 1, TWO_PI, np.mod(a_next - a_j, TWO_PI))
        self.c_radial = kv > 0
        self.c_start = np.where(kv > 0, self.offset[v] + 2 * j, self.offset[v])
        self.c_end = np.where(kv > 0, self.c_start + 1, self.c_start)
        self.c_alpha = np.where(kv > 0, np.mod(ang_n - a_j, TWO_PI), 0.0)
        self.c_beta, self.c_theta = beta, np.where(kv > 0, theta, 1.0)
        self.n_rows = self.n_vertex_rows + len(self.curve_faces)

        # Curves (F §5.4): corner positions of A, B, apex; far rows; chord frames.
        self.face_curve = np.full(len(faces), -1)
        self.face_curve[self.curve_faces] = np.arange(len(self.curve_faces))
        tri = faces[self.curve_faces]                                  # (C, 3)
        is_a, is_b = tri == self.curve_ends[:, :1], tri == self.curve_ends[:, 1:]
        self.corner_a, self.corner_b = is_a.argmax(1), is_b.argmax(1)
        self.corner_x = (~(is_a | is_b)).argmax(1)
        self.far_a = self._far_rows(self.corner_a, self.curve_ends[:, 1])
        self.far_b = self._far_rows(self.corner_b, self.curve_ends[:, 0])
        cp = self.control_points
        apex = verts[tri[np.arange(len(tri)), self.corner_x]]
        g = cp[:, 3] - cp[:, 0]
        self.ubar = g / np.sum(g * g, axis=1, keepdims=True)
        vbar = np.stack([-self.ubar[:, 1], self.ubar[:, 0]], axis=1)
        flip = np.sum((apex - cp[:, 0]) * vbar, axis=1) < 0
        self.vbar = np.where(flip[:, None], -vbar, vbar)
        rel = cp - cp[:, :1]
        self.U = np.einsum("cmd,cd->cm", rel, self.ubar)
        self.W = np.einsum("cmd,cd->cm", rel, self.vbar)

    def _far_rows(self, corner: np.ndarray, other: np.ndarray) -> np.ndarray:
        """Far row at one endpoint of every curve (F §5.4, "Sliver rows")."""
        c = np.arange(len(corner))
        tri = self.faces[self.curve_faces]
        e = tri[c, corner]
        nxt = tri[c, (corner + 1) % 3]
        q = np.argmax(self._far[e] == other[:, None], axis=1)       # index of the chord half-edge at e
        kk = self.k[e]
        return np.where(nxt == other, self.offset[e] + 2 * ((q - 1) % kk) + 1, self.offset[e] + 2 * q)

    # ------------------------------------------------------------------------------------- queries
    def clamp(self, xy) -> np.ndarray:
        x0, y0, x1, y1 = self.domain
        xy = np.asarray(xy, np.float64)
        return np.stack([np.clip(xy[:, 0], x0, x1), np.clip(xy[:, 1], y0, y1)], axis=1)

    def barycentric(self, xy: np.ndarray, face: np.ndarray) -> np.ndarray:
        """Barycentric coordinates (N, 3) of points (N, 2) in faces (N,)."""
        p = self.vertices[self.faces[face]]                          # (N, 3, 2)
        area = _cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        lam = [_cross(p[:, (i + 2) % 3] - p[:, (i + 1) % 3], xy - p[:, (i + 1) % 3]) for i in range(3)]
        return np.stack(lam, axis=1) / area[:, None]

    def locate(self, xy: np.ndarray, block: int = 1024) -> np.ndarray:
        """Face (N,) whose smallest barycentric coordinate of each point is largest (F §5.1; brute force)."""
        p = self.vertices[self.faces]                                # (T, 3, 2)
        area = _cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        out = []
        for i in range(0, len(xy), block):
            q = xy[i:i + block, None, :]
            lam = np.stack([_cross(p[:, (m + 2) % 3] - p[:, (m + 1) % 3], q - p[:, (m + 1) % 3]) for m in range(3)],
                           axis=-1) / area[:, None]
            out.append(np.argmax(lam.min(-1), axis=1))
        return np.concatenate(out) if out else np.zeros(0, np.int64)

    def in_sliver(self, xy: np.ndarray, curve: np.ndarray) -> np.ndarray:
        """Side test (F §5.4) of points (N, 2) against curves (N,): True between chord and curve."""
        rel = xy - self.control_points[curve, 0]
        u = np.sum(rel * self.ubar[curve], axis=1)
        w = np.sum(rel * self.vbar[curve], axis=1)
        U, W = self.U[curve], self.W[curve]
        u = np.clip(u, U[:, 0], U[:, 3])
        lo, hi = np.zeros(len(u)), np.ones(len(u))
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            below = _bernstein(U, mid) < u
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        t = np.where(u <= U[:, 0], 0.0, np.where(u >= U[:, 3], 1.0, 0.5 * (lo + hi)))   # exact at the ends
        return w < _bernstein(W, t)

    def weights(self, xy, face=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows (N, 7), weights (N, 7) of one slice, and the clamped points (N, 2) (F §5)."""
        xy = self.clamp(xy)
        face = self.locate(xy) if face is None else np.asarray(face, np.int64)
        lam = self.barycentric(xy, face)
        rows = np.zeros((len(xy), 7), np.int64)
        w = np.zeros((len(xy), 7))
        for i in range(3):                                           # F §5.2 radial, §5.3 blend
            v = self.faces[face, i]
            e_n = self.vertices[self.faces[face, (i + 1) % 3]] - self.vertices[v]
            d = xy - self.vertices[v]
            psi = np.arctan2(_cross(e_n, d), np.sum(e_n * d, axis=1))
            psi = np.clip(psi, 0.0, self.c_beta[face, i])
            tau = np.minimum(self.c_alpha[face, i] + psi, self.c_theta[face, i]) / self.c_theta[face, i]
            tau = np.where(self.c_radial[face, i], tau, 0.0)
            rows[:, 2 * i], rows[:, 2 * i + 1] = self.c_start[face, i], self.c_end[face, i]
            w[:, 2 * i], w[:, 2 * i + 1] = lam[:, i] * (1.0 - tau), lam[:, i] * tau
        curve = self.face_curve[face]
        cand = np.flatnonzero(curve >= 0)
        q = cand[self.in_sliver(xy[cand], curve[cand])]              # F §5.4 sliver blend
        c = curve[q]
        rows[q] = 0
        w[q] = 0.0
        for slot, corner, row in ((0, self.corner_a[c], self.far_a[c]), (2, self.corner_b[c], self.far_b[c]),
                                  (6, self.corner_x[c], self.n_vertex_rows + c)):
            rows[q, slot] = row
            w[q, slot] = lam[q, corner]
        return rows, w, xy

    def features(self, xy, t=None, face=None) -> np.ndarray:
        """Φ(x, t) (N, K) float64 (F §§5–6)."""
        rows, w, _ = self.weights(xy, face)
        return self._blend(rows, w, t)

    def _blend(self, rows, w, t) -> np.ndarray:
        S = self.bank.shape[0]
        if S == 1:
            return np.einsum("nj,njk->nk", w, self.bank[0][rows])
        times = np.asarray(self.header["times"], np.float64)
        t = np.clip(np.broadcast_to(np.asarray(t, np.float64), (len(rows),)), times[0], times[-1])
        h = np.clip(np.searchsorted(times, t, side="left"), 1, S - 1)
        sigma = (t - times[h - 1]) / (times[h] - times[h - 1])
        lo = np.einsum("nj,njk->nk", w, self.bank[h - 1][np.arange(len(rows))[:, None], rows])
        hi = np.einsum("nj,njk->nk", w, self.bank[h][np.arange(len(rows))[:, None], rows])
        return (1.0 - sigma)[:, None] * lo + sigma[:, None] * hi

    def __call__(self, xy, t=None, face=None) -> np.ndarray:
        """f(x, t) (N, C) float64 (F §§7–8), plus R(x) with a residual raster (F §7.1)."""
        f = self._network(xy, t, face)
        if self.residual is None:
            return f
        space, r = self.residual
        rx = self._residual(np.asarray(xy, np.float64), r)
        if space == 0:
            return f + rx
        s = np.clip(f / (1 + np.abs(f)) + rx, -(1 - 2.0**-24), 1 - 2.0**-24)
        return s / (1 - np.abs(s))

    def _residual(self, xy: np.ndarray, r: np.ndarray) -> np.ndarray:
        """R(x) (N, C): the bilinear interpolant of the raster's values r on its pixel centres (F §7.1)."""
        h, w = r.shape[:2]
        x0, y0, x1, y1 = self.domain
        u = np.clip((xy[:, 0] - x0) * w / (x1 - x0) - 0.5, 0, w - 1)
        v = np.clip((xy[:, 1] - y0) * h / (y1 - y0) - 0.5, 0, h - 1)
        i0, j0 = np.floor(u).astype(int), np.floor(v).astype(int)
        i1, j1 = np.minimum(i0 + 1, w - 1), np.minimum(j0 + 1, h - 1)
        a, b = (u - i0)[:, None], (v - j0)[:, None]
        return (1 - b) * ((1 - a) * r[j0, i0] + a * r[j0, i1]) + b * ((1 - a) * r[j1, i0] + a * r[j1, i1])

    def _network(self, xy, t, face) -> np.ndarray:
        rows, w, xy = self.weights(xy, face)
        z = self._blend(rows, w, t)
        n_layers = sum(1 for name in self.mlp if name.endswith(".weight"))
        bins = (self.mlp["layers.0.weight"].shape[1] - z.shape[1]) // 2   # in_0 = K + 2b (F §7)
        if bins:
            x0, y0, x1, y1 = self.domain
            u = np.stack([(xy[:, 0] - x0) / (x1 - x0), (xy[:, 1] - y0) / (y1 - y0)], axis=1)
            d = (u[:, :, None] - (np.arange(bins) + 0.5) / bins) * bins
            z = np.concatenate([z, np.exp(-0.5 * d * d).reshape(len(z), 2 * bins)], axis=1)
        act = np.tanh if self.header["model"]["activation"] == "tanh" else (lambda s: np.maximum(s, 0.0))
        for i in range(n_layers):
            z = z @ self.mlp[f"layers.{i}.weight"].T + self.mlp[f"layers.{i}.bias"]
            if i < n_layers - 1:
                z = act(z)
        transform = self.header["value_transform"]
        if transform == "affine":                                    # D §5: offset + scale · y, product first
            return np.asarray(self.header["value_offset"], np.float64) + \
                np.asarray(self.header["value_scale"], np.float64) * z
        return np.expm1(z) if transform == "log" else z


def _decode_resd(data: bytes) -> np.ndarray:
    """(space, (H, W, C) float64 values) of an rESD payload (D §6.9)."""
    import imagecodecs

    version, codec, bits, c, space, w, h, lo, hi = struct.unpack_from("<BBBBB3xIIff", data)
    if (version, codec) != (1, 1) or space > 1:
        raise ValueError("unknown rESD version, codec or space")
    pos, images = 24, []
    for _ in range(-(-c // 3)):
        (n,) = struct.unpack_from("<I", data, pos)
        images.append(np.asarray(imagecodecs.avif_decode(data[pos + 4:pos + 4 + n])))
        pos += 4 + n
    samples = np.concatenate(images, axis=2)[..., :c].astype(np.float64)
    return space, lo + (hi - lo) * samples / (2**bits - 1)


def _pixel_filter(spec: str):
    """(name, parameter or None, k(u), support radius) of a ``pixel_filter`` string (D §5.1); ValueError if invalid."""
    name, _, raw = spec.partition(":")
    param = float(raw) if raw else {"gaussian": 0.5, "blackman-harris": 1.5}.get(name)
    ranges = {"box": (1, 64), "gaussian": (0, 8), "blackman-harris": (0, 16)}
    if name not in ("point", "box", "tent", "gaussian", "blackman-harris", "mitchell") or (
            raw and (name not in ranges or not ranges[name][0] <= param <= ranges[name][1] or param == 0
                     or (name == "box" and not param.is_integer()))):
        raise ValueError(f"pixel_filter {spec!r} is not a filter of D §5.1")
    b = c = 1 / 3
    kernels = {
        "point": (lambda u: np.ones_like(u), 0.0),
        "box": (lambda u: np.ones_like(u), 0.5),
        "tent": (lambda u: 1 - np.abs(u), 1.0),
        "gaussian": (lambda u: np.maximum(0, np.exp(-u**2 / (2 * param**2)) - np.exp(-(4 * param)**2 / (2 * param**2))),
                     4 * (param or 0)),
        "blackman-harris": (lambda u: 0.35875 - 0.48829 * np.cos(2 * np.pi * (u / (2 * param) + 0.5))
                            + 0.14128 * np.cos(4 * np.pi * (u / (2 * param) + 0.5))
                            - 0.01168 * np.cos(6 * np.pi * (u / (2 * param) + 0.5)), param or 0),
        "mitchell": (lambda u: np.where(np.abs(u) < 1, (12 - 9 * b - 6 * c) * np.abs(u)**3 + (-18 + 12 * b + 6 * c) * u**2
                                        + (6 - 2 * b), (-b - 6 * c) * np.abs(u)**3 + (6 * b + 30 * c) * u**2
                                        + (-12 * b - 48 * c) * np.abs(u) + (8 * b + 24 * c)) / 6, 2.0),
    }
    kernel, radius = kernels[name]
    return name, param, kernel, radius


def _bernstein(c: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cubic Bernstein polynomials with coefficients c (N, 4) at t (N,)."""
    s = 1.0 - t
    return s**3 * c[:, 0] + 3 * s * s * t * c[:, 1] + 3 * s * t * t * c[:, 2] + t**3 * c[:, 3]
