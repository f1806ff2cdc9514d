"""``dfc benchmark encode``: time to quality of an image encode, and where a fit step's time goes.

Encodes IMAGE with its ``--curves`` (default: the README's sample, ``samples/sample.exr`` and ``sample.json``) as
``dfc encode --residual-bytes 0`` does with its defaults (``--steps`` and ``--batch-size`` as given: one fit; without
``--residual-bytes 0`` a clean image also gets a byte target of its own and a residual raster,
``dfc.codec._default_target``), for each ``--threads`` count, alone and beside a busy neighbour
(``dfc.bench.neighbour``). Each run prints the fit's seconds, its steps, the summary's
1× PSNR of the written file, and the time at which the fit came within 0.1 dB of its final training PSNR: the PSNR
of the mean squared error of the last epoch's batches (enough steps to see every training pixel once), measured on
the steps before the quantisation-aware ones, timed from the start of the fit (setup included).

The breakdown profiles one more encode, ``--profile-steps`` long with the timed runs' decoder width, one thread,
alone (``torch.profiler``): per step, drawing the batch (sampling), interpolating the features (the gather of
precomputed interpolation weights, point location included when a step locates its points), the decoder MLP
forward, the loss, the backward pass of the MLP and of the interpolation, the optimiser, in ms; the fit's setup
(point location and interpolation weights of every training point, once), and the quantisation-aware steps
against the others (from the timed run's steps).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import click
import numpy as np

from ...command import json_option, quiet_option, stdout_taken, write_json
from ..neighbour import SAMPLES
from .field import NEIGHBOUR_OPTION, THREADS_OPTION, conditions

WITHIN_DB = 0.1
"""A fit is converged once its training PSNR is within this many dB of its final one."""
PARTS = ("sampling", "interpolation", "MLP forward", "loss", "MLP backward", "interpolation backward", "optimiser")
"""The breakdown's parts, in the order printed."""


