"""Range coding of integer symbols under two-slope geometric models (spec/dfield.md §6.6), with ``constriction``.

A *group* is a run of integers ``v`` in ``[lo, hi]`` (``lo ≤ 0 ≤ hi``) coded independently of each other under one
model with parameters ``(d1, d2, m)``, u16 each: integer weights ``a_0 = 2**30``, ``a_{j+1} = (a_j · (d1 if j < m
else d2)) >> 16`` (a geometric decay by ``d1 / 65536`` per step up to ``|v| = m``, by ``d2 / 65536`` beyond, a
two-slope discrete Laplace centred on 0), ``w(v) = a_|v|``, scaled to counts ``c(v) = floor(w(v) · T / G)`` with
``T = 2**24 − n``, ``n = hi − lo + 1``, ``G = Σ w``, the rounding remainder added to ``c(0)``; symbol ``v − lo`` then
has the frequency ``c(v) + 1`` out of ``2**24`` in constriction's ``Categorical(c, perfect=False)`` (its
``from_floating_point_probabilities_fast`` reproduces integer counts that sum to ``T`` exactly). Groups with
``n = 1`` code nothing (every value is 0). All groups of a stream share one ``RangeEncoder`` (32-bit words, 64-bit
state), stored as its little-endian u32 words.

The encoder chooses each group's parameters by a grid search for the fewest bits (``fit_model``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import FormatError

__all__ = ["PRECISION", "GroupModel", "counts", "decode_groups", "encode_groups", "fit_model"]

PRECISION = 24
"""Bits of constriction's default fixed-point probabilities."""
A0 = 1 << 30
MAX_SEARCH = 1 << 22
"""Table entries (candidates × longest run of weights) ``fit_model`` evaluates per block."""
COARSE_STEP = 3
"""``fit_model`` searches every this-many-th decay first: 9 times fewer candidates than the full grid, and on the
README sample's features 0.1 % more bytes than the full search in a tenth of its time."""
_M_GRID = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 65535)
_D_GRID = np.unique(np.clip(np.rint(65536.0 * (1.0 - 2.0 ** -np.linspace(0.25, 14.0, 48))), 1, 65535)).astype(np.int64)


@dataclass(frozen=True)
class GroupModel:
    """One group's model: the value range ``[lo, hi]`` (``lo ≤ 0 ≤ hi``) and the decays ``d1``, ``d2`` (1 … 65535,
    per 65536) with the switch ``m`` (0 … 65535)."""

    lo: int
    hi: int
    d1: int
    d2: int
    m: int

    @property
    def size(self) -> int:
        return self.hi - self.lo + 1


def _weights(d1: np.ndarray, d2: np.ndarray, m: np.ndarray, top: int) -> np.ndarray:
    """(K, top + 1) int64 weights ``a_0 … a_top`` of K candidate parameter sets (each (K,) int64)."""
    a = np.empty((len(d1), top + 1), np.int64)
    a[:, 0] = A0
    for j in range(top):
        a[:, j + 1] = (a[:, j] * np.where(j < m, d1, d2)) >> 16
    return a


def _scale(w: np.ndarray, zero: int) -> np.ndarray:
    """Counts (K, n) int64 summing to ``2**PRECISION − n`` per row, from weights w (K, n); column ``zero`` is v = 0."""
    n = w.shape[1]
    total = (1 << PRECISION) - n
    c = w * total // w.sum(axis=1, keepdims=True)
    c[:, zero] += total - c.sum(axis=1)
    return c


def counts(model: GroupModel) -> np.ndarray:
    """(n,) int64 counts ``c(v)`` of ``v = lo … hi`` (module docstring); the coder's frequencies are ``c + 1``."""
    top = max(-model.lo, model.hi)
    a = _weights(np.array([model.d1]), np.array([model.d2]), np.array([model.m]), top)[0]
    w = a[np.abs(np.arange(model.lo, model.hi + 1))]
    return _scale(w[None], -model.lo)[0]


