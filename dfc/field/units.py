"""Value normalisation: the units a field is fitted in, chosen from the data, and how a file maps them back.

A fit works on values ``(v − offset[c]) / scale`` (per channel ``c``), which span [0, 1] whatever units the data
came in (pascals, 1e-9 concentrations, 16-bit counts, 1e6 millikelvin): the decoder's output bias, the learning
rates, the optimiser's epsilon, the quantisation of features and weights (float16 biases included) and the loss
then see the same numbers for the same signal in any unit, and the file stores ``offset`` and ``scale`` in its
header (``value_transform: "affine"``, ``spec/dfield.md`` §5) so that a decoder returns ``offset + scale · y`` for
the network's output ``y``, in binary64. HDR light (``dfc.metrics.is_hdr``) is fitted in log space on its own
values instead: its unit is not arbitrary (1 is the tone map's white).

Offsets are the channels' minima and the scale is the span over all channels (one scale keeps the channels'
relative weight in the loss, which is that of the PSNR's data range), each rounded to a short decimal so that the
header stays small: the scale up to ``SCALE_DIGITS`` significant digits, the offset to ``OFFSET_DIGITS`` digits
below the span's leading one; both round outwards so the normalised values stay within [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = ["CONSTANT_SCALE", "FLOAT32_LEVELS", "ValueMap", "choose", "describe"]

SCALE_DIGITS = 6
"""Significant decimal digits of a stored scale."""
OFFSET_DIGITS = 4
"""Decimal digits of a stored offset below the leading digit of the span: an offset within 1e-4 of the span."""
CONSTANT_SCALE = 2.0**-60
"""``choose``: the scale of constant data, relative to its magnitude."""
FLOAT32_LEVELS = 1 << 16
"""``describe`` warns when float32 input resolves fewer than this many levels across the data's span (a huge offset
on a small variation: its values were rounded before dfc saw them)."""


@dataclass(frozen=True)
class ValueMap:
    """value = ``offset[c] + scale[c] · y`` for network output ``y`` of channel ``c``: ``offset``, ``scale`` (C,)
    float64, finite, scale > 0 (``choose`` gives every channel the same scale)."""

    offset: np.ndarray
    scale: np.ndarray

    @property
    def unit(self) -> float:
        """The largest channel scale: a data range divided by it is the range in normalised units."""
        return float(np.max(self.scale))

    def normalise(self, values) -> np.ndarray:
        """(…, C) values → float32 ``(values − offset) / scale``, computed in binary64."""
        return ((np.asarray(values, np.float64) - self.offset) / self.scale).astype(np.float32)

    def apply(self, y: Tensor) -> Tensor:
        """Network output y (N, C) → values (N, C) float64 on y's device: product, then sum."""
        offset = torch.as_tensor(self.offset, dtype=torch.float64, device=y.device)
        scale = torch.as_tensor(self.scale, dtype=torch.float64, device=y.device)
        return y.double() * scale + offset

    def header(self) -> dict:
        """The header keys ``value_offset`` and ``value_scale`` (spec/dfield.md §5)."""
        return {"value_offset": [float(v) for v in self.offset], "value_scale": [float(v) for v in self.scale]}


def _round(x: float, digits: int, up: bool) -> float:
    """``x`` rounded outwards (up or down) to ``digits`` significant decimal digits, as its shortest decimal."""
    if x == 0.0 or not math.isfinite(x):
        return x
    e = math.floor(math.log10(abs(x))) - digits + 1
    q = 10.0**e if e >= 0 else 1.0 / 10.0 ** (-e)
    k = math.ceil(x / q) if up else math.floor(x / q)
    return float(f"{k * q:.{digits + 1}g}")


def choose(lo, hi) -> ValueMap:
    """The map of data whose channels span ``lo`` (C,) … ``hi`` (C,) (float64): offsets ``lo`` rounded down, scale
    the overall span rounded up. A constant signal (span 0, or too small to divide by) gets its exact values as
    offsets and the scale ``CONSTANT_SCALE`` times its magnitude (at least 1): below half a unit in the last place
    of the offset, so the decoded value is the offset bit for bit whatever the network returns below 1."""
    lo, hi = np.asarray(lo, np.float64).ravel(), np.asarray(hi, np.float64).ravel()
    span = float(hi.max() - lo.min())
    magnitude = float(max(np.abs(lo).max(), np.abs(hi).max()))
    if not span > 1e-300 or span <= 4 * np.finfo(np.float64).eps * magnitude:
        return ValueMap(lo.copy(), np.full_like(lo, CONSTANT_SCALE * max(1.0, magnitude)))
    scale = _round(span, SCALE_DIGITS, up=True)
    offset = []
    for v in lo:
        digits = max(1, math.floor(math.log10(abs(v))) - math.floor(math.log10(span)) + OFFSET_DIGITS) if v else 1
        offset.append(min(v, _round(v, digits, up=False)))
    offset = np.array(offset)
    while np.any((hi - offset) / scale > 1.0):  # rounding the offset down may push the top past 1
        scale = _round(scale * (1 + 10.0 ** -SCALE_DIGITS), SCALE_DIGITS, up=True)
    return ValueMap(offset, np.full_like(offset, scale))


def describe(lo: float, hi: float, value_map: ValueMap | None, dtype=np.float32) -> str:
    """One line for an encoder's summary: the data's range and the units the fit used; says so for constant data
    and for data whose span is tiny against its magnitude (``FLOAT32_LEVELS``, input read as ``dtype``)."""
    magnitude = max(abs(lo), abs(hi))
    digits = 6 if hi == lo else max(6, math.ceil(math.log10(max(magnitude, 1e-300) / (hi - lo))) + 4)
    text = f"data range [{lo:.{digits}g}, {hi:.{digits}g}]"
    if value_map is None and lo <= -1.0:  # dfc.train.fit._model_for: log(1 + v) needs v > -1
        return text + "; fitted on its values as HDR light (values ≤ −1: no log space; tone-mapped quality)"
    if value_map is None:
        return text + "; fitted in log space as HDR light (log(1 + v), tone-mapped quality)"
    if hi == lo:
        return text + f": constant data, stored exactly as the decoder's offset {value_map.offset[0]:.17g}"
    text += f" (span {hi - lo:.4g}"
    if hi - lo < 1e-3 * magnitude:
        text += f", {(hi - lo) / magnitude:.2g} of the values' magnitude: a large offset, fitted around it"
    text += f"); fitted as (v − offset) / {value_map.unit:.6g}, offset " + \
        ", ".join(repr(float(v)) for v in value_map.offset)
    resolution = np.finfo(dtype).eps * magnitude
    if (hi - lo) < FLOAT32_LEVELS * resolution:
        text += (f"; the {np.dtype(dtype).name} input resolves only about {round((hi - lo) / resolution)} levels in "
                 "that span (its values were rounded before dfc read them)")
    return text
