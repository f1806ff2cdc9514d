"""Sub-pixel edge points from the box-filtered step model (the partial-area effect).

A pixel is the mean of the scene over its square, so where a sharp edge separates values ``A`` and ``B``
a mixed pixel holds ``A + (B - A) f`` with ``f`` the share of its area on the ``B`` side: the value says
where the edge crosses it. For an edge that is mostly horizontal at pixel ``(r, c)`` take the window of
rows ``r - M .. r + M`` and columns ``c - 1 .. c + 1`` (``M = WINDOW``); the sum of a column is
``A (Y + M + 1/2) + B (M + 1/2 - Y)`` with ``Y`` the curve's mean height over that column, relative to
the pixel's centre. Fitting ``y = a + b x + k x²`` through the three column means gives the edge's
position, slope and curvature exactly for a box-filtered image of a parabola between two constants
(Trujillo-Pino et al., "Accurate subpixel edge location based on partial area effect", Image and Vision
Computing 31, 2013). ``A`` and ``B`` are read per column from the window's end rows, which the edge
cannot reach, so a smooth trend along the edge cancels.

Jumps only: the same parameters predict every pixel of the window; a step explains it to within a few
per cent of the jump, a ramp (blur, soft shadow) wider than about a pixel does not. ``residual`` is that
misfit, RMS over the window, as a share of the jump.

Other pixel filters (``dfc.pixel_filter``; ``pixel_filter`` argument): a kernel whose integer translates sum to 1
(box, tent, the B = C = 1/3 Mitchell cubic; nearly so Mitsuba's Gaussian σ 0.5 and Cycles' Blackman–Harris) leaves
each column's sum as it is, so the same column means hold; the kernel only replaces the box's variance 1/12 in the
curvature correction by its own (``offset = mean − k · var``) and predicts the window's pixels with its own step
share (``dfc.pixel_model.step_share``) in ``residual``.

Mostly vertical edges use the transposed window (three rows, ``2M + 1`` columns). Coordinates follow
``spec/conventions.md``: x right, y down, pixel ``(r, c)`` covers ``[c, c + 1] × [r, r + 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WINDOW", "EdgePoints", "edge_points"]

WINDOW = 3
"""Half-height ``M`` of the window across the edge (rows ``-M .. M``); an edge point needs no other edge
within about ``M`` pixels across it."""


@dataclass(frozen=True)
class EdgePoints:
    """Sub-pixel edge points, one per input pixel (N of them).

    xy : (N, 2) float64 positions in image coordinates (pixels, y down)
    normal : (N, 2) float64 unit normals, pointing from side A to side B
    curvature : (N,) float64 signed curvature of the fitted parabola (1/px)
    side_a, side_b : (N, C) float64 linear values on either side (means over the window's end rows)
    residual : (N,) float64 RMS misfit of the step model over the window, as a share of the jump
    key : (N,) int64 the pixel the point was finally fitted at (``2 (row W + col) + vertical``); equal keys
        are the same point
    valid : (N,) bool the model could be fitted (window inside the image, a jump, the edge inside the window)
    """

    xy: np.ndarray
    normal: np.ndarray
    curvature: np.ndarray
    side_a: np.ndarray
    side_b: np.ndarray
    residual: np.ndarray
    key: np.ndarray
    valid: np.ndarray


def edge_points(pixels: np.ndarray, rows: np.ndarray, cols: np.ndarray, vertical: np.ndarray,
                pixel_filter=None) -> EdgePoints:
    """Fit the filtered step model at edge pixels.

    pixels : (H, W, C) float linear values
    rows, cols : (N,) int pixel indices of edge pixels
    vertical : (N,) bool True where the edge is mostly vertical (|gradient x| > |gradient y|)
    pixel_filter : the ``dfc.pixel_filter.PixelFilter`` that made the pixels (None: the box)
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    vertical = np.asarray(vertical, dtype=bool)
    H, W, C = pixels.shape
    n = len(rows)
    out = {"xy": np.zeros((n, 2)), "normal": np.zeros((n, 2)), "curvature": np.zeros(n),
           "side_a": np.zeros((n, C)), "side_b": np.zeros((n, C)), "residual": np.full(n, np.inf),
           "key": np.full(n, -1, dtype=np.int64), "valid": np.zeros(n, dtype=bool)}
    for vert, image, along, across in ((False, pixels, cols, rows), (True, pixels.transpose(1, 0, 2), rows, cols)):
        idx = np.nonzero(vertical == vert)[0]
        fit = _fit_columns(image, across[idx], along[idx], pixel_filter)
        pos_across, pos_along = fit["across"], fit["along"]
        slope = fit["slope"]
        norm = np.sqrt(1.0 + slope**2)
        if vert:  # image rows were x: across = x, along = y
            out["xy"][idx] = np.stack([pos_across, pos_along], axis=1)
            out["normal"][idx] = np.stack([1.0 / norm, -slope / norm], axis=1)
            out["key"][idx] = 2 * (fit["along_px"] * W + fit["across_px"]) + 1
        else:
            out["xy"][idx] = np.stack([pos_along, pos_across], axis=1)
            out["normal"][idx] = np.stack([-slope / norm, 1.0 / norm], axis=1)
            out["key"][idx] = 2 * (fit["across_px"] * W + fit["along_px"])
        for name in ("curvature", "side_a", "side_b", "residual", "valid"):
            out[name][idx] = fit[name]
    return EdgePoints(**out)


def _fit_columns(image: np.ndarray, r: np.ndarray, c: np.ndarray, pixel_filter=None) -> dict:
    """The model on windows of rows ``r - M .. r + M``, columns ``c - 1 .. c + 1`` of ``image`` (H, W, C):
    fitted once, then once more at the pixel the edge really crosses when that is a neighbour."""
    fit = _fit_once(image, r, c, pixel_filter)
    shift = np.where(fit["valid"], np.rint(fit["offset"]), 0).astype(np.int64)
    moved = np.nonzero(shift != 0)[0]
    if len(moved):
        again = _fit_once(image, r[moved] + shift[moved], c[moved], pixel_filter)
        for name, value in again.items():
            fit[name][moved] = value
    fit["valid"] &= np.abs(fit["offset"]) <= 0.5 + 1e-9
    return fit


def _variance(pixel_filter) -> float:
    """The second moment (px²) along one axis of a pixel filter (None: the box's 1/12)."""
    if pixel_filter is None:
        return 1.0 / 12.0
    offsets, weights = pixel_filter.nodes(4096)
    return float(weights @ offsets[:, 0] ** 2)


def _fit_once(image: np.ndarray, r: np.ndarray, c: np.ndarray, pixel_filter=None) -> dict:
    H, W, C = image.shape
    M = WINDOW
    inside = (r - M >= 0) & (r + M < H) & (c - 1 >= 0) & (c + 1 < W)
    rr, cc = np.where(inside, r, M), np.where(inside, c, 1)
    k = np.arange(-M, M + 1)
    j = np.arange(-1, 2)
    win = image[rr[:, None, None] + k[None, :, None], cc[:, None, None] + j[None, None, :]]  # (n, 2M+1, 3, C)
    side_a, side_b = win[:, 0], win[:, -1]  # (n, 3, C) per column
    direction = (side_b - side_a).mean(axis=1)  # (n, C)
    length = np.linalg.norm(direction, axis=1)
    unit = direction / np.where(length > 0, length, 1.0)[:, None]
    s = np.einsum("nkjc,nc->nkj", win, unit)  # (n, 2M+1, 3) scalar profile along the jump's direction
    sa, sb = s[:, 0], s[:, -1]  # (n, 3)
    jump = sb - sa
    ok = inside & (length > 0) & np.all(np.abs(jump) > 1e-3 * length[:, None], axis=1)
    safe = np.where(np.abs(jump) > 0, jump, 1.0)
    mean_y = ((M + 0.5) * (sa + sb) - s.sum(axis=1)) / safe  # (n, 3) mean edge height per column
    yl, ym, yr = mean_y[:, 0], mean_y[:, 1], mean_y[:, 2]
    curv2 = 0.5 * (yl + yr - 2.0 * ym)  # y = a + b x + k x²: curv2 = k
    slope = 0.5 * (yr - yl)
    offset = ym - curv2 * _variance(pixel_filter)
    ok &= np.isfinite(offset) & (np.abs(slope) <= 1.5) & (np.abs(offset) <= M - 1)
    residual = _residual(s, sa, sb, mean_y, slope, curv2, pixel_filter)
    return {
        "across": r + 0.5 + offset,
        "along": c + 0.5,
        "offset": offset,
        "slope": slope,
        "curvature": 2.0 * curv2 / (1.0 + slope**2) ** 1.5,
        "side_a": side_a.mean(axis=1),
        "side_b": side_b.mean(axis=1),
        "residual": np.where(ok, residual, np.inf),
        "across_px": r,
        "along_px": c,
        "valid": ok,
    }


def _residual(s, sa, sb, mean_y, slope, curv2, pixel_filter=None) -> np.ndarray:
    """RMS over the window of observed minus predicted profile, as a share of the mean jump.

    s : (n, 2M+1, 3) profiles; sa, sb : (n, 3) side values; mean_y : (n, 3) mean edge heights per column;
    slope, curv2 : (n,) the parabola. Within each column the edge is taken as its tangent line; a ``pixel_filter``
    other than the box (None) predicts with its step share across that line (``dfc.pixel_model.step_share``).
    """
    M = WINDOW
    k = np.arange(-M, M + 1, dtype=np.float64)[None, :, None]  # rows
    signed = slope[:, None] + 2.0 * curv2[:, None] * np.arange(-1, 2)[None, :]  # (n, 3)
    col_slope = np.abs(signed)
    centre = k + 0.5 - mean_y[:, None, :]  # height of the row's bottom above the edge, at the column's centre
    if pixel_filter is not None and not (pixel_filter.name == "box" and pixel_filter.param is None):
        from ...pixel_model import step_share

        norm = np.sqrt(1.0 + signed**2)  # the tangent y = m x: the row side lies at y > m x, normal (−m, 1)/norm
        d = np.broadcast_to((centre - 0.5) / norm[:, None, :], s.shape).ravel()
        normal = np.stack([np.broadcast_to(-signed[:, None, :] / norm[:, None, :], s.shape).ravel(),
                           np.broadcast_to(1.0 / norm[:, None, :], s.shape).ravel()], axis=1)
        cover = step_share(pixel_filter, d, normal).reshape(s.shape)
        predicted = sa[:, None, :] + (sb - sa)[:, None, :] * cover
        jump = np.abs(sb - sa).mean(axis=1)
        rms = np.sqrt(np.mean((s - predicted) ** 2, axis=(1, 2)))
        return rms / np.where(jump > 0, jump, np.inf)
    half = 0.5 * col_slope[:, None, :]
    lo, hi = centre - half, centre + half
    with np.errstate(invalid="ignore", divide="ignore"):
        cover = np.where(hi - lo > 1e-9, (_ramp_integral(hi) - _ramp_integral(lo)) / (hi - lo), np.clip(centre, 0, 1))
    predicted = sa[:, None, :] + (sb - sa)[:, None, :] * cover
    jump = np.abs(sb - sa).mean(axis=1)
    rms = np.sqrt(np.mean((s - predicted) ** 2, axis=(1, 2)))
    return rms / np.where(jump > 0, jump, np.inf)


def _ramp_integral(t: np.ndarray) -> np.ndarray:
    """Antiderivative of clamp(t, 0, 1) that is 0 at t ≤ 0."""
    return np.where(t <= 0, 0.0, np.where(t >= 1, t - 0.5, 0.5 * t * t))


def residual_of_blur(sigma: float, pixel_filter=None) -> float:
    """The largest ``residual`` of straight steps blurred by a Gaussian of ``sigma`` px (pixels made with
    ``pixel_filter``, None: the box; 8 directions from 0° to 45°, 4 sub-pixel offsets): the misfit up to which a
    profile counts as a jump."""
    from scipy.special import ndtr

    size, ss = 2 * WINDOW + 7, 8
    centre = size / 2
    sub = (np.arange(size * ss) + 0.5) / ss
    X, Y = np.meshgrid(sub, sub)
    worst = 0.0
    for angle in np.radians(np.linspace(0.0, 45.0, 8)):
        n = np.array([np.sin(angle), np.cos(angle)])  # mostly horizontal edges
        for offset in (0.0, 0.25, 0.5, 0.75):
            d = (X - centre) * n[0] + (Y - centre - offset) * n[1]
            field = ndtr(d / sigma) if sigma > 0 else (d > 0).astype(np.float64)
            image = _pixels(field, size, ss, pixel_filter)[..., None]
            r = int(centre + offset)
            fit = edge_points(image, np.array([r]), np.array([int(centre)]), np.array([False]), pixel_filter)
            if fit.valid[0]:
                worst = max(worst, float(fit.residual[0]))
    return worst


def _pixels(fine: np.ndarray, size: int, ss: int, pixel_filter) -> np.ndarray:
    """(size, size) pixels of a field sampled ``ss`` times per pixel and axis (``fine`` (size·ss, size·ss)), made
    with ``pixel_filter`` (None: the box); the kernel's taps beyond the field's border repeat its edge."""
    if pixel_filter is None or (pixel_filter.name == "box" and pixel_filter.param is None):
        return fine.reshape(size, ss, size, ss).mean(axis=(1, 3))
    m = int(np.ceil(pixel_filter.radius + 0.5))
    k = np.arange(-m * ss, (m + 1) * ss)
    taps = pixel_filter.taps((k + 0.5) / ss - 0.5) if pixel_filter.name != "point" else (k == ss // 2) * 1.0
    if pixel_filter.name == "box":
        n = int(pixel_filter.param)
        centres = np.floor(((np.arange(n) + 0.5) / n) * ss).astype(int)
        taps = np.isin(k, centres) / n
    padded = np.pad(fine, m * ss, mode="edge")
    rows = sum(w * padded[m * ss + t: m * ss + t + size * ss: ss] for t, w in zip(k, taps) if w)
    return sum(w * rows[:, m * ss + t: m * ss + t + size * ss: ss] for t, w in zip(k, taps) if w)
