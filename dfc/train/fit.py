"""Fitting a field model to samples of a signal (docs/design.md §6): the entry points ``fit_image``,
``fit_samples`` and ``fit_frames`` wire a signal and a mesh into a fresh ``FieldModel`` trained by
``dfc.train.loop.train`` on a data sampler (``dfc.train.samplers``), with defaults chosen by the measurements in
CHANGELOG.md. Deterministic on CPU for a given seed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields, replace

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..field.model import FieldModel
from ..field.quantize import DEFAULT_FEATURE_BITS
from ..geometry.pixels import edge_pixels
from ..io.image import check_pixels
from ..metrics import QualityScale, is_hdr
from ..metrics import data_range as value_span
from ..pixel_filter import STEEP_POINTS, STEEP_RANGE, TRAIN_POINTS
from ..settings import FitSettings
from .loop import BETAS, Sampler, Schedule, train
from .losses import DataLoss, signed_log
from .samplers import frame_sampler, image_sampler, point_sampler

__all__ = ["BATCH_SIZE", "DECODER_LR", "DECODER_LR_MIN_STEPS", "DEFAULT_STEPS", "IMAGE_LR", "IMAGE_STEPS", "FitSettings",
           "fit", "fit_bands", "fit_frames", "fit_image", "fit_samples", "fit_settings", "image_batch_size",
           "image_decoder_lr", "image_lr"]

DECODER_LR = 0.2
"""Image fits (``fit_image``, ``fit_bands``) train the decoder at this factor on the features' learning rate
(``dfc.train.loop.Schedule``). Sample sets keep 1, as do image fits shorter than ``DECODER_LR_MIN_STEPS``. Why:
CHANGELOG.md, "The decoder learns at a fifth of the features' rate"."""

DECODER_LR_MIN_STEPS = 500
"""Image fits of fewer steps keep the decoder at the features' rate (``image_decoder_lr``): a slow decoder needs the
steps (CHANGELOG.md, "The decoder learns at a fifth of the features' rate")."""


IMAGE_LR = 4e-2
"""The features' starting learning rate in image fits (``fit_image``, ``fit_bands``) of at least
``DECODER_LR_MIN_STEPS`` steps; shorter fits start at 1e-2. Both decay to 1e-3. Why 4e-2: CHANGELOG.md, "Image fits
start at four times the learning rate"."""


def image_lr(steps: int) -> float:
    """The features' starting learning rate of an image fit of ``steps`` steps: ``IMAGE_LR`` from
    ``DECODER_LR_MIN_STEPS`` on, else 1e-2."""
    return IMAGE_LR if steps >= DECODER_LR_MIN_STEPS else 1e-2


def image_decoder_lr(steps: int) -> float:
    """The decoder's learning-rate factor of an image fit of ``steps`` steps: ``DECODER_LR`` from
    ``DECODER_LR_MIN_STEPS`` on, else 1."""
    return DECODER_LR if steps >= DECODER_LR_MIN_STEPS else 1.0


