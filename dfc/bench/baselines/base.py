"""The interface every equal-size baseline shares, and the storage rules its size is measured by.

A baseline is a ``torch.nn.Module`` mapping positions ``xy (N, 2)`` in domain units to values
``(N, C)`` float32, sized to a byte budget by ``for_budget`` and trained with the same loop as dfc
(``fit_baseline``, through the one training loop ``dfc.train.loop.train``), so all methods see the same samples
and steps.

Storage rules (what ``stored_bytes`` counts).

- *Parametric baselines* (hash grid, ReLU field; later SIREN, tanh grid, tanh MLP): every trainable
  parameter is stored as an IEEE float16, **uncompressed**: ``stored_bytes = 2 × number of parameters``.
  Architecture hyper-parameters (a handful of integers) are not counted. After ``fit_baseline`` the parameters
  are rounded through float16 in place, so the module evaluates exactly as the stored bytes decode.
  Sizing needs the size before training, which fixes the rule to raw bytes; ``dfc.bench.compare`` also reports
  ``zstd_bytes``, the zstd (level 19) size of the trained fp16 parameters. Measured on the ``shapes`` scene
  at 19 kB: the hash grid's parameters shrink by ≈ 7 %, the ReLU field's smooth grid by ≈ 39 % — under a
  compressed-size rule the ReLU field would get ≈ 1.6× the nodes (the ``.dfield`` itself is compressed).
- *Raster*: the size of a losslessly ZIP-compressed half-float OpenEXR file of the downsampled image,
  header included (``dfc.bench.baselines.raster``).

A new baseline subclasses ``Baseline``, implements ``forward`` and ``for_budget``, and may override
``stages`` / ``next_stage`` for coarse-to-fine training (see ``dfc.bench.baselines.relu_field``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn.utils import parametrize

from ...field.quantize import FakeFp16

__all__ = ["FP16_BYTES", "Baseline", "fit_baseline", "fp16_bytes", "normalise", "value_scale"]

FP16_BYTES = 2
"""Bytes per stored parameter (IEEE half float)."""


def fp16_bytes(module: nn.Module) -> int:
    """Bytes of ``module``'s trainable parameters stored as float16: ``2 × numel``."""
    return FP16_BYTES * sum(p.numel() for p in module.parameters() if p.requires_grad)


def normalise(xy: Tensor, domain) -> Tensor:
    """Positions (N, 2) in domain units -> (N, 2) float64 in units of the domain's longer side, origin at
    (x0, y0): the domain maps onto ``[0, w] × [0, h]`` with ``max(w, h) = 1`` (square cells stay square)."""
    x0, y0, x1, y1 = domain
    scale = max(x1 - x0, y1 - y0)
    origin = torch.tensor([x0, y0], dtype=torch.float64, device=xy.device)
    return (xy.to(torch.float64) - origin) / scale


def value_scale(image) -> float:
    """Output unit of a baseline fitted to ``image`` (any array, or None): 1 when its values lie in
    [-1, 1] (LDR) or it is None, else its largest magnitude."""
    return 1.0 if image is None else max(1.0, float(np.max(np.abs(image))))


