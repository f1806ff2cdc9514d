"""Fitting a field model to samples of a signal (DESIGN §6).

``fit`` is the generic loop (Adam, optional quantisation-aware final steps, progress through a
callback — the library never prints). ``image_sampler`` draws stratified samples of a raster and
``fit_image`` wires image + mesh → fitted ``FieldModel`` with defaults measured on the sample scene.
Deterministic on CPU for a given seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..field.model import FieldModel

__all__ = ["LOSSES", "edge_pixels", "fit", "fit_image", "image_sampler", "loss_value"]

LOSSES = ("mse", "relmse")
RELMSE_EPS = 0.01
"""The ``+ 0.01`` in the relative MSE's denominator (paper §5): limits the weight of near-black values."""

Sampler = Callable[[int, torch.Generator], tuple[Tensor, Tensor]]


def loss_value(name: str, f: Tensor, g: Tensor) -> Tensor:
    """Scalar loss of predictions f (B, C) against targets g (B, C).

    ``"mse"``: mean (f − g)². ``"relmse"``: mean (f − g)² / (max(f, 0)ᵈ + 0.01)², where ᵈ marks a
    detached value (no gradient through the denominator). Clamping at 0 keeps a negative prediction
    from shrinking the denominator towards 0; for f ≥ 0 it is the paper's relative MSE.
    """
    if name == "mse":
        return torch.mean((f - g) ** 2)
    if name == "relmse":
        return torch.mean((f - g) ** 2 / (f.detach().clamp_min(0) + RELMSE_EPS) ** 2)
    raise ValueError(f"loss must be one of {LOSSES}, got {name!r}")


def fit(
    model: FieldModel,
    sampler: Sampler,
    *,
    steps: int,
    lr: float = 1e-2,
    betas: tuple[float, float] = (0.9, 0.99),
    loss: str = "mse",
    seed: int = 0,
    callback: Callable[[int, float, float], None] | None = None,
    qat_steps: int = 0,
    feature_bits: int = 8,
    data_range: float = 1.0,
    final_lr: float | None = None,
) -> dict:
    """Train ``model`` in place with Adam on batches from ``sampler``.

    Parameters
    ----------
    model : FieldModel (any module ``(xy (B, 2)) -> (B, C)`` with ``quantization`` works)
    sampler : callable ``(step, generator) -> (xy (B, 2), target (B, C))`` tensors on the model's device,
        optionally with a third item: the batch's precomputed ``field.query(xy)`` (see ``image_sampler``), or a
        dict of further model arguments, e.g. ``{"t": (B,) times}`` (see ``frame_sampler``)
    steps : number of optimiser steps
    lr, betas : Adam settings (DESIGN §6: 1e-2, (0.9, 0.99))
    loss : {"mse", "relmse"}, see ``loss_value``
    seed : seeds the CPU generator handed to the sampler
    callback : called after each step as ``callback(step, loss, psnr)``; psnr is of the batch, in dB
        with ``data_range``
    qat_steps : the last ``qat_steps`` steps run with ``model.quantization = {"feature_bits":
        feature_bits}`` (quantised features, fp16 decoder weights), which stays set on return so the
        model evaluates as the written file will decode
    final_lr : if given, the learning rate decays geometrically from ``lr`` to ``final_lr`` over the run

    Returns
    -------
    dict with ``loss`` and ``psnr``: lists of floats, one per step
    """
    if not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    if not isinstance(qat_steps, int) or not 0 <= qat_steps <= steps:
        raise ValueError(f"qat_steps must be an integer in [0, steps={steps}], got {qat_steps!r}")
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    if not lr > 0 or (final_lr is not None and not final_lr > 0):
        raise ValueError(f"learning rates must be positive, got lr={lr}, final_lr={final_lr}")
    generator = torch.Generator().manual_seed(seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr, betas=betas)
    decay = (final_lr / lr) ** (1.0 / max(1, steps - 1)) if final_lr is not None else 1.0
    peak = float(data_range) ** 2
    history: dict[str, list[float]] = {"loss": [], "psnr": []}
    model.train()
    for step in range(steps):
        if qat_steps and step == steps - qat_steps:
            model.quantization = {"feature_bits": feature_bits}
        for group in optimizer.param_groups:
            group["lr"] = lr * decay**step
        xy, target, *extra = sampler(step, generator)
        if not extra:
            pred = model(xy)
        elif isinstance(extra[0], dict):
            pred = model(xy, **extra[0])
        else:
            pred = model(xy, query=extra[0])
        value = loss_value(loss, pred, target)
        optimizer.zero_grad(set_to_none=True)
        value.backward()
        optimizer.step()
        value = value.detach()
        err = float(torch.mean((pred.detach() - target) ** 2))
        psnr = 10.0 * math.log10(peak / err) if err > 0 else math.inf
        history["loss"].append(float(value))
        history["psnr"].append(psnr)
        if callback is not None:
            callback(step, history["loss"][-1], psnr)
    model.eval()
    return history


