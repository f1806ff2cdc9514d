"""A stored raster evaluated anywhere by an interpolation kernel: how a decoded image (the raster baseline, a
classical codec's output) is shown at zoom.

Pixel (i, j) of a ``w × h`` raster over the domain is centred at ``x0 + (i + 0.5)(x1 − x0) / w`` (spec/conventions.md);
beyond the outermost centres the border pixels repeat. Kernels (``KERNELS``):

- ``bicubic``: Keys' cubic convolution with a = −0.75 (``torch.nn.functional.grid_sample``, 4 × 4 taps);
- ``lanczos``: the Lanczos window of ``LANCZOS_LOBES`` lobes, ``sinc(t) sinc(t / a)`` for |t| < a, separable,
  2a × 2a taps, weights normalised to sum 1 per axis.

Both reproduce the stored pixel at its centre.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import Tensor

from .base import Baseline
from .relu_field import grid_coords

__all__ = ["KERNELS", "LANCZOS_LOBES", "PixelImage"]

KERNELS = ("bicubic", "lanczos")
LANCZOS_LOBES = 3
"""a of the Lanczos kernel (Lanczos-3)."""


class PixelImage(Baseline):
    """Raster ``xy (N, 2) domain units -> (N, C) float32`` through ``kernel``; no trainable parameters.

    Parameters
    ----------
    pixels : (h, w, C) float array covering ``domain``
    domain, channels : as every baseline
    n_bytes : its stored size in bytes (what the method's file takes)
    kernel : one of ``KERNELS``
    device : torch device
    """

    name = "pixels"

    def __init__(self, pixels: np.ndarray, domain, channels, *, n_bytes: int, kernel: str = "bicubic",
                 device: str = "cpu"):
        super().__init__(domain, channels)
        pixels = np.asarray(pixels, dtype=np.float32)
        if pixels.ndim != 3 or pixels.shape[2] != len(self.channels):
            raise ValueError(f"pixels must be (h, w, {len(self.channels)}), got {pixels.shape}")
        if kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
        self.kernel = kernel
        self.n_bytes = int(n_bytes)
        self.register_buffer("image", torch.from_numpy(pixels).permute(2, 0, 1)[None].contiguous().to(device))

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the stored raster."""
        return int(self.image.shape[3]), int(self.image.shape[2])

    def pixels(self) -> np.ndarray:
        """The stored raster (h, w, C) float32."""
        return self.image[0].permute(1, 2, 0).cpu().numpy()

    def with_kernel(self, kernel: str) -> PixelImage:
        """The same raster and size evaluated through ``kernel``."""
        return PixelImage(self.pixels(), self.domain, self.channels, n_bytes=self.n_bytes, kernel=kernel,
                          device=self.image.device)

    def stored_bytes(self) -> int:
        return self.n_bytes

    def describe(self) -> dict:
        return {"class": type(self).__name__, "raster": list(self.size), "kernel": self.kernel}

    def forward(self, xy: Tensor) -> Tensor:
        if self.kernel == "bicubic":
            return nnf.grid_sample(self.image, grid_coords(xy, self.domain), mode="bicubic", padding_mode="border",
                                   align_corners=False)[0, :, 0].T
        return self._lanczos(xy)

    def _lanczos(self, xy: Tensor) -> Tensor:
        x0, y0, x1, y1 = self.domain
        w, h = self.size
        a = LANCZOS_LOBES
        u = (xy[:, 0].to(torch.float64) - x0) * (w / (x1 - x0)) - 0.5  # continuous column index, centres integral
        v = (xy[:, 1].to(torch.float64) - y0) * (h / (y1 - y0)) - 0.5
        taps = torch.arange(-a + 1, a + 1, device=xy.device)

        def axis(t: Tensor, n: int) -> tuple[Tensor, Tensor]:
            base = torch.floor(t)
            idx = base[:, None].to(torch.int64) + taps  # (N, 2a)
            d = t[:, None] - idx
            wts = torch.where(d.abs() < a, torch.sinc(d) * torch.sinc(d / a), torch.zeros_like(d))
            wts = wts / wts.sum(dim=1, keepdim=True)
            return idx.clamp(0, n - 1), wts.to(torch.float32)

        ix, wx = axis(u, w)
        iy, wy = axis(v, h)
        img = self.image[0]  # (C, h, w)
        vals = img[:, iy[:, :, None], ix[:, None, :]]  # (C, N, 2a, 2a)
        return torch.einsum("cnji,nj,ni->nc", vals, wy, wx)
