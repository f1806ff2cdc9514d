"""Which curves earn their bytes: ``prune_curves(pixels, curves, ...) -> Pruned``.

A curve makes the field discontinuous where it runs; without it the field is continuous there and a step in the
pixels is smeared over about one triangle. Each curve is priced and paid, from the image alone (no fit):

- **what it earns** (``curve_gains``): at points every ``SPACING`` px along it, the image is read (bilinear) on
  the normal over ``±edge`` px (``edge``: the mesh's nominal edge length, in pixels), in the space the file's PSNR is
  measured in (values over their range; HDR light tone-mapped ``x / (1 + x)``). Two models are fitted to each
  profile by least squares: a *step* (``a + b s + J step(s)``, the step one pixel wide: what a curve plus the pixel
  filter draws) and a *continuous* one (``a + b s + J ramp(s)``, the ramp ``RAMP`` edge lengths wide: the best a mesh
  without the curve does). The squared error the curve removes is the continuous model's residual minus the step's,
  integrated over the profile and along the curve (value² × px²: the sum of squared pixel errors it saves, ≥ 0).
  A soft shadow or a defocused edge is explained as well by the ramp and earns little; a low-contrast step earns
  its contrast squared.
- **what it costs** (``curve_bytes``): the vertices it forces into the mesh (its pieces' ends, the apex of each
  curved piece, a vertex every edge length along a line) at ``BYTES_PER_VERTEX`` each (position, a feature vector
  per side, the triangles around it), plus ``BYTES_PER_PIECE`` for its piece in the curves chunk.

A curve is kept when it earns at least ``λ`` per byte (``MIN_GAIN_PER_BYTE`` for a file of the default size); under
a byte target, curves are kept best-earning first while their bytes stay within ``CURVE_SHARE`` of the target, so
smaller targets keep fewer curves. Only whole curves are dropped and the kept ones are returned unchanged, so every
junction, T (an end welded onto another curve) and shared end point among the kept curves stays exactly as it was;
an end welded onto a dropped curve becomes a free end.

Coordinates follow ``spec/conventions.md``: pixel ``(r, c)`` covers ``[c, c + 1] × [r, r + 1]``; curves over
another domain are scaled onto the image's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...metrics import measure_space
from .. import bezier
from ..curves import DEGREE_LINE, Curves, fit_curves_to_domain

__all__ = ["Pruned", "curve_bytes", "curve_gains", "prune_curves", "BYTES_PER_PIECE", "BYTES_PER_VERTEX",
           "CURVE_SHARE", "MIN_GAIN_PER_BYTE", "RAMP", "SPACING"]

SPACING = 0.5
"""Distance (px) between the points along a curve where its profile is read."""
STEP = 0.25
"""Distance (px) between the samples of a profile across the curve."""
RAMP = 1.0
"""Width of the continuous model's ramp, in nominal edge lengths of the mesh."""
BYTES_PER_VERTEX = 28.0
"""Bytes a vertex forced onto a curve adds to a file: its position, a feature vector per side and the triangles
around it (the smallest files of subsets of a third-party EXR's curves grow by 28–30 bytes per vertex counted
so; CHANGELOG.md, "Curves that earn their bytes")."""
BYTES_PER_PIECE = 9.0
"""Bytes a piece adds to the curves chunk."""
MIN_GAIN_PER_BYTE = 5e-4
"""λ without a byte target: squared error (values over their range, squared, × px²) a curve must remove per byte:
about what a byte buys elsewhere in a default 256² file near 40 dB (its PSNR rising 0.5–3 dB per doubling of
bytes)."""
CURVE_SHARE = 0.5
"""Under a byte target the kept curves' bytes stay within this share of it."""


