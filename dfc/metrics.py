"""Image-quality metrics with an explicit data range (the habit of ``skimage.metrics``).

Arrays of any matching shape; computed in float64. No torch: these run on decoded rasters (``tonemap`` alone also
takes tensors, for the fit's progress).

Which scale a signal's PSNR is measured on is decided in one place, ``quality_scale``: the encoder's summary, the
fit's progress bar and the benchmarks use it. Colours in [0, 1] and physical quantities are compared as they are,
with ``data_range``; HDR colours (``is_hdr``: a peak above 1 and at least ``HDR_PEAK_RATIO`` times the mean) are
compared after the tone map ``x / (1 + x)`` (values clipped at 0, as ``dfc decode`` maps HDR files into PNG), with
data range 1. A PSNR on the linear values with the input's span as data range (1000 for an image with a few very
bright pixels) is dominated by the bright pixels and hides colour errors everywhere else. Colours above 1 without
such a peak (an image in 16-bit counts, or in [0, 1] times any unit) are values in other units, compared with their
span like physical quantities: the decision does not depend on the unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HDR_PEAK_RATIO", "QualityScale", "data_range", "is_hdr", "measure_space", "mse", "noise_sigma", "psnr",
           "quality_scale", "step_size", "tonemap"]

HDR_PEAK_RATIO = 8.0
"""Colours are HDR light when their peak is above 1 and at least this many times their mean (three stops): the
HDR test images reach 20 (``WideColorGamut.exr``) to 76, the ``hdr`` scene 23, LDR images and renders about 2
(``samples/sample.exr`` 1.9). The ratio does not change with the unit, so an LDR image in sensor counts or times
1e4 is not mistaken for light."""


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


def is_hdr(values=None, *, lo: float | None = None, hi: float | None = None, mean: float | None = None) -> bool:
    """Whether colours ``values`` (any shape; or their ``hi`` peak and ``mean``) are HDR light: a peak above 1 and
    at least ``HDR_PEAK_RATIO`` times the mean. Such colours are fitted in log space and measured tone-mapped;
    others, whatever their unit, as values (``dfc.field.units``)."""
    if values is not None:
        v = np.asarray(values)
        hi, mean = float(v.max()), float(v.mean(dtype=np.float64))
    return hi > 1.0 and hi >= HDR_PEAK_RATIO * max(mean, 0.0)


def measure_space(values, like=None) -> np.ndarray:
    """float64 ``values`` (any shape) in the space a colour image's PSNR is measured in, decided by the image
    ``like`` (default ``values``): HDR light (``is_hdr(like)``) tone-mapped, ``sign(x) |x| / (1 + |x|)``; other
    values over ``like``'s range, ``(x − min) / span`` (0 where the span is 0). A step's size there, as a share of
    that range, says whether it shows, whatever the unit or the brightest highlight."""
    v = np.asarray(values, dtype=np.float64)
    ref = v if like is None else np.asarray(like)
    if is_hdr(ref):
        return np.sign(v) * np.abs(v) / (1.0 + np.abs(v))
    lo, hi = float(ref.min()), float(ref.max())
    return (v - lo) / (hi - lo) if hi > lo else np.zeros_like(v)


def noise_sigma(image) -> float:
    """Noise level of an image (H, W, C) in its ``measure_space`` (a share of its range, or tone-mapped for HDR
    light): the median absolute finest-scale Haar diagonal detail over 2 × 2 blocks, / 0.6745 (Donoho and
    Johnstone's estimator: white noise of standard deviation σ reads σ; smooth content and edges, which touch few
    blocks, read about 0)."""
    p = measure_space(image)
    h, w = p.shape[0] // 2 * 2, p.shape[1] // 2 * 2
    if h == 0 or w == 0:
        return 0.0
    p = p[:h, :w]
    detail = (p[0::2, 0::2] - p[0::2, 1::2] - p[1::2, 0::2] + p[1::2, 1::2]) / 2
    return float(np.median(np.abs(detail)) / 0.6745)


def step_size(a, b, like) -> np.ndarray:
    """(N,) size of the steps from colours ``b`` to ``a`` (N, C) in ``measure_space`` of the image ``like``, as a
    share of its range: the Euclidean norm of their difference there."""
    s = measure_space(np.stack([a, b]), like)
    return np.linalg.norm(s[0] - s[1], axis=-1)


def tonemap(values):
    """Reinhard tone map ``x / (1 + x)`` of values clipped at 0, into [0, 1): a numpy array (any shape, float64 out
    for float64 in) or a torch tensor, elementwise."""
    v = values.clip(0, None)
    return v / (1 + v)


@dataclass(frozen=True)
class QualityScale:
    """How a PSNR is measured: on ``tonemap``-ped values (``tonemap=True``) or the values, with ``data_range``."""

    data_range: float
    tonemap: bool = False

    def psnr(self, image_true, image_test) -> float:
        """``psnr`` of the two arrays on this scale."""
        a, b = (np.asarray(x, dtype=np.float64) for x in (image_true, image_test))
        if self.tonemap:
            a, b = tonemap(a), tonemap(b)
        return psnr(a, b, data_range=self.data_range)

    def describe(self) -> str:
        """'data range R', or for HDR 'tone-mapped x/(1+x), data range 1': what a summary prints after a PSNR."""
        return ("tone-mapped x/(1+x), " if self.tonemap else "") + f"data range {self.data_range:.4g}"


def quality_scale(values, *, physical: bool = False) -> QualityScale:
    """The scale dfc measures the PSNR of a signal ``values`` (any shape) on, everywhere it reports one.

    HDR colours (``physical=False`` and ``is_hdr``): tone-mapped, data range 1. Otherwise no tone map and
    ``data_range(values, physical=physical)``: 1 for colours in [0, 1], else the span.
    """
    if not physical and is_hdr(values):
        return QualityScale(1.0, tonemap=True)
    return QualityScale(data_range(values, physical=physical))
