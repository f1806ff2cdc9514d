"""Pixel filters: how a raster's pixel value is made from the continuous signal around the pixel's centre.

A pixel of a raster is ``∫∫ k(x − cx) k(y − cy) f(x, y) dx dy / (∫ k)²`` for a separable kernel ``k`` in pixel
units, centred on the pixel's centre ``(cx, cy)``. The kernels (``FILTERS``; spec strings as ``dfc encode
--pixel-filter`` takes them, ``parse``):

- ``point``: the value at the centre (aliased rasters, label maps, simulation grids sampled at cell centres);
- ``box`` / ``box:N``: the mean over the pixel's square, ``N × N`` sub-samples at the centres of an even grid when
  ``N`` is given (the default box is the continuous area average);
- ``tent``: ``1 − |u|`` over ``|u| ≤ 1``;
- ``gaussian[:STDDEV]``: Mitsuba 3's ``gaussian`` reconstruction filter, ``max(0, exp(−u²/2σ²) − exp(−r²/2σ²))`` with
  radius ``r = 4σ`` (default σ = 0.5 px);
- ``blackman-harris[:WIDTH]``: Cycles' pixel filter of ``filter_width`` WIDTH (default 1.5 px): the 4-term
  Blackman–Harris window over ``|u| ≤ WIDTH``;
- ``mitchell``: the Mitchell–Netravali cubic with B = C = 1/3 over ``|u| ≤ 2`` (negative lobes).

A filtered pixel is evaluated by quadrature (``PixelFilter.nodes``): points drawn per axis through the inverse of
the cumulative ``|k|`` (so every point carries the same weight, signed where ``k`` is negative), on a rank-1 (R2)
lattice of ``count`` points, optionally shifted (a randomised quadrature whose mean is exact).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError

__all__ = ["DECODE_POINTS", "FILTERS", "STEEP_POINTS", "STEEP_RANGE", "TRAIN_POINTS", "PixelFilter", "lattice",
           "parse"]

FILTERS = ("point", "box", "tent", "gaussian", "blackman-harris", "mitchell")
"""Filter names, as ``parse`` takes them (``auto`` is the encoder's detection, ``dfc.pixel_model``)."""
DEFAULTS = {"gaussian": 0.5, "blackman-harris": 1.5}
"""The parameter of a filter written without one (px)."""
MAX_PARAM = {"box": 64, "gaussian": 8.0, "blackman-harris": 16.0}
"""Largest parameter accepted: box sub-samples per axis, Gaussian σ and Blackman–Harris width (px)."""
TRAIN_POINTS = 16
"""Quadrature points per filtered pixel in a training batch (shifted lattice: exact in expectation)."""
STEEP_POINTS = 64
"""Quadrature points per filtered pixel of a training batch where the values span more than ``STEEP_RANGE`` of the
loss's units around it (``dfc.train.fit``): a random quadrature's variance grows with the square of the jump it
straddles, and the fit lowers the squared error's variance term by shrinking the jump."""
STEEP_RANGE = 1.0
"""Span of the values (in the loss's units: ``log(1 + v)`` for HDR light, else the values normalised to [0, 1])
within a filtered pixel's reach above which it gets ``STEEP_POINTS``: only HDR jumps, such as an emitter's edge."""
DECODE_POINTS = 256
"""Quadrature points per filtered pixel of a decode (fixed lattice); the continuous box keeps
``dfc.render.EDGE_SPP`` points, as decodes without a stored filter do."""
_TABLE = 4097
"""Samples of a kernel's cumulative table over its support."""
AXIS_SEGMENTS, AXIS_NODES = 8, 8
"""Composite Gauss–Legendre quadrature of one axis (``PixelFilter.axis_nodes``): segments of the support, points
on each."""


@dataclass(frozen=True)
class PixelFilter:
    """A separable pixel filter: ``name`` one of ``FILTERS``; ``param`` box sub-samples per axis (int or None for
    the continuous box), Gaussian σ or Blackman–Harris width (px), else None. ``str()`` is its spec string."""

    name: str
    param: float | int | None = None

    def __str__(self) -> str:
        return self.name if self.param is None else f"{self.name}:{self.param:g}"

    @property
    def radius(self) -> float:
        """Half-width of the kernel's support (px)."""
        fixed = {"point": 0.0, "box": 0.5, "tent": 1.0, "mitchell": 2.0}
        if self.name in fixed:
            return fixed[self.name]
        return 4.0 * self.param if self.name == "gaussian" else float(self.param)

    @property
    def reach(self) -> int:
        """How many pixels away a discontinuity still changes a pixel (Chebyshev distance): a pixel whose square
        the discontinuity misses is filtered when it lies within ``reach`` pixels of one it crosses."""
        return 0 if self.name in ("point", "box") else max(0, math.ceil(self.radius - 0.5 - 1e-9))

    @property
    def mixes(self) -> bool:
        """False for ``point``: every pixel is one value of the field, none blends two sides."""
        return self.name != "point"

    def filtered(self, crossed: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels whose value a discontinuity changes, from the pixels it crosses ``crossed``
        (H, W) bool (``dfc.geometry.pixels.edge_pixels``): none for ``point``, else ``crossed`` grown by
        ``reach``."""
        crossed = np.asarray(crossed, dtype=bool)
        if not self.mixes:
            return np.zeros_like(crossed)
        if not self.reach or not crossed.any():
            return crossed.copy()
        from scipy.ndimage import binary_dilation

        return binary_dilation(crossed, np.ones((2 * self.reach + 1,) * 2, dtype=bool))

    def kernel(self, u: np.ndarray) -> np.ndarray:
        """k(u), u in px (any shape), unnormalised, 0 outside the support."""
        u = np.abs(np.asarray(u, dtype=np.float64))
        r = self.radius
        if self.name == "box":
            return (u <= 0.5).astype(np.float64)
        if self.name == "tent":
            return np.maximum(0.0, 1.0 - u)
        if self.name == "gaussian":
            a = -0.5 / self.param**2
            return np.where(u <= r, np.maximum(0.0, np.exp(a * u * u) - math.exp(a * r * r)), 0.0)
        if self.name == "blackman-harris":
            x = 2.0 * np.pi * (u / (2.0 * r) + 0.5)
            k = 0.35875 - 0.48829 * np.cos(x) + 0.14128 * np.cos(2 * x) - 0.01168 * np.cos(3 * x)
            return np.where(u <= r, k, 0.0)
        if self.name == "mitchell":
            b = c = 1.0 / 3.0
            near = (12 - 9 * b - 6 * c) * u**3 + (-18 + 12 * b + 6 * c) * u**2 + (6 - 2 * b)
            far = (-b - 6 * c) * u**3 + (6 * b + 30 * c) * u**2 + (-12 * b - 48 * c) * u + (8 * b + 24 * c)
            return np.where(u < 1, near, np.where(u < 2, far, 0.0)) / 6.0
        return (u == 0).astype(np.float64)

    def nodes(self, count: int, shift: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Quadrature of one pixel: (offsets (..., K, 2) float64 px from the centre, weights (..., K) float64,
        summing to 1). ``point``: the centre. ``box:N`` with ``N² ≤ count``: its N × N sub-samples exactly.
        Otherwise ``count`` points of the R2 lattice (``lattice``), each coordinate shifted by ``shift`` (..., 2)
        in [0, 1) when given (a randomised quadrature) and mapped through the inverse cumulative ``|k|``."""
        if self.name == "point":
            lead = () if shift is None else np.shape(shift)[:-1]
            return np.zeros((*lead, 1, 2)), np.ones((*lead, 1))
        if self.name == "box" and self.param is not None and self.param**2 <= count:
            n = int(self.param)
            g = (np.arange(n) + 0.5) / n - 0.5
            grid = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
            lead = () if shift is None else np.shape(shift)[:-1]
            return (np.broadcast_to(grid, (*lead, n * n, 2)).copy(),
                    np.full((*lead, n * n), 1.0 / (n * n)))
        p = lattice(count)
        if shift is not None:
            p = np.mod(p + np.asarray(shift)[..., None, :], 1.0)
        u_table, cdf, scale, _ = self._table()
        off = np.interp(p, cdf, u_table)
        sign = np.sign(self.kernel(off)).prod(axis=-1)
        sign[sign == 0] = 1.0
        w = sign * (scale * scale / count)
        return off, w / w.sum(axis=-1, keepdims=True)

    def cdf(self, u: np.ndarray) -> np.ndarray:
        """The kernel's normalised cumulative ``∫_{−r}^{u} k / ∫ k`` at ``u`` px (any shape): 0 below the support, 1
        above it (signed: it dips where ``k`` is negative)."""
        grid, _, _, table = self._table()
        return np.interp(u, grid, table)

    @functools.lru_cache(maxsize=8)  # noqa: B019 (frozen dataclass: hashable, few instances)
    def axis_nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """Quadrature of one axis of a continuous kernel: (offsets (M,) px, weights (M,) summing to 1) of composite
        Gauss–Legendre, ``AXIS_NODES`` points on each of ``AXIS_SEGMENTS`` equal segments of the support, weighted
        by the kernel (the segments' ends fall on the kinks of every kernel of ``FILTERS``)."""
        r = self.radius
        x, w = np.polynomial.legendre.leggauss(AXIS_NODES)
        ends = np.linspace(-r, r, AXIS_SEGMENTS + 1)
        half = 0.5 * (ends[1:] - ends[:-1])
        offsets = ((ends[:-1] + half)[:, None] + half[:, None] * x[None]).ravel()
        weights = (half[:, None] * w[None]).ravel() * self.kernel(offsets)
        return offsets, weights / weights.sum()

    @functools.lru_cache(maxsize=8)  # noqa: B019 (frozen dataclass: hashable, few instances)
    def _table(self) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """(u (T,), cumulative |k| normalised to 0..1 (T,), ∫|k| / ∫k, cumulative k normalised to end at 1 (T,))
        over the support, by trapezoids."""
        u = np.linspace(-self.radius, self.radius, _TABLE)
        k = self.kernel(u)
        a = np.abs(k)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(u))])
        pieces = 0.5 * (k[1:] + k[:-1]) * np.diff(u)
        signed = np.concatenate([[0.0], np.cumsum(pieces)])
        return u, cdf / cdf[-1], cdf[-1] / float(np.sum(pieces)), signed / signed[-1]

    def taps(self, offsets: np.ndarray) -> np.ndarray:
        """Normalised 1D weights of the kernel at ``offsets`` (px) from the centre (sum 1): a separable
        convolution of sub-samples at these offsets (``dfc.bench.pixel_filters``)."""
        k = self.kernel(offsets)
        return k / k.sum()