class _Epochs:
    """Every index of ``range(n)`` once per epoch, in a fresh random order drawn from the fit's generator."""

    def __init__(self, n: int):
        self.n = n
        self.order = torch.empty(0, dtype=torch.int64)
        self.pos = self.epoch = 0

    def take(self, count: int, generator: torch.Generator) -> list[tuple[Tensor, int]]:
        """The next ``count`` indices, as runs (indices (k,) int64, 1-based epoch they belong to)."""
        parts = []
        while count:
            if self.pos == len(self.order):
                self.order, self.pos = torch.randperm(self.n, generator=generator), 0
                self.epoch += 1
            k = min(count, self.n - self.pos)
            parts.append((self.order[self.pos : self.pos + k], self.epoch))
            self.pos += k
            count -= k
        return parts


class _PixelGrid:
    """Pixel (i, j) of a ``width × height`` raster over ``domain`` covers ``[x0 + i·sx, x0 + (i+1)·sx] × …``."""

    def __init__(self, domain, width: int, height: int):
        x0, y0, x1, y1 = domain
        self.width = width
        self.origin = torch.tensor([x0, y0], dtype=torch.float64)
        self.pixel_size = torch.tensor([(x1 - x0) / width, (y1 - y0) / height], dtype=torch.float64)

    def points(self, pixel: Tensor, generator: torch.Generator) -> Tensor:
        """One uniformly jittered point (N, 2) float64 in each of the flat pixel indices ``pixel`` (N,)."""
        jitter = torch.rand(len(pixel), 2, generator=generator, dtype=torch.float64)
        ij = torch.stack([pixel % self.width, pixel // self.width], dim=1).to(torch.float64)
        return self.origin + (ij + jitter) * self.pixel_size


def _kept_pixels(height: int, width: int, exclude) -> Tensor:
    """(n,) int64 flat indices of the pixels not excluded (``exclude``: None or (H, W) bool)."""
    keep = np.arange(height * width)
    if exclude is not None:
        exclude = np.asarray(exclude, dtype=bool)
        if exclude.shape != (height, width):
            raise ValueError(f"exclude must have the image's shape {(height, width)}, got {exclude.shape}")
        keep = keep[~exclude.ravel()]
        if len(keep) == 0:
            raise InputError("every pixel is excluded from sampling")
    return torch.from_numpy(keep)


class _StratifiedPixels:
    """Stateful sampler: every pixel once per epoch in a fresh random order, each at a jittered point.

    Without ``query``, each epoch draws fresh U(0, 1)² jitters. With ``query``, ``jitter_sets`` epochs'
    jittered points and their ``query(xy)`` results are computed once and reused in turn (epoch e uses
    set e mod jitter_sets, still in a fresh order), so point location is not repeated every step.
    """

    def __init__(self, pixels: Tensor, domain, batch_size: int, query, jitter_sets: int, generator: torch.Generator,
                 keep: Tensor):
        self.pixels = pixels.reshape(-1, pixels.shape[-1])
        self.keep = keep  # (n,) int64 flat indices of the pixels sampled
        self.grid = _PixelGrid(domain, pixels.shape[1], pixels.shape[0])
        self.batch_size = batch_size
        self.epochs = _Epochs(len(keep))
        self.cache = None
        if query is not None:
            xy = torch.cat([self.grid.points(keep, generator) for _ in range(jitter_sets)])
            with torch.no_grad():
                parts = [query(xy[s : s + QUERY_CHUNK].to(pixels.device)) for s in range(0, len(xy), QUERY_CHUNK)]
            self.cache = (xy, torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))

    def __call__(self, step: int, generator: torch.Generator):
        n = len(self.keep)
        sets = len(self.cache[0]) // n if self.cache is not None else 1
        # with a cache, epoch e uses jitter set (e - 1) mod sets, whose rows start at that index times n
        rows = torch.cat([order + ((epoch - 1) % sets) * n for order, epoch in self.epochs.take(self.batch_size,
                                                                                               generator)])
        pixel = self.keep[rows % n]
        device = self.pixels.device
        target = self.pixels[pixel.to(device)]
        if self.cache is None:
            return self.grid.points(pixel, generator).to(device), target
        xy, idx, w = self.cache
        rows_d = rows.to(idx.device)
        return xy[rows].to(device), target, (idx[rows_d], w[rows_d])


QUERY_CHUNK = 1 << 16
"""Points per call when precomputing field queries (bounds the locator's temporary memory)."""


def image_sampler(image, domain, batch_size: int, *, device: str = "cpu", query=None, jitter_sets: int = 8,
                  seed: int = 0, exclude=None) -> Sampler:
    """Stratified sampler over a raster covering ``domain``.

    Each epoch visits every pixel (not excluded) once, in a random order, at one uniformly jittered
    point inside the pixel; the target is that pixel's value (signal space: the model applies its own transform).
    Pixel (i, j) (column i, row j) covers ``[x0 + i·sx, x0 + (i+1)·sx] × [y0 + j·sy, …]`` with
    ``sx = (x1 − x0) / W``, ``sy = (y1 − y0) / H`` (rows go down in y).

    Parameters
    ----------
    image : (H, W, C) float array (or an ``Image``); domain : (x0, y0, x1, y1)
    batch_size : samples per call
    query : optional ``field.query`` (xy (N, 2) → (idx, w)); when given, ``jitter_sets`` epochs of
        jittered points are located once (seeded by ``seed``) and reused in turn, and each call also
        returns the batch's (idx, w) for ``FieldModel.forward(query=...)``. Memory: about 100 bytes
        per pixel and jitter set.
    exclude : optional (H, W) bool, pixels never sampled (e.g. ``edge_pixels(mesh, H, W)``)

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32[, (idx, w)])``
    """
    pixels = _check_pixels(image)
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    if not isinstance(jitter_sets, int) or jitter_sets < 1:
        raise ValueError(f"jitter_sets must be a positive integer, got {jitter_sets!r}")
    x0, y0, x1, y1 = (float(v) for v in domain)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"domain {tuple(domain)} must have x1 > x0 and y1 > y0")
    keep = _kept_pixels(pixels.shape[0], pixels.shape[1], exclude)
    generator = torch.Generator().manual_seed(seed)
    return _StratifiedPixels(torch.from_numpy(pixels).to(device), (x0, y0, x1, y1), batch_size, query, jitter_sets,
                             generator, keep)


