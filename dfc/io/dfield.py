"""``FieldModel`` ↔ ``.dfield``: the contents a fitted model writes (``to_contents``) and the model a file describes
(``from_contents``, ``load``, ``loads``). The byte layout itself is ``dfc.io.container``'s."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import torch
from torch.nn.utils import parametrize

from .. import __version__
from ..errors import FormatError
from ..field.model import FieldModel
from ..field.quantize import FakeQuantizeWeights
from ..field.residual import ResidualGrid
from ..field.units import ValueMap
from ..settings import EncodeSettings
from .container import DfieldContents, decode_dfield, encode_dfield, read_dfield
from .residual import decode_residual, payload_head

__all__ = ["encode_model", "encoder_info", "from_contents", "load", "loads", "storage", "to_contents"]

_ARCH_KEYS = ("dim", "hidden", "layers", "activation", "oneblob_bins")


def to_contents(model: FieldModel, encoder: dict | None = None, *, pixel_size: tuple[float, float] | None = None,
                value_map=None, pixel_filter: str | None = None) -> DfieldContents:
    """The ``.dfield`` contents of a fitted ``FieldModel`` (quantised values when its quantised mode is on).

    encoder : free-form provenance stored in the header's ``encoder`` object (never needed to decode)
    pixel_size : (width, height) in domain units of a pixel of the raster the model was fitted to (header
        ``pixel_size``: decoders anti-alias at or below that resolution); None for other inputs
    pixel_filter : spec string of the filter that made that raster's pixels (header ``pixel_filter``,
        ``dfc.pixel_filter``); None: not stored
    value_map : the ``dfc.field.units.ValueMap`` to store (default ``model.value_map``): the header's
        ``value_transform`` is then "affine" with its ``value_offset`` and ``value_scale`` (identity models only)
    """
    config = model.config()
    value_map = value_map if value_map is not None else model.value_map
    if value_map is not None and config["transform"] != "identity":
        raise ValueError(f"a value map needs the identity transform, the model has {config['transform']!r}")
    header = {
        "domain": [float(v) for v in model.field.mesh.domain],
        "channels": list(config["channels"]),
        "value_transform": config["transform"] if value_map is None else "affine",
        **({} if value_map is None else value_map.header()),
        "times": config["times"],
        "model": {k: config[k] for k in _ARCH_KEYS},
        "encoder": dict(encoder or {}),
    }
    if pixel_size is not None:
        header["pixel_size"] = [float(v) for v in pixel_size]
    if pixel_filter is not None:
        header["pixel_filter"] = str(pixel_filter)
    with torch.no_grad():
        features = model.field.bank.detach().cpu().numpy().astype(np.float32)
        mlp = {}
        for i, lin in enumerate(model.decoder.linears()):
            mlp[f"layers.{i}.weight"] = _stored(lin, "weight")
            mlp[f"layers.{i}.bias"] = _stored(lin, "bias")
    return DfieldContents(header=header, mesh=model.field.mesh, features=features, mlp=mlp,
                          residual=None if model.residual is None else model.residual.payload)


def _stored(module, name: str) -> np.ndarray:
    """The float32 array a writer quantises for ``module.<name>``: the raw tensor under an integer weight
    quantiser (re-quantising its dequantised values need not reproduce them), else the value it reads as."""
    if parametrize.is_parametrized(module, name) and isinstance(module.parametrizations[name][0], FakeQuantizeWeights):
        tensor = module.parametrizations[name].original
    else:
        tensor = getattr(module, name)
    return tensor.detach().cpu().numpy().astype(np.float32)


def from_contents(contents: DfieldContents, *, device: str = "cpu") -> FieldModel:
    """Rebuild the ``FieldModel`` a file describes. Raises ``FormatError`` when the header's model does
    not match the stored features or weights."""
    h = contents.header
    arch = h["model"]
    missing = [k for k in _ARCH_KEYS if k not in arch]
    if missing:
        raise FormatError(f"header: model lacks {missing}")
    affine = h["value_transform"] == "affine"
    config = {**{k: arch[k] for k in _ARCH_KEYS}, "transform": "identity" if affine else h["value_transform"],
              "channels": h["channels"], "n_slices": int(contents.features.shape[0]), "times": h["times"]}
    model = FieldModel.from_config(contents.mesh, config, device=device)
    if affine:
        model.value_map = ValueMap(np.array(h["value_offset"], np.float64), np.array(h["value_scale"], np.float64))
    with torch.no_grad():
        bank = torch.from_numpy(np.ascontiguousarray(contents.features))
        if tuple(bank.shape) != tuple(model.field.bank.shape):
            raise FormatError(f"FEAT: bank shape {tuple(bank.shape)}, the model needs {tuple(model.field.bank.shape)}")
        model.field.bank.copy_(bank)
        linears = model.decoder.linears()
        expected = {f"layers.{i}.{p}" for i in range(len(linears)) for p in ("weight", "bias")}
        if set(contents.mlp) != expected:
            raise FormatError(f"MLPW: tensors {sorted(contents.mlp)}, the model needs {sorted(expected)}")
        for i, lin in enumerate(linears):
            for p in ("weight", "bias"):
                w = torch.from_numpy(contents.mlp[f"layers.{i}.{p}"])
                target = getattr(lin, p)
                if tuple(w.shape) != tuple(target.shape):
                    raise FormatError(f"MLPW: layers.{i}.{p} has shape {tuple(w.shape)}, expected {tuple(target.shape)}")
                target.copy_(w)
    if contents.residual is not None:
        model.residual = _residual_grid(contents.residual, h["domain"], len(h["channels"]))
    model.header = h
    model.eval()
    return model


def _residual_grid(payload: bytes, domain, channels: int) -> ResidualGrid:
    """The ``ResidualGrid`` of an ``rESD`` payload over ``domain`` for ``channels`` channels; FormatError when the
    payload is damaged or has another number of channels."""
    values = decode_residual(payload)
    if values.shape[2] != channels:
        raise FormatError(f"rESD: {values.shape[2]} channels, the header has {channels}")
    return ResidualGrid(values, domain, payload, payload_head(payload)["space"])


def loads(blob: bytes, *, device: str = "cpu", validate_mesh: bool = True) -> FieldModel:
    """``FieldModel`` from the bytes of a ``.dfield`` file (fully checked; ``FormatError`` if damaged).
    ``validate_mesh=False``: bytes an encoder just wrote from a validated mesh (``decode_dfield``)."""
    return from_contents(decode_dfield(blob, validate_mesh=validate_mesh), device=device)


def load(path: str | Path, *, device: str = "cpu") -> FieldModel:
    """``FieldModel`` from a ``.dfield`` file: ``model(xy)``, ``model.features(xy)``, ``model.render(w, h)``."""
    return from_contents(read_dfield(path), device=device)


def storage(settings, model=None) -> dict:
    """``dfc.io.container.encode_dfield``'s keyword arguments for ``settings`` (an ``EncodeSettings``); the feature
    bits are ``model``'s quantisation-aware bits when it has them (``FieldModel.quantization``: a fit stores its
    features at the bits it was fitted for), else the settings'."""
    bits = (getattr(model, "quantization", None) or {}).get("feature_bits", settings.feature_bits)
    return {"feature_bits": bits, "feature_coding": settings.feature_coding,
            "weight_bits": settings.weight_bits, "mesh_coding": settings.mesh_coding}


