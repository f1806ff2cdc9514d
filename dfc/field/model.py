"""A complete field model: feature field on a mesh → (optional one-blob of x) → MLP → signal.

``FieldModel`` is what gets fitted, written to a ``.dfield`` and rendered. Its ``config()`` holds
every hyperparameter needed to rebuild it around a mesh; weights and features come from the file.

Value transform. ``transform="identity"`` decodes the signal directly. ``transform="log"`` is for
HDR signals: the MLP output ``y`` stands for ``log(1 + v)`` and the model returns ``v = exp(y) - 1``
(so values are > -1). Losses are always computed on the returned signal values.

Units. ``model.value_map`` (None, or a ``dfc.field.units.ValueMap``) maps the network's output to the data's
units: ``offset + scale · y``, returned as float64 (an offset of 1e6 with a variation of 1e-3 does not fit float32).
Fits run without it, on values normalised by it (``dfc.codec``); a file's ``value_transform: "affine"`` sets it.

Quantised mode (quantisation-aware fine-tuning). Setting ``model.quantization =
{"feature_bits": 8}`` registers ``torch.nn.utils.parametrize`` parametrisations, so that
``field.bank`` reads as ``fake_quantize(bank, 8)`` and every decoder weight and bias reads as
``fake_fp16(W)``; with ``"weight_bits": b`` as well, the weight matrices read as
``fake_quantize_weights(W, b)`` (b-bit integers per row) and stop training (``requires_grad`` off until the mode is
switched off: moving weights across quantisation steps makes the output jump, so the features and biases adapt to
fixed integer weights instead), the biases staying fp16 — exactly the values a ``.dfield`` file stores — with
straight-through gradients
into the same underlying Parameters (an optimiser built before keeps working). ``None`` removes
them and leaves the raw float32 values. While it is on, ``state_dict()`` keys change (the raw tensors
sit under ``…parametrizations.<name>.original``): writers should read ``field.bank`` and the
decoder's ``linears()`` attributes, which give the quantised values (integer weight matrices: the raw tensor, which
the writer quantises exactly as the forward does, ``dfc.io.dfield.to_contents``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.utils import parametrize
from torch.profiler import record_function

from ..errors import DfcError, FormatError
from .feature_field import PackedQuery, packed_rows, weighted_rows
from .mlp import ACTIVATIONS, MLP, OneBlob
from .quantize import MAX_FEATURE_BITS, FakeFp16, FakeQuantize, FakeQuantizeWeights, check_weight_bits

__all__ = ["DECODE", "INTERPOLATE", "TRANSFORMS", "FieldModel"]

TRANSFORMS = ("identity", "log")
INTERPOLATE, DECODE = "dfc.interpolate", "dfc.decode"
"""``torch.profiler`` labels of the forward pass's parts: the features at the points (point location included when
no precomputed query is given) and the decoder (``dfc benchmark encode``)."""
_CONFIG_KEYS = ("dim", "hidden", "layers", "activation", "oneblob_bins", "transform", "channels", "n_slices", "times")


class FieldModel(nn.Module):
    """Signal model ``f(x, t) = T⁻¹(MLP([F(x, t), oneblob(x)]))``.

    Parameters
    ----------
    field : module with ``.bank`` (S, n_features, dim) Parameter, ``.dim``, ``.mesh`` and
        ``.features(xy (N, 2), t=None) -> (N, dim)`` (``dfc.field.feature_field.FeatureField``)
    out_channels : list of channel names; the output width is their count
    hidden, layers, activation : the MLP (see ``dfc.field.mlp.MLP``)
    oneblob_bins : 0 for none, else the one-blob encoding of x with this many bins per axis,
        concatenated to the features (the paper's rendering setting)
    transform : {"identity", "log"} value transform, see the module notes
    seed : seeds the decoder's initialisation (the field seeds its own features)
    """

    def __init__(
        self,
        field: nn.Module,
        out_channels: list[str],
        *,
        hidden: int = 64,
        layers: int = 2,
        activation: str = "relu",
        oneblob_bins: int = 0,
        transform: str = "identity",
        seed: int = 0,
    ):
        super().__init__()
        channels = [str(c) for c in out_channels]
        if not channels or len(set(channels)) != len(channels):
            raise ValueError(f"out_channels must be non-empty and unique, got {out_channels!r}")
        if transform not in TRANSFORMS:
            raise ValueError(f"transform must be one of {TRANSFORMS}, got {transform!r}")
        if not isinstance(oneblob_bins, int) or isinstance(oneblob_bins, bool) or oneblob_bins < 0:
            raise ValueError(f"oneblob_bins must be an integer ≥ 0, got {oneblob_bins!r}")
        self.field = field
        self.channels = channels
        self.transform = transform
        self.encoding = OneBlob(oneblob_bins, field.mesh.domain) if oneblob_bins else None
        in_dim = int(field.dim) + (self.encoding.get_out_dim() if self.encoding is not None else 0)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.decoder = MLP(in_dim, len(channels), hidden=hidden, layers=layers, activation=activation)
        self.decoder.mixed_precision = transform == "identity"  # bfloat16 on CUDA costs HDR fits PSNR (MLP notes)
        self.to(field.bank.device)
        self._quantization: dict | None = None
        self.value_map = None
        self.residual = None  # a dfc.field.residual.ResidualGrid added to the values (a file's rESD chunk)

    # -- evaluation ---------------------------------------------------------------------------
    def features(self, xy: Tensor, t=None) -> Tensor:
        """Interpolated features (N, dim) at positions xy (N, 2) (and time t, if the field has a time axis)."""
        return self.field.features(xy, t)

    def forward(self, xy: Tensor, t=None, *, query: tuple[Tensor, Tensor] | PackedQuery | None = None) -> Tensor:
        """Signal values (N, C) float32 at positions xy (N, 2) in domain units (float64 with a ``value_map``), the
        ``residual`` grid's values added when there is one.

        ``query`` : optional ``self.field.query(xy)`` computed beforehand — rows idx (N, k) int64 and
        weights w (N, k) float32 of the bank's single slice, or its ``PackedQuery`` — so that training can reuse
        point location across steps; only for fields with one time slice.
        """
        if self._quantization is not None:  # evaluate each fake-quantised tensor once per call
            with parametrize.cached():
                out = self._forward(xy, t, query)
        else:
            out = self._forward(xy, t, query)
        return out if self.residual is None else self.residual.add(out, xy)

    def _forward(self, xy: Tensor, t, query) -> Tensor:
        with record_function(INTERPOLATE):
            if query is None:
                F = self.features(xy, t)
            elif self.field.bank.shape[0] != 1:
                raise ValueError("a precomputed query needs a field with a single time slice")
            elif isinstance(query, PackedQuery):
                F = packed_rows(self.field.bank[0], query)
            else:
                idx, w = query
                F = weighted_rows(self.field.bank[0], idx, w)
            F = F.to(torch.float32)
        with record_function(DECODE):
            return self.decode(F, xy)

    def decode(self, F: Tensor, xy: Tensor | None = None) -> Tensor:
        """Signal values (N, C) of features F (N, dim) float32 (at positions xy (N, 2), needed only with a one-blob
        encoding): the decoder and the value transform or ``value_map``, without the residual."""
        if self.encoding is not None:
            if xy is None:
                raise ValueError("decoding features with a one-blob encoding needs their positions")
            F = torch.cat([F, self.encoding(xy)], dim=1)
        y = self.decoder(F)
        if self.value_map is not None:
            return self.value_map.apply(y)
        return torch.expm1(y) if self.transform == "log" else y

    def render(self, width: int, height: int, window=None, *, spp: int = 1, t=None, edge_spp: int = 0):
        """Raster (height, width, C) float32 of ``window`` (x0, y0, x1, y1; default the domain), see ``dfc.render``."""
        from ..render import render

        return render(self, width, height, window, spp=spp, t=t, edge_spp=edge_spp)

    # -- quantisation-aware mode --------------------------------------------------------------
    @property
    def quantization(self) -> dict | None:
        """None, or ``{"feature_bits": b[, "weight_bits": w]}``: forward sees features quantised to b bits, weight
        matrices as w-bit integers per row (fp16 without ``weight_bits`` or with None) and fp16 biases."""
        return None if self._quantization is None else dict(self._quantization)

    @quantization.setter
    def quantization(self, value: dict | None) -> None:
        if value is not None:
            ok = isinstance(value, dict) and "feature_bits" in value and set(value) <= {"feature_bits", "weight_bits"}
            bits = value["feature_bits"] if ok else None
            if not (isinstance(bits, int) and 1 <= bits <= MAX_FEATURE_BITS):
                raise ValueError(f"quantization must be None or {{'feature_bits': 1..{MAX_FEATURE_BITS}"
                                 f"[, 'weight_bits': None or an integer]}}, got {value!r}")
            if value.get("weight_bits") is not None:
                check_weight_bits(value["weight_bits"])
        if self._quantization is not None:
            parametrize.remove_parametrizations(self.field, "bank", leave_parametrized=False)
            for lin in self.decoder.linears():
                for name in ("weight", "bias"):
                    parametrize.remove_parametrizations(lin, name, leave_parametrized=False)
                lin.weight.requires_grad_(True)
        self._quantization = None
        if value is not None:
            weight_bits = value.get("weight_bits")
            parametrize.register_parametrization(self.field, "bank", FakeQuantize(value["feature_bits"]))
            for lin in self.decoder.linears():
                weights = FakeFp16() if weight_bits is None else FakeQuantizeWeights(weight_bits)
                parametrize.register_parametrization(lin, "weight", weights)
                parametrize.register_parametrization(lin, "bias", FakeFp16())
            self._quantization = {"feature_bits": value["feature_bits"]}
            if weight_bits is not None:
                self._quantization["weight_bits"] = weight_bits
            for lin in self.decoder.linears():  # integer weights stay as they were quantised: features adapt
                lin.parametrizations["weight"].original.requires_grad_(weight_bits is None)

    # -- serialisation ------------------------------------------------------------------------
    def config(self) -> dict:
        """JSON-able hyperparameters: with a mesh, enough to rebuild the model (``from_config``)."""
        times = getattr(self.field, "times", None)
        if isinstance(times, Tensor):
            times = times.tolist()
        return {
            "dim": int(self.field.dim),
            "hidden": self.decoder.hidden,
            "layers": self.decoder.layers,
            "activation": self.decoder.activation,
            "oneblob_bins": self.encoding.bins if self.encoding is not None else 0,
            "transform": self.transform,
            "channels": list(self.channels),
            "n_slices": int(self.field.bank.shape[0]),
            "times": None if times is None else [float(v) for v in times],
        }

    @classmethod
    def from_config(cls, mesh, config: dict, *, device: str = "cpu") -> FieldModel:
        """Rebuild an (untrained) model of the given shape around ``mesh``.

        Raises ``FormatError`` when the config is incomplete or inconsistent (it usually comes from a file).
        """
        from .feature_field import FeatureField

        if not isinstance(config, dict) or set(config) != set(_CONFIG_KEYS):
            got = sorted(config) if isinstance(config, dict) else type(config).__name__
            raise FormatError(f"model config must have exactly the keys {sorted(_CONFIG_KEYS)}, got {got}")
        if config["activation"] not in ACTIVATIONS or config["transform"] not in TRANSFORMS:
            raise FormatError(
                f"model config: unknown activation {config['activation']!r} or transform {config['transform']!r}"
            )
        try:
            field = FeatureField(
                mesh, dim=int(config["dim"]), n_slices=int(config["n_slices"]), times=config["times"], device=device
            )
            return cls(
                field,
                list(config["channels"]),
                hidden=int(config["hidden"]),
                layers=int(config["layers"]),
                activation=config["activation"],
                oneblob_bins=int(config["oneblob_bins"]),
                transform=config["transform"],
            )
        except (TypeError, ValueError) as e:
            if isinstance(e, DfcError):
                raise
            raise FormatError(f"model config is inconsistent: {e}") from e
