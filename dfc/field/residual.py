"""A residual raster added to the field (spec/field.md §7.1): values on the pixel centres of a W × H grid
over the domain, interpolated bilinearly, constant beyond the outer centres. Continuous, so the field's jumps stay
where the curves are."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

__all__ = ["ResidualGrid", "TONE_LIMIT", "tone_map"]

TONE_LIMIT = 1 - 2.0**-24
"""The tone-mapped sum is clamped to ±this before the inverse tone map ``t / (1 − |t|)`` (spec/field.md §7.1)."""


def tone_map(values):
    """``v / (1 + |v|)`` elementwise (a numpy array or a tensor): the space an HDR residual adds in."""
    return values / (1 + abs(values))


class ResidualGrid(nn.Module):
    """``values`` (H, W, C) float32 on the pixel centres of ``domain`` (x0, y0, x1, y1) cut into W × H pixels;
    ``payload``: the ``rESD`` bytes they were decoded from (written back unchanged); ``space``: "values" (added to
    the field's values) or "tonemapped" (added to their tone map ``v / (1 + |v|)``, ``add``)."""

    def __init__(self, values: np.ndarray, domain, payload: bytes, space: str = "values"):
        super().__init__()
        if space not in ("values", "tonemapped"):
            raise ValueError(f"space must be 'values' or 'tonemapped', got {space!r}")
        self.space = space
        self.register_buffer("values", torch.from_numpy(np.ascontiguousarray(values, dtype=np.float32)),
                             persistent=False)
        self.domain = tuple(float(v) for v in domain)
        self.payload = bytes(payload)

    def forward(self, xy: Tensor) -> Tensor:
        """(N, C) float64 residual at positions xy (N, 2) in domain units."""
        h, w = self.values.shape[:2]
        x0, y0, x1, y1 = self.domain
        u = ((xy[:, 0].double() - x0) * (w / (x1 - x0)) - 0.5).clamp(0, w - 1)
        v = ((xy[:, 1].double() - y0) * (h / (y1 - y0)) - 0.5).clamp(0, h - 1)
        i0, j0 = u.floor().long(), v.floor().long()
        i1, j1 = (i0 + 1).clamp(max=w - 1), (j0 + 1).clamp(max=h - 1)
        fu, fv = (u - i0)[:, None], (v - j0)[:, None]
        g = self.values.to(xy.device)

        def at(j, i):  # the grid's float32 values at the N corners, widened exactly
            return g[j, i].double()

        top = at(j0, i0) * (1 - fu) + at(j0, i1) * fu
        bottom = at(j1, i0) * (1 - fu) + at(j1, i1) * fu
        return top * (1 - fv) + bottom * fv

    def add(self, values: Tensor, xy: Tensor) -> Tensor:
        """``values`` (N, C) of the field at xy (N, 2) with the residual added in its space (same dtype)."""
        r = self(xy)
        if self.space == "values":
            return values + r.to(values.dtype)
        t = (tone_map(values.double()) + r).clamp(-TONE_LIMIT, TONE_LIMIT)
        return (t / (1 - t.abs())).to(values.dtype)
