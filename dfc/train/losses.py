"""The data term of a fit: the model's predictions at a batch's points against the batch's targets."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ..metrics import is_hdr, tonemap

__all__ = ["LOSSES", "RELMSE_EPS", "DataLoss", "auto_loss", "loss_value", "signed_log"]

LOSSES = ("mse", "relmse", "logmse")
RELMSE_EPS = 0.01
"""The ``+ 0.01`` in the relative MSE's denominator (paper §5): limits the weight of near-black values."""


def auto_loss(values) -> str:
    """The loss ``loss="auto"`` means for targets ``values`` (array, any shape) of an image: ``"logmse"`` for HDR
    colours (``dfc.metrics.is_hdr``), else ``"mse"``. Every fit of a colour signal resolves "auto" here: dfc's encoder and
    the comparison harness's baselines."""
    return "logmse" if is_hdr(values) else "mse"


def signed_log(v: Tensor) -> Tensor:
    """``sign(v) · log(1 + |v|)``, elementwise: ``log1p`` for v ≥ 0 (the ``log`` value transform's space), odd."""
    return torch.sign(v) * torch.log1p(v.abs())


def loss_value(name: str, f: Tensor, g: Tensor) -> Tensor:
    """Scalar loss of predictions f (B, C) against targets g (B, C).

    ``"mse"``: mean (f − g)². ``"relmse"``: mean (f − g)² / (max(f, 0)ᵈ + 0.01)², where ᵈ marks a
    detached value (no gradient through the denominator). Clamping at 0 keeps a negative prediction
    from shrinking the denominator towards 0; for f ≥ 0 it is the paper's relative MSE. ``"logmse"``: mean
    (slog f − slog g)² with ``signed_log``, the default for HDR: a relative error for bright values, an absolute
    one near 0, and for a model with the ``log`` transform the plain MSE of the decoder's own output. (The
    relative MSE weights a channel whose target is 0 by up to 1/0.01² and is flat once the prediction is well
    above 0.01: on saturated HDR colours it trades the colour for the brightness; ``dfc.train.fit._new_model``.)
    """
    if name == "mse":
        return torch.mean((f - g) ** 2)
    if name == "relmse":
        return torch.mean((f - g) ** 2 / (f.detach().clamp_min(0) + RELMSE_EPS) ** 2)
    if name == "logmse":
        return torch.mean((signed_log(f) - signed_log(g)) ** 2)
    raise ValueError(f"loss must be one of {LOSSES}, got {name!r}")


class DataLoss:
    """``loss`` of ``dfc.train.loop.train`` for data samplers (``dfc.train.samplers``).

    A batch is ``(xy (B, 2), target (B, C))``, optionally with a third item: the batch's precomputed
    ``field.query(xy)`` (``FieldModel.forward(query=…)``), a dict of further model arguments (e.g. ``{"t": times}``),
    or a ``dfc.train.pixel_sampler.PixelWeights``: then the N points' values, weighted, sum into the B pixels of
    ``target``.
    Metrics: ``loss`` and ``psnr``, the batch's PSNR in dB with ``data_range``, of tone-mapped values with
    ``tonemap`` (``dfc.metrics.quality_scale``: the scale the encoder's summary uses).
    """

    def __init__(self, name: str = "mse", data_range: float = 1.0, tonemap: bool = False):
        if name not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}, got {name!r}")
        self.name, self.peak, self.tonemap = name, float(data_range) ** 2, tonemap

    def __call__(self, model: nn.Module, batch: tuple) -> tuple[Tensor, dict[str, Tensor]]:
        xy, target, *extra = batch
        if extra and hasattr(extra[0], "row"):  # a filtered batch (``dfc.train.pixel_sampler``): points → pixels
            points = model(xy) if extra[0].query is None else model(xy, query=extra[0].query)
            pred = torch.zeros(target.shape, dtype=points.dtype, device=points.device).index_add_(
                0, extra[0].row, points * extra[0].weight[:, None].to(points.dtype))
        elif not extra:
            pred = model(xy)
        elif isinstance(extra[0], dict):
            pred = model(xy, **extra[0])
        else:
            pred = model(xy, query=extra[0])
        value = loss_value(self.name, pred, target)
        pred = pred.detach()
        if self.tonemap:
            pred, target = tonemap(pred), tonemap(target)
        err = torch.mean((pred - target) ** 2).double()
        return value, {"loss": value.detach(), "psnr": 10.0 * torch.log10(self.peak / err)}
