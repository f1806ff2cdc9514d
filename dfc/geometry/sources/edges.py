"""Edge pixels of a linear image: Canny (scikit-image) on an HDR-safe perceptual form of it, thinned to
one-pixel-wide 8-connected lines.

Perceptual channels. ``T(v) = asinh(v / black)`` is linear below the black level ``black`` and
logarithmic above it (``T(2v) - T(v) -> ln 2``), so a step's size in ``T`` is about its relative contrast
whatever the exposure, and negative values are allowed. The channels are the luminance ``T(Y)``
(Rec. 709 weights on the first three channels of a colour image, the only channel of a grey one) and,
for colour, the two chroma log-ratios ``T(R) - T(Y)`` and ``T(B) - T(Y)``; further channels (alpha,
or anything else) are each their own ``T(v)``. Edge thresholds are steps in these units (0.1 ≈ a 10 %
contrast step, for values above ``black``).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import ndimage as ndi

__all__ = ["REC709", "perceptual", "edge_skeleton", "step_response"]

REC709 = np.array([0.2126, 0.7152, 0.0722])
"""Luminance weights of linear R, G, B."""


def perceptual(pixels: np.ndarray, black: float) -> np.ndarray:
    """Perceptual channels of a linear image.

    pixels : (..., C) float linear values, e.g. (H, W, C); black : the level (same units) below which T is linear
    returns (..., K) float64: K = C (luminance and two chroma channels in place of the first three when C ≥ 3)
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    C = pixels.shape[-1]

    def t(v):
        return np.arcsinh(v / black)

    if C >= 3:
        lum = t(pixels[..., :3] @ REC709)
        planes = [lum, t(pixels[..., 0]) - lum, t(pixels[..., 2]) - lum] + [t(pixels[..., c]) for c in range(3, C)]
    else:
        planes = [t(pixels[..., c]) for c in range(C)]
    return np.stack(planes, axis=-1)


@functools.lru_cache(maxsize=32)
def step_response(sigma: float) -> float:
    """Peak Sobel magnitude, after a Gaussian of ``sigma`` px, of a unit step: the factor from a step size to
    the gradient scale in which ``skimage.feature.canny`` compares its thresholds."""
    step = np.repeat([0.0, 1.0], 64)
    smooth = ndi.gaussian_filter1d(step, sigma, mode="nearest")
    return float(4.0 * np.max(np.abs(smooth[2:] - smooth[:-2])))  # Sobel: [-1, 0, 1] × [1, 2, 1]


def edge_skeleton(channels: np.ndarray, *, sigma: float, low: float, high: float) -> tuple[np.ndarray, np.ndarray]:
    """Canny on every perceptual channel, united and thinned.

    channels : (H, W, K) float perceptual channels; sigma : Gaussian σ in px; low, high : hysteresis
    thresholds as step sizes in the channels' units
    returns skeleton (H, W) bool, one pixel wide, 8-connected; and vertical (H, W) bool, True where the
    strongest channel's smoothed gradient is more horizontal than vertical (the edge runs up-down)
    """
    try:
        from skimage.feature import canny
        from skimage.morphology import thin
    except ImportError:
        raise ImportError("finding curves in images needs scikit-image: pip install 'dfc[curves]'") from None

    scale = step_response(sigma)
    H, W, K = channels.shape
    edges = np.zeros((H, W), dtype=bool)
    best = np.zeros((H, W))
    vertical = np.zeros((H, W), dtype=bool)
    for k in range(K):
        plane = channels[..., k]
        edges |= canny(plane, sigma, low * scale, high * scale, mode="nearest")
        smooth = ndi.gaussian_filter(plane, sigma, mode="nearest")
        gx, gy = ndi.sobel(smooth, axis=1), ndi.sobel(smooth, axis=0)
        magnitude = np.hypot(gx, gy)
        stronger = magnitude > best
        best = np.where(stronger, magnitude, best)
        vertical = np.where(stronger, np.abs(gx) > np.abs(gy), vertical)
    return thin(edges), vertical
