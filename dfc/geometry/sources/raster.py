"""Discontinuity curves found in an image: ``image_curves(pixels) -> Curves``.

The stages, each in its own module:

1. ``edges``: Canny (scikit-image) on HDR-safe perceptual channels (asinh-log luminance and chroma), thinned.
2. ``subpixel``: at every edge pixel, the step model filtered by the pixel filter (``pixel_filter``: the box
   unless given; "auto": extracted with the box first, then the filter ``dfc.pixel_model.detect`` finds along
   those curves, and extracted again with it when it is another) places the edge where the mixed pixels say it is, and tells a step (kept) from a ramp wider than ``max_blur`` or a jump below ``low`` (dropped).
3. ``chains``: edge pixels linked into ordered chains of sub-pixel points, cut where the profile stops
   being a step, joined through junctions and corners; chains shorter than ``min_length`` are dropped. A
   point-sampled image holds no mixed pixel, so its points follow a staircase; a noisy render's scatter: such
   chains (every chain of a point-sampled image, any whose points scatter by more than ``max_scatter``) are smoothed
   along their length (``point_sigma``) and fitted within at least ``point_tolerance``. "auto" reads the pixel
   filter where the raw points are, before any smoothing.
4. ``dfc.geometry.fitting``: lines and cubic Béziers within ``tolerance`` of the points, cut at corners.
5. Welding (here): a free chain end that points at another curve within ``weld`` pixels is extended to
   end exactly on it (a T junction); one that points at the image border within that distance ends on it.

The result is in image coordinates: domain ``[0, W] × [0, H]``, y down, pixel centres at +0.5
(``spec/conventions.md``); every edge chain is one input curve named ``edge i``.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from ...errors import InputError
from .. import bezier
from ..curves import DEGREE_LINE, Curves, elevate
from ..fitting import fit_points
from .chains import Chain, link, trace_skeleton
from .edges import edge_skeleton, perceptual
from .subpixel import WINDOW, edge_points, residual_of_blur

__all__ = ["RasterSettings", "image_curves", "image_curves_filtered"]


@dataclass(frozen=True)
class RasterSettings:
    """Every knob of the raster curve extractor (recorded with ``to_dict`` wherever curves are extracted).

    Lengths are in pixels; ``low`` and ``high`` are step sizes on the perceptual channels (see
    ``dfc.geometry.sources.edges``: about the relative contrast, 0.1 ≈ a 10 % step).
    """

    sigma: float = 1.0
    """Canny's Gaussian σ (px): larger finds fewer, smoother edges in noisy images."""
    low: float = 0.05
    """Hysteresis low threshold: an edge continues while its step is at least this; also the smallest jump kept."""
    high: float = 0.1
    """Hysteresis high threshold: an edge starts where its step is at least this."""
    min_length: float = 8.0
    """Chains shorter than this (px) are dropped."""
    tolerance: float = 0.05
    """Largest distance (px) from an edge point to the fitted lines and Béziers."""
    max_blur: float = 0.6
    """Jumps only: a profile counts as a step when the step model explains it at least as well as it explains
    a straight step blurred by a Gaussian of this σ (px); wider ramps (soft shadows, defocus) are not curves."""
    corner_angle: float = 40.0
    """Turns sharper than this (degrees) over ``3`` px on either side are corners."""
    black: float = 0.01
    """Linear level below which the perceptual channels stop being logarithmic (noise floor of dark areas)."""
    weld: float = 6.0
    """Free chain ends are extended onto a curve or the image border they point at within this distance (px)."""
    point_sigma: float = 1.5
    """Point-sampled input only (pixel filter ``point``): a point sample holds no mixed pixel, so an edge point lies
    anywhere within about half a pixel of the edge (a staircase); the points are smoothed along their chain by a
    Gaussian of this σ (px) before fitting (0: not smoothed)."""
    point_tolerance: float = 0.3
    """Point-sampled input only: the fitting tolerance (px) is at least this; the smoothed staircase keeps a few
    tenths of a pixel of it, which a tighter fit would take for shape."""
    max_scatter: float = 0.04
    """A chain whose edge points scatter by more than this (px: the lower quartile over the chain of the RMS residual
    of a parabola through 7 consecutive points; noise in a path-traced render) is smoothed and fitted as a
    point-sampled one (``point_sigma``, ``point_tolerance``); ``inf``: never."""

    def check(self) -> None:
        """Raise ``ValueError`` naming the first impossible value."""
        for f in fields(self):
            value = getattr(self, f.name)
            if not (np.isfinite(value) or (f.name == "max_scatter" and value == np.inf)) or value < 0 \
                    or (value == 0 and f.name not in ("min_length", "max_blur", "weld", "point_sigma")):
                raise ValueError(f"{f.name} must be a finite number > 0, got {value!r}")
        if self.low > self.high:
            raise ValueError(f"low ({self.low}) must not exceed high ({self.high})")
        if self.corner_angle >= 180:
            raise ValueError(f"corner_angle must be below 180 degrees, got {self.corner_angle}")

    def to_dict(self) -> dict:
        return asdict(self)