EDGE_SAMPLE_SPACING = 0.25
"""``edge_pixels`` samples each discontinuity at this spacing, in pixels."""


def edge_pixels(mesh, height: int, width: int) -> np.ndarray:
    """(H, W) bool: pixels of a ``width × height`` raster over ``mesh.domain`` crossed by a discontinuity.

    Their values blend both sides (a box-filtered image), which no side of a sharp field can match.
    Straight discontinuous edges and curved pieces are sampled every ``EDGE_SAMPLE_SPACING`` pixels,
    so a pixel whose corner a curve clips by less than that may be missed (its blend is slight).
    """
    x0, y0, x1, y1 = mesh.domain
    v = mesh.vertices
    a, b = v[mesh.disc_edges[:, 0]], v[mesh.disc_edges[:, 1]]
    lines = np.stack([a, a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0, b], axis=1)
    cp = np.concatenate([lines, np.asarray(mesh.curve_control_points, dtype=np.float64).reshape(-1, 4, 2)])
    out = np.zeros((height, width), dtype=bool)
    if len(cp) == 0:
        return out
    scale = np.array([width / (x1 - x0), height / (y1 - y0)])
    polygon = np.linalg.norm(np.diff(cp * scale, axis=1), axis=2).sum(axis=1)  # ≥ arc length, in pixels
    n = np.maximum(np.ceil(polygon / EDGE_SAMPLE_SPACING).astype(np.int64) + 1, 2)
    piece = np.repeat(np.arange(len(cp)), n)
    start = np.concatenate([[0], np.cumsum(n)[:-1]])
    t = (np.arange(len(piece)) - start[piece]) / (n[piece] - 1)
    s = 1.0 - t
    w = np.stack([s**3, 3 * s * s * t, 3 * s * t * t, t**3], axis=1)  # (M, 4) Bernstein weights
    pts = np.einsum("mk,mkd->md", w, cp[piece])
    ij = np.floor((pts - [x0, y0]) * scale).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < width) & (ij[:, 1] >= 0) & (ij[:, 1] < height)
    out[ij[inside, 1], ij[inside, 0]] = True
    return out


