"""InstantNGP-style multiresolution hash encoding + small ReLU MLP (Müller et al. 2022), in pure torch.

Encoding. Positions are normalised by the domain's longer side (``base.normalise``), so the domain
becomes ``[0, w] × [0, h]`` with ``max(w, h) = 1``. Level ``l`` of ``L`` has resolution
``R_l = floor(N_min · b^l)`` with growth ``b = exp((ln N_max − ln N_min) / (L − 1))``: a grid of
``(ceil(R_l w) + 1) × (ceil(R_l h) + 1)`` nodes. A level whose node count fits the table size ``T``, and each
of the first ``dense_levels`` levels whatever its size, is indexed densely (``i + j · n_x``, table of exactly that
many rows); a finer one through InstantNGP's spatial hash ``((i · 1) xor (j · 2654435761 mod 2³²)) mod T`` into a table of ``T`` rows. Each row holds
``F`` features; the query bilinearly interpolates the four surrounding nodes of every level, and the
concatenated ``L · F`` features go through a ``hidden × layers`` ReLU MLP with a linear output.
InstantNGP uses ``T = 2^k``; here any integer ``T`` is allowed so that ``for_budget`` can meet a byte
budget to within a fraction of a percent (the hash is taken modulo ``T`` either way).

Storage: every table row and MLP weight as float16 (``dfc.bench.baselines.base``). Tables start uniform in
±1e-4 (InstantNGP). Vectorised over points and levels; runs on any torch device.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from ...field.mlp import MLP
from .base import FP16_BYTES, Baseline, normalise

__all__ = ["PRIMES", "HashGrid", "hash_index", "level_layout"]

PRIMES = (1, 2654435761)
"""InstantNGP's per-axis hash primes for x and y (``tiny-cuda-nn`` ``grid.h``)."""
INIT_SCALE = 1e-4
"""Tables start uniform in ±INIT_SCALE."""
MIN_HIDDEN = 8
"""``for_budget`` never shrinks the MLP below this width."""
ROUND_SLACK = 1e-9
"""Added before flooring ``N_min · b^l`` (and taken before ceiling node counts) so that a level meant to be
an integer resolution (the finest, ``N_max``) is not lost to floating-point rounding of the power."""
MLP_SHARE = 0.5
"""``for_budget`` shrinks the MLP when the default width would take more than this share of the budget."""


def level_layout(levels: int, base_resolution: int, finest_resolution: int, extent: tuple[float, float],
                 table_size: int, dense_levels: int = 0) -> dict[str, np.ndarray]:
    """Per-level resolution, node counts, table rows and row offsets.

    extent : (w, h) of the normalised domain (max = 1)
    dense_levels : the first this many levels are dense even when their nodes outnumber ``table_size``
    returns dict of (L,) int64 arrays: ``res``, ``nx``, ``ny``, ``rows``, ``offset``, and (L,) bool ``hashed``
    """
    if levels > 1:
        growth = math.exp((math.log(finest_resolution) - math.log(base_resolution)) / (levels - 1))
    else:
        growth = 1.0
    res = np.floor(base_resolution * growth ** np.arange(levels) + ROUND_SLACK).astype(np.int64)
    nx = np.ceil(res * extent[0] - ROUND_SLACK).astype(np.int64) + 1
    ny = np.ceil(res * extent[1] - ROUND_SLACK).astype(np.int64) + 1
    hashed = (nx * ny > table_size) & (np.arange(levels) >= dense_levels)
    rows = np.where(hashed, table_size, nx * ny)
    offset = np.concatenate([[0], np.cumsum(rows)[:-1]])
    return {"res": res, "nx": nx, "ny": ny, "rows": rows, "offset": offset, "hashed": hashed}


def hash_index(i: Tensor, j: Tensor, table_size: int) -> Tensor:
    """InstantNGP spatial hash of integer node coordinates (any shape, int64) -> rows in [0, table_size)."""
    return torch.bitwise_xor(i * PRIMES[0], (j * PRIMES[1]) & 0xFFFFFFFF) % table_size


def _mlp_bytes(in_dim: int, out_dim: int, hidden: int, layers: int) -> int:
    widths = [in_dim] + [hidden] * layers + [out_dim]
    return FP16_BYTES * sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:]))