def training_psnr(psnr: np.ndarray, batch_size: int, n_points: int) -> np.ndarray:
    """(steps,) PSNR in dB of the mean squared error of the batches of the last epoch ending at each step (the first
    steps: of those so far), from the steps' batch PSNRs ``psnr`` (steps,) in dB of batches of ``batch_size`` out of
    ``n_points`` training points (an epoch: ``ceil(n_points / batch_size)`` steps)."""
    window = max(1, -(-n_points // batch_size))
    mse = 10.0 ** (-np.asarray(psnr, dtype=np.float64) / 10.0)
    total = np.cumsum(mse)
    lagged = np.concatenate([np.zeros(window), total[:-window]])[: len(total)]
    count = np.minimum(np.arange(1, len(total) + 1), window)
    return -10.0 * np.log10((total - lagged) / count)


def time_to_within(curve: np.ndarray, seconds: np.ndarray, within: float = WITHIN_DB) -> tuple[float, int]:
    """(seconds, step) at which ``curve`` (steps,) in dB first comes within ``within`` dB of its last value and stays
    there; ``seconds`` (steps,) are the times the steps ended."""
    below = np.flatnonzero(curve < curve[-1] - within)
    step = 0 if len(below) == 0 else int(below[-1]) + 1
    return float(seconds[step]), step


def _category(name: str) -> str | None:
    """The breakdown part of a backward op of the profile, or None for a forward op (attributed by its label)."""
    low = name.lower()
    if "backward" not in low or not low.startswith("autograd::engine::evaluate_function"):
        return None
    return "interpolation backward" if any(k in low for k in ("embedding", "weightedrows", "packedrows")) \
        else "MLP backward"


def breakdown(run_encode, steps: int) -> dict[str, float]:
    """Milliseconds per step of each of ``PARTS`` in a profiled ``run_encode(steps, callback)``."""
    from torch.profiler import ProfilerActivity, profile

    from ...field.model import DECODE, INTERPOLATE
    from ...train.loop import BACKWARD, FORWARD, OPTIMISER, SAMPLE

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        run_encode(steps, None)
    totals = dict.fromkeys(PARTS, 0.0)
    labels = {SAMPLE: "sampling", INTERPOLATE: "interpolation", DECODE: "MLP forward", OPTIMISER: "optimiser"}
    forward = backward = 0.0
    for event in prof.key_averages():
        us = event.cpu_time_total
        if event.key in labels:
            totals[labels[event.key]] += us
        elif event.key == FORWARD:
            forward += us
        elif event.key == BACKWARD:
            backward += us
        elif _category(event.key) == "interpolation backward":
            totals["interpolation backward"] += us
    totals["loss"] = max(0.0, forward - totals["interpolation"] - totals["MLP forward"])
    totals["MLP backward"] = max(0.0, backward - totals["interpolation backward"])
    return {k: v / 1e3 / steps for k, v in totals.items()}


@click.command()
@click.argument("image", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", type=click.Path(exists=True, dir_okay=False),
              help="IMAGE's discontinuity curves (required with IMAGE).")
@click.option("--fit-curves-to-image", "fit_curves", is_flag=True,
              help="Scale the curves' domain onto the image's pixels (as dfc encode's option).")
@click.option("--steps", type=click.IntRange(1), default=None, help="Fit steps  [default: the encode's].")
@click.option("--batch-size", type=click.IntRange(1), default=None, help="Samples per step  [default: the encode's].")
@click.option("--profile-steps", type=click.IntRange(0), default=100, show_default=True,
              help="Steps of the profiled encode of the breakdown (0: no breakdown).")
@THREADS_OPTION
@NEIGHBOUR_OPTION
@json_option
@quiet_option
def command(image: str | None, curves_path: str | None, fit_curves: bool, steps: int | None, batch_size: int | None, profile_steps: int,
            thread_counts: tuple[int, ...], neighbour: bool, json_path: str | None, quiet: bool) -> None:
    """Time to quality of an image encode, the field alone (fit seconds, steps, 1x PSNR, time to within 0.1 dB of
    the final training PSNR) for each --threads count, alone and beside a busy neighbour, and a per-step
    breakdown."""
    import torch

    from ...codec import EncodeSettings, encode_image, image_decoder
    from ...geometry.sources import read_curves
    from ...io.image import read_image
    from ...train.fit import image_batch_size

    if (image is None) != (curves_path is None):
        raise click.UsageError("give IMAGE and --curves together (neither: the README's sample)")
    image_path = Path(image) if image else SAMPLES / "sample.exr"
    curves_file = Path(curves_path) if curves_path else SAMPLES / "sample.json"
    img = read_image(image_path)
    curves = read_curves(curves_file)
    given = {k: v for k, v in (("steps", steps), ("batch_size", batch_size)) if v is not None}
    settings = EncodeSettings(**given, residual_bytes=0)  # one fit: the field alone
    err = stdout_taken(json_path)
    h, w = img.pixels.shape[:2]

    width = image_decoder(settings, img.pixels.size, img.pixels.shape[2]).hidden  # the timed runs' decoder

    def run_encode(n_steps, callback):
        run = settings if n_steps is None else replace(settings, steps=n_steps, hidden=width)
        return encode_image(img, curves, run, callback=callback, fit_curves=fit_curves)

    stats = {"image": image_path.name, "curves": curves_file.name, "width": w, "height": h, "runs": []}
    click.echo(f"{image_path.name} ({w} x {h}) with {curves_file.name}; settings: "
               f"{', '.join(f'{k} {v}' for k, v in given.items()) or 'the defaults'}", err=err)
    click.echo(f"{'threads':>7} {'neighbour':>9} {'fit':>8} {'steps':>6} {'ms/step':>8} {'QAT ms/step':>11} "
               f"{'1x PSNR':>9} {'bytes':>6} {'within 0.1 dB':>17}", err=err)
    for threads, beside in conditions(thread_counts, neighbour):
        psnrs, ends = [], []

        def callback(step, loss, psnr):
            ends.append(time.perf_counter())
            psnrs.append(float(psnr))

        blob, report = run_encode(None, callback)
        fit_s = report.seconds["fit_s"]
        n = len(psnrs)
        qat = settings.qat_steps if settings.qat_steps is not None else round(0.1 * n)
        plain = n - qat
        ends_a = np.asarray(ends)
        seconds = ends_a - (ends_a[-1] - fit_s)  # since the fit began (it returns right after its last step)
        step_s = np.diff(ends_a)
        batch = settings.batch_size or image_batch_size(h * w)
        curve = training_psnr(np.asarray(psnrs[:plain]), batch, h * w)
        within_s, within_step = time_to_within(curve, seconds[:plain])
        run = {"threads": threads, "neighbour": beside, "fit_s": fit_s, "steps": n, "batch_size": batch, "qat_steps": qat,
               "setup_s": float(seconds[0] - step_s[:plain - 1].mean()) if plain > 1 else None,
               "step_ms": float(np.median(step_s[:plain - 1]) * 1e3) if plain > 1 else None,
               "qat_step_ms": float(np.median(step_s[plain:]) * 1e3) if qat > 1 else None,
               "psnr": report.psnr, "bytes": report.total_bytes, "training_psnr": float(curve[-1]),
               "within_0.1dB_s": within_s, "within_0.1dB_step": within_step}
        stats["runs"].append(run)
        qat_ms = f"{run['qat_step_ms']:>8.1f} ms" if run["qat_step_ms"] is not None else f"{'-':>11}"
        step_ms = f"{run['step_ms']:>5.1f} ms" if run["step_ms"] is not None else f"{'-':>8}"
        click.echo(f"{threads:>7} {beside:>9} {fit_s:>6.1f} s {n:>6} {step_ms} {qat_ms} {report.psnr:>6.2f} dB "
                   f"{report.total_bytes:>6} {within_s:>6.1f} s (step {within_step})", err=err)
    if profile_steps:
        torch.set_num_threads(1)
        parts = breakdown(run_encode, profile_steps)
        stats["breakdown"] = [{"part": k, "ms_per_step": v} for k, v in parts.items()]
        stats["breakdown_steps"] = profile_steps
        click.echo(f"per step, 1 thread, alone ({profile_steps} profiled steps, ms): "
                   + ", ".join(f"{k} {v:.2f}" for k, v in parts.items()), err=err)
    click.echo("fit: the encode's fit (setup, steps and quantisation-aware steps); within 0.1 dB: when the training "
               "PSNR (last epoch's batches, before the quantisation-aware steps) came within 0.1 dB of its final "
               "value; neighbour busy: another dfc encode with as many threads", err=err)
    if json_path:
        write_json(json_path, stats)