def _check_pixels(image) -> np.ndarray:
    pixels = np.ascontiguousarray(getattr(image, "pixels", image), dtype=np.float32)
    if pixels.ndim != 3 or min(pixels.shape) < 1:
        raise InputError(f"expected an image (H, W, C) with H, W, C ≥ 1, got shape {pixels.shape}")
    bad = ~np.isfinite(pixels)
    if bad.any():
        j, i, c = np.argwhere(bad)[0]
        raise InputError(f"image has {int(bad.sum())} NaN/Inf values, the first at row {j}, column {i}, channel {c}")
    return pixels


DEFAULT_STEPS = 1000
"""Default optimiser steps of ``fit_image``. On the 256 × 256 sample scene (2,560 triangles, batch 2¹⁴,
one CPU thread) 1,000 steps take ≈ 25 s and reach 44.4 dB (4 spp render against the 2 × 2 box-filtered
truth); 2,000 steps take ≈ 50 s for 44.5 dB."""
DEFAULT_QAT_FRACTION = 0.1
"""Default share of the steps run quantisation-aware."""
MAX_DROPPED_FRACTION = 0.5
"""``fit_image`` keeps mixed pixels after all when they are more than this share of the image."""
MAX_CACHED_SAMPLES = 1 << 22
"""``fit_image`` caches point location for at most this many samples (≈ 100 bytes each)."""