def encode_model(model, settings, info: dict | None = None, pixel_size=None, value_map: ValueMap | None = None,
                 pixel_filter: str | None = None) -> tuple[bytes, dict[str, int]]:
    """(``.dfield`` bytes, bytes per chunk) of ``model`` written with ``storage(settings, model)``, the header's
    ``encoder`` record ``info``, ``pixel_size``, ``value_map`` (a model fitted in normalised units,
    ``dfc.field.units``) and ``pixel_filter``. The mesh was validated once, when rate control built it
    (``dfc.rate.build_mesh``), and its bytes decode to it exactly: it is not validated again."""
    return encode_dfield(to_contents(model, info, pixel_size=pixel_size, value_map=value_map,
                                     pixel_filter=pixel_filter), mesh_validated=True, **storage(settings, model))


def encoder_info(settings, source: str, extra: dict) -> dict:
    """The header's ``encoder`` record: software, curves source, the settings (a dataclass whose fields all have
    defaults) that differ from their defaults — the others are the named software version's — and ``extra``.

    Every setting written out took 456 of the 2 KB of a small file (the zstd-compressed header JSON); the settings
    that differ keep the record complete at about a third of that."""
    def named(s) -> dict:
        return s.to_dict() if isinstance(s, EncodeSettings) else {f.name: getattr(s, f.name) for f in fields(s)}

    defaults = named(type(settings)())
    changed = {name: value for name, value in named(settings).items() if value != defaults[name]}
    return {"software": f"dfc {__version__}", "source": source, **changed, **extra}