_SPAN = 3.0  # px over which tangents at chain ends and corners are measured
_MIN_POINTS = 6  # edge points scatter by a few hundredths of a pixel: pieces under 6 points are not split for that


def image_curves_filtered(pixels: np.ndarray, settings: RasterSettings | None = None, pixel_filter: str = "auto"):
    """(curves, ``PixelFilter`` used, ``dfc.pixel_model.Detection`` or None) of ``image_curves`` with the pixel filter
    of spec ``pixel_filter``: a ``dfc.pixel_filter`` spec, or "auto": extracted with the box, then with the filter
    ``dfc.pixel_model.detect`` finds along those curves when that is another. Raises ``InputError`` for an unknown
    spec."""
    from ...pixel_filter import parse
    from ...pixel_model import detect

    if str(pixel_filter).strip().lower() != "auto":
        f = parse(pixel_filter)
        return image_curves(pixels, settings, pixel_filter=f), f, None
    pixels, settings = _checked(pixels, settings)
    chains = _chains(pixels, settings)  # with the box; the filter is read where the raw edge points are
    found = detect(pixels, _curves(chains, settings, pixels.shape, smooth=False))
    if found.pixels and str(found.filter) != "box":
        return _curves(_chains(pixels, settings, found.filter), settings, pixels.shape, _is_point(found.filter)), \
            found.filter, found
    return _curves(chains, settings, pixels.shape), found.filter, found


def image_curves(pixels: np.ndarray, settings: RasterSettings | None = None, pixel_filter=None,
                 **overrides) -> Curves:
    """Discontinuity curves of a linear image.

    pixels : (H, W, C) float linear values (EXR scene-linear or decoded sRGB), H, W ≥ 2, all finite
    settings : ``RasterSettings`` (default ``RasterSettings()``); ``overrides`` replace single fields,
        e.g. ``image_curves(pixels, tolerance=0.1)``
    pixel_filter : the ``dfc.pixel_filter.PixelFilter`` that made the pixels (None: the box), for the sub-pixel
        step model
    returns ``Curves`` over ``[0, W] × [0, H]``, every control point inside it; empty (no pieces) when the image has
        no jumps

    Raises ``InputError`` for an image that is too small or holds NaN or infinite values, ``ValueError``
    for impossible settings.
    """
    pixels, settings = _checked(pixels, settings, overrides)
    return _curves(_chains(pixels, settings, pixel_filter), settings, pixels.shape, _is_point(pixel_filter))


def _checked(pixels, settings: RasterSettings | None, overrides: dict | None = None):
    """(pixels (H, W, C) float64, settings with ``overrides``), both checked (``image_curves``' errors)."""
    settings = replace(settings or RasterSettings(), **(overrides or {}))
    settings.check()
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3 or pixels.shape[2] < 1:
        raise ValueError(f"pixels: expected (H, W, C), got shape {pixels.shape}")
    H, W, _ = pixels.shape
    if H < 2 or W < 2:
        raise InputError(f"image is {W} × {H} pixels: curves need at least 2 × 2")
    if not np.isfinite(pixels).all():
        raise InputError(f"image holds {int((~np.isfinite(pixels)).sum())} NaN or infinite value(s)")
    return pixels, settings


def _is_point(pixel_filter) -> bool:
    return pixel_filter is not None and pixel_filter.name == "point"


def _curves(chains: list[Chain], settings: RasterSettings, shape, point: bool = False, smooth: bool = True) -> Curves:
    """Curves over ``[0, W] × [0, H]`` (``shape`` (H, W, …)) fitted to ``chains``, which are left as they are: rough
    chains (all of a point-sampled image's, ``point``; any scattering past ``settings.max_scatter``) smoothed first
    unless not ``smooth``, then fitted, welded and clamped into the image."""
    H, W = shape[:2]
    domain = (0.0, 0.0, float(W), float(H))
    chains = [replace(c) for c in chains]  # smoothing and welding rebind a chain's points
    for c in chains:
        c.rough = smooth and (point or _scatter(c.points) > settings.max_scatter)
        if c.rough:
            c.points = _smooth(c.points, c.closed, settings.point_sigma)
    fits = _weld(chains, [_fit(c, settings) for c in chains], settings, domain)
    degree = [d for d, _ in fits]
    cp = [c for _, c in fits]
    counts = np.array([len(d) for d in degree], dtype=np.int64)
    n = int(counts.sum())
    k = np.arange(n) - np.repeat(np.cumsum(counts) - counts, counts)
    # a corner where two tangents meet past the border, or a cubic's handle, can fall outside the image: pulled
    # back onto it (the same for every piece sharing the point, so joins stay), the curves stay inside the image
    cp = [np.clip(c, 0.0, [float(W), float(H)]) for c in cp]
    return Curves(domain, np.concatenate(cp) if n else np.zeros((0, 4, 2)),
                  np.concatenate(degree) if n else np.zeros(0, np.int8), np.repeat(np.arange(len(fits)), counts),
                  np.stack([k, k + 1.0], axis=1), [f"edge {i}" for i in range(len(fits))], [None] * len(fits))


