"""Uniform quantisation of feature banks, integer quantisation of MLP weight matrices and fp16 rounding of the
other MLP parameters.

The same functions serve the writer (``quantize_features``, ``quantize_weights``), the reader
(``dequantize_features``, ``dequantize_weights``) and quantisation-aware fine-tuning (``fake_quantize``,
``fake_quantize_weights``, ``fake_fp16``, with straight-through gradients), so the values the encoder measures
are exactly those the decoder reconstructs.

Features are quantised per feature channel: for channel k, ``offset[k] = min``, ``scale[k] =
(max - min) / (2**bits - 1)`` over all rows (and time slices), ``q = round((F - offset) / scale)``,
and ``F' = offset + q * scale`` computed in float32.

Weight matrices W (out, in) are quantised symmetrically per output row: ``scale[o]`` is ``max |W[o]| /
(2**(bits-1) - 1)`` rounded up to float16 (so no weight is clipped), at least the smallest normal float16 (2**-14:
at 15 and 16 bits a row of weights below 1 or 2 would otherwise get a subnormal scale) and 1 for an all-zero or
non-finite row,
``q = round(W / scale)`` (half to even) clamped to ``[-(2**(bits-1) - 1), 2**(bits-1) - 1]`` and ``W' = q * scale``,
all in float32 torch arithmetic on the tensor's own device (IEEE division and product, so CPU and GPU agree bit for
bit).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

MAX_FEATURE_BITS = 16
DEFAULT_FEATURE_BITS = 10
"""Bits per stored feature value unless told otherwise (``--feature-bits``; 1 … ``MAX_FEATURE_BITS``). Why 10:
CHANGELOG.md, "10-bit features"; the measurements: docs/results.md, "10-bit features"."""
MIN_WEIGHT_BITS, MAX_WEIGHT_BITS = 2, 16
OUTLIER_QUANTILE = 0.01
"""``clip_feature_outliers`` keeps each channel within its ``OUTLIER_QUANTILE`` … ``1 - OUTLIER_QUANTILE`` quantiles,
widened by ``OUTLIER_MARGIN`` of their distance on each side."""
OUTLIER_MARGIN = 0.25


def feature_ranges(F: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel (scale, offset), each (K,) float32, for features F (..., K)."""
    if not 1 <= bits <= MAX_FEATURE_BITS:
        raise ValueError(f"feature bits must be in 1..{MAX_FEATURE_BITS}, got {bits}")
    F = np.asarray(F, dtype=np.float32).reshape(-1, F.shape[-1])
    lo = F.min(axis=0) if len(F) else np.zeros(F.shape[-1], np.float32)
    hi = F.max(axis=0) if len(F) else np.zeros(F.shape[-1], np.float32)
    scale = ((hi - lo) / np.float32(2**bits - 1)).astype(np.float32)
    scale[scale <= 0] = np.float32(1.0)  # constant channel: any positive scale reproduces it
    return scale, lo.astype(np.float32)


