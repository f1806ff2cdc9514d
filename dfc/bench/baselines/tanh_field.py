"""TanH fields, the paper's physics-informed grid baseline (§6.3): a ReLU field with tanh in place of the clamp.

``f(x) = s · tanh(bilinear(G)(x))``: a regular grid ``G`` of C values per node, bilinearly interpolated exactly as
``dfc.bench.baselines.relu_field.ReluField`` does (nodes on the domain's corners and evenly in between), then a tanh
per channel, times the output unit ``s`` (``value_scale``, 1 for colours in [0, 1]). A ReLU field's clamp has
zero second derivative, which a loss on derivatives cannot train through; tanh is smooth and saturates like
the clamp, so a cell can still hold a steep edge. Trained coarse to fine like the ReLU field.

Storage: the final grid's values as float16 (``dfc.bench.baselines.base``): ``2 · C · n_x · n_y`` bytes, sized to the
budget by ``for_budget``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .base import value_scale
from .relu_field import COARSE_TO_FINE, ReluField

__all__ = ["TanhField"]

SATURATION = 0.999
"""``init_mean`` clips the starting value into ± this fraction of the output unit (atanh stays finite)."""


class TanhField(ReluField):
    """Bilinear grid then tanh, ``xy (N, 2) domain units -> (N, C) float32``.

    Parameters
    ----------
    domain, channels : as every baseline
    shape : (n_y, n_x) final node counts
    stages : coarse-to-fine schedule (``relu_field.COARSE_TO_FINE``)
    value_scale : the output unit ``s``; device : torch device
    """

    name = "tanh_field"

    def __init__(self, domain, channels, *, shape: tuple[int, int], stages=COARSE_TO_FINE, value_scale: float = 1.0,
                 device: str = "cpu"):
        super().__init__(domain, channels, shape=shape, lo=-value_scale, hi=value_scale, stages=stages,
                         value_scale=value_scale, device=device)

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels, *, image: np.ndarray | None = None, seed: int = 0,
                   device: str = "cpu", stages=COARSE_TO_FINE) -> TanhField:
        """The grid ``ReluField.for_budget`` picks for ``n_bytes`` (the most nodes that fit, the domain's aspect).
        ``image`` only sets the output unit (``base.value_scale``); ``seed`` is unused (deterministic)."""
        grid = ReluField.for_budget(n_bytes, domain, channels, image=image, stages=stages)
        return cls(domain, channels, shape=grid.shape, stages=stages, value_scale=value_scale(image), device=device)

    def init_mean(self, mean: Tensor) -> None:
        """Fill the grid with ``atanh`` of a constant (C,) value (the mean prescribed value)."""
        with torch.no_grad():
            v = (torch.as_tensor(mean, dtype=torch.float32) / self.value_scale).clamp(-SATURATION, SATURATION)
            self.grid.copy_(torch.atanh(v).reshape(1, -1, 1, 1).expand_as(self.grid))

    def describe(self) -> dict:
        return {"class": type(self).__name__, "grid": [self.shape[1], self.shape[0]], "value_scale": self.value_scale}

    def forward(self, xy: Tensor) -> Tensor:
        return torch.tanh(self.bilinear(xy)) * self.value_scale
