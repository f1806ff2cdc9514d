"""The ``FEAC`` chunk (spec/dfield.md §6.5): the quantised feature bank predicted from its neighbours and
range-coded (``dfc.io.entropy``).

Rows are *neighbours* when one triangle uses both: as the start or end row of one of its corners, or as a row of
its sliver when it holds a curve (``dfc.field.layout``). Each quantised value ``q[s, r, k]`` is predicted from the
rows ``j < r`` among row ``r``'s neighbours, ``p = floor((Σ q[s, j, k] + floor(n / 2)) / n)`` over those ``n``
rows (``2**(bits − 1)`` when there are none), and the residual ``q − p`` is coded. A row's class — 0 for the row
of a vertex without discontinuities, 1 for the rows of a vertex with them, 2 for a curve's row — picks one of three
models shared by all slices and channels; the stream holds, for each slice, class and channel in turn, the
residuals of that class's rows in increasing order. The decoder rebuilds the rows level by level (a row's level
is one more than the highest level among its earlier neighbours), each level in one vectorised step.
"""

from __future__ import annotations

import struct

import numpy as np
import scipy.sparse as sp

from ..errors import FormatError
from ..field.quantize import dequantize_features, quantize_features
from .entropy import GroupModel, decode_groups, encode_groups, fit_model

__all__ = ["CLASSES", "decode_feac", "encode_feac", "prediction_graph"]

CLASSES = 3
_HEAD = struct.Struct("<IIHBx")
_MODEL = struct.Struct("<iiHHHxx")


def prediction_graph(layout) -> tuple[sp.csr_matrix, np.ndarray]:
    """(P, classes): P (N, N) CSR with P[r, j] = 1 for every neighbour j < r of row r, and the (N,) int64 row classes
    of ``layout`` (``dfc.field.layout.Layout``)."""
    n = layout.n_features
    sets = [np.concatenate([layout.corner_start, layout.corner_end], axis=1), layout.curve_sliver_rows]
    rows, cols = [], []
    for s in sets:
        k = s.shape[1]
        rows.append(np.repeat(s, k, axis=1).ravel())
        cols.append(np.tile(s, (1, k)).ravel())
    r, c = np.concatenate(rows), np.concatenate(cols)
    keep = c < r
    P = sp.csr_matrix((np.ones(int(keep.sum()), np.int64), (r[keep], c[keep])), shape=(n, n))
    P.sum_duplicates()
    P.data[:] = 1
    classes = np.full(n, 2, np.int64)
    vertex_rows = np.where(layout.vertex_sectors > 0, 2 * layout.vertex_sectors, 1)
    classes[:layout.n_vertex_features] = np.repeat((layout.vertex_sectors > 0).astype(np.int64), vertex_rows)
    return P, classes


