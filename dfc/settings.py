"""Encode settings: what an encode is asked to do, in four groups, each validated when it is made.

``EncodeSettings`` composes ``MeshSettings`` (mesh size and refinement, ``dfc.rate``), ``FitSettings`` (the fit,
``dfc.train.fit``), ``StorageSettings`` (how the file stores features, weights and vertices, spec/dfield.md) and
``RunSettings`` (out-of-core epochs and ranks, ``dfc.codec.encode_bands``). Every field of every group is also a
keyword and a read-only attribute of ``EncodeSettings`` (``EncodeSettings(steps=1000).steps``), and
``dataclasses.replace(settings, steps=500)`` works on it. A value that breaks a group's rule raises
``dfc.errors.SettingsError`` (a ``ValueError``) with one line that states the rule, naming the field; the CLI
(``dfc.cli.encode``) builds its settings here, so it refuses what the API refuses.

Adding a setting: add a field with a default to the group it belongs to and its check to that group's
``__post_init__``; it is then a keyword and attribute of ``EncodeSettings`` and recorded in a file's header when it
differs from its default (``to_dict``). On the command line, a ``dfc encode`` option whose parameter is named as the
field reaches it through ``dfc.cli.encode.encode_settings`` (every option the command does not name in its
signature is a setting). Torch-free.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, fields, replace

from .errors import InputError, SettingsError

__all__ = ["EncodeSettings", "FitSettings", "LOSSES", "MeshSettings", "RunSettings", "StorageSettings",
           "FEATURE_CODINGS", "MESH_CODINGS"]

LOSSES = ("auto", "mse", "relmse", "logmse")
FEATURE_CODINGS = ("predicted", "plain")
MESH_CODINGS = ("derived", "draco")


def _integer(obj, name: str, lo: int | None, hi: int | None = None, optional: bool = False,
             note: str = "") -> None:
    """``SettingsError`` unless ``obj.name`` is an integer in lo..hi (None: unbounded; None allowed as the value
    when ``optional``)."""
    value = getattr(obj, name)
    if value is None and optional:
        return
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if ok and (lo is None or lo <= value) and (hi is None or value <= hi):
        return
    allowed = ("an integer" if lo is None else f"an integer of at least {lo}" if hi is None
               else f"an integer in {lo}..{hi}")
    suffix = note or (" or None" if optional else "")
    raise SettingsError(f"{name} must be {allowed}{suffix}, got {value!r}")


def _positive(obj, name: str, hi: float | None = None) -> None:
    """``SettingsError`` unless ``obj.name`` is None or a finite number > 0 (and at most ``hi``)."""
    value = getattr(obj, name)
    if value is None and hi is None:
        return
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if ok and value > 0 and (hi is None or value <= hi):
        return
    allowed = "a finite number > 0 or None" if hi is None else f"a number in (0, {hi}]"
    raise SettingsError(f"{name} must be {allowed}, got {value!r}")


def _choice(obj, name: str, choices: tuple[str, ...]) -> None:
    value = getattr(obj, name)
    if value not in choices:
        raise SettingsError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")


@dataclass(frozen=True)
class MeshSettings:
    """Mesh size and refinement (``dfc.rate``). Size: at most one of ``max_area`` (domain units²), ``edge_length``
    (domain units) and ``target_bytes`` (the file's size cap), with or without ``max_triangles`` (≥ 2); else about
    ``dfc.rate`` 's default count. ``target_psnr`` (dB > 0, not with ``target_bytes``): refine until the file
    reaches it. ``refine``: rounds of error-driven refinement (0..16; None: one under a byte target, up to
    ``dfc.codec.TARGET_PSNR_ROUNDS`` under a PSNR target, else none), each splitting at most ``refine_fraction``
    (0 < f ≤ 1) of the triangles and refitting for ``refine_steps`` (None: ``dfc.codec.refit_steps``)."""

    max_triangles: int | None = None
    max_area: float | None = None
    edge_length: float | None = None
    target_bytes: int | None = None
    target_psnr: float | None = None
    refine: int | None = None
    refine_steps: int | None = None
    refine_fraction: float = 0.25

    def __post_init__(self):
        _integer(self, "max_triangles", 2, optional=True)
        _positive(self, "max_area")
        _positive(self, "edge_length")
        _integer(self, "target_bytes", 1, optional=True)
        _positive(self, "target_psnr")
        _integer(self, "refine", 0, 16, optional=True)
        _integer(self, "refine_steps", 1, optional=True)
        _positive(self, "refine_fraction", hi=1.0)
        if sum(v is not None for v in (self.max_area, self.edge_length, self.target_bytes)) > 1:
            raise SettingsError("give at most one of max_area, edge_length and target_bytes")
        if self.target_bytes is not None and self.target_psnr is not None:
            raise SettingsError("give target_bytes or target_psnr, not both")


@dataclass(frozen=True)
class FitSettings:
    """The fit (``dfc.train.fit``): ``steps`` optimiser steps (≥ 1; None: the input kind's default,
    ``dfc.codec.default_steps``) of ``batch_size`` samples (≥ 1; None: ``dfc.train.fit.BATCH_SIZE``, for an image
    read whole ``dfc.train.fit.image_batch_size`` of its pixels), ``dim`` feature channels per vertex (1..64), a
    decoder of ``layers`` hidden layers (≥ 1) of ``hidden`` units (≥ 1), the last ``qat_steps`` steps (≥ 0; None:
    a tenth) quantisation-aware, ``loss`` (one of ``LOSSES``; "auto": log-MSE for HDR values), ``seed`` (an integer:
    features, decoder and sampling), torch ``device`` (a name such as "cpu" or "cuda:1"), ``pixel_filter`` (images
    read whole: the filter that made the pixels, a ``dfc.pixel_filter.parse`` spec, or "auto": detected from the
    pixels, ``dfc.pixel_model``; ``dfc.codec.encode_image`` resolves it and hands the fit the filter itself)."""

    steps: int | None = None
    batch_size: int | None = None
    dim: int = 5
    hidden: int = 64
    layers: int = 2
    qat_steps: int | None = None
    loss: str = "auto"
    seed: int = 0
    device: str = "cpu"
    pixel_filter: str = "auto"

    def __post_init__(self):
        _integer(self, "steps", 1, optional=True)
        _integer(self, "batch_size", 1, optional=True)
        _integer(self, "dim", 1, 64)
        _integer(self, "hidden", 1)
        _integer(self, "layers", 1)
        _integer(self, "qat_steps", 0, optional=True)
        _choice(self, "loss", LOSSES)
        _integer(self, "seed", None)
        if not isinstance(self.device, str) or not self.device:
            raise SettingsError(f"device must be a torch device name such as 'cpu' or 'cuda:1', got {self.device!r}")
        if self.pixel_filter != "auto":
            from .pixel_filter import parse

            try:
                parse(self.pixel_filter)
            except InputError as e:
                raise SettingsError(str(e)) from None


@dataclass(frozen=True)
class StorageSettings:
    """How the file stores the fit (spec/dfield.md): ``feature_bits`` per feature value (1..16; None:
    ``dfc.field.quantize.DEFAULT_FEATURE_BITS``, or fewer when a byte target is too small for them),
    ``feature_coding`` ("predicted": ``FEAC``; "plain": zstd, the 1.0 ``FEAT``), ``weight_bits`` of the integer
    weight matrices (2..16: a sign and a magnitude; None: float16 ``MLPW``), ``mesh_bits`` of the vertex positions
    (1..23), ``mesh_coding`` ("derived": the free vertices on a coarse lattice and the triangles rebuilt by the
    decoder, content 1.3; "draco": every vertex at ``mesh_bits`` and the triangles in a Draco stream),
    ``residual_bytes`` (images read whole): bytes given to a residual raster (``rESD``, ``dfc.io.residual``), out of
    ``target_bytes`` when there is one: an integer ≥ 0 (0: none), or "auto" (``dfc.rate.residual_choices``: a
    share of a byte target for a clean image, else none)."""

    feature_bits: int | None = None
    feature_coding: str = "predicted"
    weight_bits: int | None = 8
    mesh_bits: int = 20
    mesh_coding: str = "derived"
    residual_bytes: int | str = "auto"

    def __post_init__(self):
        _integer(self, "feature_bits", 1, 16, optional=True)
        _choice(self, "feature_coding", FEATURE_CODINGS)
        _integer(self, "weight_bits", 2, 16, optional=True, note=" (a sign and a magnitude), or None for float16")
        _integer(self, "mesh_bits", 1, 23)
        _choice(self, "mesh_coding", MESH_CODINGS)
        if self.residual_bytes != "auto":
            _integer(self, "residual_bytes", 0, note=' or "auto"')


@dataclass(frozen=True)
class RunSettings:
    """How an image read out of core is fitted (``dfc.codec.encode_bands``): ``epoch_pixels`` drawn per epoch (≥ 1;
    None: sized to memory) on ``workers`` local ranks (≥ 1; recorded in the file)."""

    epoch_pixels: int | None = None
    workers: int = 1

    def __post_init__(self):
        _integer(self, "epoch_pixels", 1, optional=True)
        _integer(self, "workers", 1)


GROUPS = {"mesh": MeshSettings, "fit": FitSettings, "storage": StorageSettings, "run": RunSettings}
"""``EncodeSettings``' groups: attribute name → class."""
FLAT = {f.name: group for group, cls in GROUPS.items() for f in fields(cls)}
"""Every setting's name → the group that holds it."""
assert len(FLAT) == sum(len(fields(cls)) for cls in GROUPS.values()), "a setting's name is in two groups"

_RECORD_ORDER = ("max_triangles", "max_area", "edge_length", "target_bytes", "target_psnr", "refine", "refine_steps",
                 "refine_fraction", "steps", "batch_size", "dim", "hidden", "layers", "feature_bits", "feature_coding",
                 "weight_bits", "mesh_bits", "qat_steps", "loss", "seed", "device", "epoch_pixels", "workers")
"""The order files written so far list their settings in (``to_dict``); settings added since follow, by group."""


@dataclass(frozen=True, init=False)
class EncodeSettings:
    """Every setting of an encode: ``mesh``, ``fit``, ``storage`` and ``run`` groups (see the module). Made from the
    groups, from any of their fields as keywords (applied on top of the groups given), or both:
    ``EncodeSettings(steps=1000, target_bytes=8000)``, ``EncodeSettings(fit=FitSettings(steps=1000))``. Fields read
    as attributes (``settings.steps``); immutable (``dataclasses.replace`` makes a changed copy).

    Raises ``SettingsError`` (a ``ValueError``) for a value that breaks its group's rule, ``TypeError`` for a name
    that is no setting."""

    mesh: MeshSettings = field(default_factory=MeshSettings)
    fit: FitSettings = field(default_factory=FitSettings)
    storage: StorageSettings = field(default_factory=StorageSettings)
    run: RunSettings = field(default_factory=RunSettings)

    def __init__(self, mesh: MeshSettings | None = None, fit: FitSettings | None = None,
                 storage: StorageSettings | None = None, run: RunSettings | None = None, **settings):
        unknown = sorted(set(settings) - set(FLAT))
        if unknown:
            raise TypeError(f"EncodeSettings got unknown settings {', '.join(unknown)}; the settings are "
                            f"{', '.join(FLAT)}")
        for name, cls in GROUPS.items():
            group = {"mesh": mesh, "fit": fit, "storage": storage, "run": run}[name]
            if group is None:
                group = cls()
            elif not isinstance(group, cls):
                raise SettingsError(f"{name} must be a {cls.__name__}, got {type(group).__name__}")
            changes = {k: v for k, v in settings.items() if FLAT[k] == name}
            object.__setattr__(self, name, replace(group, **changes) if changes else group)

    def __getattr__(self, name: str):
        group = FLAT.get(name)
        if group is None:
            raise AttributeError(f"'EncodeSettings' object has no attribute {name!r}")
        return getattr(object.__getattribute__(self, group), name)

    @staticmethod
    def names() -> tuple[str, ...]:
        """The names of every setting (the keywords ``EncodeSettings`` takes besides the groups)."""
        return tuple(FLAT)

    def to_dict(self) -> dict:
        """Every setting by name (files' order: ``_RECORD_ORDER``, then settings added since)."""
        order = [*_RECORD_ORDER, *(n for n in FLAT if n not in _RECORD_ORDER)]
        return {name: getattr(self, name) for name in order}