def _chains(pixels: np.ndarray, s: RasterSettings, pixel_filter=None) -> list[Chain]:
    """Edge chains of sub-pixel points, at least ``min_length`` long."""
    H, W, _ = pixels.shape
    channels = perceptual(pixels, s.black)
    skeleton, vertical = edge_skeleton(channels, sigma=s.sigma, low=s.low, high=s.high)
    rows, cols = np.nonzero(skeleton)
    points = edge_points(pixels, rows, cols, vertical[rows, cols], pixel_filter)
    sides = perceptual(np.stack([points.side_a, points.side_b])[:, :, None, :], s.black)[:, :, 0]
    jump = np.abs(sides[1] - sides[0]).max(axis=-1) if len(rows) else np.zeros(0)
    accepted = points.valid & (points.residual <= _max_residual(s.max_blur, pixel_filter)) & (jump >= s.low)
    point_of_pixel = np.full(H * W, -1, dtype=np.int64)
    point_of_pixel[(rows * W + cols)[accepted]] = np.nonzero(accepted)[0]
    paths, closed, ends, junction_xy = trace_skeleton(skeleton)
    chains = link(paths, closed, ends, junction_xy, point_of_pixel, points.xy, points.key,
                  max_gap=4 * WINDOW, span=_SPAN, reach=s.weld)
    return [c for c in chains if c.length >= max(s.min_length, 1e-9) and len(c.points) >= 2]


@functools.lru_cache(maxsize=16)
def _max_residual(max_blur: float, pixel_filter=None) -> float:
    return residual_of_blur(max_blur, pixel_filter)


def _smooth(points: np.ndarray, closed: bool, sigma: float) -> np.ndarray:
    """Points (n, 2) of a chain smoothed along it by a Gaussian of ``sigma`` px (in steps of the median spacing);
    an open chain is extended by its points reflected through each end, so its ends stay and straight runs stay
    straight up to them."""
    from scipy.ndimage import gaussian_filter1d

    n = len(points)
    spacing = np.median(np.linalg.norm(np.diff(points, axis=0), axis=1)) if n > 1 else 0.0
    if sigma <= 0 or n < 3 or spacing <= 0:
        return points
    steps = sigma / spacing
    if closed:
        return gaussian_filter1d(points, steps, axis=0, mode="wrap")
    k = min(n - 1, int(np.ceil(4 * steps)))
    padded = np.concatenate([2 * points[0] - points[k:0:-1], points, 2 * points[-1] - points[-2:-k - 2:-1]])
    return gaussian_filter1d(padded, steps, axis=0, mode="nearest")[k:k + n]


def _scatter(points: np.ndarray, k: int = 7) -> float:
    """Scatter (px) of a chain's points (n, 2): the lower quartile of the RMS residual of a least-squares parabola
    through each run of ``k`` consecutive points (in the frame of the run's chord; corners and curvature raise only
    the runs around them); 0 for fewer than ``k`` points."""
    if len(points) < k:
        return 0.0
    runs = np.lib.stride_tricks.sliding_window_view(points, (k, 2))[:, 0]  # (m, k, 2)
    chord = runs[:, -1] - runs[:, 0]
    along = chord / np.maximum(np.linalg.norm(chord, axis=1, keepdims=True), 1e-12)
    q = runs - runs[:, k // 2][:, None]
    x = np.einsum("mkd,md->mk", q, along)
    y = np.einsum("mkd,md->mk", q, np.stack([-along[:, 1], along[:, 0]], axis=1))
    basis = np.stack([np.ones_like(x), x, x * x], axis=2)  # (m, k, 3)
    residual = (basis @ (np.linalg.pinv(basis) @ y[..., None]))[..., 0] - y
    return float(np.percentile(np.sqrt((residual ** 2).mean(axis=1)), 25))


def _fit(chain: Chain, s: RasterSettings) -> tuple[np.ndarray, np.ndarray]:
    if chain.rough:
        s = replace(s, tolerance=max(s.tolerance, s.point_tolerance))
    return fit_points(chain.points, tolerance=s.tolerance, corner_angle=s.corner_angle, span=_SPAN,
                      closed=chain.closed, min_points=_MIN_POINTS)


def _weld(chains: list[Chain], fits: list, s: RasterSettings, domain) -> list:
    """Extend free chain ends onto the curve or border they point at (within ``weld`` px), refit those chains,
    then move each welded end exactly onto its target's final curve."""
    welds = []  # (chain, side, target chain or -1 for the border)
    for c, chain in enumerate(chains):
        for side in (0, 1):
            if not chain.free[side] or chain.closed:
                continue
            end, direction = _end(chain.points, side)
            hit = _ray_hit(end, direction, fits, c, side, s.weld, domain)
            if hit is not None:
                point, target = hit
                pts = chain.points
                chain.points = np.concatenate([point[None], pts]) if side == 0 else np.concatenate([pts, point[None]])
                welds.append((c, side, target))
    for c in {w[0] for w in welds}:
        fits[c] = _fit(chains[c], s)
    for _ in range(2):  # a target may itself move at a welded end: a second pass settles chains of welds
        for c, side, target in welds:
            _snap(fits, c, side, target, domain)
    return fits


def _end(points: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """A chain's end point (side 0: start, 1: end) and the unit direction leaving it there."""
    p = points if side == 1 else points[::-1]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p[::-1], axis=0), axis=1))]
    tail = p[len(p) - max(2, int(np.searchsorted(arc, _SPAN, side="right"))):]
    centred = tail - tail.mean(axis=0)
    d = np.linalg.svd(centred, full_matrices=False)[2][0]
    return p[-1], (-d if d @ (tail[-1] - tail[0]) < 0 else d)