def fit_image(
    image,
    mesh,
    *,
    steps: int | None = None,
    batch_size: int = 1 << 14,
    dim: int = 5,
    seed: int = 0,
    loss: str = "auto",
    device: str = "cpu",
    qat_steps: int | None = None,
    feature_bits: int = 8,
    callback: Callable[[int, float, float], None] | None = None,
    channels: list[str] | None = None,
    lr: float = 1e-2,
    final_lr: float | None = 1e-3,
    mixed_pixels: str = "drop",
    **model_kw,
) -> FieldModel:
    """Fit a ``FieldModel`` on ``mesh`` to a raster covering ``mesh.domain``.

    Parameters
    ----------
    image : (H, W, C) float array of linear values, or a ``dfc.io.image.Image``
    mesh : dfc.geometry.mesh.Mesh
    steps : optimiser steps (default ``DEFAULT_STEPS``)
    batch_size : samples per step (stratified, see ``image_sampler``)
    dim : feature channels
    seed : seeds features, decoder and sampling; the result is bit-identical on CPU for a seed
    loss : {"auto", "mse", "relmse"}; "auto" is "relmse" for HDR images (any value > 1), else "mse"
    qat_steps : quantisation-aware final steps (default ``DEFAULT_QAT_FRACTION`` of ``steps``)
    feature_bits : bits of the features during those steps (as the file will store them)
    callback : ``callback(step, loss, batch_psnr)`` after each step
    channels : output channel names (default: the Image's, else R, G, B[, A] / Y / c0, c1, …)
    lr, final_lr : Adam learning rate, decayed geometrically to ``final_lr`` (None: constant)
    mixed_pixels : {"drop", "keep"}; "drop" leaves out the pixels a discontinuity crosses
        (``edge_pixels``): their box-filtered blend of both sides would otherwise pull the field's
        values near every edge towards the blend, visible as a soft band at zoom. Ignored when it
        would leave out more than ``MAX_DROPPED_FRACTION`` of the pixels.
    **model_kw : ``FieldModel`` options (hidden, layers, activation, oneblob_bins, transform; the transform
        defaults to "log" for HDR images whose values are all > -1, else "identity")

    Returns
    -------
    FieldModel, in evaluation mode; quantised mode stays on when ``qat_steps > 0``.
    """
    from ..io.samples import default_channels

    pixels = _check_pixels(image)
    if channels is None:
        channels = getattr(image, "channels", None) or default_channels(pixels.shape[2])
    values = pixels.reshape(-1, pixels.shape[2])
    model, run = _start(values, mesh, channels, loss, steps, qat_steps, dim, seed, device, model_kw)
    field = model.field
    if mixed_pixels not in ("drop", "keep"):
        raise ValueError(f"mixed_pixels must be 'drop' or 'keep', got {mixed_pixels!r}")
    exclude = edge_pixels(mesh, *pixels.shape[:2]) if mixed_pixels == "drop" else None
    if exclude is not None and exclude.mean() > MAX_DROPPED_FRACTION:
        exclude = None
    n = pixels.shape[0] * pixels.shape[1]
    cached = n <= MAX_CACHED_SAMPLES
    sampler = image_sampler(
        pixels, mesh.domain, batch_size, device=device, query=field.query if cached else None,
        jitter_sets=max(1, min(8, MAX_CACHED_SAMPLES // n)), seed=seed, exclude=exclude,
    )
    fit(model, sampler, lr=lr, final_lr=final_lr, seed=seed, callback=callback, feature_bits=feature_bits, **run)
    return model


def _start(values: np.ndarray, mesh, channels, loss, steps, qat_steps, dim, seed, device, model_kw, times=None):
    """A fresh ``FieldModel`` for targets ``values`` (M, C) and the ``fit`` settings derived from them
    (one feature slice per entry of ``times`` when given).

    HDR targets (some value > 1) default to the relative MSE and, when every value is > -1, to the ``log`` value
    transform, whose output is ``log(1 + v)``: the decoder then works on a range it can reach. The decoder's
    output bias starts at the (transformed) mean of the targets. Returns (model, dict of ``fit`` keywords:
    steps, qat_steps, loss, data_range).
    """
    from ..field.feature_field import FeatureField

    hdr = float(values.max()) > 1.0
    if loss == "auto":
        loss = "relmse" if hdr else "mse"
    if hdr and float(values.min()) > -1.0:
        model_kw = {"transform": "log", **model_kw}
    steps = DEFAULT_STEPS if steps is None else steps
    if qat_steps is None:
        qat_steps = round(DEFAULT_QAT_FRACTION * steps) if isinstance(steps, int) else 0
    n_slices = 1 if times is None else len(times)
    field = FeatureField(mesh, dim=dim, seed=seed, n_slices=n_slices, times=times, device=device)
    model = FieldModel(field, list(channels), seed=seed, **model_kw)
    mean = torch.from_numpy(values.mean(axis=0, dtype=np.float64))
    with torch.no_grad():  # start at the mean value: HDR values are far from the MLP's initial output
        out_bias = model.decoder.linears()[-1].bias
        out_bias.copy_(torch.log1p(mean.clamp_min(0)) if model.transform == "log" else mean)
    data_range = max(float(values.max() - values.min()), 1e-12) if loss == "relmse" else 1.0
    return model, {"steps": steps, "qat_steps": qat_steps, "loss": loss, "data_range": data_range}


SAMPLES_LR = 5e-3
"""Initial learning rate of ``fit_samples``. Noisy targets: 1e-2 sometimes diverges near the curves."""
SAMPLES_FINAL_LR = 1e-4
"""Final learning rate of ``fit_samples``. On walk-on-spheres samples (the pepper at 256², 11 spp) the fit
averages the noise only once the rate is this low: 400 steps to 1e-3 denoise 7.6×, 1,500 steps to 1e-4 21.5×."""


class _ShuffledPoints:
    """Stateful sampler: every sample once per epoch, in a fresh random order (the fit's generator)."""

    def __init__(self, xy: Tensor, values: Tensor, batch_size: int, cache):
        self.xy, self.values, self.batch_size, self.cache = xy, values, batch_size, cache
        self.epochs = _Epochs(len(xy))

    def __call__(self, step: int, generator: torch.Generator):
        rows = torch.cat([order for order, _ in self.epochs.take(self.batch_size, generator)]).to(self.xy.device)
        if self.cache is None:
            return self.xy[rows], self.values[rows]
        idx, w = self.cache
        return self.xy[rows], self.values[rows], (idx[rows], w[rows])


def point_sampler(xy, values, batch_size: int, *, device: str = "cpu", query=None) -> Sampler:
    """Sampler over scattered samples, e.g. walk-on-spheres estimates (``dfc.io.samples.SampleSet``).

    Each epoch visits every sample once, in a random order drawn from the generator ``fit`` hands it; the
    target is the sample's value as given (noisy values and repeated positions are fine: the MSE fit
    averages them).

    Parameters
    ----------
    xy : (N, 2) float positions in domain units; values : (N, C) float targets (signal space)
    batch_size : samples per call
    query : optional ``field.query``; when given, every sample is located once here and each call also
        returns the batch's (idx, w) for ``FieldModel.forward(query=...)`` (about 100 bytes per sample)

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32[, (idx, w)])``
    """
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    xy = torch.as_tensor(np.ascontiguousarray(xy, dtype=np.float64)).to(device)
    values = torch.as_tensor(np.ascontiguousarray(values, dtype=np.float32)).to(device)
    if xy.ndim != 2 or xy.shape[1] != 2 or values.ndim != 2 or len(values) != len(xy) or len(xy) == 0:
        raise ValueError(f"expected xy (N, 2) and values (N, C) with N ≥ 1, got {tuple(xy.shape)} and "
                         f"{tuple(values.shape)}")
    cache = None
    if query is not None:
        with torch.no_grad():
            parts = [query(xy[s : s + QUERY_CHUNK]) for s in range(0, len(xy), QUERY_CHUNK)]
        cache = (torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))
    return _ShuffledPoints(xy, values, batch_size, cache)


def fit_samples(
    samples,
    mesh,
    *,
    steps: int | None = None,
    batch_size: int = 1 << 14,
    dim: int = 5,
    seed: int = 0,
    loss: str = "auto",
    device: str = "cpu",
    qat_steps: int | None = None,
    feature_bits: int = 8,
    callback: Callable[[int, float, float], None] | None = None,
    channels: list[str] | None = None,
    lr: float = SAMPLES_LR,
    final_lr: float | None = SAMPLES_FINAL_LR,
    **model_kw,
) -> FieldModel:
    """Fit a ``FieldModel`` on ``mesh`` to a sample set (noisy values at scattered, possibly repeated points).

    Parameters
    ----------
    samples : dfc.io.samples.SampleSet (validated here); its points must lie in ``mesh.domain``
    mesh : dfc.geometry.mesh.Mesh
    steps : optimiser steps (default ``DEFAULT_STEPS``)
    batch_size : samples per step (shuffled epochs, see ``point_sampler``)
    dim, seed, qat_steps, feature_bits, callback, **model_kw : as in ``fit_image``
    lr, final_lr : Adam learning rate, decayed geometrically to ``final_lr`` (lower than ``fit_image``'s, see
        ``SAMPLES_LR``)
    loss : {"auto", "mse", "relmse"}; "auto" is "relmse" when some value is > 1 (HDR), else "mse"
    channels : output channel names (default: the sample set's, else ``dfc.io.samples.default_channels``)

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
    model, run = _start(values, mesh, channels, loss, steps, qat_steps, dim, seed, device, model_kw)
    cached = len(xy) <= MAX_CACHED_SAMPLES
    sampler = point_sampler(xy, values, batch_size, device=device, query=model.field.query if cached else None)
    fit(model, sampler, lr=lr, final_lr=final_lr, seed=seed, callback=callback, feature_bits=feature_bits, **run)
    return model


__all__ += ["fit_samples", "point_sampler"]


class _StratifiedFrames:
    """Stateful sampler: every (frame, pixel) pair once per epoch in a fresh random order, at a jittered point."""

    def __init__(self, frames: Tensor, times: Tensor, domain, batch_size: int, keep: Tensor):
        self.values = frames.reshape(-1, frames.shape[-1])  # row s · H · W + pixel
        self.times = times
        self.keep = keep  # (n,) flat pixel indices sampled in every frame
        self.pixels_per_frame = frames.shape[1] * frames.shape[2]
        self.grid = _PixelGrid(domain, frames.shape[2], frames.shape[1])
        self.batch_size = batch_size
        self.epochs = _Epochs(frames.shape[0] * len(keep))

    def __call__(self, step: int, generator: torch.Generator):
        rows = torch.cat([order for order, _ in self.epochs.take(self.batch_size, generator)])
        frame, pixel = rows // len(self.keep), self.keep[rows % len(self.keep)]
        xy = self.grid.points(pixel, generator)
        device = self.values.device
        target = self.values[(frame * self.pixels_per_frame + pixel).to(device)]
        return xy.to(device), target, {"t": self.times[frame.to(device)]}


def frame_sampler(frames, times, domain, batch_size: int, *, device: str = "cpu", exclude=None) -> Sampler:
    """Stratified sampler over a frame sequence covering ``domain``: ``image_sampler``'s pixels, in every frame.

    Each epoch visits every (frame, pixel) pair once, in a random order, at a uniformly jittered point in the
    pixel, at the frame's exact time, so each time slice of the field is trained at its own time.

    Parameters
    ----------
    frames : (T, H, W, C) float array; times : (T,) increasing; domain : (x0, y0, x1, y1)
    exclude : optional (H, W) bool, pixels never sampled (in any frame)

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32, {"t": (B,) float64})``
    """
    frames = np.ascontiguousarray(frames, dtype=np.float32)
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    keep = _kept_pixels(frames.shape[1], frames.shape[2], exclude)
    return _StratifiedFrames(torch.from_numpy(frames).to(device),
                             torch.as_tensor(np.asarray(times, dtype=np.float64)).to(device),
                             tuple(float(v) for v in domain), batch_size, keep)


def fit_frames(
    sequence,
    mesh,
    *,
    steps: int | None = None,
    batch_size: int = 1 << 14,
    dim: int = 5,
    seed: int = 0,
    loss: str = "auto",
    device: str = "cpu",
    qat_steps: int | None = None,
    feature_bits: int = 8,
    callback: Callable[[int, float, float], None] | None = None,
    channels: list[str] | None = None,
    lr: float = 1e-2,
    final_lr: float | None = 1e-3,
    **model_kw,
) -> FieldModel:
    """Fit a time-sliced ``FieldModel`` on ``mesh`` to a frame sequence (``dfc.io.frames.FrameSequence``) covering
    ``mesh.domain``: one feature slice per frame, at the frame's time, sharing the mesh and the decoder.

    Arguments as in ``fit_image`` (steps count batches over all frames together; pixels that a discontinuity
    crosses are left out as with ``mixed_pixels="drop"``). Returns the model in evaluation mode.
    """
    from ..io.frames import check_frames
    from ..io.samples import default_channels

    sequence = check_frames(sequence)
    frames = sequence.frames
    if channels is None:
        channels = sequence.channels or default_channels(frames.shape[3])
    values = frames.reshape(-1, frames.shape[3])
    model, run = _start(values, mesh, channels, loss, steps, qat_steps, dim, seed, device, model_kw,
                        times=sequence.times)
    exclude = edge_pixels(mesh, *frames.shape[1:3])
    sampler = frame_sampler(frames, sequence.times, mesh.domain, batch_size, device=device,
                            exclude=exclude if exclude.mean() <= MAX_DROPPED_FRACTION else None)
    fit(model, sampler, lr=lr, final_lr=final_lr, seed=seed, callback=callback, feature_bits=feature_bits, **run)
    return model


__all__ += ["fit_frames", "frame_sampler"]
