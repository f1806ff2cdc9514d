"""Which pixel filter made a raster: ``detect(pixels, curves)`` (``dfc encode --pixel-filter auto``, ``dfc curves``).

Near a straight stretch of a discontinuity, a pixel at signed distance ``d`` (px, along the unit normal ``n``) from
it holds ``B + (A − B) S(d, n)``: ``A`` and ``B`` are the two sides' values there and ``S`` the share of the pixel's
filter (``dfc.pixel_filter``) on ``A``'s side — 0 or 1 for ``point``, the covered area for ``box``, a smooth ramp for
the wider kernels. The sides are read on the normal through the pixel, ``SIDE_NEAR`` and ``SIDE_FAR`` px from the
curve (bilinear), beyond every candidate's reach, and extrapolated linearly to the pixel (a smooth trend across the
curve cancels). Each candidate (``CANDIDATES``) predicts every pixel within ``PROFILE_REACH`` px of a curve; the one
with the smallest RMS misfit, as a share of the jump, wins. Only clean profiles count: the curve straight within
``STRAIGHT`` px over ``STRAIGHT_REACH`` px around its foot point, no other curve near the side samples, a jump of at
least ``MIN_JUMP`` of the image's range where its PSNR is measured (``dfc.metrics.measure_space``: tone-mapped for HDR
light, so an emitter in view does not make every other edge too small to count).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .metrics import step_size
from .pixel_filter import PixelFilter, parse

__all__ = ["CANDIDATES", "Detection", "detect", "resolve", "step_share"]

CANDIDATES = ("point", "box:2", "box:3", "box:4", "box:5", "box:6", "box:8", "box:16", "box", "tent", "gaussian:0.5",
              "blackman-harris:1.5", "mitchell")
"""Filters ``detect`` tries, as spec strings."""
PROFILE_REACH = 2.5
"""Pixels whose centre lies within this many px of a curve are predicted."""
SIDE_NEAR, SIDE_FAR = 3.5, 5.5
"""Distances (px) from the curve at which each side's value is read."""
STRAIGHT = 0.25
"""Largest deviation (px) of the curve from its tangent within ``STRAIGHT_REACH`` px of the foot point."""
STRAIGHT_REACH = 3.0
"""Distance (px) from the foot point over which the curve must be straight: the stretch a candidate's support
(at most 2 px from a pixel within ``PROFILE_REACH``) can cross, so a curve of radius 20 px still counts."""
MIN_JUMP = 0.05
"""Smallest jump of a profile that counts, as a share of the image's range in ``dfc.metrics.measure_space``."""
KEEP = 0.9
"""Share of the profile pixels a candidate's misfit is measured on (its best fitted ones). On the README sample's
scene (box, 4 x 4 sub-samples) all of them gave ``box`` (2.39 % misfit) over ``box:4`` (3.66 %): a few pixels near
the stroke's fading tips weigh more than the filter; without the worst tenth ``box:4`` wins (0.008 % against
0.30 %), at 64² with 2 x 2 sub-samples too (``box:2``)."""
MIN_PIXELS = 20
"""Fewer clean pixels than this: no evidence; ``detect`` falls back to ``FALLBACK``."""
FALLBACK = "box"
"""The filter of an image without clean profiles (dfc's model before filters were detected)."""
MIN_EVIDENCE = 3.0
"""A winner outside the box family replaces ``FALLBACK`` only when it fits better by this many standard errors (the
paired t statistic of the two squared misfits over the pixels both fit within their best ``KEEP``) or its misfit is
under ``DECISIVE`` times ``FALLBACK``'s. The misfits of a noisy render lie close (a box-filtered 128² render at 256
spp: Gaussian 17.65 %, box 18.15 %, t = 0.5), while the corpus's Gaussian-filtered renders give t = 6 to 11."""
DECISIVE = 0.5
"""A misfit under this share of ``FALLBACK``'s wins without the t statistic: a noise-free raster with few clean
pixels (a point-sampled disc: 31 pixels, point 0.00 %, box 4.2 %, t = 2.1, the two differing on four pixels)."""
SPACING = 0.05
"""Curves are sampled every this many px to find each pixel's foot point."""
_POINTS = 4096
"""Sub-samples of a ``box:N`` candidate's step share ``S`` (all of them: N ≤ 64)."""


