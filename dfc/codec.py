"""The codec pipeline: signal + curves → mesh → fit → ``.dfield`` bytes, and ``.dfield`` → model (``load``).

Every encoder runs the same steps: check the input, build the mesh exactly as the decoder will see it
(``dfc.rate``), fit it (``dfc.train.fit``) with the last steps quantisation-aware, write the file and measure the
written bytes decoded again (``_finish``), so the file decodes to what it reports. PSNRs are measured on
``dfc.metrics.quality_scale`` (tone-mapped for HDR colours), the same scale the fit's progress sees.

Units (``dfc.field.units``): every input but HDR light is fitted on its values normalised to [0, 1] by an offset and
a scale chosen from the data (``_units``), which the file stores; the fit's PSNRs are of the normalised values with
the data range divided by the scale, the same dB. So a signal fits the same in any unit.
"""

from __future__ import annotations

import functools
import inspect
import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from .errors import InputError, ResidualBytesError, TargetBytesError
from .field.quantize import DEFAULT_FEATURE_BITS
from .field.units import ValueMap, choose, describe
from .geometry.curves import Curves, fit_curves_to_domain, split_pieces
from .io.dfield import encode_model, encoder_info, load, loads, storage
from .metrics import QualityScale, is_hdr, quality_scale
from .metrics import data_range as signal_range
from .rate import (COARSE_FEATURE_BITS, COARSE_LOSS_DB, DECODER_HIDDEN, DECODER_SHARE, FEATURE_BITS_FALLBACK, FILL,
                   FILL_RETRIES, RASTER_MARGIN_DB, RASTER_STEPS, RASTER_TRIANGLES, SHORT_FIT_HIDDEN, build_mesh,
                   decoder_hidden, features_at, field_bytes, forced_mesh, image_mesh_size, is_clean, mesh_bytes,
                   mesh_size_set, residual_choices, sample_mesh_size, size_at, sized_mesh, smallest_bytes)
from .render import values_at
from .settings import EncodeSettings
from .train.fit import BATCH_SIZE, DECODER_LR_MIN_STEPS, DEFAULT_STEPS, IMAGE_STEPS

__all__ = ["FEM_TARGET_PSNR", "EncodeReport", "EncodeSettings", "check_domain", "default_steps", "encode_bands",
           "encode_fem", "encode_frames", "encode_image", "encode_samples", "encoder_info", "fem_settings",
           "heldout_split", "image_decoder", "load", "loads", "sample_piece_length", "sample_steps"]

QUERY_BLOCK = 1 << 18
"""Points evaluated per call when measuring a decoded file at scattered positions."""
SAMPLE_PIECES = 1.55
"""Sample sets: curved pieces are cut to at most the domain's longer side / (``SAMPLE_PIECES`` · n^¼) for n
samples before meshing (``sample_piece_length``, ``dfc.geometry.curves.split_pieces``). A curved piece's sliver
carries one curve feature, so long pieces leave a wide band along the curve with little freedom; short ones force
triangles whose features see few samples each. On the pepper at 11 spp, with the samples' triangles on top of the
curves' (``dfc.rate.sample_mesh_size``), 1/32 of the side beat 1/64 at 128² (180k samples: 10.1× against 5.4× less
error variance than the raw mean, in 31 % fewer bytes) and 1/64 beat 1/32 at 500² (2.75M samples: 39× against 33×);
n^¼ passes through both."""

SAMPLE_PASSES = 12
"""``dfc encode`` of a sample set without ``--steps`` runs enough steps for this many passes over its samples, at
least ``DEFAULT_STEPS`` (``sample_steps``): 2.75M walk-on-spheres samples of the pepper at 500² and 11 spp, fitted
for 1000 steps (6 passes), denoised 26× or 40× depending on the seed alone; 1,813 steps (12 passes) gave 39× and
41×."""

HOLDOUT_FRACTION = 0.1
"""Sample sets: this share of the samples (at most ``HOLDOUT_MAX``, none below ``HOLDOUT_MIN_SAMPLES``) is left out
of the fit and the file's PSNR is measured against them: against the samples it was fitted to, a fit that follows
their noise would look better the worse it denoises."""
TARGET_PSNR_ROUNDS = 4
"""Refinement rounds an image or FEM encode runs at most to reach ``EncodeSettings.target_psnr``."""
FEM_TARGET_PSNR = 50.0
"""A FEM encode without a mesh-size option, target or ``refine`` aims at this PSNR at the nodes (dB, against the
values' span; up to ``TARGET_PSNR_ROUNDS`` refinement rounds) instead of a fixed triangle count: simulation data asks
for more triangles the more wavelengths or layers it holds (README "Rate and quality levers")."""
HOLDOUT_MAX = 1 << 18
HOLDOUT_MIN_SAMPLES = 100

Callback = Callable[..., None]
"""``callback(step, loss, batch_psnr)`` after each optimiser step (0-dim tensors)."""


@dataclass
class EncodeReport:
    """What an encode measured. ``psnr`` is of the written file decoded, against the input (for a sample set: the
    ``heldout`` samples left out of the fit; for an image read out of core: its ``heldout`` held-out pixels), with
    ``data_range``, on tone-mapped values when ``tonemapped`` (``dfc.metrics.quality_scale``). ``units``: one line
    with the data's range and the units it was fitted in (``dfc.field.units.describe``). ``psnr_reference``:
    against the exact values given as ``reference``, on the same scale (sample sets), else None. ``target_psnr``: the
    PSNR the encode aimed at (``EncodeSettings.target_psnr``, or ``FEM_TARGET_PSNR`` by default for a FEM solution),
    else None. ``feature_bits``: the bits the features were stored with; ``fallback_from``: the bits whose smallest
    mesh a byte target could not hold when the encoder fell back to fewer (``dfc.rate.FEATURE_BITS_FALLBACK``), else
    None. ``pixel_filter``: the filter an image read whole was fitted and stored with, and ``pixel_evidence`` why
    ``auto`` chose it (``Detection.evidence``). ``pruned_curves``: when a byte target too small for every curve
    given made the encoder prune them (``encode_image(..., prune_to_fit=True)``), ``Pruned.to_dict`` of that, else
    None. ``default_target``: the byte target the encoder gave a clean image encoded without one, shared with a
    residual raster (``_default_target``), else None. ``flat_rows``: the feature rows set to the exact value of a
    flat region of an image (``dfc.train.flat``; 0: none; in the raster mode every row). ``raster_mode``: the file
    is the raster mode's, a constant field and a residual raster holding the image (``_raster_mode``);
    ``field_psnr`` is then the PSNR of the file with a fitted field it replaced (None when no such file fitted the
    target)."""

    chunk_bytes: dict[str, int]
    total_bytes: int
    bits_per_pixel: float
    psnr: float
    data_range: float
    n_vertices: int
    n_triangles: int
    n_features: int
    seconds: dict[str, float] = field(default_factory=dict)
    tonemapped: bool = False
    heldout: int = 0
    psnr_reference: float | None = None
    target_psnr: float | None = None
    feature_bits: int = DEFAULT_FEATURE_BITS
    fallback_from: int | None = None
    pixel_filter: str | None = None
    pixel_evidence: str | None = None
    units: str = ""
    pruned_curves: dict | None = None
    default_target: int | None = None
    flat_rows: int = 0
    raster_mode: bool = False
    field_psnr: float | None = None