class HashGrid(Baseline):
    """Hash-grid field ``xy (N, 2) domain units -> (N, C) float32``.

    Parameters
    ----------
    domain : (x0, y0, x1, y1); channels : output channel names
    levels, features : L and F (InstantNGP: 16, 2)
    table_size : T, rows per hashed level
    dense_levels : the first this many levels are stored densely whatever their size (``level_layout``)
    base_resolution, finest_resolution : N_min and N_max, cells per longer domain side
    hidden, layers : the ReLU MLP (InstantNGP: 64, 2)
    value_scale : the output unit (``Baseline``)
    seed : seeds the tables and the MLP; device : torch device
    """

    name = "hashgrid"

    def __init__(self, domain, channels, *, levels: int = 16, features: int = 2, table_size: int = 1 << 14,
                 base_resolution: int = 16, finest_resolution: int = 512, hidden: int = 64, layers: int = 2,
                 dense_levels: int = 0, value_scale: float = 1.0, seed: int = 0, device: str = "cpu"):
        super().__init__(domain, channels, value_scale)
        for key, v in (("levels", levels), ("features", features), ("table_size", table_size),
                       ("base_resolution", base_resolution), ("finest_resolution", finest_resolution)):
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{key} must be a positive integer, got {v!r}")
        if not isinstance(dense_levels, (int, np.integer)) or not 0 <= dense_levels <= levels:
            raise ValueError(f"dense_levels must be an integer in [0, levels={levels}], got {dense_levels!r}")
        if finest_resolution < base_resolution:
            raise ValueError(f"finest_resolution {finest_resolution} < base_resolution {base_resolution}")
        x0, y0, x1, y1 = self.domain
        side = max(x1 - x0, y1 - y0)
        self.extent = ((x1 - x0) / side, (y1 - y0) / side)
        self.levels, self.features, self.table_size = int(levels), int(features), int(table_size)
        self.base_resolution, self.finest_resolution = int(base_resolution), int(finest_resolution)
        self.dense_levels = int(dense_levels)
        layout = level_layout(self.levels, self.base_resolution, self.finest_resolution, self.extent, self.table_size,
                              self.dense_levels)
        self.first_hashed = int(np.argmax(layout["hashed"])) if layout["hashed"].any() else self.levels
        for key in ("res", "nx", "offset"):
            self.register_buffer(key, torch.from_numpy(layout[key]), persistent=False)
        self.register_buffer("limit", torch.from_numpy(np.stack([layout["nx"], layout["ny"]], 1) - 2), persistent=False)
        gen = torch.Generator().manual_seed(seed)
        table = (torch.rand(int(layout["rows"].sum()), self.features, generator=gen) * 2 - 1) * INIT_SCALE
        self.table = nn.Parameter(table)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.decoder = MLP(self.levels * self.features, len(self.channels), hidden=hidden, layers=layers)
        self.to(device)

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels, *, image: np.ndarray | None = None, seed: int = 0,
                   device: str = "cpu", levels: int = 16, features: int = 2, base_resolution: int = 16,
                   finest_resolution: int | None = None, hidden: int = 64, layers: int = 2,
                   dense_levels: int = 0) -> HashGrid:
        """Largest table size ``T`` whose stored bytes stay ≤ ``n_bytes``.

        The MLP keeps width ``hidden`` unless that would take more than ``MLP_SHARE`` of the budget; then
        it gets the widest width that fits that share (≥ ``MIN_HIDDEN``). ``finest_resolution`` defaults to
        the longer side of ``image`` in pixels, else of the domain in its own units. The output unit stays 1:
        the MLP scales itself (a unit of the data's maximum trains worse on HDR data: CHANGELOG.md, "Benchmark
        settings"). When even all-dense levels fit, the model is smaller than the budget. Raises ValueError when
        the budget cannot hold the MLP.
        """
        x0, y0, x1, y1 = (float(v) for v in domain)
        if finest_resolution is None:
            side = max(np.shape(image)[:2]) if image is not None else math.ceil(max(x1 - x0, y1 - y0))
            finest_resolution = max(base_resolution, int(side))
        in_dim, out_dim = levels * features, len(channels)
        while hidden > MIN_HIDDEN and _mlp_bytes(in_dim, out_dim, hidden, layers) > MLP_SHARE * n_bytes:
            hidden -= 1
        spare = (n_bytes - _mlp_bytes(in_dim, out_dim, hidden, layers)) // (FP16_BYTES * features)
        side = max(x1 - x0, y1 - y0)
        extent = ((x1 - x0) / side, (y1 - y0) / side)

        def rows(t: int) -> int:
            return int(level_layout(levels, base_resolution, finest_resolution, extent, t, dense_levels)["rows"].sum())

        if spare < rows(1):
            raise ValueError(f"a budget of {n_bytes} bytes cannot hold a {levels}-level hash grid"
                             + (f" with {dense_levels} dense levels" if dense_levels else "") + " and its MLP")
        nodes = level_layout(levels, base_resolution, finest_resolution, extent, 1)
        lo, hi = 1, int((nodes["nx"] * nodes["ny"]).max())  # beyond hi every level is dense
        while lo < hi:  # largest t with rows(t) ≤ spare (rows is non-decreasing in t)
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if rows(mid) <= spare else (lo, mid - 1)
        return cls(domain, channels, levels=levels, features=features, table_size=lo,
                   base_resolution=base_resolution, finest_resolution=finest_resolution, hidden=hidden,
                   layers=layers, dense_levels=dense_levels, seed=seed, device=device)

    def init_mean(self, mean: Tensor) -> None:
        """Start the output at a constant (C,) value (the data's mean): the MLP's output bias."""
        with torch.no_grad():
            self.decoder.linears()[-1].bias.copy_(torch.as_tensor(mean, dtype=torch.float32) / self.value_scale)

    def describe(self) -> dict:
        return {"class": type(self).__name__, "levels": self.levels, "features": self.features,
                "table_size": self.table_size, "base_resolution": self.base_resolution,
                "finest_resolution": self.finest_resolution, "dense_levels": self.first_hashed,
                "hidden": self.decoder.hidden, "layers": self.decoder.layers,
                "mlp_bytes": FP16_BYTES * sum(p.numel() for p in self.decoder.parameters()),
                "value_scale": self.value_scale}

    def corners(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Rows (N, L, 4) int64 into ``table`` and bilinear weights (N, L, 4) float32 of positions xy (N, 2).

        Corner order (i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1). Hashed levels are a suffix of the
        levels (node counts grow with the level), so dense and hashed rows are computed on slices.
        """
        u = normalise(xy, self.domain)
        u = torch.minimum(u.clamp_min(0), torch.tensor(self.extent, dtype=u.dtype, device=u.device))
        p = u[:, None, :] * self.res[None, :, None].to(u.dtype)  # (N, L, 2) node units
        i0 = torch.minimum(torch.floor(p).to(torch.int64), self.limit[None])  # (N, L, 2), ≤ n - 2
        f = (p - i0).to(torch.float32)
        step = torch.tensor([0, 1], device=xy.device)
        i = i0[..., 0, None] + step  # (N, L, 2): i, i + 1
        j = i0[..., 1, None] + step  # (N, L, 2): j, j + 1
        h = self.first_hashed
        dense = i[:, :h, None, :] + (j[:, :h] * self.nx[None, :h, None])[..., None]  # (N, Ld, 2 (j), 2 (i))
        hashed = hash_index(i[:, h:, None, :], j[:, h:, :, None], self.table_size)  # (N, Lh, 2 (j), 2 (i))
        rows = torch.cat([dense, hashed], dim=1).reshape(len(xy), self.levels, 4)
        fx, fy = f[..., 0, None], f[..., 1, None]
        wx = torch.cat([1 - fx, fx], dim=-1)  # (N, L, 2)
        wy = torch.cat([1 - fy, fy], dim=-1)
        w = (wy[..., :, None] * wx[..., None, :]).reshape(len(xy), self.levels, 4)
        return rows + self.offset[None, :, None], w

    def encode(self, xy: Tensor) -> Tensor:
        """Concatenated level features (N, L · F) float32."""
        rows, w = self.corners(xy)
        feats = self.table[rows]  # (N, L, 4, F)
        return (feats * w[..., None]).sum(dim=2).reshape(len(xy), -1)

    def forward(self, xy: Tensor) -> Tensor:
        return self.decoder(self.encode(xy)) * self.value_scale