def _ray_hit(origin, direction, fits, own: int, side: int, reach: float, domain):
    """Nearest crossing of the ray ``origin + s direction``, s > 0, with another chain's curve (or this chain's
    pieces other than the one at this end) or the domain border. The border counts when ``origin`` lies within
    ``reach`` px of it, measured across it (the band the sub-pixel fits cannot see is as wide on a slant), and at
    most ``√2 · reach`` along the ray; a curve counts within ``reach`` along the ray, or before the border the ray
    reaches (the end would cross it on its way). Returns (point (2,), target chain index or -1 for the border) or
    None."""
    best, target = np.sqrt(2.0) * reach, None
    x0, y0, x1, y1 = domain
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, bound in ((0, x0), (0, x1), (1, y0), (1, y1)):
            t = (bound - origin[k]) / direction[k]
            if 0 < t <= best and abs(bound - origin[k]) <= reach:
                best, target = t, -1
    if target is None:
        best = reach
    normal = np.array([-direction[1], direction[0]])
    box = np.r_[origin - best, origin + best]
    for c, (_, cp) in enumerate(fits):
        if c == own:
            cp = cp[1:] if side == 0 else cp[:-1]
        if not len(cp):
            continue
        bb = bezier.bounding_boxes(cp)
        near = (bb[:, 0] <= box[2]) & (bb[:, 2] >= box[0]) & (bb[:, 1] <= box[3]) & (bb[:, 3] >= box[1])
        if not near.any():
            continue
        pieces = cp[near]
        roots = bezier.bernstein_roots((pieces - origin) @ normal)
        for i, j in zip(*np.nonzero(np.isfinite(roots))):
            point = bezier.evaluate(pieces[i: i + 1], roots[i, j: j + 1])[0]
            t = (point - origin) @ direction
            if 1e-9 < t <= best:
                best, target = t, c
    if target is None:
        return None
    return origin + best * direction, target


def _snap(fits: list, c: int, side: int, target: int, domain) -> None:
    """Move the welded end of chain ``c`` exactly onto its target: the nearest point of the target chain's
    curve, or the border line it was extended to."""
    degree, cp = fits[c]
    piece = 0 if side == 0 else len(cp) - 1
    end = cp[piece, 0 if side == 0 else 3]
    if target < 0:
        x0, y0, x1, y1 = domain
        dist = np.abs(np.array([end[0] - x0, end[0] - x1, end[1] - y0, end[1] - y1]))
        k = int(np.argmin(dist))
        point = end.copy()
        point[k // 2] = (x0, x1, y0, y1)[k]
    else:
        tcp = fits[target][1]
        starts = np.linspace(0.0, 1.0, 9)
        many = np.repeat(tcp, len(starts), axis=0)
        t = bezier.closest_parameter(many, np.broadcast_to(end, (len(many), 2)), np.tile(starts, len(tcp)))
        on = bezier.evaluate(many, t)
        point = on[int(np.argmin(np.linalg.norm(on - end, axis=1)))]
    delta = point - end
    cp = cp.copy()
    if side == 0:
        cp[piece, :2] += delta
    else:
        cp[piece, 2:] += delta
    if degree[piece] == DEGREE_LINE:
        cp[piece] = elevate(cp[piece][None, [0, 3]], DEGREE_LINE)[0]
    fits[c] = (degree, cp)