@dataclass(frozen=True)
class Pruned:
    """The outcome of ``prune_curves``.

    curves : the kept curves (``Curves``; pieces, names and sides of the kept input curves, in their order)
    kept : (n,) bool per input curve of the given set
    gain : (n,) float64 squared error each curve removes (normalised values² × px²)
    cost : (n,) float64 bytes each curve costs
    lam : the λ (gain per byte) the kept curves reach
    """

    curves: Curves
    kept: np.ndarray
    gain: np.ndarray
    cost: np.ndarray
    lam: float

    def summary(self) -> str:
        n, k = len(self.kept), int(self.kept.sum())
        return (f"{n - k} of {n} curves dropped (each kept curve removes at least {self.lam:.2g} of squared error per "
                f"byte it costs; {self.cost[self.kept].sum():.0f} of {self.cost.sum():.0f} curve bytes kept)")

    def to_dict(self) -> dict:
        return {"curves": int(len(self.kept)), "dropped": int((~self.kept).sum()), "lambda": float(f"{self.lam:.4g}"),
                "bytes_kept": round(float(self.cost[self.kept].sum()), 1), "bytes": round(float(self.cost.sum()), 1)}


def _residual_projector(s: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """(K, K) projector onto the residual of least squares by ``a + b s + J shape(s)``."""
    a = np.stack([np.ones_like(s), s, shape], axis=1)
    return np.eye(len(s)) - a @ np.linalg.pinv(a)


def curve_gains(pixels: np.ndarray, curves: Curves, edge: float) -> np.ndarray:
    """(n_curves,) float64 ≥ 0: squared error (values in the PSNR's space, squared, × px²) each input curve of
    ``curves`` removes against a continuous field on a mesh of nominal edge length ``edge`` (px).

    pixels : (H, W, C) linear values; curves : over the image's domain ``[0, W] × [0, H]`` (scaled onto it when over
    another domain)
    """
    values = measure_space(pixels)
    H, W, C = values.shape
    curves = fit_curves_to_domain(curves, (0.0, 0.0, float(W), float(H)))
    half = max(float(edge), 2.0)
    s = np.arange(-half, half + STEP / 2, STEP)
    step = np.clip(s + 0.5, 0.0, 1.0)
    ramp = np.clip(s / (RAMP * edge) + 0.5, 0.0, 1.0)
    keep_step, keep_ramp = _residual_projector(s, step), _residual_projector(s, ramp)
    gains = np.zeros(curves.n_curves)
    if not len(curves):
        return gains
    from scipy.ndimage import map_coordinates

    cp = curves.control_points
    lengths = np.linalg.norm(np.diff(bezier.flatten(cp, 16), axis=1), axis=2).sum(axis=1)
    counts = np.maximum(1, np.ceil(lengths / SPACING).astype(np.int64))
    piece = np.repeat(np.arange(len(cp)), counts)
    t = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + 0.5) / np.repeat(counts, counts)
    xy = bezier.evaluate(cp[piece], t)
    d = bezier.derivative(cp[piece], t)
    norm = np.linalg.norm(d, axis=1)
    ok = norm > 1e-12
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.where(ok, norm, 1.0)[:, None]
    ds = (lengths / counts)[piece]
    for start in range(0, len(xy), 4096):
        sl = slice(start, start + 4096)
        pts = xy[sl, None, :] + s[None, :, None] * n[sl, None, :]  # (M, K, 2)
        rows, cols = pts[..., 1] - 0.5, pts[..., 0] - 0.5
        profile = np.stack([map_coordinates(values[..., c], [rows, cols], order=1, mode="nearest")
                            for c in range(C)], axis=-1)  # (M, K, C)
        sse_ramp = (np.einsum("kj,mjc->mkc", keep_ramp, profile) ** 2).sum(axis=(1, 2))
        sse_step = (np.einsum("kj,mjc->mkc", keep_step, profile) ** 2).sum(axis=(1, 2))
        gain = np.maximum(sse_ramp - sse_step, 0.0) * STEP * ds[sl] * ok[sl]
        np.add.at(gains, curves.curve[piece[sl]], gain)
    return gains


