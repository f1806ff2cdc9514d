"""Image-quality metrics with an explicit data range (the habit of ``skimage.metrics``).

Arrays of any matching shape; computed in float64. No torch: these run on decoded rasters.
"""

from __future__ import annotations

import numpy as np

__all__ = ["data_range", "mse", "psnr"]


def _pair(image_true, image_test) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(image_true)
    b = np.asarray(image_test)
    if a.shape != b.shape:
        raise ValueError(f"images must have the same shape, got {a.shape} and {b.shape}")
    if a.size == 0:
        raise ValueError("images are empty")
    return a, b


def mse(image_true, image_test) -> float:
    """Mean squared error between two arrays of the same shape (any dtype), as a float64 scalar."""
    a, b = _pair(image_true, image_test)
    return float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))


def psnr(image_true, image_test, data_range: float | None = None) -> float:
    """Peak signal-to-noise ratio ``10 log10(data_range² / mse)`` in dB.

    Parameters
    ----------
    image_true, image_test : array_like, same shape
    data_range : float, optional
        The span of possible values (1.0 for linear images in [0, 1]). Inferred only for integer
        inputs (the dtype's range, e.g. 255 for uint8); float inputs must pass it.

    Returns
    -------
    float
        ``inf`` when the images are identical.

    Raises
    ------
    ValueError
        Shapes differ, ``data_range`` is not positive, or it is missing for float input.
    """
    a, b = _pair(image_true, image_test)
    if data_range is None:
        if not (np.issubdtype(a.dtype, np.integer) and a.dtype == b.dtype):
            raise ValueError(
                "data_range is required for float images: pass data_range=1.0 for values in [0, 1], "
                "or data_range=image_true.max() - image_true.min() for HDR"
            )
        info = np.iinfo(a.dtype)
        data_range = float(info.max) - float(info.min)
    data_range = float(data_range)
    if not (np.isfinite(data_range) and data_range > 0):
        raise ValueError(f"data_range must be a positive finite number, got {data_range}")
    err = mse(a, b)
    if err == 0:
        return float("inf")
    return float(10.0 * np.log10(data_range**2 / err))


def data_range(values, *, physical: bool = False) -> float:
    """The PSNR data range dfc measures a signal ``values`` (any shape) with, everywhere it reports a PSNR.

    Colours (``physical=False``): 1 when every value lies in [0, 1] (LDR), else the values' span (HDR).
    Physical quantities (simulation data, of any magnitude): the span. At least 1e-12 (a constant signal).
    """
    v = np.asarray(values)
    lo, hi = float(v.min()), float(v.max())
    if not physical and lo >= 0.0 and hi <= 1.0:
        return 1.0
    return max(hi - lo, 1e-12)
