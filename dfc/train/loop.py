"""The training loop (docs/design.md §6): every model dfc trains — fitted fields, the physics-informed solve and the
baselines — goes through ``train``.

``train(model, loss, sampler, schedule)`` runs Adam on ``model``'s parameters: each step draws a batch from
``sampler``, evaluates ``loss`` on it and steps. The ``Schedule`` gives the learning rate (optionally decaying
geometrically), the quantisation-aware final steps and how coarse-to-fine stages are run. The library never prints:
progress goes to ``callback``. Metrics stay on the model's device during the run (no host round trip per step) and
come back as floats at the end; the sampling generator lives on the model's device too.

Data-parallel runs (``dfc.train.distributed``): inside a process group of several ranks the model is wrapped in
``DistributedDataParallel`` (re-wrapped when coarse-to-fine stages grow it and when quantisation-aware steps start),
so every step averages the ranks' gradients and every rank takes the same optimiser step; each rank draws its own
batch with the generator seeded ``rank_seed(seed, rank)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.optim.adam import adam
from torch.profiler import record_function

from ..field.quantize import DEFAULT_FEATURE_BITS, clip_feature_outliers
from .distributed import parallel, rank_seed, world

__all__ = ["BACKWARD", "BETAS", "FOREACH_DEVICES", "FORWARD", "FUSED_DEVICES", "Loss", "OPTIMISER", "SAMPLE", "Sampler",
           "Schedule", "train"]

BETAS = (0.9, 0.99)
"""Adam's betas (docs/design.md §6)."""
FOREACH_DEVICES = ("cuda",)
"""Devices whose Adam updates all parameters with ``foreach`` kernels."""
FUSED_DEVICES = ("cpu",)
"""Devices whose Adam runs fused (one kernel per tensor): on the CPU a third of the time of the one-tensor-at-a-time
update for a fit's few tensors, the same values to float rounding (CHANGELOG.md, "Faster CPU fit steps"). Elsewhere
(not in either) Adam updates one tensor at a time."""
SAMPLE, FORWARD, BACKWARD, OPTIMISER = "dfc.sample", "dfc.forward", "dfc.backward", "dfc.optimiser"
"""``torch.profiler`` labels of a step's parts: drawing the batch, the loss's forward pass, its backward pass and the
optimiser step (``dfc benchmark encode`` breaks steps down by them; free when no profiler runs)."""

Sampler = Callable[[int, torch.Generator], tuple]
"""``sampler(step, generator) -> batch``: the batch for global step ``step``, drawn with ``generator``."""
Loss = Callable[[nn.Module, tuple], tuple[Tensor, dict[str, Tensor]]]
"""``loss(model, batch) -> (value, metrics)``: the scalar to minimise and named 0-dim metrics of the step, in the
order the callback receives them (values of their own, not views of parameters the step will change)."""


@dataclass(frozen=True)
class Schedule:
    """Optimiser settings of one training run.

    steps : optimiser steps (a model with coarse-to-fine ``stages`` splits them between its stages)
    lr, final_lr : Adam's learning rate, decaying geometrically to ``final_lr`` over the run (None: constant)
    betas : Adam's betas
    qat_steps : the last ``qat_steps`` steps (before them a ``FieldModel``'s features are clipped to their bulk,
        ``dfc.field.quantize.clip_feature_outliers``) run with ``model.quantization = {"feature_bits": feature_bits}``
        (quantised features, fp16 weights; with ``weight_bits`` also ``"weight_bits": weight_bits``, integer weight
        matrices), which stays set on return so the model evaluates as stored
    restart_stages : coarse-to-fine stages each restart the learning-rate decay and reseed the sampling
        generator with ``seed + stage``; else the decay and the generator run straight through all stages
    decoder_lr : for a model with a ``field`` (``FieldModel``), the factor on the learning rate of every parameter
        outside it (the decoder); the field's features keep ``lr``
    """

    steps: int
    lr: float = 1e-2
    final_lr: float | None = None
    betas: tuple[float, float] = BETAS
    qat_steps: int = 0
    feature_bits: int = DEFAULT_FEATURE_BITS
    restart_stages: bool = False
    weight_bits: int | None = None
    decoder_lr: float = 1.0

    def check(self) -> None:
        """Raise ValueError on settings no run can have."""
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps must be a positive integer, got {self.steps!r}")
        if not isinstance(self.qat_steps, int) or not 0 <= self.qat_steps <= self.steps:
            raise ValueError(f"qat_steps must be an integer in [0, steps={self.steps}], got {self.qat_steps!r}")
        if not self.lr > 0 or (self.final_lr is not None and not self.final_lr > 0) or not self.decoder_lr > 0:
            raise ValueError(f"learning rates must be positive, got lr={self.lr}, final_lr={self.final_lr}, "
                             f"decoder_lr={self.decoder_lr}")

    def quantization(self) -> dict:
        """The ``model.quantization`` of the quantisation-aware steps."""
        q = {"feature_bits": self.feature_bits}
        return q if self.weight_bits is None else {**q, "weight_bits": self.weight_bits}

    def decay(self, length: int) -> float:
        """Per-step factor of the learning rate over a run of ``length`` steps."""
        return 1.0 if self.final_lr is None else (self.final_lr / self.lr) ** (1.0 / max(1, length - 1))


