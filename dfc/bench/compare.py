"""Equal-size comparison of dfc against tuned neural baselines and classical codecs at increasing zoom (paper Figs. 1,
2, 9), with the same truth, pixels and budget rules for every method.

``run_bench`` fits dfc first (``dfc.codec.encode_image``, decoded again with ``dfc.codec.loads``; sized to
``target_bytes`` when given); its file's size is every other method's budget (else ``target_bytes`` is):

- the neural baselines (hash grid, ReLU field) are tuned for the budget by a short sweep scored at 1× on the training
  raster, and the best is trained for ``steps`` steps or, with ``match_time``, at least as long as dfc's encode took
  (``dfc.bench.tuning``); they see every pixel (they do not know the curves);
- the raster (``dfc.bench.baselines.raster``) is the input area-averaged down to the largest lossless half-float EXR
  that fits;
- the classical codecs (JPEG XL, AVIF, WebP for SDR input, JPEG 2000; ``dfc.bench.codecs``) code the input at the
  highest quality that fits.

Measurements, the same for every method:

- *1× image PSNR*: each method rendered over the whole domain at the raster's resolution with the same box filter
  (a centred ``pixel_grid`` × ``pixel_grid`` grid of points per pixel), but for what its own decoder gives at that
  size: a stored raster of that size as stored, dfc's file as ``dfc decode`` renders it at its input's size (its
  stored pixel filter on the pixels a curve changes; ``dfc.bench.measure``), against the best
  truth there is: for an analytic scene its box-filtered exact value on a finer stratified grid
  (``TRUTH_SPP`` × ``TRUTH_SPP`` points per pixel; the training raster used 4 × 4 others), for a user image the
  image itself. Reported on every pixel and without the pixels a curve crosses.
- *Zoom windows*: each probe (``dfc.bench.probes``: edges, junctions, stroke tips, smooth regions) gets one window
  per zoom ``z``, the domain's size divided by ``z`` centred on the probe and shifted inside the domain (zoom 1 is the
  domain itself), rendered at ``render`` pixels on its longer side with ``spp`` points per pixel. With a *reference*
  (``AnalyticReference``: an analytic scene's exact value at the same points; ``dfc.bench.rendered
  .MitsubaReference``: Mitsuba rendering just that window) every window is measured against it; a user image alone
  only at zoom 1 (at its own pixels, against itself), larger zooms get PSNR ``None``. A reference that is itself an
  estimate (a Monte Carlo render) also gives its own PSNR against the noise-free truth, estimated from two
  independent halves of its samples (``reference_psnr``): a method scoring near it is limited by the reference.
  Stored rasters (raster, codecs) are shown through both the bicubic and the Lanczos kernel and the better one
  counts, window by window (both are recorded).
- *Super-resolution* (with a reference): the whole domain rendered at ``super_resolution`` times the input's pixels
  per axis (``spp`` points per pixel, as a window), against the reference rendered there; beside the methods, the
  input raster itself upsampled through each kernel — what doing nothing gives.

Every PSNR is measured on ``dfc.metrics.quality_scale`` of the input, as ``dfc.codec`` measures its files: colours in
[0, 1] as they are with data range 1, HDR colours tone-mapped ``x / (1 + x)`` with data range 1. The neural baselines
are fitted with the loss dfc's encoder uses for the input (``dfc.train.losses.auto_loss``: the MSE, or for HDR
colours the MSE of ``sign(v) log(1 + |v|)``), and their sweep and the codecs' choice of configuration are scored on
the same scale. Decode throughput is points per second of one batched forward pass, best of
``THROUGHPUT_REPEATS``. The library never prints: progress goes through ``progress(message)``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import InputError
from ..metrics import QualityScale, is_hdr, quality_scale
from ..render import window_shape, zoom_window
from ..train.fit import IMAGE_STEPS
from ..train.losses import auto_loss
from .codecs import CODECS, SDR_ONLY
from .measure import image_render, image_scores, mixed_pixels, pixel_render
from .probes import PROBE_KINDS
from .report import contact_sheet as contact_sheet_grid
from .report import display, write_report
from .report import markdown_table as table
from .timing import best_seconds

__all__ = ["LABELS", "METHODS", "TRUTH_SPP", "ZOOMS", "AnalyticReference", "BenchResult", "BenchSettings",
           "config_label", "contact_sheet", "markdown_table", "methods_for", "run_bench", "run_scene", "scene_inputs",
           "square_pixels", "throughput", "write_outputs"]

ZOOMS = (1, 10, 33, 100)
SUPER_RESOLUTION = 2
"""Default factor (per axis) of the super-resolution measure."""
METHODS = ("dfc", "hashgrid", "relu", "raster", *CODECS)
LABELS = {"dfc": "dfc", "hashgrid": "hash grid", "relu": "ReLU field", "raster": "raster (lossless half EXR)",
          "jpegxl": "JPEG XL", "avif": "AVIF", "webp": "WebP", "jpeg2k": "JPEG 2000"}
"""How reports name each method."""
PIXEL_METHODS = ("raster", *CODECS)
"""Methods that store a raster, shown at zoom through both interpolation kernels."""
TRUTH_SPP = 8
"""Points per pixel and axis of an analytic scene's 1× truth (box filter on a stratified grid)."""
THROUGHPUT_POINTS = 1 << 16
THROUGHPUT_REPEATS = 3