@dataclass
class Detection:
    """The outcome of ``detect``: ``filter`` chosen; ``misfit`` RMS misfit per candidate spec (share of the jump, over
    its best ``KEEP`` of the pixels), best first; ``pixels`` clean profile pixels measured (0: no evidence, ``filter``
    is ``FALLBACK``); ``t`` the best candidate's evidence over the filter it had to beat (``FALLBACK`` when it is
    outside the box family, or ``detect``'s ``incumbent``; ``MIN_EVIDENCE``, ``DECISIVE``), else None."""

    filter: PixelFilter
    misfit: dict[str, float] = field(default_factory=dict)
    pixels: int = 0
    t: float | None = None

    def evidence(self, top: int = 3) -> str:
        """One line: the misfits of the ``top`` best candidates and the pixel count (and why ``FALLBACK`` was kept
        when the best is not it)."""
        if not self.pixels:
            return f"no clean edge profile; {FALLBACK} assumed"
        best = ", ".join(f"{k} {100 * v:.2f} %" for k, v in list(self.misfit.items())[:top])
        first = next(iter(self.misfit))
        kept = (f"; {self.filter} kept: {first} better by {self.t:.1f} standard errors, under {MIN_EVIDENCE:g}"
                if str(self.filter) != first and self.t is not None else "")
        return f"misfit on {self.pixels} edge pixels: {best}{kept}"

    def to_dict(self, top: int = 3) -> dict:
        """The record a file's encoder info keeps: the choice, the pixel count and the ``top`` best misfits."""
        return {"filter": str(self.filter), "pixels": self.pixels,
                "misfit": {k: round(v, 5) for k, v in list(self.misfit.items())[:top]}}


def resolve(spec: str, pixels: np.ndarray, curves) -> tuple[PixelFilter, Detection | None]:
    """The filter of ``spec``: ``"auto"`` → ``detect`` (returned with its ``Detection``), else ``parse(spec)``."""
    if str(spec).strip().lower() == "auto":
        found = detect(pixels, curves)
        return found.filter, found
    return parse(spec), None


def detect(pixels: np.ndarray, curves, candidates=CANDIDATES, incumbent: str | None = None) -> Detection:
    """The candidate filter that explains ``pixels`` (H, W, C) near ``curves`` (over the image's domain) best.
    ``incumbent``: a spec (tried too) that any other must beat by ``MIN_EVIDENCE`` standard errors (or
    ``DECISIVE``), as a winner outside the box family must beat ``FALLBACK`` without one."""
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    profile = _profiles(pixels, curves)
    if profile is None:
        return Detection(parse(FALLBACK))
    d, normal, value, side_a, side_b = profile
    jump = side_a - side_b
    if incumbent is not None and incumbent not in candidates:
        candidates = (*candidates, incumbent)
    misfit, errors = {}, {}
    for spec in candidates:
        share = step_share(parse(spec), d, normal)
        errors[spec] = ((value - side_b - jump * share) / jump) ** 2
        misfit[spec] = float(np.sqrt(np.mean(np.sort(errors[spec])[:max(1, int(KEEP * len(d)))])))
    ranked = dict(sorted(misfit.items(), key=lambda kv: kv[1]))
    best, t = next(iter(ranked)), None
    keep = FALLBACK if incumbent is None else incumbent
    if best != keep and keep in errors and (incumbent is not None or parse(best).name != "box"):
        t = _paired_t(errors[keep], errors[best])
        best = best if t >= MIN_EVIDENCE or misfit[best] < DECISIVE * misfit[keep] else keep
    return Detection(parse(best), ranked, len(d), t)


def _paired_t(worse: np.ndarray, better: np.ndarray) -> float:
    """The paired t statistic of ``worse − better`` (N,) squared misfits over the pixels whose larger misfit is
    within the best ``KEEP`` of them."""
    keep = np.argsort(np.maximum(worse, better))[:max(2, int(KEEP * len(worse)))]
    diff = (worse - better)[keep]
    sd = float(diff.std(ddof=1))
    if sd == 0.0:
        return float("inf") if diff.mean() > 0 else 0.0
    return float(diff.mean() / (sd / np.sqrt(len(diff))))


