"""``FeatureField``: the discontinuity-aware feature field on a curved mesh (docs/design.md §5).

A point ``x`` maps to at most seven (bank row, weight) pairs (``dfc.field.interp``) and its feature
is their weighted sum, a gather done by ``torch.nn.functional.embedding_bag``; autograd provides
the backward pass to the bank and to ``x``. Bank rows are laid out as in ``dfc.field.layout``.

Queries outside the domain rectangle are clamped onto it (the gradient w.r.t. a clamped coordinate
is zero). Geometry is float64; features are float32.

Time axis: with ``S > 1`` slices at increasing ``times``, ``features(xy, t)`` blends linearly
between the two slices around ``t`` (``t`` clamped into ``[times[0], times[-1]]``); ``S == 1``
ignores ``t``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from ..errors import InputError
from ..geometry.mesh import Mesh
from .interp import Interpolator
from .layout import build_layout
from .locate import PointLocator

__all__ = ["FeatureField", "INIT_RANGE", "PackedQuery", "pack_query", "packed_rows", "weighted_rows"]

INIT_RANGE = 2e-3
"""Features start uniform in ±INIT_RANGE (paper §5 and the official code)."""


class _WeightedRows(torch.autograd.Function):
    """``embedding_bag`` sum of weighted rows whose backward to the table is one ``index_add_`` (on the CPU several
    times faster than ``embedding_bag``'s, which sorts the indices every step); the weights get no gradient."""

    @staticmethod
    def forward(ctx, table, idx, w):
        ctx.save_for_backward(idx, w)
        ctx.rows = table.shape[0]
        return weighted_rows(table, idx, w)

    @staticmethod
    def backward(ctx, grad):
        idx, w = ctx.saved_tensors
        rows = (w[:, :, None] * grad[:, None, :]).reshape(-1, grad.shape[1])
        return grad.new_zeros(ctx.rows, grad.shape[1]).index_add_(0, idx.reshape(-1), rows), None, None


def _table_grad_on_cpu(table: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> bool:
    """Whether a gather of ``table``'s rows takes the CPU's custom backward: on the CPU, a gradient wanted for the
    table and none for the weights (a fit's precomputed queries)."""
    return idx.device.type == "cpu" and not w.requires_grad and table.requires_grad and torch.is_grad_enabled()


def weighted_rows(table: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(N, D) sums of ``table`` (R, D) rows ``idx`` (N, k) int64 weighted by ``w`` (N, k): ``embedding_bag``, with a
    faster gradient to ``table`` on the CPU when ``w`` needs none (a fit's precomputed queries)."""
    if _table_grad_on_cpu(table, idx, w):
        return _WeightedRows.apply(table, idx, w)
    return nnf.embedding_bag(idx, table, per_sample_weights=w, mode="sum")


class PackedQuery(NamedTuple):
    """A precomputed query without its zero-weight slots (most points use three of the seven): ``idx`` (M,) int64
    bank rows and ``w`` (M,) float32 weights of every point's nonzero slots, point after point in slot order;
    ``offsets`` (N,) int64 each point's first slot; ``point`` (M,) int64 each slot's point. ``packed_rows`` of it
    equals ``weighted_rows`` of the full query."""

    idx: torch.Tensor
    w: torch.Tensor
    offsets: torch.Tensor
    point: torch.Tensor


def pack_query(idx: torch.Tensor, w: torch.Tensor) -> PackedQuery:
    """The ``PackedQuery`` of a query ``idx`` (N, k) int64, ``w`` (N, k)."""
    nonzero = w != 0
    keep = torch.nonzero(nonzero.reshape(-1)).squeeze(1)
    counts = nonzero.sum(1)
    return PackedQuery(idx.reshape(-1).index_select(0, keep), w.reshape(-1).index_select(0, keep),
                       torch.cumsum(counts, 0) - counts,
                       torch.repeat_interleave(torch.arange(len(idx), device=idx.device), counts))


class _PackedRows(torch.autograd.Function):
    """``embedding_bag`` sums of a ``PackedQuery``'s weighted rows, whose backward to the table is one ``index_add_``
    of the nonzero slots' rows (the weights get no gradient)."""

    @staticmethod
    def forward(ctx, table, idx, w, offsets, point):
        ctx.save_for_backward(idx, w, point)
        ctx.rows = table.shape[0]
        return nnf.embedding_bag(idx, table, offsets, mode="sum", per_sample_weights=w)

    @staticmethod
    def backward(ctx, grad):
        idx, w, point = ctx.saved_tensors
        rows = grad.index_select(0, point) * w[:, None]
        return grad.new_zeros(ctx.rows, grad.shape[1]).index_add_(0, idx, rows), None, None, None, None


def packed_rows(table: torch.Tensor, q: PackedQuery) -> torch.Tensor:
    """(N, D) sums of ``table`` (R, D) rows weighted as the packed query ``q`` says (``weighted_rows`` of the full
    query); on the CPU, when only ``table`` needs a gradient, through ``_PackedRows``."""
    if _table_grad_on_cpu(table, q.idx, q.w):
        return _PackedRows.apply(table, q.idx, q.w, q.offsets, q.point)
    return nnf.embedding_bag(q.idx, table, q.offsets, mode="sum", per_sample_weights=q.w)


class FeatureField(nn.Module):
    """Discontinuity-aware feature field.

    mesh : the curved triangulation; dim : feature channels K; seed : seeds the bank's initialisation
    (``torch.Generator``); n_slices : time slices S; times : (S,) increasing times (required when
    S > 1); device : where parameters and geometry live.

    Attributes: ``bank`` (S, n_features, dim) float32 parameter, ``dim``, ``n_features``, ``mesh``,
    ``times`` ((S,) float64 buffer or None), ``layout``.
    """

    def __init__(self, mesh: Mesh, dim: int = 5, seed: int = 0, n_slices: int = 1, times=None,
                 device: str | torch.device = "cpu"):
        super().__init__()
        if int(dim) < 1:
            raise InputError(f"feature field: dim must be >= 1, got {dim}")
        if int(n_slices) < 1:
            raise InputError(f"feature field: n_slices must be >= 1, got {n_slices}")
        n_slices = int(n_slices)
        if times is not None:
            times = torch.as_tensor(np.asarray(times, dtype=np.float64).reshape(-1))
            if len(times) != n_slices:
                raise InputError(f"feature field: {len(times)} times given for {n_slices} slices")
            if n_slices > 1 and not bool((times[1:] > times[:-1]).all()):
                raise InputError("feature field: times must be strictly increasing")
        elif n_slices > 1:
            raise InputError("feature field: n_slices > 1 needs times")
        self.mesh = mesh
        self.dim = int(dim)
        self.layout = build_layout(mesh)
        self.n_features = self.layout.n_features
        self.locator = PointLocator(mesh.vertices, mesh.triangles, mesh.domain)
        self.interp = Interpolator(mesh, self.layout)
        gen = torch.Generator().manual_seed(int(seed))
        bank = (torch.rand((n_slices, self.n_features, self.dim), generator=gen) * 2.0 - 1.0) * INIT_RANGE
        self.bank = nn.Parameter(bank)
        self.register_buffer("times", times)
        self.to(device)

    @property
    def n_slices(self) -> int:
        return self.bank.shape[0]

    def _points(self, xy) -> torch.Tensor:
        if not isinstance(xy, torch.Tensor):
            xy = torch.as_tensor(np.asarray(xy, dtype=np.float64))
        if xy.ndim != 2 or xy.shape[1] != 2 or not xy.dtype.is_floating_point:
            raise InputError(f"feature field: expected query points of shape (N, 2) float, got {tuple(xy.shape)} {xy.dtype}")
        return xy.to(device=self.bank.device, dtype=torch.float64)

    def query(self, xy) -> tuple[torch.Tensor, torch.Tensor]:
        """Bank rows and weights of points.

        xy : (N, 2) float32/float64 tensor in domain units (clamped into the domain).
        Returns idx (N, 7) int64 rows of one slice of the bank (padding: row 0, weight 0) and
        w (N, 7) float32 weights summing to 1, differentiable w.r.t. xy. Slot layout: ``dfc.field.interp``.
        """
        xy = self.locator.clamp(self._points(xy))
        tri, bary = self.locator(xy.detach())
        if xy.requires_grad:
            bary = self.locator.barycentric(xy, tri)
        return self.interp(xy, tri, bary)

    def _slices(self, t, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Lower slice (N,) int64, upper slice (N,) int64 and blend (N,) float32 for times t."""
        t = torch.as_tensor(t, dtype=torch.float64, device=self.bank.device).reshape(-1).expand(n)
        times = self.times
        t = t.clamp(times[0], times[-1])
        hi = torch.searchsorted(times, t, right=False).clamp(1, len(times) - 1)
        lo = hi - 1
        s = (t - times[lo]) / (times[hi] - times[lo])
        return lo, hi, s.to(torch.float32)

    def features(self, xy, t=None) -> torch.Tensor:
        """Features (N, dim) float32 of points xy (N, 2) at time t (float or (N,) tensor; ignored when S == 1).

        Differentiable w.r.t. ``bank`` and ``xy``.
        """
        idx, w = self.query(xy)
        table = self.bank.reshape(-1, self.dim)
        if self.n_slices > 1:
            if t is None:
                raise InputError("feature field: a time t is needed with several time slices")
            lo, hi, s = self._slices(t, len(idx))
            nf = self.n_features
            idx = torch.cat([idx + (lo * nf)[:, None], idx + (hi * nf)[:, None]], dim=1)
            w = torch.cat([w * (1.0 - s)[:, None], w * s[:, None]], dim=1)
        return weighted_rows(table, idx, w)

    forward = features