def _predict(P: sp.csr_matrix, counts: np.ndarray, q: np.ndarray, bits: int) -> np.ndarray:
    """Predictions (N', K) int64 for the rows of P (N', N) from q (N, K) int64; ``counts`` (N',) their earlier
    neighbours."""
    total = P @ q
    n = counts[:, None]
    return np.where(n > 0, (total + n // 2) // np.maximum(n, 1), 1 << (bits - 1))


def encode_feac(F: np.ndarray, bits: int, layout) -> bytes:
    """``FEAC`` chunk data of a feature bank F (S, N, K) float32 quantised to ``bits`` on ``layout``."""
    S, N, K = F.shape
    if N != layout.n_features:
        raise FormatError(f"cannot write: {N} feature rows, the mesh's layout has {layout.n_features}")
    q, scale, offset = quantize_features(F, bits)
    q = q.astype(np.int64)
    P, classes = prediction_graph(layout)
    counts = np.diff(P.indptr)
    residual = np.stack([q[s] - _predict(P, counts, q[s], bits) for s in range(S)])  # (S, N, K)
    models = [fit_model(residual[:, classes == c]) for c in range(CLASSES)]
    groups = [(models[c], residual[s, classes == c, k]) for s in range(S) for c in range(CLASSES) for k in range(K)]
    head = _HEAD.pack(S, N, K, bits) + scale.astype("<f4").tobytes() + offset.astype("<f4").tobytes()
    table = b"".join(_MODEL.pack(m.lo, m.hi, m.d1, m.d2, m.m) for m in models)
    return head + table + encode_groups(groups)


def decode_feac(data, info: dict, layout) -> np.ndarray:
    """The (S, N, K) float32 bank of ``FEAC`` chunk data whose fixed fields ``info`` holds (slices, rows, width,
    bits), on the decoded mesh's ``layout``; ``FormatError`` on any inconsistency."""
    S, N, K, bits = info["slices"], info["rows"], info["width"], info["bits"]
    if layout.n_features != N:
        raise FormatError(f"FEAC: {N} feature rows, the mesh's layout has {layout.n_features}")
    pos = _HEAD.size + 8 * K
    scale = np.frombuffer(data, "<f4", K, _HEAD.size).astype(np.float32)
    offset = np.frombuffer(data, "<f4", K, _HEAD.size + 4 * K).astype(np.float32)
    if not (np.all(np.isfinite(scale)) and np.all(scale > 0) and np.all(np.isfinite(offset))):
        raise FormatError("FEAC: scales must be finite and positive, offsets finite")
    if len(data) < pos + CLASSES * _MODEL.size:
        raise FormatError("FEAC: chunk too short for its models")
    limit = (1 << bits) - 1
    models = []
    for c in range(CLASSES):
        lo, hi, d1, d2, m = _MODEL.unpack_from(data, pos + c * _MODEL.size)
        if data[pos + c * _MODEL.size + 14] or data[pos + c * _MODEL.size + 15]:
            raise FormatError("FEAC: reserved field is not zero")
        if not -limit <= lo <= 0 <= hi <= limit:
            raise FormatError(f"FEAC: class {c} residual range [{lo}, {hi}] outside ±{limit}")
        models.append(GroupModel(lo, hi, d1, d2, m))
    P, classes = prediction_graph(layout)
    members = [np.flatnonzero(classes == c) for c in range(CLASSES)]
    groups = [(models[c], len(members[c])) for _ in range(S) for c in range(CLASSES) for _ in range(K)]
    values = iter(decode_groups(bytes(data[pos + CLASSES * _MODEL.size:]), groups, "FEAC"))
    residual = np.empty((S, N, K), np.int64)
    for s in range(S):
        for c in range(CLASSES):
            for k in range(K):
                residual[s, members[c], k] = next(values)
    q = np.stack([_rebuild(P, residual[s], bits) for s in range(S)])
    if q.min() < 0 or q.max() > limit:
        raise FormatError(f"FEAC: a quantised value lies outside 0 … 2**{bits} - 1")
    with np.errstate(over="ignore", invalid="ignore"):
        F = dequantize_features(q, scale, offset)
    if not np.all(np.isfinite(F)):
        raise FormatError("FEAC: a dequantised feature is not finite")
    return np.ascontiguousarray(F)


def _rebuild(P: sp.csr_matrix, residual: np.ndarray, bits: int) -> np.ndarray:
    """q (N, K) int64 from residuals (N, K), level by level (module docstring)."""
    indptr, indices = P.indptr.tolist(), P.indices.tolist()
    level = [0] * P.shape[0]
    for r in range(P.shape[0]):
        parents = indices[indptr[r]:indptr[r + 1]]
        if parents:
            level[r] = 1 + max(level[j] for j in parents)
    level = np.asarray(level, np.int64)
    order = np.argsort(level, kind="stable")
    bounds = np.searchsorted(level[order], np.arange(level.max(initial=0) + 2))
    counts = np.diff(P.indptr)
    q = np.zeros_like(residual)
    for a, b in zip(bounds[:-1], bounds[1:]):
        rows = order[a:b]
        q[rows] = residual[rows] + _predict(P[rows], counts[rows], q, bits)
    return q
