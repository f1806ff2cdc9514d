"""A plain tanh MLP, the paper's physics-informed-network baseline (§6.3; Raissi et al. 2019).

Positions are normalised by the domain's longer side (``base.normalise``) and mapped to ``[-1, 1]`` along it,
``v = 2u − 1``, then ``layers`` tanh layers of width ``hidden`` and a linear output layer (``dfc.field.mlp.MLP``);
the paper's network is 4 layers × 512. Weights start Glorot-normal and biases at zero, the usual PINN
initialisation.

Storage: every weight and bias as float16 (``dfc.bench.baselines.base``). The architecture is fixed, not sized to a
budget: ``for_budget`` returns the paper's network whatever the budget (about 1.58 MB for 3 channels), and
``stored_bytes`` reports its true size.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ...field.mlp import MLP
from .base import Baseline, normalise

__all__ = ["TanhMLP"]


class TanhMLP(Baseline):
    """Tanh MLP ``xy (N, 2) domain units -> (N, C) float32``.

    Parameters
    ----------
    domain, channels : as every baseline
    hidden, layers : width and number of hidden layers (paper: 512, 4)
    value_scale : the output unit (``Baseline``); seed : seeds the initialisation; device : torch device
    """

    name = "tanh_mlp"

    def __init__(self, domain, channels, *, hidden: int = 512, layers: int = 4, value_scale: float = 1.0,
                 seed: int = 0, device: str = "cpu"):
        super().__init__(domain, channels, value_scale)
        self.decoder = MLP(2, len(self.channels), hidden=int(hidden), layers=int(layers), activation="tanh")
        gen = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            for lin in self.decoder.linears():
                std = (2.0 / (lin.in_features + lin.out_features)) ** 0.5
                lin.weight.copy_(torch.randn(lin.weight.shape, generator=gen) * std)
                lin.bias.zero_()
        self.to(device)

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels, *, image: np.ndarray | None = None, seed: int = 0,
                   device: str = "cpu", hidden: int = 512, layers: int = 4) -> TanhMLP:
        """The fixed ``hidden × layers`` network (module docstring): ``n_bytes`` is not used, nor ``image``."""
        return cls(domain, channels, hidden=hidden, layers=layers, seed=seed, device=device)

    def init_mean(self, mean: Tensor) -> None:
        """Start the output near a constant (C,) value: the output layer's bias."""
        with torch.no_grad():
            self.decoder.linears()[-1].bias.copy_(torch.as_tensor(mean, dtype=torch.float32) / self.value_scale)

    def describe(self) -> dict:
        return {"class": type(self).__name__, "hidden": self.decoder.hidden, "layers": self.decoder.layers}

    def forward(self, xy: Tensor) -> Tensor:
        return self.decoder((2.0 * normalise(xy, self.domain) - 1.0).to(torch.float32)) * self.value_scale
