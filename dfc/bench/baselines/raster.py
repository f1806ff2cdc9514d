"""The plain raster at equal bytes: the input image, area-averaged down to the largest size whose
losslessly compressed file fits the budget, evaluated anywhere by bicubic interpolation (or Lanczos,
``dfc.bench.baselines.upsample``).

Storage: the byte size of a half-float, ZIP-compressed scanline OpenEXR file of the downsampled image,
header included, as ``dfc.io.image.write_exr`` writes it: lossless, apart from the rounding to half floats.
Evaluation uses the half-float values (what the file decodes to); pixel (i, j) of the ``w × h`` raster is centred
at ``x0 + (i + 0.5)(x1 − x0) / w`` (spec/conventions.md).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from .upsample import PixelImage

__all__ = ["REFINE", "Raster", "area_resize", "exr_bytes"]

REFINE = 0.15
"""``Raster.for_budget`` also tries widths up to this fraction above the binary search's answer."""


def _area_matrix(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) float64: row i averages the input cells overlapping output cell i, by overlap length."""
    edges = np.arange(n_out + 1) * (n_in / n_out)
    lo, hi = edges[:-1, None], edges[1:, None]
    j = np.arange(n_in)[None, :]
    overlap = np.clip(np.minimum(hi, j + 1) - np.maximum(lo, j), 0.0, None)
    return overlap / (n_in / n_out)


def area_resize(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Exact box-filter (area-average) resampling of (H, W, C) to (height, width, C) float32, any ratio."""
    H, W, C = pixels.shape
    ay, ax = _area_matrix(H, height), _area_matrix(W, width)
    out = np.einsum("yh,hwc,xw->yxc", ay, pixels.astype(np.float64), ax, optimize=True)
    return out.astype(np.float32)


def exr_bytes(pixels: np.ndarray, channels: list[str]) -> int:
    """Size in bytes of ``pixels`` (h, w, C) written as a half-float ZIP EXR by ``dfc.io.image.write_exr``."""
    from ...io.image import write_exr

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "raster.exr"
        write_exr(path, pixels, channels, half=True)
        return path.stat().st_size


class Raster(PixelImage):
    """Bicubic-interpolated raster ``xy (N, 2) domain units -> (N, C) float32``; no trainable parameters.

    Parameters
    ----------
    pixels : (h, w, C) float array, the stored raster covering ``domain`` (rounded to float16 here)
    domain, channels : as every baseline
    n_bytes : its stored size (``exr_bytes``); computed when None
    device : torch device
    """

    name = "raster"

    def __init__(self, pixels: np.ndarray, domain, channels, *, n_bytes: int | None = None, device: str = "cpu"):
        pixels = np.asarray(pixels, dtype=np.float32)
        if pixels.ndim != 3 or pixels.shape[2] != len(channels):
            raise ValueError(f"pixels must be (h, w, {len(channels)}), got {pixels.shape}")
        n_bytes = exr_bytes(pixels, list(channels)) if n_bytes is None else int(n_bytes)
        super().__init__(pixels.astype(np.float16).astype(np.float32), domain, channels, n_bytes=n_bytes,
                         kernel="bicubic", device=device)

    @classmethod
    def for_budget(cls, n_bytes: int, domain, channels, *, image: np.ndarray | None = None, seed: int = 0,
                   device: str = "cpu") -> Raster:
        """The area-averaged downsampling of ``image`` (H, W, C) whose EXR comes closest to ``n_bytes``
        without exceeding it; the full image when it fits whole. Raises ValueError when not even 1 px fits
        or ``image`` is missing (it is required here); ``seed`` is unused.

        A binary search over the width (height by the aspect ratio) finds the largest fitting size; since
        compressed sizes are not monotonic and one pixel of width is a step of ≈ 2 / w in size, widths up to
        ``REFINE`` above it and heights within one pixel of the aspect ratio are then tried as well.
        """
        if image is None:
            raise ValueError("the raster baseline needs the image")
        image = np.asarray(image, dtype=np.float32)
        H, W = image.shape[:2]
        sizes: dict[tuple[int, int], int] = {}

        def size(w: int, h: int) -> int:
            if (w, h) not in sizes:
                sizes[(w, h)] = exr_bytes(image if (w, h) == (W, H) else area_resize(image, w, h), channels)
            return sizes[(w, h)]

        def height(w: int) -> int:
            return min(H, max(1, round(H * w / W)))

        if size(1, 1) > n_bytes:
            raise ValueError(f"a budget of {n_bytes} bytes cannot hold even a 1-pixel EXR ({size(1, 1)} bytes)")
        if size(W, H) <= n_bytes:
            return cls(image, domain, channels, n_bytes=size(W, H), device=device)
        lo, hi = 1, W
        while lo < hi:  # largest w whose file fits, assuming sizes grow with w
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if size(mid, height(mid)) <= n_bytes else (lo, mid - 1)
        for w in range(lo, min(W, math.ceil(lo * (1 + REFINE))) + 1):
            for h in {max(1, height(w) - 1), height(w), min(H, height(w) + 1)}:
                size(w, h)
        w, h = max((k for k, v in sizes.items() if v <= n_bytes), key=lambda k: (sizes[k], k))
        pixels = image if (w, h) == (W, H) else area_resize(image, w, h)
        return cls(pixels, domain, channels, n_bytes=sizes[(w, h)], device=device)

    def describe(self) -> dict:
        return {"class": type(self).__name__, "raster": list(self.size), "storage": "half-float ZIP EXR",
                "lossless": True}
