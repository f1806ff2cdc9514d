"""Per-budget tuning of the neural baselines, so that each is sized the way its authors would size it for the bytes.

For a budget, every candidate architecture of the method (``candidates``: hash grid levels, features per level, MLP
width, dense coarse levels, with the table size filling the rest of the budget; ReLU field channels per node, with
the resolution filling the rest) is built at that budget, trained for ``sweep_steps`` and scored by its 1× PSNR on
the training raster (box-filtered render against the raster, ``dfc.bench.measure.image_render``), on the input's
``dfc.metrics.quality_scale`` (tone-mapped for HDR colours), with the loss dfc's encoder uses for it. The best is then
trained from scratch for the full run: ``steps`` steps, or more when that is shorter than ``match_seconds`` (dfc's
encode time), estimated from the candidate's own sweep time per step. Everything goes into the record: every
candidate with its score, the chosen configuration, the steps and wall time of the final run, and how much its batch
PSNR still rose over its last tenth of steps (``plateau_db``, a plateau when near 0).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from ..metrics import QualityScale

__all__ = ["HASHGRID_SWEEP", "TUNED", "Tuned", "candidates", "plateau_db", "tune_baseline"]

HASHGRID_SWEEP = (
    {"levels": 16, "features": 2, "hidden": 64},  # InstantNGP's defaults, the MLP held to half the budget
    {"levels": 16, "features": 2, "hidden": 16},
    {"levels": 8, "features": 2, "hidden": 16},
    {"levels": 8, "features": 4, "hidden": 16},
    {"levels": 4, "features": 4, "hidden": 16},
    {"levels": 8, "features": 2, "hidden": 32},
    {"levels": 16, "features": 2, "hidden": 16, "dense_levels": 4},
    {"levels": 12, "features": 1, "hidden": 16},
)
"""Hash-grid candidates (``HashGrid.for_budget`` keywords); the table size fills the rest of the budget."""
TUNED = ("hashgrid", "relu")
"""The baselines tuned per budget."""


def candidates(name: str, n_channels: int) -> list[dict]:
    """``for_budget`` keyword sets tried for baseline ``name`` with ``n_channels`` outputs, the default first."""
    if name == "hashgrid":
        return [dict(c) for c in HASHGRID_SWEEP]
    if name == "relu":
        return [{"features": k} for k in dict.fromkeys([n_channels, 1, 2, 2 * n_channels])]
    return [{}]


def plateau_db(batch_psnr: list[float]) -> float | None:
    """Mean batch PSNR of the last tenth of a run minus that of the tenth before (dB); None for runs under 20
    steps."""
    n = len(batch_psnr) // 10
    if n < 2:
        return None
    v = np.asarray(batch_psnr, dtype=np.float64)
    return float(v[-n:].mean() - v[-2 * n : -n].mean())


@dataclass
class Tuned:
    """A tuned baseline: ``model`` trained and rounded to storage; ``config`` its ``describe()``; ``sweep`` every
    candidate tried (config, architecture, bytes, 1× PSNR, seconds, or the error that ruled it out); ``train`` the
    final run (steps, seconds, step_s, matched_s, plateau_db)."""

    model: nn.Module
    config: dict
    sweep: list[dict] = field(default_factory=list)
    train: dict = field(default_factory=dict)


def tune_baseline(name: str, pixels: np.ndarray, domain, channels: list[str], n_bytes: int, *, steps: int,
                  sweep_steps: int, batch_size: int, pixel_grid: int, scale: QualityScale, loss: str,
                  match_seconds: float | None = None, sweep: bool = True, seed: int = 0, device: str = "cpu",
                  progress: Callable[[str], None] | None = None) -> Tuned:
    """Tune and train baseline ``name`` (``dfc.bench.baselines.BASELINES``) for ``n_bytes`` (module docstring).

    pixels : (H, W, C) float32 training raster over ``domain``; loss : of the fit (``dfc.train.losses``)
    scale : ``dfc.metrics.QualityScale`` of the fit's progress and the candidates' scores
    sweep : False tries the default candidate only (its short run still times a step for ``match_seconds``)
    Raises ValueError when no candidate fits the budget.
    """
    progress = progress or (lambda message: None)
    tried = candidates(name, len(channels)) if sweep else candidates(name, len(channels))[:1]
    record, best = [], None
    for k, kw in enumerate(tried):
        try:
            model = _build(name, kw, n_bytes, pixels, domain, channels, seed, device)
        except ValueError as e:
            record.append({"config": kw, "error": str(e)})
            continue
        clock = time.perf_counter()
        _train(model, pixels, domain, sweep_steps, batch_size, loss, scale, seed, device)
        seconds = time.perf_counter() - clock
        score = _score(model, pixels, domain, pixel_grid, scale, device)
        record.append({"config": kw, "architecture": model.describe(), "bytes": model.stored_bytes(),
                       "psnr_1x": score, "seconds": seconds})
        progress(f"{name}: candidate {k + 1}/{len(tried)} {kw}: {score:.2f} dB at 1x after {sweep_steps} steps")
        if best is None or score > record[best]["psnr_1x"]:
            best = len(record) - 1
    if best is None:
        raise ValueError(f"no {name} configuration fits {n_bytes} bytes: " + record[0]["error"])
    chosen = record[best]
    step_s = chosen["seconds"] / sweep_steps
    run_steps = steps if match_seconds is None else max(steps, math.ceil(match_seconds / step_s))
    model = _build(name, chosen["config"], n_bytes, pixels, domain, channels, seed, device)
    every = max(1, run_steps // 10)

    def callback(step, loss_value, psnr):
        if (step + 1) % every == 0 or step + 1 == run_steps:
            progress(f"{name}: step {step + 1}/{run_steps}, batch PSNR {psnr:.2f} dB")

    clock = time.perf_counter()
    history = _train(model, pixels, domain, run_steps, batch_size, loss, scale, seed, device, callback)
    train = {"steps": run_steps, "seconds": time.perf_counter() - clock, "step_s": step_s,
             "matched_s": match_seconds, "plateau_db": plateau_db(history["psnr"])}
    return Tuned(model, {"candidate": chosen["config"], **model.describe()}, record, train)


def _build(name, kw, n_bytes, pixels, domain, channels, seed, device):
    from .baselines import BASELINES

    model = BASELINES[name].for_budget(n_bytes, domain, channels, image=pixels, seed=seed, device=device, **kw)
    model.init_mean(torch.from_numpy(pixels.reshape(-1, pixels.shape[2]).mean(axis=0)))
    return model


def _train(model, pixels, domain, steps, batch_size, loss, scale, seed, device, callback=None) -> dict:
    from ..train.samplers import image_sampler
    from .baselines import fit_baseline

    sampler = image_sampler(pixels, domain, batch_size, device=device, seed=seed)
    return fit_baseline(model, sampler, steps, loss=loss, seed=seed, data_range=scale.data_range,
                        tonemap=scale.tonemap, callback=callback)


def _score(model, pixels, domain, spp, scale, device) -> float:
    from .measure import image_render

    model.eval()
    h, w = pixels.shape[:2]
    return scale.psnr(pixels, image_render(model, domain, w, h, spp, device))