@dataclass
class BenchSettings:
    """Knobs of a benchmark run (stored in ``results.json``).

    steps, batch_size : optimiser steps (at least; default dfc's own, ``IMAGE_STEPS``) and samples per step, the same
        for every trained method
    size : longer side of the raster fitted for an analytic scene (default: the domain's longer side in its units);
        ignored for a user image
    render, spp : window resolution (longer side) and points averaged per pixel
    zooms : zoom factors ≥ 1
    methods : subset of ``METHODS``; None: every method that applies to the input (``methods_for``)
    target_bytes : the byte budget; with dfc, its ``.dfield`` is sized to it and its size is the others' budget
    max_triangles : dfc mesh size cap (default: ``dfc.geometry.triangulate``'s)
    sweep : tune the neural baselines per budget (``dfc.bench.tuning``); sweep_steps : steps of each candidate
        (default steps // 5)
    match_time : neural baselines train at least as long as dfc's encode took
    pixel_grid : the 1× image renders average a pixel_grid × pixel_grid stratified grid of points per pixel
    keep_going : a method that cannot meet the budget is recorded under ``failed`` instead of ending the run
    default_encode : dfc is encoded as ``dfc encode`` does by default (its own steps and batch size;
        ``steps`` and ``batch_size`` then apply to the neural baselines only)
    prune_curves : curves found in the image (``Curves.source`` "auto") are pruned for each budget before dfc's
        encode, as ``dfc encode --curves auto`` does (``dfc.geometry.sources.prune``); given curves, only for a
        budget too small for all of them, as ``dfc encode`` does with a curves file (``dfc.codec.encode_image``'s
        ``prune_to_fit``)
    refine_curves : such curves are then refined against the pixels, as ``dfc encode --curves auto`` does
        (``dfc.geometry.sources.refine``; both by ``dfc.geometry.sources.auto.ready_curves``)
    pixel_filter : the filter dfc's encode and refinement assume (``dfc encode --pixel-filter``); the benchmarks set
        the one found with curves found in the image, as ``dfc encode --curves auto`` does
    super_resolution : with a reference, also measure every method over the whole domain at this many times the
        input's pixels per axis (module notes); 0: not measured
    residual_share : in [0, 1): the share of ``target_bytes`` dfc's encode gives a residual raster
        (``EncodeSettings.residual_bytes``; 0: none); None: the encoder's default ("auto")
    raster_mode : dfc's encode may store a clean image in the raster mode (``dfc.codec.encode_image``'s
        ``raster_mode``, as ``dfc encode`` does by default)
    """

    steps: int = IMAGE_STEPS
    batch_size: int = 1 << 14
    size: int | None = None
    render: int = 256
    spp: int = 4
    zooms: tuple[float, ...] = ZOOMS
    methods: tuple[str, ...] | None = None
    target_bytes: int | None = None
    max_triangles: int | None = None
    seed: int = 0
    device: str = "cpu"
    sweep: bool = True
    sweep_steps: int | None = None
    match_time: bool = True
    pixel_grid: int = 4
    keep_going: bool = False
    default_encode: bool = False
    prune_curves: bool = True
    refine_curves: bool = True
    pixel_filter: str = "auto"
    super_resolution: int = SUPER_RESOLUTION
    residual_share: float | None = None
    raster_mode: bool = True

    def check(self, budgeted: bool = False) -> None:
        """Raise InputError on inconsistent settings (``budgeted``: an RD sweep will set ``target_bytes``)."""
        methods = METHODS if self.methods is None else self.methods
        unknown = [m for m in methods if m not in METHODS]
        if not methods or unknown:
            raise InputError(f"methods must be a non-empty subset of {', '.join(METHODS)}, got {list(methods)}")
        if "dfc" not in methods and self.target_bytes is None and not budgeted:
            raise InputError("without dfc among the methods, give the byte budget (target_bytes / --bytes)")
        if not self.zooms or any(not (math.isfinite(z) and z >= 1) for z in self.zooms):
            raise InputError(f"zooms must be finite numbers ≥ 1, got {list(self.zooms)}")
        for key in ("steps", "batch_size", "render", "spp", "pixel_grid"):
            if getattr(self, key) < 1:
                raise InputError(f"{key} must be ≥ 1, got {getattr(self, key)}")
        if self.super_resolution != 0 and self.super_resolution < 2:
            raise InputError(f"super_resolution must be 0 (not measured) or a factor ≥ 2, got {self.super_resolution}")
        if self.residual_share is not None and not 0.0 <= self.residual_share < 1.0:
            raise InputError(f"residual_share must be in [0, 1), got {self.residual_share}")
        if self.sweep_steps is not None and self.sweep_steps < 1:
            raise InputError(f"sweep_steps must be ≥ 1, got {self.sweep_steps}")
        if any(m in CODECS for m in methods):
            from .codecs import require_imagecodecs

            require_imagecodecs()

    @property
    def candidate_steps(self) -> int:
        return self.sweep_steps or max(1, self.steps // 5)


def methods_for(settings: BenchSettings, hdr: bool) -> tuple[str, ...]:
    """The methods a run on an input (HDR or not) runs: ``settings.methods``, or by default every method, leaving
    the SDR-only codecs out for HDR input. InputError when an SDR-only codec is asked for HDR input."""
    if settings.methods is None:
        return tuple(m for m in METHODS if not (hdr and m in SDR_ONLY))
    bad = [m for m in settings.methods if hdr and m in SDR_ONLY]
    if bad:
        raise InputError(f"{', '.join(bad)} codes 8-bit SDR images only and the input is HDR; leave it out of "
                         "--methods")
    return tuple(m for m in METHODS if m in settings.methods)


# ----------------------------------------------------------------------------------------------- models
def throughput(model: nn.Module, domain, device: str, seed: int = 0) -> float:
    """Decode throughput in points per second: best of ``THROUGHPUT_REPEATS`` forward passes of
    ``THROUGHPUT_POINTS`` uniformly random points (after one warm-up pass)."""
    x0, y0, x1, y1 = domain
    rng = np.random.default_rng(seed)
    xy = torch.from_numpy(rng.random((THROUGHPUT_POINTS, 2)) * [x1 - x0, y1 - y0] + [x0, y0]).to(device)
    with torch.no_grad():
        return THROUGHPUT_POINTS / best_seconds(lambda: model(xy), THROUGHPUT_REPEATS, device)


class _Remap(nn.Module):
    """``model`` living on ``inner`` domain, queried in ``outer`` domain units (an affine map per axis). With
    ``size`` (the input's (width, height)), ``model`` a dfc file's: ``pixels()`` is that file decoded at its input's
    size as ``dfc decode`` decodes it there (``dfc.render.default_pixel_filter``: the stored pixel filter), what
    ``dfc.bench.measure.image_render`` takes for the 1× render, as it takes a stored raster's pixels."""

    def __init__(self, model: nn.Module, outer, inner, size: tuple[int, int] | None = None):
        super().__init__()
        self.model = model
        self.scale = [(inner[2] - inner[0]) / (outer[2] - outer[0]), (inner[3] - inner[1]) / (outer[3] - outer[1])]
        self.outer, self.inner = outer, inner
        self.size = size

    def pixels(self) -> np.ndarray:
        from ..render import default_pixel_filter, render

        w, h = self.size
        return render(self.model, w, h, pixel_filter=default_pixel_filter(self.model, w, h)[0])

    def forward(self, xy):
        s = torch.tensor(self.scale, dtype=xy.dtype, device=xy.device)
        o = torch.tensor(self.outer[:2], dtype=xy.dtype, device=xy.device)
        i = torch.tensor(self.inner[:2], dtype=xy.dtype, device=xy.device)
        return self.model((xy - o) * s + i)


def _fit_dfc(pixels, curves, channels, settings: BenchSettings, progress) -> tuple[nn.Module, int, dict]:
    from ..codec import EncodeSettings, encode_image, loads
    from ..io.image import Image

    from ..codec import default_steps

    h, w = pixels.shape[:2]
    default = settings.default_encode
    enc = EncodeSettings(max_triangles=settings.max_triangles, target_bytes=settings.target_bytes,
                         steps=None if default else settings.steps, batch_size=None if default else settings.batch_size,
                         seed=settings.seed, device=settings.device, pixel_filter=settings.pixel_filter,
                         residual_bytes="auto" if settings.residual_share is None else
                         round(settings.residual_share * (settings.target_bytes or 0)))
    image = Image(pixels, list(channels), hdr=is_hdr(pixels))
    steps = default_steps("image") if default else settings.steps
    every = max(1, steps // 10)

    def callback(step, loss, batch_psnr):
        if (step + 1) % every == 0 or step + 1 == steps:
            progress(f"dfc: step {step + 1}/{steps}, batch PSNR {batch_psnr:.2f} dB")

    pruned = refined = None
    if curves.source == "auto" and (settings.prune_curves or settings.refine_curves):
        from ..geometry.sources.auto import ready_curves
        from ..rate import field_bytes

        curves, pruned, refined = ready_curves(pixels, curves, prune=settings.prune_curves,
                                               refine=settings.refine_curves, n_triangles=settings.max_triangles,
                                               target_bytes=field_bytes(pixels, settings.target_bytes,
                                                                        enc.residual_bytes),
                                               pixel_filter=settings.pixel_filter,
                                               detected=True)
        if refined is not None:  # the filter found with the curves, detected again along the refined ones
            enc = replace(enc, pixel_filter=refined.pixel_filter)
        for what, done in (("pruned", pruned), ("refined", refined)):
            if done is not None:
                why = getattr(done, "warning", None)
                progress(f"dfc: curves {what}: {done.summary()}" + (f" ({why})" if why else ""))
    blob, report = encode_image(image, curves, enc, fit_curves=True, callback=callback,
                                prune_to_fit=settings.prune_curves and curves.source != "auto",
                                raster_mode=settings.raster_mode)
    if report.pruned_curves:
        progress(f"dfc: curves pruned to fit the budget: {report.pruned_curves['dropped']} of "
                 f"{report.pruned_curves['curves']} left out")
    model = loads(blob, device=settings.device)
    details = {"config": {"triangles": report.n_triangles, "vertices": report.n_vertices, "features": report.n_features,
                          "dim": enc.dim, "feature_bits": report.feature_bits, "mesh_bits": enc.mesh_bits,
                          "steps": steps},
               "chunk_bytes": report.chunk_bytes, "psnr_at_pixels": report.psnr, "encode_s": report.seconds,
               **({"pruned_curves": pruned.to_dict()} if pruned is not None else {}),
               **({"pruned_curves": report.pruned_curves} if report.pruned_curves else {}),
               **({"refined_curves": refined.to_dict()} if refined is not None else {}),
               **({"raster_mode": {"field_psnr": report.field_psnr}} if report.raster_mode else {})}
    if report.raster_mode:
        progress("dfc: raster mode (a constant field and a residual raster holding the image): "
                 + ("the field did not fit" if report.field_psnr is None else
                    f"{report.psnr:.2f} dB against the field's {report.field_psnr:.2f}"))
    return _Remap(model, curves.domain, (0.0, 0.0, float(w), float(h)), (w, h)), len(blob), {"blob": blob, **details}


def _fit_neural(name, pixels, domain, channels, n_bytes, settings: BenchSettings, loss, scale, match_s,
                progress) -> tuple[nn.Module, dict]:
    import zstandard

    from .tuning import tune_baseline

    tuned = tune_baseline(name, pixels, domain, channels, n_bytes, steps=settings.steps,
                          sweep_steps=settings.candidate_steps, batch_size=settings.batch_size,
                          pixel_grid=settings.pixel_grid, scale=scale, loss=loss,
                          match_seconds=match_s if settings.match_time else None, sweep=settings.sweep,
                          seed=settings.seed, device=settings.device, progress=progress)
    details = {"config": tuned.config, "sweep": tuned.sweep, "train": {"loss": loss, **tuned.train}}
    # what zstd would save on the fp16 parameters
    raw = b"".join(p.detach().cpu().numpy().astype("<f2").tobytes() for p in tuned.model.parameters())
    details["zstd_bytes"] = len(zstandard.ZstdCompressor(level=19).compress(raw))
    return tuned.model, details


def _fit_pixels(name, pixels, domain, channels, n_bytes, settings: BenchSettings, scale):
    """The raster or a codec's decoded stream as a ``PixelImage`` (bicubic), and its record details."""
    from .baselines import Raster
    from .baselines.upsample import PixelImage
    from .codecs import encode_to_budget

    if name == "raster":
        model = Raster.for_budget(n_bytes, domain, channels, image=pixels, device=settings.device)
        return model, {"config": model.describe()}
    coded = encode_to_budget(name, pixels, n_bytes, scale)
    model = PixelImage(coded.decoded, domain, channels, n_bytes=coded.n_bytes, device=settings.device)
    return model, {"config": {"codec": name, **coded.config}, "candidates": coded.candidates,
                   "next_bytes": coded.next_bytes, "saturated": coded.saturated}


def _fit_all(pixels, curves, channels, methods, settings: BenchSettings, scale: QualityScale, progress):
    """Every method fitted: (models {method: module}, record {method: bytes, fit_s, points_per_s, details},
    failures {method: message}, dfc's file or None, the others' budget). dfc runs first: its file's size is the
    others' budget. The neural baselines get the loss dfc's encoder uses for these pixels."""
    loss = auto_loss(pixels)
    models: dict[str, nn.Module] = {}
    record: dict[str, dict] = {}
    failed: dict[str, str] = {}
    blob, dfc_s = None, None
    n_bytes = settings.target_bytes
    for method in methods:
        progress(f"{method}: fitting" + (f" to {n_bytes} bytes" if method != "dfc" else ""))
        clock = time.perf_counter()
        try:
            if method == "dfc":
                model, size, details = _fit_dfc(pixels, curves, channels, settings, progress)
                blob = details.pop("blob")
                n_bytes, dfc_s = size, time.perf_counter() - clock
            elif method in PIXEL_METHODS:
                model, details = _fit_pixels(method, pixels, curves.domain, channels, n_bytes, settings, scale)
            else:
                model, details = _fit_neural(method, pixels, curves.domain, channels, n_bytes, settings, loss,
                                             scale, dfc_s, progress)
        except (InputError, ValueError) as e:
            if not settings.keep_going:
                raise InputError(f"{method}: {e}") from e
            failed[method] = str(e)
            progress(f"{method}: {e}")
            continue
        model.eval()
        models[method] = model
        record[method] = {"label": LABELS[method], "bytes": int(model.stored_bytes() if method != "dfc" else size),
                          "fit_s": time.perf_counter() - clock,
                          "points_per_s": throughput(model, curves.domain, settings.device, settings.seed), **details}
    return models, record, failed, blob, n_bytes


# ----------------------------------------------------------------------------------------------- measuring
def _views(method: str, model: nn.Module) -> dict[str, nn.Module]:
    """How a method is rendered: {variant: module}; stored rasters through each kernel, the rest as they are."""
    if method in PIXEL_METHODS:
        from .baselines.upsample import KERNELS

        return {k: model.with_kernel(k) for k in KERNELS}
    return {"": model}


def _measure_windows(models, windows, pixels, domain, reference, settings: BenchSettings, scale: QualityScale,
                     progress, cache: dict | None = None):
    """Renders and PSNR of every window (``windows[probe][zoom]``). Returns (tiles {key: [probe][zoom] render or
    None} with ``"reference"``, psnr {method: {zoom key: [dB or None per probe]}}, kernels {method: {zoom key:
    [kernel per probe]}} and by_kernel {method: {kernel: {zoom key: [...]}}} for stored rasters, reference_psnr
    {zoom key: [the reference's own estimated PSNR or None per probe]}). ``cache`` keeps the reference renders by
    window across calls (an RD sweep measures the same windows at every budget)."""
    cache = {} if cache is None else cache
    tiles: dict[str, list[list]] = {k: [] for k in ["reference", *models]}
    psnr_: dict[str, dict[str, list]] = {m: {_zkey(z): [] for z in settings.zooms} for m in models}
    kernels: dict[str, dict[str, list]] = {m: {_zkey(z): [] for z in settings.zooms} for m in models
                                           if m in PIXEL_METHODS}
    by_kernel: dict[str, dict] = {m: {} for m in kernels}
    reference_psnr: dict[str, list] = {_zkey(z): [] for z in settings.zooms}
    done: dict[tuple, tuple] = {}
    H, W = pixels.shape[:2]
    for k, row in enumerate(windows):
        for key in tiles:
            tiles[key].append([])
        for z, window in zip(settings.zooms, row):
            progress(f"probe {k + 1}/{len(windows)}, zoom {_zkey(z)}: rendering")
            whole = bool(np.allclose(window, domain))
            if window not in done:
                if reference is None and whole:  # a user image is a reference at zoom 1 only, pixel for pixel
                    width, height = W, H
                else:
                    width, height = window_shape(window, settings.render)
                ref, ref_db = (pixels if whole else None), None
                if reference is not None:
                    if window not in cache:
                        cache[window] = reference.window(window, width, height, settings.spp)
                    ref, halves = cache[window]
                    ref_db = None if halves is None else scale.psnr(*halves) + HALVES_DB
                renders = {}
                for m, model in models.items():
                    renders[m] = {v: pixel_render(view, window, width, height, settings.spp, settings.device)
                                  for v, view in _views(m, model).items()}
                done[window] = (ref, ref_db, renders)
            ref, ref_db, renders = done[window]
            tiles["reference"][-1].append(ref)
            reference_psnr[_zkey(z)].append(ref_db)
            for m, variants in renders.items():
                scores = {v: None if ref is None else scale.psnr(ref, r) for v, r in variants.items()}
                best = max(scores, key=lambda v: -math.inf if scores[v] is None else scores[v])
                tiles[m][-1].append(variants[best])
                psnr_[m][_zkey(z)].append(scores[best])
                if m in kernels:
                    kernels[m][_zkey(z)].append(best if ref is not None else None)
                    for v, s in scores.items():
                        by_kernel[m].setdefault(v, {_zkey(q): [] for q in settings.zooms})[_zkey(z)].append(s)
    return tiles, psnr_, kernels, by_kernel, reference_psnr


def _super_resolution(models, pixels, channels, domain, reference, settings: BenchSettings, scale: QualityScale,
                      cache: dict) -> dict:
    """The super-resolution measure (module notes): {"factor", "width", "height" (of the render), "reference_psnr"
    (a Monte Carlo reference's own estimate, else None), "input": {kernel: dB} (the input raster upsampled),
    "methods": {method: dB} (stored rasters through the better kernel)}. ``cache`` keeps the reference's render."""
    from .baselines.upsample import PixelImage

    H, W = pixels.shape[:2]
    k = settings.super_resolution
    width, height = k * W, k * H
    key = ("super-resolution", width, height)
    if key not in cache:
        cache[key] = reference.window(domain, width, height, settings.spp)
    ref, halves = cache[key]

    def score(method: str, model) -> dict[str, float]:
        return {v: scale.psnr(ref, pixel_render(view, domain, width, height, settings.spp, settings.device))
                for v, view in _views(method, model).items()}

    image = PixelImage(pixels, domain, channels, n_bytes=0, device=settings.device)
    return {"factor": k, "width": width, "height": height,
            "reference_psnr": None if halves is None else scale.psnr(*halves) + HALVES_DB,
            "input": score("raster", image), "methods": {m: max(score(m, model).values()) for m, model in models.items()}}


class _Exact:
    """An analytic value ``(N, 2) float64 -> (N, C)`` as a model for ``pixel_render`` (tensors in, tensors out)."""

    def __init__(self, value):
        self.value = value

    def __call__(self, xy):
        return torch.from_numpy(np.asarray(self.value(xy.cpu().numpy()), dtype=np.float64))


def square_pixels(window, longer: int) -> tuple[float, float, float, float]:
    """``window`` (x0, y0, x1, y1) narrowed about its centre along its shorter side, by less than one of its pixels,
    so that its render at ``longer`` pixels on the longer side (``window_shape``) has square pixels, as a renderer's
    camera has them (``MitsubaReference.square_pixels``)."""
    x0, y0, x1, y1 = window
    a, b = x1 - x0, y1 - y0
    n = max(1, math.floor(longer * min(a, b) / max(a, b) + 1e-9))  # floor: the narrowed window stays inside
    half = 0.5 * n * max(a, b) / longer
    if a >= b:
        c = 0.5 * (y0 + y1)
        return (x0, c - half, x1, c + half)
    c = 0.5 * (x0 + x1)
    return (c - half, y0, c + half, y1)


HALVES_DB = 10.0 * math.log10(4.0)
"""A Monte Carlo render of 2n samples per pixel against the noise-free truth scores this much above its two halves
of n samples against each other (their difference has four times the variance of their mean's error)."""


class AnalyticReference:
    """An analytic scene's exact value ``value`` (``(N, 2)`` float64 domain points -> ``(N, C)``) as the reference
    of every window: its mean over the very points each method's pixel is rendered at (``pixel_render``).

    The protocol of a ``run_bench`` reference: ``label`` (str) and ``window(window, width, height, spp)`` ->
    (``(height, width, C)`` float32 reference render, None or the two independent halves of a Monte Carlo render
    whose mean it is)."""

    label = "analytic"

    def __init__(self, value: Callable[[np.ndarray], np.ndarray]):
        self.value = value

    def window(self, window, width: int, height: int, spp: int):
        return pixel_render(_Exact(self.value), window, width, height, spp), None


@dataclass
class BenchResult:
    """``results``: the JSON-able record (see ``run_bench``); ``tiles[method][probe][zoom]``: (h, w, C)
    float32 renders, with the key ``"reference"`` for the exact (scene) or input (zoom 1) raster;
    ``blob``: the dfc file's bytes (or None)."""

    results: dict
    tiles: dict[str, list[list[np.ndarray | None]]]
    blob: bytes | None = None


def run_bench(pixels: np.ndarray, curves, channels: list[str], *, probes, settings: BenchSettings,
              probe_kinds: list[str] | None = None, reference=None, truth: np.ndarray | None = None,
              truth_label: str | None = None, truth_psnr: float | None = None, name: str = "",
              progress: Callable[[str], None] | None = None, cache: dict | None = None,
              other_truths: dict[str, np.ndarray] | None = None) -> BenchResult:
    """Fit every method to ``pixels`` at equal bytes and measure it at 1× and at every probe and zoom.

    Parameters
    ----------
    pixels : (H, W, C) float32 raster covering ``curves.domain`` (what every method is fitted to)
    curves : dfc.geometry.curves.Curves, the discontinuities (used by dfc, and to find the mixed pixels)
    channels : C channel names
    probes : (P, 2) float points in domain units, the zoom centres; probe_kinds : P labels (default "given")
    settings : BenchSettings
    reference : the truth of every window: ``AnalyticReference`` (an analytic scene's exact value),
        ``dfc.bench.rendered.MitsubaReference`` (Mitsuba renders of the window), or None for a user image alone
    truth : (H, W, C) the best box-filtered 1× truth (default: ``pixels``); truth_label : how it was made;
        truth_psnr : its own estimated PSNR against the noise-free truth when it is a Monte Carlo render
    name : label of the input, stored in the results
    cache : reference window renders by window, shared by the runs of an RD sweep
    other_truths : {label: (H, W, C) raster}: further 1× truths each method is also measured against (a noisy
        input's clean truth), recorded as ``image_psnr_vs[label]``

    Returns
    -------
    BenchResult. ``results["methods"][m]``: ``label``, ``bytes`` (int), ``config`` (the configuration used),
    ``image_psnr`` ({"all", "unmixed"}: dB at 1×), ``psnr`` ({str(zoom): [dB or None per probe]}),
    ``points_per_s``, ``fit_s`` and method details (tuned baselines: ``sweep``, ``train``; codecs: ``candidates``,
    ``next_bytes``, ``kernel`` and ``psnr_by_kernel`` per window). ``results["failed"]``: {method: why} with
    ``keep_going``. ``results["quality_scale"]``: how every PSNR is measured (``QualityScale.describe``, with
    ``data_range`` and ``tonemap``); ``results["zoom_truth"]``: whether windows above 1× are measured;
    ``results["reference_psnr"]`` (Monte Carlo references only): {str(zoom): [the reference's estimated PSNR]};
    ``results["super_resolution"]`` (with a reference and ``settings.super_resolution``): ``_super_resolution``'s
    record.
    """
    settings.check()
    progress = progress or (lambda message: None)
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    if pixels.ndim != 3 or pixels.shape[2] != len(channels):
        raise InputError(f"expected a raster (H, W, {len(channels)}) for channels {list(channels)}, got {pixels.shape}")
    probes = np.asarray(probes, dtype=np.float64).reshape(-1, 2)
    kinds = list(probe_kinds) if probe_kinds is not None else ["given"] * len(probes)
    domain = curves.domain
    x0, y0, x1, y1 = domain
    if len(probes) == 0 or not np.all((probes >= [x0, y0]) & (probes <= [x1, y1])):
        raise InputError(f"probes must be points inside the domain {domain}, got {probes.tolist()}")
    if len(kinds) != len(probes):
        raise InputError(f"expected one kind per probe, got {len(kinds)} for {len(probes)}")
    hdr = is_hdr(pixels)
    methods = methods_for(settings, hdr)
    scale = quality_scale(pixels)
    H, W = pixels.shape[:2]
    truth = pixels if truth is None else np.asarray(truth, dtype=np.float32)
    mixed = mixed_pixels(curves, H, W)
    models, record, failed, blob, budget = _fit_all(pixels, curves, channels, methods, settings, scale, progress)
    for m, model in models.items():
        progress(f"{m}: 1x image")
        renders = [image_render(view, domain, W, H, settings.pixel_grid, settings.device)
                   for view in _views(m, model).values()]
        scores = [image_scores(truth, r, mixed, scale) for r in renders]
        best = int(np.argmax([s["all"] for s in scores]))
        record[m]["image_psnr"] = scores[best]
        if other_truths:
            record[m]["image_psnr_vs"] = {label: image_scores(np.asarray(t, dtype=np.float32), renders[best], mixed,
                                                              scale) for label, t in other_truths.items()}
    windows = [[zoom_window(domain, p, z) for z in settings.zooms] for p in probes]
    if getattr(reference, "square_pixels", False):
        windows = [[square_pixels(w, settings.render) for w in row] for row in windows]
    tiles, scores, kernels, by_kernel, reference_psnr = _measure_windows(models, windows, pixels, domain, reference,
                                                                         settings, scale, progress, cache)
    for m in models:
        record[m]["psnr"] = scores[m]
        if m in kernels:
            record[m]["kernel"], record[m]["psnr_by_kernel"] = kernels[m], by_kernel[m]
    upscaled = None
    if reference is not None and settings.super_resolution:
        progress(f"{settings.super_resolution}x super-resolution: rendering")
        upscaled = _super_resolution(models, pixels, channels, domain, reference, settings, scale,
                                     {} if cache is None else cache)
    results = {
        "input": name,
        "reference": reference.label if reference is not None else "input image (zoom 1 only; larger zooms "
                                                                    "unmeasured)",
        "zoom_truth": reference is not None,
        "quality_scale": scale.describe(),
        "data_range": scale.data_range,
        "tonemap": scale.tonemap,
        "hdr": hdr,
        "budget_bytes": int(budget),
        "image": {"width": W, "height": H, "pixel_grid": settings.pixel_grid, "mixed_pixels": int(mixed.sum()),
                  "truth": truth_label or ("the input image" if reference is None else reference.label),
                  "truth_psnr": truth_psnr},
        "zooms": [float(z) for z in settings.zooms],
        "probes": probes.tolist(),
        "probe_kinds": kinds,
        "windows": [[list(w) for w in row] for row in windows],
        "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(settings).items()},
        "methods": record,
        "failed": failed,
    }
    if any(v is not None for values in reference_psnr.values() for v in values):
        results["reference_psnr"] = reference_psnr
    if upscaled is not None:
        results["super_resolution"] = upscaled
    return BenchResult(results, tiles, blob)


def scene_inputs(scene, settings: BenchSettings, *, probes=None, progress=None) -> dict:
    """The keyword arguments ``run_bench`` gets for an analytic scene (``dfc.bench.scenes.AnalyticScene``): its
    box-filtered raster (longer side ``settings.size``, default the domain's longer side in its units; 4 × 4
    points per pixel), curves, channels, probes (default ``dfc.bench.probes.labelled_probes``), exact value and
    1× truth (``TRUTH_SPP`` × ``TRUTH_SPP`` other points per pixel)."""
    from .probes import labelled_probes

    progress = progress or (lambda message: None)
    x0, y0, x1, y1 = scene.domain
    longer = settings.size or max(8, round(max(x1 - x0, y1 - y0)))
    scale = longer / max(x1 - x0, y1 - y0)
    w, h = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
    progress(f"scene {scene.name}: rendering the {w}x{h} raster to fit and its {TRUTH_SPP}x{TRUTH_SPP}-point truth")
    if probes is None or len(probes) == 0:
        points, kinds = labelled_probes(scene.curves)
    else:
        points, kinds = np.asarray(probes, dtype=np.float64), None
    return {"pixels": scene.render(w, h), "curves": scene.curves, "channels": scene.channels, "probes": points,
            "probe_kinds": kinds, "reference": AnalyticReference(scene.value),
            "truth": scene.render(w, h, spp=TRUTH_SPP),
            "truth_label": f"analytic, box filter of {TRUTH_SPP}x{TRUTH_SPP} stratified points per pixel",
            "name": f"scene {scene.name}"}


def run_scene(scene, settings: BenchSettings, *, probes=None,
              progress: Callable[[str], None] | None = None) -> BenchResult:
    """``run_bench`` on an analytic scene (``scene_inputs``), measured against its exact value."""
    settings.check()
    return run_bench(**scene_inputs(scene, settings, probes=probes, progress=progress), settings=settings,
                     progress=progress)


def _zkey(z: float) -> str:
    return str(int(z)) if float(z).is_integer() else str(z)


# ----------------------------------------------------------------------------------------------- outputs
def config_label(method: str, record: dict) -> str:
    """A short human form of a method's configuration for tables."""
    c = record.get("config", {})
    if method == "dfc":
        return f"{c['triangles']} triangles, {c['dim']}-d features"
    if method == "hashgrid":
        return (f"L{c['levels']} F{c['features']} T{c['table_size']} ({c['dense_levels']} dense), "
                f"MLP {c['hidden']}×{c['layers']}")
    if method == "relu":
        return f"{c['grid'][0]}×{c['grid'][1]} nodes × {c['features']} ch"
    if method == "raster":
        return f"{c['raster'][0]}×{c['raster'][1]} px"
    if "lossless" in c and c["lossless"]:
        return "lossless"
    quality = {k: v for k, v in c.items() if k in ("distance", "quality", "psnr_target_db")}
    (key, value), = quality.items()
    knob = {"distance": "d", "quality": "q", "psnr_target_db": "target"}[key]
    kind = "float" if c["input"] == "float" else f"{c['bits']}-bit {c['transfer']}"
    return f"{kind}, {knob} {value:.3g}"


def _mean(values) -> str:
    vals = [v for v in values if v is not None]
    return f"{np.mean(vals):.2f}" if vals else "–"


def markdown_table(results: dict) -> str:
    """``results.md``: one row per method — configuration, bytes, 1× PSNR on all pixels and without the mixed ones,
    mean PSNR over the probes per zoom, decode throughput; then the PSNR per probe kind at each zoom above 1."""
    zooms = [_zkey(z) for z in results["zooms"]]
    rows = []
    for m, r in results["methods"].items():
        img = r["image_psnr"]
        rows.append([r["label"], config_label(m, r), str(r["bytes"]), _mean([img["all"]]), _mean([img["unmixed"]]),
                     *(_mean(r["psnr"][z]) for z in zooms), f"{r['points_per_s']:.3g}"])
    own = results.get("reference_psnr")
    if own:  # a Monte Carlo reference: its own estimated PSNR, the ceiling of what can be measured against it
        truth_db = results["image"].get("truth_psnr")
        rows.append(["reference itself (estimated)", "two independent halves of its samples", "–",
                     _mean([truth_db]), "–", *(_mean(own[z]) for z in zooms), "–"])
    kinds = [k for k in PROBE_KINDS + ("given",) if k in results["probe_kinds"]]
    counts = ", ".join(f"{results['probe_kinds'].count(k)} {k}" for k in kinds)
    notes = (f"Reference: {results['reference']}; 1× truth: {results['image']['truth']}. PSNR in dB "
             f"({results['quality_scale']}); "
             f"1× on all {results['image']['width']}×{results['image']['height']} "
             f"pixels and without the {results['image']['mixed_pixels']} a curve crosses; zooms: mean over the "
             f"probes ({counts}); budget {results['budget_bytes']} bytes.")
    text = table(f"dfc bench: {results['input']}", notes,
                 ["method", "configuration", "bytes", "1× all px", "1× unmixed", *(f"{z}× probes" for z in zooms),
                  "points/s"], rows)
    big = [z for z in zooms if float(z) > 1]
    if big and results["zoom_truth"]:
        header = ["method", *(f"{k} {z}×" for z in big for k in kinds)]
        kind_rows = []
        named = [(r["label"], r["psnr"]) for r in results["methods"].values()]
        for label, psnr_ in named + ([("reference itself (estimated)", own)] if own else []):
            cells = [_mean([v for v, kk in zip(psnr_[z], results["probe_kinds"]) if kk == k])
                     for z in big for k in kinds]
            kind_rows.append([label, *cells])
        text += "\n" + table("By probe kind", "Mean PSNR (dB) over the probes of each kind.", header, kind_rows)
    sr = results.get("super_resolution")
    if sr:
        rows = [[results["methods"][m]["label"], f"{v:.2f}"] for m, v in sr["methods"].items()]
        rows += [[f"the input, {kernel}", f"{v:.2f}"] for kernel, v in sr["input"].items()]
        if sr["reference_psnr"] is not None:
            rows.append(["reference itself (estimated)", f"{sr['reference_psnr']:.2f}"])
        text += "\n" + table(f"{sr['factor']}× super-resolution", f"The whole domain at {sr['width']}×{sr['height']} "
                             "pixels against the reference there (stored rasters through the better kernel); the "
                             "input upsampled as it is, for comparison.", ["method", "PSNR (dB)"], rows)
    if results.get("failed"):
        text += "\n" + "\n".join(f"- {LABELS[m]}: not run ({why})" for m, why in results["failed"].items()) + "\n"
    return text


def contact_sheet(result: BenchResult) -> bytes:
    """PNG bytes: for each probe, a block of rows (reference, then each method) by columns (zooms)."""
    res = result.results
    rows = []
    for p in range(len(res["probes"])):
        for key in ["reference", *res["methods"]]:
            tiles = [None if t is None else display(t, res["hdr"]) for t in result.tiles[key][p]]
            captions = [None] * len(tiles)
            if key != "reference":
                captions = [None if v is None else f"{v:.1f} dB"
                            for v in (res["methods"][key]["psnr"][_zkey(z)][p] for z in res["zooms"])]
            label = "reference" if key == "reference" else res["methods"][key]["label"]
            rows.append((f"{res['probe_kinds'][p]} {p + 1}\n{label}", tiles, captions))
    return contact_sheet_grid([f"{_zkey(z)}x" for z in res["zooms"]], rows)


def write_outputs(result: BenchResult, directory: str | Path) -> list[Path]:
    """Write ``results.json``, ``results.md``, ``contact.png`` (and ``dfc.dfield`` when dfc ran) into
    ``directory`` (``dfc.bench.report.write_report``). Returns the paths written."""
    return write_report(directory, result.results, markdown_table(result.results), contact_sheet(result),
                        result.blob)
