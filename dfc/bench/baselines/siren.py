"""SIREN (Sitzmann et al. 2020), the paper's physics-informed baseline: an MLP with sine activations.

Positions are normalised by the domain's longer side (``base.normalise``) and mapped to ``[-1, 1]`` along it,
``v = 2u − 1``. ``layers`` sine layers of width ``hidden``, ``y ← sin(ω₀ (W y + b))``, then a linear output
layer; the paper's network is 5 layers × 256 with ``ω₀ = 30``. Initialisation as in the SIREN paper: the first
layer's weights uniform in ``±1 / in_dim``, every later weight uniform in ``±√(6 / n) / ω₀`` (n its input
width); biases as ``torch.nn.Linear`` draws them.

Storage: every weight and bias as float16 (``dfc.bench.baselines.base``). The architecture is fixed, not sized to a
budget: ``for_budget`` returns the paper's network whatever the budget (about 529 kB for 3 channels, far more
than a ``.dfield``), and ``stored_bytes`` reports its true size.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from .base import Baseline, normalise

__all__ = ["Siren"]

OMEGA_0 = 30.0
"""Frequency factor ω₀ of every sine layer (SIREN's default)."""


class Siren(Baseline):
    """Sine-activated MLP ``xy (N, 2) domain units -> (N, C) float32``.

    Parameters
    ----------
    domain, channels : as every baseline
    hidden, layers : width and number of sine layers (paper: 256, 5)
    omega : ω₀; value_scale : the output unit (``Baseline``)
    seed : seeds the initialisation; device : torch device
    """

    name = "siren"

    def __init__(self, domain, channels, *, hidden: int = 256, layers: int = 5, omega: float = OMEGA_0,
                 value_scale: float = 1.0, seed: int = 0, device: str = "cpu"):
        super().__init__(domain, channels, value_scale)
        if hidden < 1 or layers < 1:
            raise ValueError(f"hidden and layers must be ≥ 1, got {hidden} and {layers}")
        self.hidden, self.layers, self.omega = int(hidden), int(layers), float(omega)
        widths = [2] + [self.hidden] * self.layers + [len(self.channels)]
        gen = torch.Generator().manual_seed(seed)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.linears = nn.ModuleList(nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))
        with torch.no_grad():
            for k, lin in enumerate(self.linears):
                bound = 1.0 / lin.in_features if k == 0 else math.sqrt(6.0 / lin.in_features) / self.omega
                lin.weight.copy_((torch.rand(lin.weight.shape, generator=gen) * 2 - 1) * bound)
        x0, y0, x1, y1 = self.domain
        side = max(x1 - x0, y1 - y0)
        self.extent = ((x1 - x0) / side, (y1 - y0) / side)
        self.to(device)

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels, *, image: np.ndarray | None = None, seed: int = 0,
                   device: str = "cpu", hidden: int = 256, layers: int = 5) -> Siren:
        """The fixed ``hidden × layers`` network (module docstring): ``n_bytes`` is not used, nor ``image``."""
        return cls(domain, channels, hidden=hidden, layers=layers, seed=seed, device=device)

    def init_mean(self, mean: Tensor) -> None:
        """Start the output near a constant (C,) value: the output layer's bias."""
        with torch.no_grad():
            self.linears[-1].bias.copy_(torch.as_tensor(mean, dtype=torch.float32) / self.value_scale)

    def describe(self) -> dict:
        return {"class": type(self).__name__, "hidden": self.hidden, "layers": self.layers, "omega": self.omega}

    def forward(self, xy: Tensor) -> Tensor:
        y = (2.0 * normalise(xy, self.domain) - 1.0).to(torch.float32)
        for lin in self.linears[:-1]:
            y = torch.sin(self.omega * lin(y))
        return self.linears[-1](y) * self.value_scale