def check_domain(curves: Curves, width: int, height: int, fit: bool) -> Curves:
    """The image covers [0, W] × [0, H]; curves must share that domain (or be scaled onto it with ``fit``)."""
    image_domain = (0.0, 0.0, float(width), float(height))
    if np.allclose(curves.domain, image_domain, rtol=0, atol=1e-9 * max(width, height)):
        return curves
    if fit:
        return fit_curves_to_domain(curves, image_domain)
    raise InputError(
        f"the curves' domain {tuple(round(v, 6) for v in curves.domain)} does not match the image's "
        f"[0, {width}] × [0, {height}]; pass --fit-curves-to-image to scale the curves onto the image"
    )


def refine_rounds(settings) -> int:
    """Rounds of refinement of an image encode read whole or a FEM encode: ``settings.refine``, else (None) one under
    a byte target (it fills the target: ``dfc.rate.fill_points``), at most ``TARGET_PSNR_ROUNDS`` under a PSNR
    target, and none without either."""
    if settings.refine is not None:
        return settings.refine
    return 1 if settings.target_bytes else TARGET_PSNR_ROUNDS if settings.target_psnr is not None else 0


def refit_steps(settings) -> int:
    """Optimiser steps of each refit of a refinement round: ``settings.refine_steps``, else (None) the fit's own
    steps under a byte target (its refit is the file), half of them otherwise. ``settings.steps`` is resolved."""
    if settings.refine_steps is not None:
        return settings.refine_steps
    return settings.steps if settings.target_bytes else max(1, settings.steps // 2)


def fem_settings(settings: EncodeSettings) -> EncodeSettings:
    """``settings`` of a FEM encode: aiming at ``FEM_TARGET_PSNR`` when they set no mesh size, target or ``refine``."""
    if settings.refine is None and settings.target_psnr is None and not mesh_size_set(settings):
        return replace(settings, target_psnr=FEM_TARGET_PSNR)
    return settings


def image_decoder(settings: EncodeSettings, n_values: int, n_channels: int) -> EncodeSettings:
    """``settings`` with the decoder width of an image of ``n_values`` numbers (``dfc.rate.decoder_hidden``; under a
    byte target, within its ``dfc.rate.DECODER_SHARE``; a fit of fewer than ``DECODER_LR_MIN_STEPS`` steps up to
    ``dfc.rate.SHORT_FIT_HIDDEN``), never wider than ``settings.hidden``."""
    budget = None if settings.target_bytes is None else DECODER_SHARE * settings.target_bytes
    short = (settings.steps or IMAGE_STEPS) < DECODER_LR_MIN_STEPS
    width = decoder_hidden(n_values, budget, inputs=settings.dim, outputs=n_channels, layers=settings.layers,
                           weight_bits=settings.weight_bits, widest=SHORT_FIT_HIDDEN if short else None)
    return replace(settings, hidden=min(settings.hidden, width))


def _units(values, scale: QualityScale, dtype=np.float32) -> tuple[ValueMap | None, QualityScale, str]:
    """The units a signal ``values`` (…, C) measured on ``scale`` is fitted in: (``dfc.field.units.choose``'s map,
    or None for HDR light (``scale.tonemap``), which is fitted on its values; the scale of the fit's PSNRs in those
    units: the data range divided by the map's scale, the same dB; the summary line ``describe``, ``dtype`` being
    the input's)."""
    v = np.asarray(values)
    v = v.reshape(-1, v.shape[-1])
    lo, hi = v.min(axis=0).astype(np.float64), v.max(axis=0).astype(np.float64)
    value_map = None if scale.tonemap else choose(lo, hi)
    fit_scale = scale if value_map is None else QualityScale(scale.data_range / value_map.unit)
    return value_map, fit_scale, describe(float(lo.min()), float(hi.max()), value_map, dtype)


# ----------------------------------------------------------------------------------------------- encoders
def _feature_bits(encode):
    """``encode(signal, curves, settings, **kw)`` with the default ``settings.feature_bits`` (None) resolved:
    ``DEFAULT_FEATURE_BITS``; when a byte target is too small for the smallest mesh with them, each of
    ``dfc.rate.FEATURE_BITS_FALLBACK`` in turn (a target is refused before any fitting, so a retry costs only the
    mesh sizing; the report's ``fallback_from`` then says so). An encoder taking ``chosen_bits`` is told so (its byte
    target's fill may then store fewer bits, ``_refine``); bits given in ``settings`` are kept as given."""
    chooses = "chosen_bits" in inspect.signature(encode).parameters

    @functools.wraps(encode)
    def resolved(signal, curves: Curves, settings: EncodeSettings | None = None, **kw):
        settings = settings or EncodeSettings()
        if settings.feature_bits is not None:
            return encode(signal, curves, settings, **kw)
        kw = {**kw, "chosen_bits": True} if chooses else kw
        tried = (DEFAULT_FEATURE_BITS, *(FEATURE_BITS_FALLBACK if settings.target_bytes else ()))
        for bits in tried:
            try:
                blob, report = encode(signal, curves, replace(settings, feature_bits=bits), **kw)
            except TargetBytesError:
                if bits == tried[-1]:
                    raise
                continue
            if bits != DEFAULT_FEATURE_BITS and report is not None:  # None: a rank of a distributed encode but 0
                report.fallback_from = DEFAULT_FEATURE_BITS
            return blob, report

    return resolved


def _residual_auto(encode):
    """``encode_image`` with ``settings.residual_bytes`` "auto" resolved (``dfc.rate.residual_choices``) and
    handed over as ``residual``: while the field cannot fit what a choice leaves of the target
    (``TargetBytesError``) the next is tried; when none fits, or the residual cannot use its share
    (``ResidualBytesError``: its smallest stream is larger, or its best would add error), the image is encoded
    again without one. Without a byte target, a clean image gets ``_default_target`` and the field shares it with a
    residual the same way, without a fill round (``settings.refine`` 0 unless given: the residual takes what the
    field leaves instead; the report's ``default_target`` says so); when no choice fits, it is encoded without
    target or residual. Bytes given in ``settings`` are kept as given."""

    @functools.wraps(encode)
    def resolved(image, curves: Curves, settings: EncodeSettings | None = None, **kw):
        settings = settings or EncodeSettings()
        if settings.residual_bytes != "auto":
            return encode(image, curves, settings, **kw)
        from .io.image import check_pixels

        pixels = check_pixels(image)
        default, choices = _default_target(pixels, getattr(image, "channels", None), curves, settings,
                                           kw.get("fit_curves", False))
        own = settings if default is None else \
            replace(settings, target_bytes=default, refine=0 if settings.refine is None else settings.refine)
        for n in choices if default else residual_choices(pixels, settings.target_bytes):
            try:
                blob, report = encode(image, curves, own, residual=n, default_target=default is not None, **kw)
            except TargetBytesError:
                continue
            except ResidualBytesError:
                break
            report.default_target = default
            return blob, report
        return encode(image, curves, settings, residual=0, **kw)

    return resolved


def _default_target(pixels: np.ndarray, channels: list[str] | None, curves: Curves, settings: EncodeSettings,
                    fit_curves: bool) -> tuple[int | None, list[int]]:
    """(target, residual bytes to try) of an image ``pixels`` (H, W, C) encoded without a byte target, so that a
    residual raster can share one (``_residual_auto``): the bytes of the mesh the encode would build by default
    (``dfc.rate.image_mesh_size``) with incompressible features (``dfc.rate.mesh_bytes``), and those of its
    ``residual_choices`` that leave the field at least the smallest file the curves allow
    (``dfc.rate.smallest_bytes``). (None, []) for an image that is not clean (``dfc.rate.is_clean``), settings that
    choose a size themselves (a mesh-size option or a PSNR target), or when no choice leaves the field enough."""
    if settings.target_bytes is not None or settings.target_psnr is not None or mesh_size_set(settings) \
            or not is_clean(pixels):
        return None, []
    from .io.samples import default_channels

    h, w, c = pixels.shape
    channels = channels or default_channels(c)
    curves = check_domain(curves, w, h, fit_curves)
    base = replace(settings, feature_bits=settings.feature_bits or DEFAULT_FEATURE_BITS)
    sized, mesh = image_mesh_size(curves, base, w * h)
    sized = image_decoder(sized, pixels.size, c)
    target = mesh_bytes(build_mesh(curves, sized) if mesh is None else mesh, sized, channels)

    choices = residual_choices(pixels, target, clean=True)
    forced = forced_mesh(curves, base) if choices else None

    def room(n: int) -> bool:  # the field's share holds the curves' smallest file, with the decoder it would get
        return target - n >= smallest_bytes(forced, image_decoder(replace(base, target_bytes=target - n),
                                                                  pixels.size, c), channels)

    choices = [n for n in choices if room(n)]
    return (target, choices) if choices else (None, [])


def _pruned_to_fit(encode):
    """``encode_image`` that, with ``prune_to_fit=True``, meets a byte target too small for every curve given
    (``TargetBytesError`` after every residual share and feature depth was tried) by leaving out the curves that earn
    the least per byte (``dfc.geometry.sources.prune.prune_curves`` for what the target leaves the field,
    ``dfc.rate.field_bytes``) and encoding again; the report's ``pruned_curves`` says how many were left out. The
    error stands without it, and when pruning would keep every curve; when the pruned curves do not fit either, its
    message says how many were left out."""

    @functools.wraps(encode)
    def resolved(image, curves: Curves, settings: EncodeSettings | None = None, *, prune_to_fit: bool = False,
                 **kw):
        settings = settings or EncodeSettings()
        try:
            return encode(image, curves, settings, **kw)
        except TargetBytesError:
            if not prune_to_fit:
                raise
            from .geometry.sources.prune import prune_curves
            from .io.image import check_pixels

            pixels = check_pixels(image)
            pruned = prune_curves(pixels, curves, n_triangles=settings.max_triangles,
                                  target_bytes=field_bytes(pixels, settings.target_bytes, settings.residual_bytes))
            if pruned.kept.all():
                raise
        try:
            blob, report = encode(image, replace(pruned.curves, source=curves.source), settings, **kw)
        except TargetBytesError as e:
            raise TargetBytesError(f"{e} (with {int((~pruned.kept).sum())} of {len(pruned.kept)} curves left out)") \
                from None
        report.pruned_curves = pruned.to_dict()
        return blob, report

    return resolved


def _raster_mode(encode):
    """``encode_image`` that, for a clean image (``dfc.rate.is_clean``) under ``--residual-bytes auto``, also makes
    the raster mode's file at the same size (the byte target, else the size of the file the encode made) and keeps
    it when its PSNR is ``dfc.rate.RASTER_MARGIN_DB`` or more above the field's file's. Its field has
    ``dfc.rate.RASTER_TRIANGLES`` triangles, no curves and one vector in every feature row
    (``dfc.train.flat.constant_rows``), so that it decodes one value; its residual raster holds the image
    (docs/design.md §12). On content the field does not model (test charts, textures, fills with sharp edges) a
    field's residual codes worse than the image itself. When the field cannot fit a byte target
    (``TargetBytesError``), the raster mode's file is made instead when it fits. ``raster_mode=False``, a PSNR
    target, residual bytes or a mesh size given (without a byte target): ``encode`` alone."""

    @functools.wraps(encode)
    def resolved(image, curves: Curves, settings: EncodeSettings | None = None, *, raster_mode: bool = True, **kw):
        settings = settings or EncodeSettings()
        if not raster_mode or settings.residual_bytes != "auto" or settings.target_psnr is not None or \
                (settings.target_bytes is None and mesh_size_set(settings)):
            return encode(image, curves, settings, **kw)
        from .io.image import check_pixels

        pixels = check_pixels(image)
        if not is_clean(pixels):
            return encode(image, curves, settings, **kw)
        try:
            blob, report = encode(image, curves, settings, **kw)
        except TargetBytesError as exc:
            if settings.target_bytes is None:
                raise
            blob, report, refused = None, None, exc
        h, w = pixels.shape[:2]
        nothing = Curves((0.0, 0.0, float(w), float(h)), np.zeros((0, 4, 2)), [], [], np.zeros((0, 2)))
        own = replace(settings, target_bytes=None, max_triangles=RASTER_TRIANGLES, max_area=None, edge_length=None,
                      refine=0, steps=RASTER_STEPS, qat_steps=None, hidden=DECODER_HIDDEN[0], pixel_filter="box",
                      residual_bytes=0, feature_bits=settings.feature_bits or DEFAULT_FEATURE_BITS)
        clock = time.perf_counter()
        try:
            raster = encode(image, nothing, own, raster_bytes=settings.target_bytes or len(blob))
        except ResidualBytesError:
            raster = None
        seconds = time.perf_counter() - clock
        if raster is None or (report is not None and raster[1].psnr < report.psnr + RASTER_MARGIN_DB):
            if report is None:
                raise refused
            report.seconds["raster_s"] = seconds
            return blob, report
        blob, chosen = raster
        chosen.raster_mode, chosen.field_psnr = True, None if report is None else report.psnr
        chosen.seconds = {**(report.seconds if report else {}), "raster_s": seconds}
        return blob, chosen

    return resolved


@_raster_mode
@_pruned_to_fit
@_residual_auto
@_feature_bits
def encode_image(image, curves: Curves, settings: EncodeSettings | None = None, *,
                 fit_curves: bool = False, callback: Callback | None = None, curves_info: dict | None = None,
                 chosen_bits: bool = False, residual: int | None = None, default_target: bool = False,
                 raster_bytes: int | None = None):
    """Encode a raster with its discontinuity curves.

    Without a mesh-size setting, a small image gets at most one triangle per ``dfc.rate.PIXELS_PER_TRIANGLE`` pixels
    (``dfc.rate.image_mesh_size``), and without a byte target its decoder's width follows the number of values
    (``dfc.rate.decoder_hidden``).

    Parameters
    ----------
    image : ``dfc.io.image.Image`` or (H, W, C) float array of linear values covering [0, W] × [0, H]
    curves : Curves over the same domain (or any domain with ``fit_curves=True``, scaled onto the image)
    settings : EncodeSettings (defaults when None)
    callback : ``callback(step, loss, batch_psnr)`` after each optimiser step
    curves_info : where the curves came from, stored in the file's encoder info under ``curves`` (``dfc encode
        --curves auto``: extracted from the image, with the extractor's settings)
    chosen_bits : the feature bits are the encoder's choice (``settings.feature_bits`` was None): a byte target's
        fill may store fewer (``_refine``)
    residual : the bytes of the residual raster (``rESD``) as ``settings.residual_bytes`` "auto" resolved them
        (``_residual_auto``); None: ``settings.residual_bytes``, an integer. A byte target is shared: the field gets
        the target less these bytes.
    default_target : ``settings.target_bytes`` is the encoder's own (``_default_target``), recorded as such in the
        header's ``encoder`` record; the residual then also gets what the field leaves of its share
    prune_to_fit : a byte target too small for every curve leaves out those that earn the least
        (``_pruned_to_fit``; ``report.pruned_curves``) instead of raising ``TargetBytesError``
    raster_mode : a clean image under ``--residual-bytes auto`` may be stored in the raster mode, a constant field
        and a residual raster, when that file decodes closer to the input at the same size (``_raster_mode``;
        ``report.raster_mode``); False: never
    raster_bytes : make the raster mode's file in this many bytes: the field's rows set to one vector, the residual
        given what the field leaves (``_raster_mode`` calls it so, with settings for its field)

    The pixel filter (``settings.pixel_filter``; "auto": ``dfc.pixel_model.detect`` on the pixels near the curves)
    is fitted (``dfc.train.fit.fit_image``) and stored in the header (``pixel_filter``).

    Returns
    -------
    (blob, report): the ``.dfield`` bytes and an ``EncodeReport`` whose ``psnr`` is of ``blob`` decoded and
    rendered as ``dfc decode`` renders it at the input's size (the pixels a curve changes filtered with the stored
    filter, the others at their centres), against the input (tone-mapped for HDR input, ``report.tonemapped``).
    """
    from .geometry.pixels import edge_pixels
    from .io.image import check_pixels
    from .io.samples import default_channels
    from .pixel_model import resolve
    from .render import render, window_points
    from .train.fit import fit_image

    settings = _with_steps(settings or EncodeSettings(), "image")
    pixels = check_pixels(image)
    h, w, c = pixels.shape
    n_residual = settings.residual_bytes if residual is None else residual
    if not isinstance(n_residual, int):
        raise InputError(f"residual bytes must be an integer here, got {n_residual!r} (encode_image resolves "
                         "\"auto\")")
    asked = {}
    if n_residual and settings.target_bytes is not None:  # the field gets what the residual leaves
        if n_residual >= settings.target_bytes:
            raise InputError(f"--residual-bytes {n_residual} leaves nothing of --target-bytes "
                             f"{settings.target_bytes} for the field")
        asked = {"target_bytes": settings.target_bytes, **({"default_target": True} if default_target else {})}
        settings = replace(settings, target_bytes=settings.target_bytes - n_residual)
    if raster_bytes:
        asked = {"target_bytes": raster_bytes, "raster_mode": True}
    channels = getattr(image, "channels", None) or default_channels(c)
    curves = check_domain(curves, w, h, fit_curves)
    scale = quality_scale(pixels)
    value_map, fit_scale, units = _units(pixels, scale)
    fitted = pixels if value_map is None else value_map.normalise(pixels)
    clock = time.perf_counter()
    pixel_filter, detection = resolve(settings.pixel_filter, pixels, curves)
    settings = replace(settings, pixel_filter=str(pixel_filter))  # recorded as resolved: auto writes the same file
    detect_s = time.perf_counter() - clock
    clock = time.perf_counter()
    settings, mesh = image_mesh_size(curves, settings, w * h)  # small images: a mesh and decoder sized to them
    sizing_s = time.perf_counter() - clock
    settings = replace(image_decoder(settings, pixels.size, c), refine=refine_rounds(settings))

    def mixed(m):  # (H, W) bool: the pixels a curve of m's mesh changes under the pixel filter
        return pixel_filter.filtered(edge_pixels(m.field.mesh, h, w))

    def residual(m):  # squared error at the pixel centres (those a curve changes left out): refinement
        centres = window_points(curves.domain, w, h)
        err = _error(m, centres, fitted.reshape(-1, c), settings)
        err[mixed(m).ravel()] = 0.0
        return centres, err

    info = encoder_info(settings, curves.source, {**asked, "input": f"image {w}x{h}", "pixels": w * h,
                                                  "hdr": scale.tonemap,
                                                  **({"curves": curves_info} if curves_info else {})})
    stored = str(pixel_filter)

    def size_of(m):
        return len(encode_model(m, settings, info, (1.0, 1.0), value_map, stored)[0])

    model, seconds = _mesh_and_fit(fit_image, fitted, curves, settings, channels, callback, mesh=mesh,
                                   residual=residual, min_area=0.25, size_of=size_of,
                                   quality=lambda m: fit_scale.psnr(fitted, render(m, w, h, pixel_filter=pixel_filter)),
                                   fewer_bits=chosen_bits, data_range=fit_scale.data_range,
                                   tonemap=fit_scale.tonemap, pixel_filter=pixel_filter)
    seconds["mesh_s"] += sizing_s
    seconds = {"detect_s": detect_s, **seconds}
    clock = time.perf_counter()
    if raster_bytes:
        from .train.flat import constant_rows

        flat_rows = constant_rows(model)
    else:
        flat_rows = _snap_flat(model, fitted, curves.domain, settings, fit_scale.data_range, mixed(model), size_of)
    seconds["flat_s"] = time.perf_counter() - clock
    rendered = []  # the written file's 1x render, which the residual completes

    def truth(m):
        rendered[:] = [render(m, w, h, pixel_filter=pixel_filter)]
        return pixels, rendered[0]

    blob, report = _finish(model, settings, info, seconds, w * h, truth, scale,
                           pixel_size=(1.0, 1.0), value_map=value_map, units=units, pixel_filter=stored)
    if raster_bytes:
        n_residual = raster_bytes - len(blob)
    if n_residual:
        if default_target:  # no fill round: the residual takes what the field left of its share too
            n_residual += max(0, settings.target_bytes - len(blob))
        blob = _with_residual(blob, report, pixels, rendered[0], n_residual, scale,
                              lambda m: render(m, w, h, pixel_filter=pixel_filter), settings.device)
    report.pixel_filter, report.flat_rows = stored, flat_rows
    report.pixel_evidence = detection.evidence() if detection else None
    return blob, report


@_feature_bits
def encode_bands(source, curves: Curves, settings: EncodeSettings | None = None, *, fit_curves: bool = False,
                 callback: Callback | None = None):
    """Encode a raster read in bands (``dfc.io.bands``: an EXR file of any size, never held whole) with its
    discontinuity curves; data-parallel when called on every rank of a ``torch.distributed`` run.

    Steps (``report.seconds``): the mesh, built on rank 0 and sent to the others (``mesh_s``); one pass over the
    bands checking every pixel and gathering the range, mean and held-out pixels (``scan_s``, ``dfc.train.bands``);
    the out-of-core fit (``fit_s``, ``dfc.train.fit.fit_bands``: ``settings.epoch_pixels`` stratified pixels per
    epoch, mixed and held-out pixels left out); then rank 0 writes and measures the file (``write_s``, ``verify_s``).
    ``report.psnr`` is of the decoded file at the held-out pixels' centres against their values (stratified, never
    trained on; ``dfc.train.bands.HELD_OUT_PIXELS`` of them).

    Returns (blob, report) on rank 0 and (None, None) on the other ranks, after checking that every rank holds the
    same parameters (``dfc.train.distributed.check_replicas``).
    """
    from .geometry.pixels import EdgeMask
    from .io.bands import MappedBands
    from .train import distributed
    from .train.bands import HeldOut, scan
    from .train.fit import MAX_DROPPED_FRACTION, fit_bands

    _image_only(settings, "an image read in bands (out of core)")
    settings = _with_steps(settings or EncodeSettings(), "image")
    rank, world = distributed.world()
    h, w = source.height, source.width
    channels = list(source.channels)
    curves = check_domain(curves, w, h, fit_curves)
    settings = image_decoder(settings, w * h * len(channels), len(channels))
    clock = time.perf_counter()
    mesh = _on_rank0(lambda: sized_mesh(curves, settings, channels)[1])
    seconds = {"mesh_s": time.perf_counter() - clock}
    clock = time.perf_counter()
    mixed, held_out = EdgeMask(mesh, h, w), HeldOut(w, h, seed=settings.seed)
    stats = scan(source, mixed=mixed, held_out=held_out, rank=rank, world=world)
    stats.lo, stats.hi = distributed.reduce(stats.lo, "min"), distributed.reduce(stats.hi, "max")
    stats.total, stats.log_total = distributed.reduce(stats.total), distributed.reduce(stats.log_total)
    stats.count, stats.mixed = (int(v) for v in distributed.reduce(np.array([stats.count, stats.mixed])))
    held_xy, held_values = distributed.gather_rows(stats.held_xy), distributed.gather_rows(stats.held_values)
    seconds["scan_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    scale = (QualityScale(1.0, tonemap=True)
             if is_hdr(hi=float(stats.hi.max()), mean=float(np.mean(stats.mean)))
             else quality_scale(np.array([stats.lo.min(), stats.hi.max()])))
    value_map, fit_scale, units = _units(np.stack([stats.lo, stats.hi]), scale)
    fit_source, fit_stats = source, stats
    if value_map is not None:  # the fit reads normalised bands; its statistics follow
        fit_source = MappedBands(source, value_map)
        fit_stats = replace(stats, lo=(stats.lo - value_map.offset) / value_map.scale,
                            hi=(stats.hi - value_map.offset) / value_map.scale,
                            total=(stats.total - stats.count * value_map.offset) / value_map.scale)
    model = fit_bands(fit_source, mesh, fit_stats, settings.fit, epoch_pixels=settings.epoch_pixels,
                      mixed=mixed if stats.mixed <= MAX_DROPPED_FRACTION * stats.count else None, held_out=held_out,
                      feature_bits=settings.feature_bits, weight_bits=settings.weight_bits, callback=callback,
                      channels=channels, data_range=fit_scale.data_range, tonemap=fit_scale.tonemap)
    seconds["fit_s"] = time.perf_counter() - clock
    distributed.check_replicas(model)
    distributed.barrier()
    if rank != 0:
        return None, None
    settings = replace(settings, workers=world)
    info = encoder_info(settings, curves.source, {"input": f"image {w}x{h} (bands)", "pixels": w * h,
                                                  "hdr": scale.tonemap, "held_out": len(held_xy)})
    centres = (held_xy + 0.5) * np.array([(mesh.domain[2] - mesh.domain[0]) / w, (mesh.domain[3] - mesh.domain[1]) / h])
    centres += np.array(mesh.domain[:2])
    blob, report = _finish(model, settings, info, seconds, w * h, lambda m: (held_values, values_at(
        m, centres, device=settings.device, block=QUERY_BLOCK)), scale, pixel_size=(1.0, 1.0), value_map=value_map,
        units=units)
    report.heldout = len(held_xy)
    return blob, report


def _on_rank0(build):
    """``build()`` run on rank 0 and its result (or its ``DfcError``) sent to every rank."""
    from .errors import DfcError
    from .train import distributed

    result = None
    if distributed.world()[0] == 0:
        try:
            result = build()
        except DfcError as e:
            result = e
    result = distributed.broadcast_object(result)
    if isinstance(result, DfcError):
        raise result
    return result


@_feature_bits
def encode_samples(samples, curves: Curves, settings: EncodeSettings | None = None, *,
                   reference: np.ndarray | None = None, callback: Callback | None = None):
    """Encode a scattered sample set (``dfc.io.samples.SampleSet``) with its discontinuity curves.

    The samples' domain (when given) must equal the curves'. Curved pieces are cut to ``sample_piece_length``, and
    without a mesh-size setting the mesh follows the sample count
    (``dfc.rate.sample_mesh_size``). A random ``HOLDOUT_FRACTION`` of the samples (``heldout_split``) is left out of
    the fit: ``report.psnr`` is of the decoded file at their positions against their values (``report.heldout``
    of them). Without ``settings.steps``, ``sample_steps`` of them.
    ``reference`` : optional (H, W, C) exact values at the pixel centres of a W × H grid over the
    domain (``dfc wos --reference``); ``report.psnr_reference`` is of the file rendered there against them.
    ``bits_per_pixel`` counts bits per sample.
    """
    from .io.samples import SampleSet, default_channels
    from .render import render
    from .train.fit import fit_samples

    settings = settings or EncodeSettings()
    _image_only(settings, "a sample set")
    domain = getattr(samples, "domain", None)
    if domain is not None and not np.allclose(domain, curves.domain, rtol=1e-9, atol=0):
        raise InputError(f"the samples' domain {tuple(domain)} differs from the curves' {tuple(curves.domain)}")
    values = np.asarray(samples.values, dtype=np.float32)
    settings = _with_steps(settings, "samples", len(values))
    channels = samples.channels or default_channels(values.shape[1])
    if reference is not None and (np.ndim(reference) != 3 or np.shape(reference)[2] != values.shape[1]):
        raise InputError(f"the reference must be an (H, W, {values.shape[1]}) raster of the samples' channels, got "
                         f"shape {np.shape(reference)}")
    xy = np.asarray(samples.xy, dtype=np.float64)
    fitted, held = heldout_split(len(xy), settings.seed)
    scale = quality_scale(values)
    value_map, fit_scale, units = _units(values, scale)
    train = SampleSet(xy[fitted], values[fitted] if value_map is None else value_map.normalise(values[fitted]), domain,
                      samples.channels)
    curves = split_pieces(curves, sample_piece_length(curves.domain, len(train)))
    clock = time.perf_counter()
    settings, mesh = sample_mesh_size(curves, settings, len(train))
    sizing_s = time.perf_counter() - clock
    model, seconds = _mesh_and_fit(fit_samples, train, curves, settings, channels, callback, mesh=mesh,
                                   data_range=fit_scale.data_range, tonemap=fit_scale.tonemap)
    seconds["mesh_s"] += sizing_s
    info = encoder_info(settings, curves.source, {"input": f"samples {len(xy)}", "samples": len(xy)})
    check = held if len(held) else fitted

    def truth(m):
        return values[check], values_at(m, xy[check], device=settings.device, block=QUERY_BLOCK)

    blob, report = _finish(model, settings, info, seconds, len(xy), truth, scale, value_map=value_map, units=units)
    report.heldout = len(held)
    if reference is not None:
        h, w = np.shape(reference)[:2]
        report.psnr_reference = scale.psnr(reference, render(loads(blob, device=settings.device), w, h))
    return blob, report


def sample_piece_length(domain, n_samples: int) -> float:
    """Longest curved piece (domain units) a sample set of ``n_samples`` meshes with (``SAMPLE_PIECES``)."""
    x0, y0, x1, y1 = domain
    return max(x1 - x0, y1 - y0) / (SAMPLE_PIECES * max(1, n_samples) ** 0.25)


def sample_steps(n_samples: int, batch_size: int) -> int:
    """Fit steps of a sample set of ``n_samples`` when none are given: ``SAMPLE_PASSES`` passes over them with
    ``batch_size`` samples per step, at least ``DEFAULT_STEPS``."""
    return max(DEFAULT_STEPS, math.ceil(SAMPLE_PASSES * n_samples / batch_size))


def default_steps(kind: str, n_samples: int = 0, batch_size: int | None = None) -> int:
    """Fit steps of an encode whose settings give none: ``IMAGE_STEPS`` for an image (read whole or in bands),
    ``sample_steps`` for a sample set of ``n_samples``, ``DEFAULT_STEPS`` for FEM data and frames. ``kind`` is one
    of "image", "samples", "fem", "frames"; ``batch_size`` None is ``dfc.train.fit.BATCH_SIZE``."""
    if kind == "image":
        return IMAGE_STEPS
    return sample_steps(n_samples, batch_size or BATCH_SIZE) if kind == "samples" else DEFAULT_STEPS


def _image_only(settings, kind: str) -> None:
    """Raise ``InputError`` when ``settings`` name a pixel filter or residual bytes for an input ``kind`` that has
    no pixels to filter or is not fitted with one (only images read whole are), or no pixel grid to hold a
    residual."""
    if getattr(settings, "pixel_filter", "auto") != "auto":
        raise InputError(f"a pixel filter applies to an image read whole, not to {kind}")
    if getattr(settings, "residual_bytes", "auto") not in ("auto", 0):
        raise InputError(f"--residual-bytes applies to an image read whole, not to {kind}")


def _with_steps(settings: EncodeSettings, kind: str, n_samples: int = 0) -> EncodeSettings:
    """``settings`` with ``steps`` set to ``default_steps`` when None."""
    if settings.steps is not None:
        return settings
    return replace(settings, steps=default_steps(kind, n_samples, settings.batch_size))


def heldout_split(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (fitted, held out) of ``n`` samples: a random ``HOLDOUT_FRACTION`` (at most ``HOLDOUT_MAX``) held out,
    drawn with ``seed``; none below ``HOLDOUT_MIN_SAMPLES`` samples. Both sorted (int64)."""
    n_held = 0 if n < HOLDOUT_MIN_SAMPLES else min(HOLDOUT_MAX, round(HOLDOUT_FRACTION * n))
    held = np.zeros(n, dtype=bool)
    held[np.random.default_rng(seed).choice(n, n_held, replace=False)] = True
    return np.flatnonzero(~held), np.flatnonzero(held)


@_feature_bits
def encode_fem(solution, curves: Curves, settings: EncodeSettings | None = None, *, sampling: str = "linear",
               callback: Callback | None = None, chosen_bits: bool = False):
    """Encode a FEM solution (``dfc.io.fem.FemSolution``) with its barrier curves.

    The domain is the curves' when it contains the mesh, else the mesh's bounding box (``dfc.physics.fem.fem_curves``).
    The fit sees the nodes and ``dfc.physics.fem.SAMPLES_PER_TRIANGLE`` points per element valued by ``sampling``
    ("linear" or "nearest", ``dfc.physics.fem.interpolate``: never across a barrier). ``report.psnr`` is of the
    decoded file at the nodes (each read just inside its first element, ``dfc.physics.fem.node_points``) against the
    nodal values, data range the values' span over all channels; ``bits_per_pixel`` counts bits per node.
    Refinement (``refine_rounds``: ``target_bytes``, ``target_psnr`` or ``refine``) splits where the error at those
    training points is largest, never below the median element's area (the data holds no finer detail), and
    ``target_psnr`` is of the nodal PSNR; without a mesh-size option, target or ``refine`` the encode aims at
    ``FEM_TARGET_PSNR``. ``chosen_bits``: as in ``encode_image``.
    """
    from .geometry.plane import triangle_areas
    from .io.samples import SampleSet
    from .physics.fem import fem_curves, node_points, sample_fem
    from .train.fit import fit_samples

    _image_only(settings, "a FEM solution")
    settings, fit_kw = _physical(_with_steps(fem_settings(settings or EncodeSettings()), "fem"))
    settings = replace(settings, refine=refine_rounds(settings))
    curves = fem_curves(solution, curves)
    node_xy = node_points(solution)[0]
    nodal = solution.values[np.unique(solution.triangles)]
    scale = quality_scale(nodal, physical=True)
    value_map, fit_scale, units = _units(nodal, scale, dtype=solution.values.dtype)
    normalised = replace(solution, values=value_map.normalise(solution.values))
    nodal_fitted = value_map.normalise(nodal)
    xy, values = sample_fem(normalised, curves, mode=sampling, seed=settings.seed)
    samples = SampleSet(xy, values, curves.domain, list(solution.channels))
    info = encoder_info(settings, curves.source, {"input": f"FEM {solution.source or 'mesh'}: {len(nodal)} nodes, "
                                                           f"{len(solution.triangles)} triangles",
                                                  "nodes": len(nodal), "fem_sampling": sampling})

    def at_nodes(m, truth=nodal):
        return truth, values_at(m, node_xy, device=settings.device, block=QUERY_BLOCK)

    model, seconds = _mesh_and_fit(fit_samples, samples, curves, settings, list(solution.channels), callback,
                                   residual=lambda m: (xy, _error(m, xy, values, settings)),
                                   min_area=float(np.median(triangle_areas(solution.points[solution.triangles]))),
                                   size_of=lambda m: len(encode_model(m, settings, info, value_map=value_map)[0]),
                                   quality=lambda m: fit_scale.psnr(*at_nodes(m, nodal_fitted)),
                                   fewer_bits=chosen_bits, data_range=fit_scale.data_range, tonemap=False, **fit_kw)
    return _finish(model, settings, info, seconds, len(nodal), at_nodes, scale, value_map=value_map, units=units)


@_feature_bits
def encode_frames(sequence, curves: Curves, settings: EncodeSettings | None = None, *, fit_curves: bool = False,
                  callback: Callback | None = None):
    """Encode a frame sequence (``dfc.io.frames.FrameSequence``, T frames of W × H covering [0, W] × [0, H]) with its
    discontinuity curves into a time-sliced file: one feature slice per frame time, linear blending between them.

    ``report.psnr`` is of the decoded file rendered at every frame's pixel centres and time against the frames;
    ``bits_per_pixel`` counts T · W · H pixels.
    """
    from .io.frames import check_frames
    from .io.samples import default_channels
    from .render import default_edge_spp, render
    from .train.fit import fit_frames

    _image_only(settings, "a frame sequence")
    sequence = check_frames(sequence)
    frames = sequence.frames
    t, h, w, c = frames.shape
    channels = sequence.channels or default_channels(c)
    curves = check_domain(curves, w, h, fit_curves)
    settings, fit_kw = _physical(_with_steps(settings or EncodeSettings(), "frames"))
    scale = QualityScale(signal_range(frames))  # values as they are: frames are fitted as physical quantities
    value_map, fit_scale, units = _units(frames, scale)
    fitted = replace(sequence, frames=value_map.normalise(frames))
    model, seconds = _mesh_and_fit(fit_frames, fitted, curves, settings, channels, callback,
                                   data_range=fit_scale.data_range, tonemap=False, **fit_kw)
    info = encoder_info(settings, curves.source, {"input": f"frames {t}x{w}x{h}", "pixels": t * w * h})

    def truth(m):
        edge_spp = default_edge_spp(m, w, h)
        return frames, np.stack([render(m, w, h, t=float(s), edge_spp=edge_spp) for s in sequence.times])

    return _finish(model, settings, info, seconds, t * w * h, truth, scale, pixel_size=(1.0, 1.0),
                   value_map=value_map, units=units)


# ----------------------------------------------------------------------------------------------- shared steps
def _physical(settings: EncodeSettings) -> tuple[EncodeSettings, dict]:
    """Settings and fit options for simulation data: values above 1 are physical quantities, not HDR light, so
    ``loss="auto"`` means the MSE and the values are decoded without the log transform."""
    if settings.loss == "auto":
        settings = replace(settings, loss="mse")
    return settings, {"transform": "identity"}


def _mesh_and_fit(fit_fn, signal, curves: Curves, settings: EncodeSettings, channels: list[str], callback,
                  mesh=None, residual=None, min_area: float = 0.0, size_of=None, quality=None,
                  fewer_bits: bool = False, **fit_kw):
    """Build the decoder-view mesh (unless ``mesh`` is that mesh already), then fit ``fit_fn`` (``fit_image``,
    ``fit_samples`` or ``fit_frames``) to ``signal`` on it, and refine ``settings.refine`` times (``_refine``, with
    ``residual(model) -> (xy (M, 2), squared error (M,))``, triangles of at least ``min_area`` split,
    ``size_of(model) -> bytes`` of its file for a byte target, ``quality(model) -> dB`` for a PSNR target and
    ``fewer_bits`` for ``_refine``); ``fit_kw`` go to ``fit_fn``. Returns (model, seconds per stage)."""
    clock = time.perf_counter()
    mesh_settings, mesh = (settings, mesh) if mesh is not None else sized_mesh(curves, settings, channels, size_of)
    seconds = {"mesh_s": time.perf_counter() - clock}
    clock = time.perf_counter()
    fit_kw = {"feature_bits": settings.feature_bits, "weight_bits": settings.weight_bits, "callback": callback,
              "channels": channels, **fit_kw}
    model = fit_fn(signal, mesh, settings.fit, **fit_kw)
    seconds["fit_s"] = time.perf_counter() - clock
    if settings.refine and residual is not None:
        clock = time.perf_counter()
        model = _refine(model, fit_fn, signal, curves, settings, mesh_settings, residual, min_area, size_of, quality,
                        fit_kw, fewer_bits)
        seconds["refine_s"] = time.perf_counter() - clock
    return model, seconds


def _refine(model, fit_fn, signal, curves: Curves, settings: EncodeSettings, mesh_settings, residual,
            min_area: float, size_of, quality, fit_kw, fewer_bits: bool = False):
    """``settings.refine`` rounds of error-driven refinement of a fitted ``model``: split the triangles where
    ``residual`` is largest (a curved triangle by halving its piece), rebuild the mesh (with ``mesh_settings``,
    which built the first one, plus the new points) and refit from the current fit (``init``). Without a byte
    target a round splits the triangles holding ``dfc.rate.REFINE_SHARE`` of the error, at most
    ``refine_fraction`` of them (``dfc.rate.refinement_points``); with one, as many as the target still pays for
    (``dfc.rate.fill_points``, files priced with ``size_of``), and a refit whose file still outgrows the target is
    redone (``_fill_within``, ``fewer_bits`` as it says). With ``fewer_bits`` (the encoder chose the bits), a fill
    from a fit at those bits prices and refits at ``dfc.rate.COARSE_FEATURE_BITS`` when they cost the fit little
    (``_coarse_costs_little``), after a refit on the mesh the target buys at those bits (``dfc.rate.sized_mesh``)
    when it is the first round.
    Stops early when no triangle is left to split, or when ``quality(model)`` reaches ``settings.target_psnr``."""
    from .rate import build_mesh, fill_points, refinement_points

    extra = np.zeros((0, 2))
    steps = refit_steps(settings)
    chosen = settings.feature_bits  # the bits the encoder chose: the settings', or the coarse ones once switched

    def refit(points, bits):
        mesh = build_mesh(curves, mesh_settings, extra_points=np.concatenate([extra, points]))
        fitted = fit_fn(signal, mesh, replace(settings.fit, steps=steps, qat_steps=None), init=model,
                        **{**fit_kw, "feature_bits": bits})
        if fitted.quantization is None:  # too few steps for quantisation-aware ones: stored with the bits asked for
            fitted.quantization = {"feature_bits": bits}
        return fitted

    for _ in range(settings.refine):
        if settings.target_psnr is not None and quality(model) >= settings.target_psnr:
            break
        mesh = model.field.mesh
        xy, err = residual(model)
        bits = storage(settings, model)["feature_bits"]  # a round refits at the bits of the fit it starts from
        if settings.target_bytes is None:
            most = max(1, round(settings.refine_fraction * mesh.n_triangles))
            points = refinement_points(mesh, xy, err, most=most, min_area=min_area)
            refined = refit(points, bits) if len(points) else None
        else:
            if fewer_bits and bits == chosen and _coarse_costs_little(model, residual, err, bits):
                bits = chosen = COARSE_FEATURE_BITS
                if not len(extra):  # the first mesh was sized for more bits: refit on one sized for these
                    mesh_settings = sized_mesh(curves, settings, model.channels,
                                               lambda m: size_at(size_of, m, COARSE_FEATURE_BITS))[0]
                    model = refit(extra, bits)
                    xy, err = residual(model)
            points = fill_points(model, curves, mesh_settings, extra, xy, err, size_of, settings.target_bytes,
                                 min_area=min_area, bits=bits)
            refined, points = _fill_within(model, points, refit, size_of, settings.target_bytes, bits,
                                           fewer_bits and bits == chosen)  # one bit fewer than chosen at most
        if refined is None:
            break
        extra = np.concatenate([extra, points])
        model = refined
    return model


def _coarse_costs_little(model, residual, err: np.ndarray, bits: int) -> bool:
    """Whether ``model``'s features stored with ``COARSE_FEATURE_BITS`` instead of ``bits`` raise its squared error
    ``err`` (M,) at the points of ``residual(model) -> (xy, squared error)`` by less than ``COARSE_LOSS_DB``."""
    if bits <= COARSE_FEATURE_BITS:
        return False
    with features_at(model, COARSE_FEATURE_BITS):
        coarse = residual(model)[1]
    return 10.0 * math.log10(max(float(coarse.sum()), 1e-300) / max(float(err.sum()), 1e-300)) < COARSE_LOSS_DB


def _fill_within(model, points: np.ndarray, refit, size_of, target: int, bits: int, fewer_bits: bool = False):
    """(refitted model, points (P, 2) it used), or (None, no points) when even the fewest fill points outgrow
    ``target``: ``refit(points, bits)`` on the fill's points (``dfc.rate.fill_points``, in decreasing order of error
    per byte) with ``bits`` per feature. While the file is over ``target`` bytes (the refit's features cost more than
    the carried-over ones it was priced with), at most ``FILL_RETRIES`` times, on a prefix of the points (``_cut``).
    With ``fewer_bits``, the last retry, or the first that no cut can bring within the target, keeps the points at
    one bit fewer per feature, about a tenth of the features' bytes (``CHANGELOG.md``, "A byte target's fill stores a
    bit fewer rather than nothing")."""
    base, sizes = None, []  # sizes: (points, bytes) of each refit
    for attempt in range(FILL_RETRIES + 1):
        if not len(points):
            break
        refined = refit(points, bits)
        size = size_of(refined)
        if size <= target:
            return refined, points
        sizes.append((len(points), size))
        base = size_at(size_of, model, bits) if base is None else base
        keep = _cut(sizes, base, target)
        if fewer_bits and bits > 1 and (attempt == FILL_RETRIES - 1 or keep < 1):
            refined = refit(points, bits - 1)
            return (refined, points) if size_of(refined) <= target else (None, points[:0])
        points = points[:max(0, min(keep, len(points) - 1))]
    return None, points[:0]


def _cut(sizes: list[tuple[int, int]], base: int, target: int) -> int:
    """Fill points a refit keeps for a file of ``FILL`` × ``target`` bytes, from ``sizes`` ((points, bytes) of the
    refits so far, all over ``target``): after one, in proportion to its overshoot over ``base`` (the file with no
    point); after more, where the line through the last two meets ``FILL`` × ``target``, since a refit costs more than
    ``base`` even with few points (below 1: no count does)."""
    n1, s1 = sizes[-1]
    if len(sizes) == 1 or sizes[-2][0] == n1:
        return int(n1 * FILL * (target - base) / max(s1 - base, 1))
    n0, s0 = sizes[-2]
    slope = (s0 - s1) / (n0 - n1)
    return int(n1 - (s1 - FILL * target) / slope) if slope > 0 else 0


def _error(model, xy: np.ndarray, values: np.ndarray, settings: EncodeSettings) -> np.ndarray:
    """(M,) float64 squared error of ``model`` at points xy (M, 2) against values (M, C), summed over channels."""
    pred = values_at(model, xy, device=settings.device, block=QUERY_BLOCK)
    return ((pred - values) ** 2).sum(axis=1)


def _with_residual(blob: bytes, report: EncodeReport, pixels: np.ndarray, base: np.ndarray, n_bytes: int,
                   scale: QualityScale, render_1x: Callable[[object], np.ndarray], device: str) -> bytes:
    """``blob`` with an ``rESD`` chunk of at most ``n_bytes`` (framing included) holding what its field, ``base``
    (H, W, C: ``blob`` decoded and rendered at the input's size by ``render_1x``), leaves of ``pixels`` (H, W, C);
    ``report``'s sizes and PSNR updated to the new file, rendered again (``blob`` unchanged when the field leaves
    nothing). Raises ResidualBytesError (an InputError) when
    ``n_bytes`` is too small for the residual's smallest stream, or for one that lowers the error."""
    from .field.residual import tone_map
    from .io.container import with_residual
    from .io.residual import encode_residual

    clock = time.perf_counter()
    base = base.astype(np.float64)
    space = tone_map if scale.tonemap else (lambda v: v)  # HDR light: where its PSNR is measured
    try:  # 12 framing bytes, up to 3 of padding
        payload = encode_residual(space(pixels.astype(np.float64)) - space(base), n_bytes - 15,
                                  "tonemapped" if scale.tonemap else "values")
    except ResidualBytesError as exc:
        raise ResidualBytesError(f"--residual-bytes {n_bytes}: {exc} (framing: 15 bytes)") from None
    if payload is None:
        return blob
    blob, chunk = with_residual(blob, payload)
    report.psnr = scale.psnr(pixels, render_1x(loads(blob, device=device, validate_mesh=False)))
    report.chunk_bytes = {**{k: v for k, v in report.chunk_bytes.items() if k != "DEND"}, "rESD": chunk,
                          "DEND": report.chunk_bytes["DEND"]}
    report.total_bytes = len(blob)
    report.bits_per_pixel = 8.0 * len(blob) / (pixels.shape[0] * pixels.shape[1])
    report.seconds["residual_s"] = time.perf_counter() - clock
    return blob


def _snap_flat(model, pixels: np.ndarray, domain, settings: EncodeSettings, data_range: float, mixed: np.ndarray,
               size_of: Callable[[object], int]) -> int:
    """``dfc.train.flat.snap_flat_rows`` on a fitted image model (``mixed`` (H, W) bool: the pixels a curve crosses),
    evaluated with the features and weights its file will store (its quantisation as written, ``storage``); the rows
    it changed. Under a byte target the change is kept only when the file (``size_of(model)``: its bytes) still
    fits."""
    from .train.flat import snap_flat_rows

    kept = model.quantization
    stored = storage(settings, model)
    target = settings.target_bytes
    model.quantization = {"feature_bits": stored["feature_bits"],
                          **({"weight_bits": stored["weight_bits"]} if stored["weight_bits"] else {})}
    try:
        return snap_flat_rows(model, pixels, domain, stored["feature_bits"], data_range, mixed,
                              accept=(lambda m: size_of(m) <= target) if target else None)
    finally:
        model.quantization = kept


def _finish(model, settings: EncodeSettings, info: dict, seconds: dict, n_pixels: int,
            truth: Callable[[object], tuple[np.ndarray, np.ndarray]], scale: QualityScale, pixel_size=None,
            value_map: ValueMap | None = None, units: str = "", pixel_filter: str | None = None):
    """Write the model (fitted in the units of ``value_map``, ``_units``) to bytes, decode them, measure PSNR of the
    decoded model against ``truth`` on ``scale`` (``pixel_size``, ``pixel_filter``: of a raster input, for the
    header; ``units``: the summary's line). The file stores the model's feature bits (``dfc.io.dfield.storage``:
    a byte target's fill may have taken one fewer, ``_fill_within``), which ``info`` and the report then say."""
    clock = time.perf_counter()
    bits = storage(settings, model)["feature_bits"]
    if bits != settings.feature_bits:
        settings, info = replace(settings, feature_bits=bits), {**info, "feature_bits": bits}
    blob, sizes = encode_model(model, settings, info, pixel_size, value_map, pixel_filter)
    decoded = loads(blob, device=settings.device, validate_mesh=False)
    seconds["write_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    reference, test = truth(decoded)
    seconds["verify_s"] = time.perf_counter() - clock
    mesh = decoded.field.mesh
    report = EncodeReport(
        chunk_bytes=sizes, total_bytes=len(blob), bits_per_pixel=8.0 * len(blob) / n_pixels,
        psnr=scale.psnr(reference, test), data_range=scale.data_range,
        n_vertices=mesh.n_vertices, n_triangles=mesh.n_triangles, n_features=decoded.field.n_features,
        seconds=seconds, tonemapped=scale.tonemap, target_psnr=settings.target_psnr,
        feature_bits=settings.feature_bits, units=units,
    )
    return blob, report
