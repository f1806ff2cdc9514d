"""Uniform quantisation of feature banks and fp16 rounding of MLP weights.

The same functions serve the writer (``quantize_features``), the reader (``dequantize_features``)
and quantisation-aware fine-tuning (``fake_quantize`` with a straight-through gradient), so the
values the encoder measures are exactly those the decoder reconstructs.

Features are quantised per feature channel: for channel k, ``offset[k] = min``, ``scale[k] =
(max - min) / (2**bits - 1)`` over all rows (and time slices), ``q = round((F - offset) / scale)``,
and ``F' = offset + q * scale`` computed in float32.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

MAX_FEATURE_BITS = 16


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
