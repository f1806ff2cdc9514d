"""dfc — the discontinuity-aware field codec.

The torch-based parts (``FeatureField``, ``FieldModel``, ``fit_image``, ``fit_samples``, ``load``,
``encode_image``, ``render_model``, ...) are imported on first use, so that ``import dfc`` and torch-free commands
(``dfc stats``, ``dfc mesh``) start fast.
"""

__version__ = "0.1.0"

import importlib

from .errors import CurveError, DfcError, FormatError, InputError, MeshError, SettingsError
from .geometry.curves import Curves, SideValues
from .geometry.mesh import Mesh
from .geometry.triangulate import triangulate

_LAZY = {
    "read_curves": "dfc.geometry.sources",
    "FeatureField": "dfc.field.feature_field",
    "FieldModel": "dfc.field.model",
    "fit_image": "dfc.train.fit",
    "fit_samples": "dfc.train.fit",
    "fit_frames": "dfc.train.fit",
    "EncodeSettings": "dfc.settings",
    "MeshSettings": "dfc.settings",
    "FitSettings": "dfc.settings",
    "StorageSettings": "dfc.settings",
    "RunSettings": "dfc.settings",
    "encode_image": "dfc.codec",
    "encode_bands": "dfc.codec",
    "ExrBands": "dfc.io.bands",
    "encode_samples": "dfc.codec",
    "encode_fem": "dfc.codec",
    "encode_frames": "dfc.codec",
    "encode_file_in_bands": "dfc.workers",
    "read_fem": "dfc.io.fem",
    "read_frames": "dfc.io.frames",
    "load": "dfc.io.dfield",
    "loads": "dfc.io.dfield",
    "read_image": "dfc.io.image",
    "read_samples": "dfc.io.samples",
    "solve_scene": "dfc.physics.solve",
    "render_model": "dfc.render:render",
}
"""Names imported on first use: name → module (``module:attribute`` when the attribute is named otherwise)."""
_SUBMODULES = ("render",)
"""Modules whose name is also a function's: ``dfc.render`` is always the module (its ``render`` function is
``dfc.render_model``), whether or not it has been imported yet."""

__all__ = [
    "Curves",
    "SideValues",
    "Mesh",
    "triangulate",
    "DfcError",
    "CurveError",
    "MeshError",
    "InputError",
    "FormatError",
    "SettingsError",
    *_LAZY,
]


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    if name in _LAZY:
        module, _, attribute = _LAZY[name].partition(":")
        return getattr(importlib.import_module(module), attribute or name)
    raise AttributeError(f"module 'dfc' has no attribute {name!r}")
