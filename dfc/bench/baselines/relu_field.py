"""ReLU fields (Karnewar et al. 2022) for 2-D signals: a regular grid of C values per node, bilinear
interpolation, then clamping — ``clamp(bilinear(grid)(x), lo, hi)``.

The grid's ``n_x × n_y`` nodes sit on the domain's corners and evenly in between (``grid_sample`` with
``align_corners=True``). Clamping is what lets a cell hold a sharp edge: with ``[lo, hi] = [0, 1]`` (LDR,
the paper's setting) an edge is sharp where one side saturates; ``hi=None`` clamps at 0 only (a ReLU, for
HDR signals). Training runs coarse to fine: ``COARSE_TO_FINE`` gives the grid sizes (fractions of the
final one) and each stage's share of the steps; between stages the grid is bilinearly upsampled.

Channels: by default the grid holds the C output values per node (the paper's form). With ``features=K ≠ C``
it holds K values per node and a linear map ``K → C`` (weights and biases stored too) runs before the clamp: fewer
channels buy a finer grid at the same bytes (``dfc.bench.tuning`` sweeps K per budget).

Storage: the final grid's values as float16 (``dfc.bench.baselines.base``): ``2 · K · n_x · n_y`` bytes, plus
``2 · (K + 1) · C`` for the linear map when there is one.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import Tensor, nn

from .base import FP16_BYTES, Baseline, value_scale

__all__ = ["COARSE_TO_FINE", "ReluField", "hdr_unit"]

COARSE_TO_FINE = ((0.25, 0.25), (0.5, 0.25), (1.0, 0.5))
"""(grid size as a fraction of the final, share of the steps) per training stage."""
MIN_NODES = 2
"""Fewest nodes per axis."""
FILL = 0.98
FILL_ROWS = 3
"""``for_budget``: when the grid closest to the domain's aspect ratio uses less than ``FILL`` of the nodes the budget
holds, node rows up to ``FILL_ROWS`` more or fewer are tried and the fullest grid is kept."""


def hdr_unit(image) -> float:
    """The unit a ReLU field's grid stores values in for ``image`` (any array, or None): the square root of
    ``base.value_scale`` — 1 for colours in [-1, 1], else the geometric mean of 1 and the largest magnitude.

    Adam moves each node by about the learning rate per step, in this unit: the data's maximum reaches bright values
    within the 200 steps of a tuning candidate but cannot settle the dark ones, a unit of 1 settles them but starts
    too slowly for a sweep to pick it; the geometric mean does both (CHANGELOG.md, "Benchmark settings").
    """
    return math.sqrt(value_scale(image))


def grid_coords(xy: Tensor, domain) -> Tensor:
    """Positions (N, 2) in domain units -> ``grid_sample`` coordinates (1, 1, N, 2) float32 in [-1, 1]."""
    x0, y0, x1, y1 = domain
    lo = torch.tensor([x0, y0], dtype=torch.float64, device=xy.device)
    span = torch.tensor([x1 - x0, y1 - y0], dtype=torch.float64, device=xy.device)
    return (2.0 * (xy.to(torch.float64) - lo) / span - 1.0).to(torch.float32)[None, None]


class ReluField(Baseline):
    """Clamped bilinear grid ``xy (N, 2) domain units -> (N, C) float32``.

    Parameters
    ----------
    domain, channels : as every baseline
    shape : (n_y, n_x) final node counts
    lo, hi : clamp range; ``hi=None`` for no upper clamp
    stages : ``COARSE_TO_FINE``-style schedule; ``((1.0, 1.0),)`` trains at the final size only
    value_scale : the grid stores values in this unit (``Baseline``); the clamp applies to the values
    features : K values per node (default C: no linear map); seed : seeds the linear map; device : torch device
    """

    name = "relu"

    def __init__(self, domain, channels, *, shape: tuple[int, int], lo: float = 0.0, hi: float | None = 1.0,
                 stages=COARSE_TO_FINE, value_scale: float = 1.0, features: int | None = None, seed: int = 0,
                 device: str = "cpu"):
        super().__init__(domain, channels, value_scale)
        ny, nx = (int(v) for v in shape)
        if min(ny, nx) < MIN_NODES:
            raise ValueError(f"shape must have at least {MIN_NODES} nodes per axis, got {shape}")
        if not stages or not math.isclose(sum(s for _, s in stages), 1.0) or stages[-1][0] != 1.0:
            raise ValueError(f"stages must end at size 1.0 and their step shares sum to 1, got {stages}")
        k = len(self.channels) if features is None else int(features)
        if k < 1:
            raise ValueError(f"features must be ≥ 1, got {features!r}")
        self.shape, self.lo, self.hi = (ny, nx), float(lo), None if hi is None else float(hi)
        self.schedule = tuple((float(a), float(b)) for a, b in stages)
        self.stage = 0
        self.features = k
        self.grid = nn.Parameter(torch.zeros(1, k, *self._stage_shape(0), device=device))
        self.head = None
        if k != len(self.channels):
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                self.head = nn.Linear(k, len(self.channels)).to(device)

    def _stage_shape(self, k: int) -> tuple[int, int]:
        f = self.schedule[k][0]
        return tuple(max(MIN_NODES, round(n * f)) for n in self.shape)

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels, *, image: np.ndarray | None = None, seed: int = 0,
                   device: str = "cpu", lo: float | None = None, hi: float | None = None,
                   stages=COARSE_TO_FINE, features: int | None = None) -> ReluField:
        """The grid with (n_x − 1) / (n_y − 1) closest to the domain's aspect ratio (up to ``FILL_ROWS`` rows off, to
        fill a small budget) and the most nodes whose stored bytes (with ``features`` per node, default C) stay
        ≤ ``n_bytes``. Raises ValueError when not even 2 × 2 nodes fit.

        Clamp range: ``lo`` defaults to min(0, image minimum) (0 without an image); ``hi`` to 1 when the
        image lies in [0, 1] (or there is no image), else no upper clamp. The grid stores values in units of
        ``hdr_unit(image)``. ``seed`` seeds the linear map (when ``features`` differs from C).
        """
        if lo is None:
            lo = min(0.0, float(np.min(image))) if image is not None else 0.0
        if hi is None and (image is None or float(np.max(image)) <= 1.0):
            hi = 1.0
        x0, y0, x1, y1 = (float(v) for v in domain)
        k = len(channels) if features is None else int(features)
        head = 0 if k == len(channels) else FP16_BYTES * (k + 1) * len(channels)
        nodes = max(0, n_bytes - head) // (FP16_BYTES * k)
        if nodes < MIN_NODES**2:
            raise ValueError(f"a budget of {n_bytes} bytes cannot hold a {MIN_NODES}×{MIN_NODES} grid")
        aspect = (x1 - x0) / (y1 - y0)
        ny = max(MIN_NODES, min(nodes // MIN_NODES, math.floor(math.sqrt(nodes / aspect))))
        if (nodes // ny) * ny < FILL * nodes:  # a small grid: a row more or less may fill the budget better
            ny = max(range(max(MIN_NODES, ny - FILL_ROWS), min(nodes // MIN_NODES, ny + FILL_ROWS) + 1),
                     key=lambda n: ((nodes // n) * n, -abs(n - ny)))
        nx = nodes // ny
        return cls(domain, channels, shape=(ny, nx), lo=lo, hi=hi, stages=stages, value_scale=hdr_unit(image),
                   features=k, seed=seed, device=device)

    def stored_bytes(self) -> int:
        """Bytes of the final grid in float16 (also while training at a coarser stage), and of the linear map."""
        head = 0 if self.head is None else FP16_BYTES * sum(p.numel() for p in self.head.parameters())
        return FP16_BYTES * self.features * self.shape[0] * self.shape[1] + head

    def init_mean(self, mean: Tensor) -> None:
        """Start at a constant (C,) value (the data's mean): in the grid, or in the linear map's bias."""
        with torch.no_grad():
            mean = torch.as_tensor(mean, dtype=torch.float32) / self.value_scale
            if self.head is None:
                self.grid.copy_(mean.reshape(1, -1, 1, 1).expand_as(self.grid))
            else:
                self.head.bias.copy_(mean.to(self.head.bias.device))

    def describe(self) -> dict:
        return {"class": type(self).__name__, "grid": [self.shape[1], self.shape[0]], "features": self.features,
                "lo": self.lo, "hi": self.hi, "value_scale": self.value_scale}

    def stages(self, steps: int) -> list[int]:
        counts = [max(1, round(steps * share)) for _, share in self.schedule[:-1]]
        return counts + [max(1, steps - sum(counts))]

    def next_stage(self) -> None:
        """Bilinearly upsample the grid to the next stage's size (a new Parameter)."""
        self.stage += 1
        with torch.no_grad():
            up = nnf.interpolate(self.grid, size=self._stage_shape(self.stage), mode="bilinear", align_corners=True)
        self.grid = nn.Parameter(up)

    def bilinear(self, xy: Tensor) -> Tensor:
        """The grid bilinearly interpolated at xy (N, 2) domain units, through the linear map when there is one:
        (N, C) float32, in units of ``value_scale``."""
        v = nnf.grid_sample(self.grid, grid_coords(xy, self.domain), mode="bilinear", padding_mode="border",
                            align_corners=True)[0, :, 0].T
        return v if self.head is None else self.head(v)

    def forward(self, xy: Tensor) -> Tensor:
        v = self.bilinear(xy) * self.value_scale
        return v.clamp_min(self.lo) if self.hi is None else v.clamp(self.lo, self.hi)