def step_share(f: PixelFilter, d: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(N,) share of filter ``f`` on the positive side of straight edges at signed distances ``d`` (N,) px from
    the pixels' centres (the centre lies on the positive side for d > 0), unit normals ``normal`` (N, 2).

    ``point`` and ``box:N`` sum their sub-samples exactly. The continuous kernels integrate one axis by quadrature
    (``PixelFilter.axis_nodes``) and the other exactly (``PixelFilter.cdf``): with ``|n_y| ≥ |n_x|`` (the axes
    swapped otherwise, ``n`` negated so ``n_y > 0``: the kernel is even and the same on both axes), the point
    ``(x, y)`` lies on the positive side when ``y > −(d + n_x x) / n_y``."""
    d = np.asarray(d, dtype=np.float64)
    normal = np.asarray(normal, dtype=np.float64)
    if f.name == "point" or (f.name == "box" and f.param is not None):
        offsets, weights = f.nodes(_POINTS)
        out = np.empty(len(d))
        for s in range(0, len(d), 2048):
            along = normal[s:s + 2048] @ offsets.T  # (n, K)
            out[s:s + 2048] = ((along + d[s:s + 2048, None]) > 0).astype(np.float64) @ weights
        return out
    swap = np.abs(normal[:, 0]) > np.abs(normal[:, 1])
    nx, ny = np.where(swap, normal[:, 1], normal[:, 0]), np.where(swap, normal[:, 0], normal[:, 1])
    flip = np.where(ny < 0, -1.0, 1.0)
    nx, ny = nx * flip, ny * flip
    x, w = f.axis_nodes()
    below = f.cdf(-(d[:, None] + nx[:, None] * x[None]) / ny[:, None])  # (N, M) share of y under the edge
    return (1.0 - below) @ w


def _curve_samples(curves, scale: np.ndarray, origin: np.ndarray):
    """Points (M, 2) and unit tangents (M, 2) along every piece, in pixel units, about ``SPACING`` apart."""
    cp = (curves.control_points - origin) * scale  # (P, 4, 2)
    if not len(cp):
        return np.zeros((0, 2)), np.zeros((0, 2))
    length = np.linalg.norm(np.diff(cp, axis=1), axis=2).sum(axis=1)
    pts, tan = [], []
    for piece, n in zip(cp, np.maximum(2, np.ceil(length / SPACING).astype(int) + 1)):
        t = np.linspace(0.0, 1.0, n)[:, None]
        s = 1 - t
        pts.append(s**3 * piece[0] + 3 * s * s * t * piece[1] + 3 * s * t * t * piece[2] + t**3 * piece[3])
        tan.append(3 * s * s * (piece[1] - piece[0]) + 6 * s * t * (piece[2] - piece[1]) + 3 * t * t * (piece[3] - piece[2]))
    pts, tan = np.concatenate(pts), np.concatenate(tan)
    norm = np.linalg.norm(tan, axis=1)
    keep = norm > 1e-12
    return pts[keep], tan[keep] / norm[keep, None]


def _profiles(pixels: np.ndarray, curves):
    """(d (N,), normal (N, 2), value (N,), side_a (N,), side_b (N,)) of the clean profile pixels, values projected
    on each jump's colour direction; None when fewer than ``MIN_PIXELS``."""
    from scipy.ndimage import map_coordinates
    from scipy.spatial import cKDTree

    H, W, C = pixels.shape
    x0, y0, x1, y1 = curves.domain
    scale = np.array([W / (x1 - x0), H / (y1 - y0)])
    pts, tan = _curve_samples(curves, scale, np.array([x0, y0]))
    if len(pts) < 2:
        return None
    tree = cKDTree(pts)
    jj, ii = np.mgrid[0:H, 0:W]
    centres = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], axis=1)
    dist, foot = tree.query(centres, distance_upper_bound=PROFILE_REACH)
    near = np.isfinite(dist)
    centres, foot = centres[near], foot[near]
    p, t = pts[foot], tan[foot]
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    d = np.einsum("ij,ij->i", centres - p, n)
    ok = np.ones(len(d), dtype=bool)
    # straight: every curve sample within STRAIGHT_REACH of the foot point lies near its tangent line
    for k, group in enumerate(tree.query_ball_point(p, STRAIGHT_REACH)):
        q = pts[group] - p[k]
        if np.abs(q @ n[k]).max() > STRAIGHT:
            ok[k] = False
    # side samples on the normal through the pixel, clear of every curve
    offsets = np.array([SIDE_NEAR, SIDE_FAR, -SIDE_NEAR, -SIDE_FAR])
    spots = centres[:, None, :] + (offsets[None, :, None] - d[:, None, None]) * n[:, None, :]  # (N, 4, 2)
    flat = spots.reshape(-1, 2)
    clear = tree.query(flat, distance_upper_bound=SIDE_NEAR - 0.6)[0]
    ok &= np.isinf(clear).reshape(-1, 4).all(axis=1)
    ok &= ((flat[:, 0] >= 0.5) & (flat[:, 0] <= W - 0.5) & (flat[:, 1] >= 0.5) & (flat[:, 1] <= H - 0.5)).reshape(-1, 4).all(axis=1)
    if ok.sum() < MIN_PIXELS:
        return None
    d, n, centres, spots = d[ok], n[ok], centres[ok], spots[ok]
    rc = [spots.reshape(-1, 2)[:, 1] - 0.5, spots.reshape(-1, 2)[:, 0] - 0.5]
    sides = np.stack([map_coordinates(pixels[..., c], rc, order=1, mode="nearest") for c in range(C)], axis=-1)
    sides = sides.reshape(-1, 4, C)
    a = sides[:, 0] + (sides[:, 0] - sides[:, 1]) * (SIDE_NEAR - d)[:, None] / (SIDE_FAR - SIDE_NEAR)
    b = sides[:, 2] + (sides[:, 2] - sides[:, 3]) * (SIDE_NEAR + d)[:, None] / (SIDE_FAR - SIDE_NEAR)
    jump = a - b
    size = np.linalg.norm(jump, axis=1)
    keep = step_size(a, b, pixels) >= MIN_JUMP
    if keep.sum() < MIN_PIXELS:
        return None
    unit = jump[keep] / size[keep, None]
    ij = np.floor(centres[keep]).astype(np.int64)
    value = np.einsum("ic,ic->i", pixels[ij[:, 1], ij[:, 0]], unit)
    return (d[keep], n[keep], value, np.einsum("ic,ic->i", a[keep], unit), np.einsum("ic,ic->i", b[keep], unit))