class Baseline(nn.Module):
    """Base class: ``forward(xy (N, 2) float, domain units) -> (N, C) float32``.

    Attributes
    ----------
    name : str, the method's key in benchmark results ("hashgrid", "relu", "raster", …)
    domain : (x0, y0, x1, y1) float
    channels : list of output channel names
    value_scale : float, parametric baselines output ``value_scale ×`` their raw values. With Adam's
        fixed step sizes this lets one learning rate serve LDR (scale 1) and HDR (the tanh field: the data's
        largest magnitude, ``value_scale(image)``, its range; the ReLU field: ``relu_field.hdr_unit``; the hash
        grid's MLP scales itself); one number of the architecture, not counted in bytes.

    ``quantization`` mirrors ``FieldModel.quantization`` so ``dfc.train.loop.train`` can run
    quantisation-aware steps on a baseline: any non-None value makes every parameter read as its
    float16 rounding (straight-through gradient), which is how the parameters are stored.
    """

    name = "baseline"

    def __init__(self, domain, channels: list[str], value_scale: float = 1.0):
        super().__init__()
        x0, y0, x1, y1 = (float(v) for v in domain)
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"domain {tuple(domain)} must have x1 > x0 and y1 > y0")
        if not channels:
            raise ValueError("channels must be non-empty")
        self.domain = (x0, y0, x1, y1)
        self.channels = [str(c) for c in channels]
        if not (np.isfinite(value_scale) and value_scale > 0):
            raise ValueError(f"value_scale must be a positive finite number, got {value_scale!r}")
        self.value_scale = float(value_scale)
        self._quantization: dict | None = None
        self._fp16_params: list[tuple[nn.Module, str]] = []

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels: list[str], *, image: np.ndarray | None = None,
                   seed: int = 0, device: str = "cpu") -> Baseline:
        """A model whose ``stored_bytes()`` is as close to ``n_bytes`` as the architecture allows (≤ it).

        image : (H, W, C) float, the raster the model will be fitted to, when known: baselines take their
            data-dependent settings from it (resolution, value range) or, for the raster, their content
        seed : seeds the initialisation (ignored by deterministic baselines)
        Subclasses add keyword-only architecture options. Raises ValueError when the budget is too small.
        """
        raise NotImplementedError

    def stored_bytes(self) -> int:
        """Bytes of the stored form (module docstring); parametric baselines: fp16 parameters."""
        return fp16_bytes(self)

    def init_mean(self, mean: Tensor) -> None:
        """Start the output near a constant (C,) value, the data's mean (default: nothing)."""

    def describe(self) -> dict:
        """JSON-able architecture summary for benchmark records (default: the class name)."""
        return {"class": type(self).__name__}

    # -- coarse-to-fine hooks -----------------------------------------------------------------
    def stages(self, steps: int) -> list[int]:
        """Split ``steps`` into training stages; ``next_stage()`` runs between consecutive ones."""
        return [steps]

    def next_stage(self) -> None:
        """Grow the model between stages (default: nothing)."""

    # -- storage ------------------------------------------------------------------------------
    def round_to_storage(self) -> None:
        """Round every parameter through float16 in place: the module then evaluates as stored."""
        self.quantization = None
        with torch.no_grad():
            for p in self.parameters():
                p.copy_(p.half().to(p.dtype))

    @property
    def quantization(self) -> dict | None:
        return None if self._quantization is None else dict(self._quantization)

    @quantization.setter
    def quantization(self, value: dict | None) -> None:
        for m, n in self._fp16_params:
            parametrize.remove_parametrizations(m, n, leave_parametrized=False)
        self._fp16_params: list[tuple[nn.Module, str]] = []
        self._quantization = None
        if value is not None:
            targets = [(m, n) for m in self.modules() for n, _ in list(m.named_parameters(recurse=False))]
            for m, n in targets:
                parametrize.register_parametrization(m, n, FakeFp16())
            self._fp16_params = targets
            self._quantization = dict(value)


def fit_baseline(
    model: Baseline,
    sampler: Callable,
    steps: int,
    *,
    lr: float = 1e-2,
    loss: str = "mse",
    seed: int = 0,
    final_lr: float | None = 1e-3,
    callback: Callable[..., None] | None = None,
    data_range: float = 1.0,
    tonemap: bool = False,
) -> dict:
    """Fit a baseline to a data sampler for ``steps`` steps (``dfc.train.loop.train`` with ``DataLoss``), then
    round it to storage.

    Coarse-to-fine models train stage by stage (``model.stages``), each stage with a fresh Adam and the
    learning-rate schedule restarted; ``callback(step, loss, psnr)`` sees the global step, its batch PSNR with
    ``data_range`` on tone-mapped values when ``tonemap`` (``dfc.metrics.quality_scale``). A model with no
    trainable parameters (the raster) is returned untouched. Returns ``{"loss": [...], "psnr": [...]}``.
    """
    from ...train.loop import Schedule, train
    from ...train.losses import DataLoss

    if not any(p.requires_grad for p in model.parameters()):
        return {"loss": [], "psnr": []}
    schedule = Schedule(steps, lr=lr, final_lr=final_lr, restart_stages=True)
    history = train(model, DataLoss(loss, data_range, tonemap), lambda step, g: sampler(step, g)[:2], schedule,
                    seed=seed, callback=callback)
    model.round_to_storage()
    return history