def fit_model(values: np.ndarray) -> GroupModel:
    """A model of the grid (``d1``, ``d2`` in 48 steps, ``m`` in 15) that codes integers ``values`` in few bits:
    the best of the whole grid when the values span at most a block of ``MAX_SEARCH`` table entries; else the best of
    a coarse grid (every ``COARSE_STEP``-th decay), then of the full grid around it (within ``COARSE_STEP`` − 1 steps
    of each decay and two of ``m``); one slope only when the values span so much that even that would be slow."""
    values = np.asarray(values, np.int64).ravel()
    lo, hi = min(0, int(values.min(initial=0))), max(0, int(values.max(initial=0)))
    if lo == hi:
        return GroupModel(0, 0, 1, 1, 0)
    hist = np.bincount(values - lo, minlength=hi - lo + 1).astype(np.float64)
    search = _Search(hist, lo)
    m_grid = np.array(_M_GRID, np.int64)
    table = len(_D_GRID) ** 2 * len(m_grid) * (hi - lo + 1)  # entries of the whole grid's search
    if table <= MAX_SEARCH:
        d1, d2, m = (g.ravel() for g in np.meshgrid(_D_GRID, _D_GRID, m_grid, indexing="ij"))
        return GroupModel(lo, hi, *search.best(d1, d2, m))
    if table > 64 * MAX_SEARCH * COARSE_STEP**2:
        d1, d2, m = search.best(_D_GRID, _D_GRID, np.zeros_like(_D_GRID))
        return GroupModel(lo, hi, d1, d2, m)
    coarse = np.arange(0, len(_D_GRID), COARSE_STEP)
    i1, i2, im = (g.ravel() for g in np.meshgrid(coarse, coarse, np.arange(len(m_grid)), indexing="ij"))
    k = search.index(_D_GRID[i1], _D_GRID[i2], m_grid[im])
    r = COARSE_STEP - 1
    near = [np.arange(max(0, c - reach), min(size, c + reach + 1))
            for c, reach, size in ((i1[k], r, len(_D_GRID)), (i2[k], r, len(_D_GRID)), (im[k], 2, len(m_grid)))]
    j1, j2, jm = (g.ravel() for g in np.meshgrid(*near, indexing="ij"))
    d1, d2, m = search.best(_D_GRID[j1], _D_GRID[j2], m_grid[jm])
    return GroupModel(lo, hi, d1, d2, m)


class _Search:
    """The candidate of a list that codes the histogram ``hist`` of ``v = lo …`` in the fewest bits."""

    def __init__(self, hist: np.ndarray, lo: int):
        self.hist, self.lo = hist, lo
        self.top = max(-lo, len(hist) - 1 + lo)
        self.where = np.abs(np.arange(lo, lo + len(hist)))

    def index(self, d1: np.ndarray, d2: np.ndarray, m: np.ndarray) -> int:
        """Position in the (K,) candidate arrays of the best one (the first of equals)."""
        block = max(1, MAX_SEARCH // len(self.hist))
        best, best_bits = 0, np.inf
        for s in range(0, len(d1), block):
            w = _weights(d1[s:s + block], d2[s:s + block], m[s:s + block], self.top)[:, self.where]
            bits = -(np.log2(_scale(w, -self.lo) + 1.0) @ self.hist)
            k = int(np.argmin(bits))
            if bits[k] < best_bits:
                best, best_bits = s + k, bits[k]
        return best

    def best(self, d1: np.ndarray, d2: np.ndarray, m: np.ndarray) -> tuple[int, int, int]:
        k = self.index(d1, d2, m)
        return int(d1[k]), int(d2[k]), int(m[k])


def _categorical(model: GroupModel):
    import constriction

    return constriction.stream.model.Categorical(counts(model).astype(np.float64), perfect=False)


def encode_groups(groups: list[tuple[GroupModel, np.ndarray]]) -> bytes:
    """Range-code every group's integers (in ``[lo, hi]`` of its model) in order; the little-endian u32 words."""
    import constriction

    encoder = constriction.stream.queue.RangeEncoder()
    for model, values in groups:
        values = np.asarray(values, np.int64).ravel()
        if model.size > 1 and len(values):
            encoder.encode((values - model.lo).astype(np.int32), _categorical(model))
    return np.asarray(encoder.get_compressed(), "<u4").tobytes()


def decode_groups(data: bytes, groups: list[tuple[GroupModel, int]], chunk: str) -> list[np.ndarray]:
    """Inverse of ``encode_groups`` for ``(model, count)`` per group: (count,) int64 values each. ``FormatError``
    when the words are not whole u32 or the stream ends early."""
    import constriction

    if len(data) % 4:
        raise FormatError(f"{chunk}: range-coded stream is not a whole number of 32-bit words")
    words = np.frombuffer(data, "<u4").astype(np.uint32)
    decoder = constriction.stream.queue.RangeDecoder(words)
    out = []
    for model, count in groups:
        if model.size == 1 or count == 0:
            out.append(np.zeros(count, np.int64))
            continue
        try:
            symbols = np.asarray(decoder.decode(_categorical(model), count), np.int64)
        except Exception as exc:  # constriction raises its own types on a malformed stream
            raise FormatError(f"{chunk}: range-coded stream is corrupt ({type(exc).__name__})") from None
        out.append(symbols + model.lo)
    return out