def fit(
    model: FieldModel,
    sampler: Sampler,
    *,
    steps: int,
    lr: float = 1e-2,
    betas: tuple[float, float] = BETAS,
    loss: str = "mse",
    seed: int = 0,
    callback: Callable[[int, Tensor, Tensor], None] | None = None,
    qat_steps: int = 0,
    feature_bits: int = DEFAULT_FEATURE_BITS,
    data_range: float = 1.0,
    final_lr: float | None = None,
    weight_bits: int | None = None,
    tonemap: bool = False,
    decoder_lr: float = 1.0,
) -> dict:
    """Train ``model`` in place on batches from a data sampler (``dfc.train.loop.train`` with ``DataLoss``).

    Parameters
    ----------
    model : FieldModel (any module ``(xy (B, 2)) -> (B, C)`` with ``quantization`` works)
    sampler : ``(step, generator) -> (xy (B, 2), target (B, C)[, extra])`` tensors on the model's device
        (``dfc.train.samplers``; ``extra`` as ``DataLoss`` takes it)
    steps : number of optimiser steps
    lr, betas : Adam settings (docs/design.md §6: 1e-2, (0.9, 0.99))
    loss : {"mse", "relmse", "logmse"}, see ``loss_value``
    seed : seeds the CPU generator handed to the sampler
    callback : called after each step as ``callback(step, loss, psnr)``; psnr is of the batch, in dB
        with ``data_range``, of tone-mapped values with ``tonemap`` (0-dim tensors; ``dfc.metrics.quality_scale``)
    qat_steps : the last ``qat_steps`` steps run with ``model.quantization = {"feature_bits":
        feature_bits}`` (quantised features, fp16 decoder weights), which stays set on return so the
        model evaluates as the written file will decode
    weight_bits : with ``qat_steps``, the weight matrices are ``weight_bits``-bit integers per row during those
        steps (``dfc.field.quantize.quantize_weights``) instead of fp16
    final_lr : if given, the learning rate decays geometrically from ``lr`` to ``final_lr`` over the run
    decoder_lr : the decoder's learning rate as a factor on the features' (``DECODER_LR``: image fits)

    Returns
    -------
    dict with ``loss`` and ``psnr``: lists of floats, one per step
    """
    schedule = Schedule(steps, lr=lr, final_lr=final_lr, betas=betas, qat_steps=qat_steps, feature_bits=feature_bits,
                        weight_bits=weight_bits, decoder_lr=decoder_lr)
    return train(model, DataLoss(loss, data_range, tonemap), sampler, schedule, seed=seed, callback=callback)


DEFAULT_STEPS = 1000
"""Default optimiser steps of ``fit_samples`` and ``fit_frames`` (and the least of a sample-set encode)."""
IMAGE_STEPS = 3000
"""Default optimiser steps of the image fits (``fit_image``, ``fit_bands``; ``--steps``). Why 3,000 and not 1,000:
CHANGELOG.md, "Image fits run 3,000 steps"; docs/results.md, "Image fits run 3,000 steps"."""
BATCH_SIZE = 1 << 14
"""Default samples per step of every fit but that of a small image (``image_batch_size``)."""
IMAGE_BATCH_PIXELS = 256
"""An image fit's default batch is a power of two near its pixels over this (``image_batch_size``)."""
MIN_IMAGE_BATCH = 4096
"""The smallest default batch of an image fit. Why 4,096 up to 1024 × 1024 pixels: CHANGELOG.md, "Image fits up to
1024 × 1024 take batches of 4,096"."""
DEFAULT_QAT_FRACTION = 0.1
"""Default share of the steps run quantisation-aware."""
MAX_DROPPED_FRACTION = 0.5
"""``fit_image`` keeps mixed pixels after all when they are more than this share of the image."""
MAX_CACHED_SAMPLES = 1 << 22
"""``fit_image`` caches point location for at most this many samples (≈ 100 bytes each)."""
MAX_CARRY_POINTS = 1 << 18
"""``fit_samples`` carries a previous fit over at about this many of the sample positions."""
_FIT_FIELDS = frozenset(f.name for f in fields(FitSettings))