def quantize_features(F: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F (..., K) float -> (q (..., K) uint8/uint16, scale (K,) float32, offset (K,) float32)."""
    scale, offset = feature_ranges(F, bits)
    q = np.rint((np.asarray(F, np.float32) - offset) / scale)
    q = np.clip(q, 0, 2**bits - 1)
    return q.astype(np.uint8 if bits <= 8 else np.uint16), scale, offset


def dequantize_features(q: np.ndarray, scale: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Inverse of ``quantize_features``: (..., K) integers -> (..., K) float32."""
    return (offset.astype(np.float32) + q.astype(np.float32) * scale.astype(np.float32)).astype(np.float32)


def fake_quantize(F: torch.Tensor, bits: int) -> torch.Tensor:
    """Quantise-dequantise ``F`` (..., K) exactly as the file will, with a straight-through gradient. Computed on
    ``F``'s device (no host round trip): the ranges are ``feature_ranges``' float32 arithmetic in torch."""
    if not 1 <= bits <= MAX_FEATURE_BITS:
        raise ValueError(f"feature bits must be in 1..{MAX_FEATURE_BITS}, got {bits}")
    flat = F.detach().float().reshape(-1, F.shape[-1])
    if len(flat):
        lo, hi = flat.amin(dim=0), flat.amax(dim=0)
    else:
        lo = hi = flat.new_zeros(F.shape[-1])
    scale_t = (hi - lo) / torch.tensor(2**bits - 1, dtype=torch.float32, device=F.device)
    scale_t = torch.where(scale_t > 0, scale_t, torch.ones_like(scale_t))  # constant channel: any positive scale
    offset_t = lo
    q = torch.clamp(torch.round((F.detach().float() - offset_t) / scale_t), 0, 2**bits - 1)
    Fq = (offset_t + q * scale_t).to(F.dtype)
    return F + (Fq - F).detach()


def clip_feature_outliers(F: torch.Tensor) -> None:
    """Clamp the features ``F`` (..., K) in place, per channel, to the ``OUTLIER_QUANTILE`` quantiles (order
    statistics, no interpolation) widened by ``OUTLIER_MARGIN``. Run before quantisation-aware steps: the quantiser's
    range is each channel's min … max, and a few features far outside the rest (rows that almost no sample reaches
    drift under Adam) would otherwise take most of its levels, leaving the bulk of the features a handful
    (CHANGELOG.md, "Feature outliers")."""
    with torch.no_grad():
        flat = F.detach().reshape(-1, F.shape[-1])
        n = len(flat)
        if n < 2:
            return
        ordered = flat.sort(dim=0).values
        lo, hi = ordered[int(OUTLIER_QUANTILE * (n - 1))], ordered[math.ceil((1 - OUTLIER_QUANTILE) * (n - 1))]
        width = hi - lo
        F.copy_(torch.maximum(torch.minimum(F, hi + OUTLIER_MARGIN * width), lo - OUTLIER_MARGIN * width))


def fake_fp16(W: torch.Tensor) -> torch.Tensor:
    """Round a weight tensor through float16 as the file stores it, straight-through gradient."""
    return W + (W.detach().half().float().to(W.dtype) - W).detach()


class FakeQuantize(nn.Module):
    """``torch.nn.utils.parametrize`` parametrisation: a tensor reads as ``fake_quantize(X, bits)``."""

    def __init__(self, bits: int):
        super().__init__()
        self.bits = bits

    def forward(self, X: torch.Tensor) -> torch.Tensor:
        return fake_quantize(X, self.bits)


class FakeFp16(nn.Module):
    """``torch.nn.utils.parametrize`` parametrisation: a tensor reads as its float16 rounding (``fake_fp16``)."""

    def forward(self, X: torch.Tensor) -> torch.Tensor:
        return fake_fp16(X)


def check_weight_bits(bits) -> int:
    """``bits`` when it is an integer in ``MIN_WEIGHT_BITS .. MAX_WEIGHT_BITS``, else ValueError."""
    if not (isinstance(bits, int) and not isinstance(bits, bool) and MIN_WEIGHT_BITS <= bits <= MAX_WEIGHT_BITS):
        raise ValueError(f"weight bits must be an integer in {MIN_WEIGHT_BITS}..{MAX_WEIGHT_BITS}, got {bits!r}")
    return bits


def weight_scales(W: torch.Tensor, bits: int) -> torch.Tensor:
    """Per-row scales (out,) float32 (each a float16 value) of a weight matrix W (out, in), on W's device."""
    top = float(2 ** (check_weight_bits(bits) - 1) - 1)
    amax = W.detach().float().abs().amax(dim=1)
    exact = amax / top
    half = exact.half()
    half = torch.where(half.float() < exact, torch.nextafter(half, torch.full_like(half, float("inf"))), half)
    scale = half.float().clamp_min(torch.finfo(torch.float16).tiny)  # rounded up: |W| / scale ≤ top
    return torch.where((amax > 0) & torch.isfinite(scale), scale, torch.ones_like(scale))


def quantize_weights(W: torch.Tensor, bits: int) -> tuple[torch.Tensor, torch.Tensor]:
    """W (out, in) float -> (q (out, in) int32, scale (out,) float32), on W's device."""
    scale = weight_scales(W, bits)
    top = 2 ** (bits - 1) - 1
    q = torch.clamp(torch.round(W.detach().float() / scale[:, None]), -top, top)
    return q.to(torch.int32), scale


def dequantize_weights(q: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Inverse of ``quantize_weights``: (out, in) float32 ``q * scale`` per row."""
    return q.float() * scale.float()[:, None]


def fake_quantize_weights(W: torch.Tensor, bits: int) -> torch.Tensor:
    """W (out, in) quantised and dequantised exactly as the file stores it, with a straight-through gradient."""
    q, scale = quantize_weights(W, bits)
    return W + (dequantize_weights(q, scale).to(W.dtype) - W).detach()


class FakeQuantizeWeights(nn.Module):
    """``torch.nn.utils.parametrize`` parametrisation: a weight matrix reads as ``fake_quantize_weights(X, bits)``."""

    def __init__(self, bits: int):
        super().__init__()
        self.bits = check_weight_bits(bits)

    def forward(self, X: torch.Tensor) -> torch.Tensor:
        return fake_quantize_weights(X, self.bits)