def lattice(count: int) -> np.ndarray:
    """(count, 2) float64 points of the R2 sequence in [0, 1)² (the points ``dfc.render.pixel_offsets`` takes)."""
    g = 1.32471795724474602596  # plastic number
    n = np.arange(count)[:, None]
    return np.mod(0.5 + n * np.array([1 / g, 1 / g**2]), 1.0)


def parse(spec: str) -> PixelFilter:
    """The filter of a spec string ``NAME[:PARAM]`` (``FILTERS``; ``box:N`` N ≥ 1 an integer, ``gaussian:STDDEV``
    and ``blackman-harris:WIDTH`` > 0 px). Raises ``InputError`` naming the problem."""
    if not isinstance(spec, str):
        raise InputError(f"pixel filter must be a string, got {spec!r}")
    name, _, raw = spec.strip().lower().partition(":")
    if name not in FILTERS:
        raise InputError(f"unknown pixel filter {spec!r}; known: point, box[:N], gaussian[:STDDEV], tent, "
                         "blackman-harris[:WIDTH], mitchell")
    if not raw:
        return PixelFilter(name, DEFAULTS.get(name))
    if name not in MAX_PARAM:
        raise InputError(f"pixel filter {name!r} takes no parameter, got {spec!r}")
    try:
        value = float(raw)
    except ValueError:
        raise InputError(f"pixel filter {spec!r}: {raw!r} is not a number") from None
    top = MAX_PARAM[name]
    if name == "box":
        if not value.is_integer() or not 1 <= value <= top:
            raise InputError(f"pixel filter {spec!r}: box sub-samples must be an integer from 1 to {top}")
        return PixelFilter("box", int(value))
    what = "stddev" if name == "gaussian" else "width"
    if not (math.isfinite(value) and 0 < value <= top):
        raise InputError(f"pixel filter {spec!r}: the {what} must be a number > 0 and ≤ {top:g} px, got {raw}")
    return PixelFilter(name, value)