def curve_bytes(curves: Curves, edge: float, domain_px: tuple[int, int] | None = None) -> np.ndarray:
    """(n_curves,) float64: bytes each input curve adds to a file whose mesh has nominal edge length ``edge`` (px):
    ``BYTES_PER_VERTEX`` per vertex it forces (one per piece end — shared ends counted once per curve —, one per
    curved piece's apex, one every ``edge`` along a line) and ``BYTES_PER_PIECE`` per piece. ``domain_px``: (W, H)
    of the image the curves are scaled onto (default: the curves' own domain)."""
    if domain_px is not None:
        curves = fit_curves_to_domain(curves, (0.0, 0.0, *map(float, domain_px)))
    cost = np.zeros(curves.n_curves)
    if not len(curves):
        return cost
    cp = curves.control_points
    chord = np.linalg.norm(cp[:, 3] - cp[:, 0], axis=1)
    line = curves.degree == DEGREE_LINE
    vertices = 1.0 + np.where(line, np.floor(chord / max(edge, 1e-9)), 1.0)  # the end vertex, apex or cuts
    per_piece = BYTES_PER_VERTEX * vertices + BYTES_PER_PIECE
    np.add.at(cost, curves.curve, per_piece)
    starts = np.bincount(curves.curve, minlength=curves.n_curves) > 0
    return cost + BYTES_PER_VERTEX * starts  # each curve's first vertex


def prune_curves(pixels: np.ndarray, curves: Curves, *, n_triangles: int | None = None,
                 target_bytes: int | None = None) -> Pruned:
    """The curves of ``curves`` that earn their bytes on the image ``pixels`` (H, W, C), for a mesh of about
    ``n_triangles`` triangles (default ``dfc.geometry.triangulate.DEFAULT_TRIANGLES``, at most one per 16 pixels)
    and a file of at most ``target_bytes`` (None: no target).

    Raises ``InputError`` for an image with NaN or infinite values, ``ValueError`` for a target or triangle count
    below 1.
    """
    from ...rate import PIXELS_PER_TRIANGLE
    from ..triangulate import DEFAULT_TRIANGLES, nominal_edge

    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3:
        raise ValueError(f"pixels: expected (H, W, C), got shape {pixels.shape}")
    if not np.isfinite(pixels).all():
        raise InputError(f"image holds {int((~np.isfinite(pixels)).sum())} NaN or infinite value(s)")
    if target_bytes is not None and target_bytes < 1:
        raise ValueError(f"target_bytes must be at least 1, got {target_bytes}")
    if n_triangles is not None and n_triangles < 1:
        raise ValueError(f"n_triangles must be at least 1, got {n_triangles}")
    H, W = pixels.shape[:2]
    if n_triangles is None:
        n_triangles = max(2, min(DEFAULT_TRIANGLES, W * H // PIXELS_PER_TRIANGLE))
    edge = nominal_edge((0.0, 0.0, float(W), float(H)), n_triangles)  # px
    gain = curve_gains(pixels, curves, edge)
    cost = curve_bytes(curves, edge, (W, H))
    ratio = gain / np.maximum(cost, 1e-9)
    kept = ratio >= MIN_GAIN_PER_BYTE
    lam = MIN_GAIN_PER_BYTE
    if target_bytes is not None:
        order = np.argsort(-ratio, kind="stable")
        within = np.cumsum(cost[order]) <= CURVE_SHARE * target_bytes
        fits = np.zeros_like(kept)
        fits[order[within]] = True
        kept &= fits
    if kept.any():
        lam = max(lam, float(ratio[kept].min()))
    return Pruned(_subset(curves, kept), kept, gain, cost, lam)


def _subset(curves: Curves, kept: np.ndarray) -> Curves:
    """The pieces of the kept input curves, renumbered in order."""
    pieces = kept[curves.curve]
    new = np.cumsum(kept) - 1
    return Curves(curves.domain, curves.control_points[pieces], curves.degree[pieces], new[curves.curve[pieces]],
                  curves.t_range[pieces], [n for n, k in zip(curves.names, kept) if k],
                  [sd for sd, k in zip(curves.sides, kept) if k] if curves.sides else [], curves.source)