def image_batch_size(n_pixels: int) -> int:
    """Default samples per step of a fit to an image of ``n_pixels``: the power of two nearest below
    ``n_pixels / IMAGE_BATCH_PIXELS``, within ``MIN_IMAGE_BATCH`` .. ``BATCH_SIZE`` (4,096 up to 1024 × 1024 pixels,
    16,384 from 2048 × 2048 up)."""
    return min(BATCH_SIZE, max(MIN_IMAGE_BATCH, 1 << max(0, (n_pixels // IMAGE_BATCH_PIXELS).bit_length() - 1)))


def fit_settings(settings: FitSettings | None, overrides: dict, default_steps: int,
                 default_batch: int = BATCH_SIZE) -> tuple[FitSettings, dict]:
    """(``settings`` with ``overrides`` that name ``FitSettings`` fields applied and ``steps`` None resolved to
    ``default_steps``, ``batch_size`` None to ``default_batch``, ``FieldModel`` keywords: ``hidden`` and ``layers``
    from them and the other ``overrides``). Raises ``SettingsError`` for a value that breaks a ``FitSettings``
    rule."""
    settings = replace(settings or FitSettings(), **{k: v for k, v in overrides.items() if k in _FIT_FIELDS})
    if settings.steps is None:
        settings = replace(settings, steps=default_steps)
    if settings.batch_size is None:
        settings = replace(settings, batch_size=default_batch)
    model_kw = {k: v for k, v in overrides.items() if k not in _FIT_FIELDS}
    return settings, {"hidden": settings.hidden, "layers": settings.layers, **model_kw}


def fit_image(
    image,
    mesh,
    settings: FitSettings | None = None,
    *,
    feature_bits: int = DEFAULT_FEATURE_BITS,
    weight_bits: int | None = None,
    callback: Callable[[int, Tensor, Tensor], None] | None = None,
    channels: list[str] | None = None,
    lr: float | None = None,
    final_lr: float | None = 1e-3,
    mixed_pixels: str = "drop",
    data_range: float | None = None,
    init: FieldModel | None = None,
    exclude: np.ndarray | None = None,
    tonemap: bool | None = None,
    pixel_filter=None,
    **overrides,
) -> FieldModel:
    """Fit a ``FieldModel`` on ``mesh`` to a raster covering ``mesh.domain``.

    Parameters
    ----------
    image : (H, W, C) float array of linear values, or a ``dfc.io.image.Image``
    mesh : dfc.geometry.mesh.Mesh
    settings : ``dfc.settings.FitSettings`` (default: its defaults), of which
        steps : optimiser steps (None: ``IMAGE_STEPS``)
        batch_size : samples per step (stratified, see ``image_sampler``; None: ``image_batch_size`` of the image)
        dim : feature channels; hidden, layers : the decoder's
        seed : seeds features, decoder and sampling; the result is bit-identical on CPU for a seed
        loss : {"auto", "mse", "relmse", "logmse"}; "auto" is "logmse" for HDR images (``dfc.metrics.is_hdr``),
            else "mse"
        qat_steps : quantisation-aware final steps (None: ``DEFAULT_QAT_FRACTION`` of ``steps``)
        device : torch device
        pixel_filter : not read here (the encoder's request; ``dfc.codec`` resolves it into ``pixel_filter``)
    feature_bits : bits of the features during those steps (as the file will store them)
    weight_bits : bits of the integer weight matrices during those steps (None: fp16, as ``MLPW`` stores them)
    callback : ``callback(step, loss, batch_psnr)`` after each step
    channels : output channel names (default: the Image's, else R, G, B[, A] / Y / c0, c1, …)
    lr, final_lr : Adam learning rate (None: ``image_lr(steps)``), decayed geometrically to ``final_lr`` (None:
        constant); the decoder's is ``image_decoder_lr(steps)`` times it
    mixed_pixels : {"drop", "keep"}; "drop" leaves out the pixels a discontinuity crosses
        (``edge_pixels``): their box-filtered blend of both sides would otherwise pull the field's
        values near every edge towards the blend, visible as a soft band at zoom. Ignored when it
        would leave out more than ``MAX_DROPPED_FRACTION`` of the pixels.
    data_range, tonemap : the scale of the batch PSNR the callback sees (default: ``dfc.metrics.quality_scale`` of
        the image, the scale ``dfc.codec`` reports the file's PSNR on)
    init : a model fitted before on another mesh of the same curves: the fit starts from it
        (``dfc.field.transfer.carry_over`` at every pixel centre) instead of from scratch
    exclude : optional (H, W) bool, pixels never trained on besides the mixed ones (held out to measure the fit)
    pixel_filter : the ``dfc.pixel_filter.PixelFilter`` that made the pixels: each pixel is then compared with the
        field filtered by it there (``dfc.train.pixel_sampler``; every pixel is trained, ``mixed_pixels`` is
        ignored); None: point samples jittered in each pixel, mixed pixels as ``mixed_pixels`` says
    **overrides : ``FitSettings`` fields, applied on top of ``settings`` (``fit_image(image, mesh, steps=1000)``),
        and ``FieldModel`` options (activation, oneblob_bins, transform; the transform defaults to "log" for HDR
        images whose values are all > -1, else "identity"). ``SettingsError`` for a value that breaks a rule. The
        fit works on the values as given: ``dfc.codec`` hands it values normalised to [0, 1] (``dfc.field.units``)

    Returns
    -------
    FieldModel, in evaluation mode; quantised mode stays on when ``qat_steps > 0``.
    """
    from ..io.samples import default_channels

    pixels = check_pixels(image)
    if channels is None:
        channels = getattr(image, "channels", None) or default_channels(pixels.shape[2])
    values = pixels.reshape(-1, pixels.shape[2])
    settings, model_kw = fit_settings(settings, overrides, IMAGE_STEPS, image_batch_size(len(values)))
    model, run = _new_model(values, mesh, channels, settings, (data_range, tonemap), model_kw)
    field = model.field
    if mixed_pixels not in ("drop", "keep"):
        raise ValueError(f"mixed_pixels must be 'drop' or 'keep', got {mixed_pixels!r}")
    held_out = exclude
    if pixel_filter is not None:
        mixed_pixels = "keep"
    exclude = edge_pixels(mesh, *pixels.shape[:2]) if mixed_pixels == "drop" else None
    if exclude is not None and exclude.mean() > MAX_DROPPED_FRACTION:
        exclude = None
    if held_out is not None:
        exclude = held_out if exclude is None else exclude | held_out
    if init is not None:
        from ..field.transfer import carry_over
        from ..render import window_points

        carry_over(init, model, window_points(mesh.domain, pixels.shape[1], pixels.shape[0]))
    n = pixels.shape[0] * pixels.shape[1]
    cached = n <= MAX_CACHED_SAMPLES
    if pixel_filter is not None:
        from .pixel_sampler import filtered_sampler

        if held_out is not None:
            raise ValueError("exclude is not supported with a pixel filter")
        filtered = pixel_filter.filtered(edge_pixels(mesh, *pixels.shape[:2]))
        steep = steep_pixels(pixels, run["loss"], pixel_filter.reach) & filtered
        points = n + (TRAIN_POINTS - 1) * int(filtered.sum()) + (STEEP_POINTS - TRAIN_POINTS) * int(steep.sum())
        sampler = filtered_sampler(pixels, mesh.domain, settings.batch_size, pixel_filter, filtered,
                                   device=settings.device,
                                   query=field.query if points <= MAX_CACHED_SAMPLES else None,
                                   sets=max(1, min(8, MAX_CACHED_SAMPLES // points)), seed=settings.seed,
                                   steep=steep)
    else:
        sampler = image_sampler(
            pixels, mesh.domain, settings.batch_size, device=settings.device, query=field.query if cached else None,
            jitter_sets=max(1, min(8, MAX_CACHED_SAMPLES // n)), seed=settings.seed, exclude=exclude,
        )
    fit(model, sampler, lr=image_lr(run["steps"]) if lr is None else lr, final_lr=final_lr, seed=settings.seed,
        callback=callback, feature_bits=feature_bits, weight_bits=weight_bits,
        decoder_lr=image_decoder_lr(run["steps"]), **run)
    return model


def steep_pixels(pixels: np.ndarray, loss: str, reach: int) -> np.ndarray:
    """(H, W) bool: the pixels of ``pixels`` (H, W, C) around which, within ``reach`` px, the values span more than
    ``dfc.pixel_filter.STEEP_RANGE`` in the units of ``loss`` (``signed_log`` for the relative losses "logmse" and
    "relmse", else the values)."""
    from scipy.ndimage import maximum_filter, minimum_filter

    v = np.asarray(pixels, dtype=np.float64)
    if loss in ("logmse", "relmse"):
        v = signed_log(torch.from_numpy(v)).numpy()
    size = (2 * reach + 1, 2 * reach + 1, 1)
    return ((maximum_filter(v, size=size) - minimum_filter(v, size=size)).max(axis=2)) > STEEP_RANGE


def _new_model(values: np.ndarray, mesh, channels, settings: FitSettings, scale, model_kw, times=None):
    """A fresh ``FieldModel`` for targets ``values`` (M, C) and the ``fit`` settings derived from them
    (one feature slice per entry of ``times`` when given); see ``_model_for``."""
    log_mean = np.log1p(np.maximum(values, 0.0)).mean(axis=0, dtype=np.float64)
    return _model_for(float(values.min()), float(values.max()), values.mean(axis=0, dtype=np.float64), log_mean, mesh,
                      channels, settings, scale, model_kw, times)


def _model_for(lo: float, hi: float, mean: np.ndarray, log_mean: np.ndarray, mesh, channels, settings: FitSettings,
               scale, model_kw, times=None):
    """A fresh ``FieldModel`` for targets whose values span ``lo .. hi``, with per-channel ``mean`` (C,) and mean
    ``log_mean`` (C,) of ``log(1 + max(v, 0))``, and the ``fit`` settings derived from them.

    HDR targets (``dfc.metrics.is_hdr``) default to the ``logmse`` loss and, when every value is > -1, to the ``log`` value
    transform, whose output is ``log(1 + v)``: the decoder then works on a range it can reach. The decoder's
    output bias starts at the mean of the targets in its output space (for the log transform the mean of the logs,
    not the log of the mean, which bright pixels pull far above most of the image). ``scale`` is (data_range,
    tonemap) of the progress PSNR, each None for ``dfc.metrics.quality_scale`` of the targets. Returns (model, dict
    of ``fit`` keywords: steps, qat_steps, loss, data_range, tonemap).
    """
    from ..field.feature_field import FeatureField

    hdr = is_hdr(hi=hi, mean=float(np.mean(mean)))
    loss, steps, qat_steps, seed = settings.loss, settings.steps, settings.qat_steps, settings.seed
    if loss == "auto":  # ``dfc.train.losses.auto_loss`` of the targets, from their statistics
        loss = "logmse" if hdr else "mse"
    if hdr and lo > -1.0:
        model_kw = {"transform": "log", **model_kw}
    steps = DEFAULT_STEPS if steps is None else steps
    if qat_steps is None:
        qat_steps = round(DEFAULT_QAT_FRACTION * steps) if isinstance(steps, int) else 0
    n_slices = 1 if times is None else len(times)
    field = FeatureField(mesh, dim=settings.dim, seed=seed, n_slices=n_slices, times=times, device=settings.device)
    model = FieldModel(field, list(channels), seed=seed, **model_kw)
    with torch.no_grad():
        model.decoder.linears()[-1].bias.copy_(torch.from_numpy(log_mean if model.transform == "log" else mean))
    default = QualityScale(1.0, tonemap=True) if hdr else QualityScale(value_span(np.array([lo, hi])))
    data_range, tonemap = scale
    data_range = default.data_range if data_range is None else data_range
    tonemap = default.tonemap if tonemap is None else tonemap
    return model, {"steps": steps, "qat_steps": qat_steps, "loss": loss, "data_range": data_range,
                   "tonemap": tonemap}


def fit_bands(
    source,
    mesh,
    stats,
    settings: FitSettings | None = None,
    *,
    epoch_pixels: int | None = None,
    mixed=None,
    held_out=None,
    feature_bits: int = DEFAULT_FEATURE_BITS,
    weight_bits: int | None = None,
    callback: Callable[[int, Tensor, Tensor], None] | None = None,
    channels: list[str] | None = None,
    lr: float | None = None,
    final_lr: float | None = 1e-3,
    data_range: float | None = None,
    tonemap: bool | None = None,
    **overrides,
) -> FieldModel:
    """Fit a ``FieldModel`` on ``mesh`` to a raster read in bands (``dfc.io.bands``), out of core and, inside a
    ``torch.distributed`` run, data-parallel (``dfc.train.bands.band_sampler``, ``dfc.train.distributed``).

    Parameters
    ----------
    source : band source covering ``mesh.domain``; stats : its ``dfc.train.bands.BandStats`` over all ranks (range
        and mean initialise the model as ``fit_image`` does)
    settings.batch_size : samples per step over all ranks (rank r draws ``batch_size // N``, plus one for r below
        the remainder)
    epoch_pixels : pixels per epoch over all ranks (default ``dfc.train.bands.default_epoch_pixels``)
    mixed, held_out : pixels never sampled (``EdgeMask``, ``HeldOut``, or None)
    other arguments : as in ``fit_image``

    Returns
    -------
    FieldModel, in evaluation mode, equal on every rank; quantised mode stays on when ``qat_steps > 0``.
    """
    from .bands import band_sampler
    from .distributed import world

    rank, size = world()
    settings, model_kw = fit_settings(settings, overrides, IMAGE_STEPS)
    model, run = _model_for(float(stats.lo.min()), float(stats.hi.max()), stats.mean, stats.log_mean, mesh,
                            channels or source.channels, settings, (data_range, tonemap), model_kw)
    batch_size, device = settings.batch_size, settings.device
    local = batch_size // size + (rank < batch_size % size)
    if local < 1:
        raise InputError(f"batch size {batch_size} is smaller than the number of ranks ({size})")
    # on a GPU each epoch's points are located once, so that a step has no host round trip; on the CPU that would
    # save nothing (every sample is used once per epoch) and cost about 84 bytes per sample
    query = model.field.query if torch.device(device).type == "cuda" else None
    sampler = band_sampler(source, mesh.domain, local, epoch_pixels=epoch_pixels, mixed=mixed, held_out=held_out,
                           rank=rank, world=size, device=device, query=query)
    fit(model, sampler, lr=image_lr(run["steps"]) if lr is None else lr, final_lr=final_lr, seed=settings.seed,
        callback=callback, feature_bits=feature_bits, weight_bits=weight_bits,
        decoder_lr=image_decoder_lr(run["steps"]), **run)
    return model


SAMPLES_LR = 5e-3
"""Initial learning rate of ``fit_samples``. Noisy targets: 1e-2 sometimes diverges near the curves."""
SAMPLES_FINAL_LR = 1e-4
"""Final learning rate of ``fit_samples``. On walk-on-spheres samples (the pepper at 256², 11 spp) the fit
averages the noise only once the rate is this low: 400 steps to 1e-3 denoise 7.6×, 1,500 steps to 1e-4 21.5×."""


def fit_samples(
    samples,
    mesh,
    settings: FitSettings | None = None,
    *,
    feature_bits: int = DEFAULT_FEATURE_BITS,
    weight_bits: int | None = None,
    callback: Callable[[int, Tensor, Tensor], None] | None = None,
    channels: list[str] | None = None,
    lr: float = SAMPLES_LR,
    final_lr: float | None = SAMPLES_FINAL_LR,
    data_range: float | None = None,
    init: FieldModel | None = None,
    tonemap: bool | None = None,
    **overrides,
) -> FieldModel:
    """Fit a ``FieldModel`` on ``mesh`` to a sample set (noisy values at scattered, possibly repeated points).

    Parameters
    ----------
    samples : dfc.io.samples.SampleSet (validated here); its points must lie in ``mesh.domain``
    mesh : dfc.geometry.mesh.Mesh
    settings, **overrides : as in ``fit_image``, but ``steps`` None is ``DEFAULT_STEPS`` and ``batch_size`` samples
        are drawn per step in shuffled epochs (``point_sampler``)
    feature_bits, weight_bits, callback, data_range, tonemap : as in ``fit_image``
    lr, final_lr : Adam learning rate, decayed geometrically to ``final_lr`` (lower than ``fit_image``'s, see
        ``SAMPLES_LR``)
    channels : output channel names (default: the sample set's, else ``dfc.io.samples.default_channels``)
    init : a model fitted before on another mesh of the same curves: the fit starts from it
        (``dfc.field.transfer.carry_over`` at up to ``MAX_CARRY_POINTS`` of the sample positions)

    Returns
    -------
    FieldModel, in evaluation mode; quantised mode stays on when ``qat_steps > 0``. The output bias starts
    at the samples' mean.
    """
    from ..io.samples import check_samples, default_channels

    samples = check_samples(samples)
    x0, y0, x1, y1 = mesh.domain
    xy = samples.xy
    outside = (xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1)
    if outside.any():
        raise InputError(f"samples: {int(outside.sum())} points lie outside the mesh's domain {mesh.domain}")
    values = samples.values
    if channels is None:
        channels = samples.channels or default_channels(values.shape[1])
    settings, model_kw = fit_settings(settings, overrides, DEFAULT_STEPS)
    model, run = _new_model(values, mesh, channels, settings, (data_range, tonemap), model_kw)
    if init is not None:
        from ..field.transfer import carry_over

        carry_over(init, model, xy[::max(1, len(xy) // MAX_CARRY_POINTS)])
    cached = len(xy) <= MAX_CACHED_SAMPLES
    sampler = point_sampler(xy, values, settings.batch_size, device=settings.device,
                            query=model.field.query if cached else None)
    fit(model, sampler, lr=lr, final_lr=final_lr, seed=settings.seed, callback=callback, feature_bits=feature_bits,
        weight_bits=weight_bits, **run)
    return model


def fit_frames(
    sequence,
    mesh,
    settings: FitSettings | None = None,
    *,
    feature_bits: int = DEFAULT_FEATURE_BITS,
    weight_bits: int | None = None,
    callback: Callable[[int, Tensor, Tensor], None] | None = None,
    channels: list[str] | None = None,
    lr: float = 1e-2,
    final_lr: float | None = 1e-3,
    data_range: float | None = None,
    tonemap: bool | None = None,
    **overrides,
) -> FieldModel:
    """Fit a time-sliced ``FieldModel`` on ``mesh`` to a frame sequence (``dfc.io.frames.FrameSequence``) covering
    ``mesh.domain``: one feature slice per frame, at the frame's time, sharing the mesh and the decoder.

    Arguments as in ``fit_image`` (``steps`` None is ``DEFAULT_STEPS``, counting batches over all frames together;
    pixels that a discontinuity crosses are left out as with ``mixed_pixels="drop"``). Returns the model in
    evaluation mode.
    """
    from ..io.frames import check_frames
    from ..io.samples import default_channels

    sequence = check_frames(sequence)
    frames = sequence.frames
    if channels is None:
        channels = sequence.channels or default_channels(frames.shape[3])
    values = frames.reshape(-1, frames.shape[3])
    settings, model_kw = fit_settings(settings, overrides, DEFAULT_STEPS)
    model, run = _new_model(values, mesh, channels, settings, (data_range, tonemap), model_kw, times=sequence.times)
    exclude = edge_pixels(mesh, *frames.shape[1:3])
    sampler = frame_sampler(frames, sequence.times, mesh.domain, settings.batch_size, device=settings.device,
                            exclude=exclude if exclude.mean() <= MAX_DROPPED_FRACTION else None)
    fit(model, sampler, lr=lr, final_lr=final_lr, seed=settings.seed, callback=callback, feature_bits=feature_bits,
        weight_bits=weight_bits, **run)
    return model