def train(model: nn.Module, loss: Loss, sampler: Sampler, schedule: Schedule, *, seed: int = 0,
          callback: Callable[..., None] | None = None) -> dict[str, list[float]]:
    """Train ``model`` in place; return its metrics, one float per step, by name.

    model : any module; ``model.quantization`` is set for quantisation-aware steps (``FieldModel``, baselines), and a
        model with ``stages(steps) -> [n, …]`` and ``next_stage()`` trains coarse to fine: it grows between stages and
        each stage gets a fresh Adam (its parameters are new)
    loss, sampler : see ``Loss`` and ``Sampler``; the sampler's generator is a ``torch.Generator`` on the model's
        device seeded by ``seed`` (rank r of a data-parallel run: ``rank_seed(seed, r)``); ``loss`` gets the model,
        or in a data-parallel run its ``DistributedDataParallel`` wrapper
    callback : ``callback(step, *metrics)`` after every step, metrics as 0-dim tensors (``float()`` reads one)
    """
    schedule.check()
    stages = model.stages(schedule.steps) if hasattr(model, "stages") else [schedule.steps]
    total = sum(stages)
    qat_from = total - schedule.qat_steps if schedule.qat_steps else None
    history: dict[str, list[Tensor]] = {}
    rank = world()[0]
    device = next(model.parameters(), torch.empty(0)).device
    generator = torch.Generator(device).manual_seed(rank_seed(seed, rank))
    step = 0
    model.train()
    for k, n in enumerate(stages):
        if k:
            model.next_stage()
        if schedule.restart_stages:
            generator = torch.Generator(device).manual_seed(rank_seed(seed + k, rank))
        start, length = (step, n) if schedule.restart_stages else (0, total)
        decay = schedule.decay(length)
        optimizer = _Adam(_groups(model, schedule.decoder_lr), schedule.betas, device)
        net = parallel(model)
        for _ in range(n):
            if step == qat_from:
                if isinstance(getattr(model, "field", None), nn.Module) and hasattr(model.field, "bank"):
                    clip_feature_outliers(model.field.bank)
                model.quantization = schedule.quantization()
                net = parallel(model, sync=False)
            for group in optimizer.groups:
                group["lr"] = group["factor"] * schedule.lr * decay ** (step - start)
            with record_function(SAMPLE):
                batch = sampler(step, generator)
            with record_function(FORWARD):
                value, metrics = loss(net, batch)
            optimizer.zero_grad()
            with record_function(BACKWARD):
                value.backward()
            with record_function(OPTIMISER):
                optimizer.step()
            for name, v in metrics.items():
                history.setdefault(name, []).append(v.detach())
            if callback is not None:
                callback(step, *(values[-1] for values in history.values()))
            step += 1
    model.eval()
    return {name: torch.stack(values).cpu().tolist() for name, values in history.items()}


class _Adam:
    """Adam (no weight decay, eps 1e-8) over parameter groups ``[{"params": [...], "lr": float, …}]``, each step
    the update ``torch.optim.Adam`` makes (``torch.optim.adam.adam``: fused on ``FUSED_DEVICES``, foreach on
    ``FOREACH_DEVICES``, else one tensor at a time). Not ``torch.optim.Adam`` itself: its first use imports
    ``torch._dynamo``, about a second of every encode's fit on the CPU (CHANGELOG.md, "Fit steps slice laid-out
    blocks")."""

    def __init__(self, groups: list[dict], betas: tuple[float, float], device: torch.device):
        self.groups, self.betas = groups, betas
        self.fused = device.type in FUSED_DEVICES
        self.foreach = device.type in FOREACH_DEVICES and not self.fused
        self.state: dict[Tensor, tuple[Tensor, Tensor, Tensor]] = {}

    def zero_grad(self) -> None:
        for group in self.groups:
            for p in group["params"]:
                p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        for group in self.groups:
            params = [p for p in group["params"] if p.grad is not None]
            for p in params:
                if p not in self.state:  # step count, first and second moments
                    step = torch.zeros((), dtype=torch.float32, device=p.device if self.fused else "cpu")
                    self.state[p] = (step, torch.zeros_like(p), torch.zeros_like(p))
            steps, avgs, squares = zip(*(self.state[p] for p in params)) if params else ((), (), ())
            adam(params, [p.grad for p in params], list(avgs), list(squares), [], list(steps), foreach=self.foreach,
                 fused=self.fused, amsgrad=False, beta1=self.betas[0], beta2=self.betas[1], lr=group["lr"],
                 weight_decay=0.0, eps=1e-8, maximize=False)


def _groups(model: nn.Module, decoder_lr: float) -> list[dict]:
    """Adam's parameter groups, each with the ``factor`` on the schedule's learning rate: a model's ``field``
    parameters 1, the rest ``decoder_lr``; a model without a ``field`` one group at 1."""
    field = getattr(model, "field", None)
    if field is None:
        return [{"params": list(model.parameters()), "factor": 1.0}]
    own = {id(p) for p in field.parameters()}
    return [{"params": [p for p in model.parameters() if id(p) in own], "factor": 1.0},
            {"params": [p for p in model.parameters() if id(p) not in own], "factor": decoder_lr}]
