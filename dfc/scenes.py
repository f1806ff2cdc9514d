"""Analytic piecewise-smooth scenes whose value is known exactly at any point.

They serve as the shipped sample (``samples/make_sample.py``) and as exact references for zoomed
quality measurements: a raster is only exact at 1×, these are exact at every zoom.

Region membership and open-stroke jumps are computed from the *subtended angle*: for a curve γ and
a point x, ``w(x) = (1 / 2π) Σ signed angle of each flattened segment seen from x``. For a closed
curve it is the winding number (0 or ±1); for an open curve it jumps by exactly one across the
curve and is continuous (harmonic) everywhere else, including around its tips. The curves are
flattened into ``FLATTEN`` segments per piece; the polyline deviates from the Bézier by far less
than 1e-4 domain units, below what a 100× zoom of the sample resolves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .curves import Curves, elevate

FLATTEN = 512


def _bezier_points(cp: np.ndarray, degree: np.ndarray, n: int = FLATTEN) -> np.ndarray:
    """Chained pieces cp (P, 4, 2) of degrees (P,) -> polyline (M, 2); lines are not subdivided."""
    pts = []
    for piece, deg in zip(cp, degree):
        t = np.linspace(0.0, 1.0, (1 if deg == 1 else n) + 1)[:-1, None]
        pts.append(sum(w * piece[i] for i, w in enumerate([(1 - t) ** 3, 3 * (1 - t) ** 2 * t, 3 * (1 - t) * t**2, t**3])))
    return np.concatenate(pts + [cp[-1, 3][None]], axis=0)


def inside(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Points (N, 2) strictly enclosed by a closed polyline (M, 2) (non-zero winding) -> (N,) bool.
    Only points in the polygon's bounding box are tested."""
    lo, hi = polygon.min(0), polygon.max(0)
    box = np.all((xy >= lo) & (xy <= hi), axis=1)
    out = np.zeros(len(xy), dtype=bool)
    out[box] = np.abs(subtended(xy[box], polygon)) > 0.5
    return out


def subtended(xy: np.ndarray, polyline: np.ndarray, chunk: int = 1 << 14) -> np.ndarray:
    """Signed angle subtended by a polyline at points, divided by 2π.

    xy : (N, 2) float64 query points; polyline : (M, 2) float64 vertices
    returns (N,) float64; integer (winding number) for closed polylines
    """
    xy = np.asarray(xy, dtype=np.float64)
    out = np.empty(len(xy))
    for s in range(0, len(xy), chunk):
        d = polyline[None, :, :] - xy[s : s + chunk, None, :]  # (n, M, 2)
        a, b = d[:, :-1], d[:, 1:]
        cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        dot = (a * b).sum(-1)
        out[s : s + chunk] = np.arctan2(cross, dot).sum(-1) / (2 * np.pi)
    return out


@dataclass(frozen=True)
class AnalyticScene:
    """A scene with exact values.

    curves : the discontinuities, as a reader would return them
    channels : output channel names
    value : callable (N, 2) float64 domain points -> (N, C) float64 exact values
    """

    name: str
    curves: Curves
    channels: list[str]
    value: Callable[[np.ndarray], np.ndarray]

    @property
    def domain(self) -> tuple[float, float, float, float]:
        return self.curves.domain

    def render(self, width: int, height: int, window=None, spp: int = 4) -> np.ndarray:
        """Box-filtered raster (height, width, C) float32 of ``window`` (default: the domain),
        averaging ``spp × spp`` stratified points per pixel."""
        x0, y0, x1, y1 = self.domain if window is None else window
        u = (np.arange(width * spp) + 0.5) / (width * spp)
        v = (np.arange(height * spp) + 0.5) / (height * spp)
        X, Y = np.meshgrid(x0 + u * (x1 - x0), y0 + v * (y1 - y0))
        vals = self.value(np.stack([X.ravel(), Y.ravel()], axis=1))
        vals = vals.reshape(height, spp, width, spp, -1).mean(axis=(1, 3))
        return vals.astype(np.float32)


def _pieces(chains: list[tuple[str, list[tuple[int, list]]]], domain) -> Curves:
    """Build Curves from [(name, [(degree, points), ...]), ...] chains."""
    cps, degs, ids, trs, names = [], [], [], [], []
    for c, (name, pieces) in enumerate(chains):
        names.append(name)
        for k, (deg, pts) in enumerate(pieces):
            cps.append(elevate(np.asarray([pts], dtype=np.float64), deg)[0])
            degs.append(deg)
            ids.append(c)
            trs.append((k, k + 1))
    return Curves(domain, np.array(cps), degs, ids, trs, names=names, sides=[None] * len(names))


def sample_scene() -> AnalyticScene:
    """The shipped sample: 256 × 256 px, a closed cubic blob, a triangle of lines, a region cut by a
    quadratic, and an open cubic stroke whose jump ends inside the domain. RGB in [0, 1]."""
    domain = (0.0, 0.0, 256.0, 256.0)
    blob = [  # closed chain of four cubics
        (3, [(60, 150), (60, 110), (120, 100), (130, 140)]),
        (3, [(130, 140), (140, 175), (115, 215), (85, 210)]),
        (3, [(85, 210), (55, 205), (40, 185), (45, 170)]),
        (3, [(45, 170), (48, 162), (55, 157), (60, 150)]),
    ]
    tri = [(1, [(150, 30), (230, 60)]), (1, [(230, 60), (170, 120)]), (1, [(170, 120), (150, 30)])]
    cap = [(2, [(140, 256), (195, 120), (250, 256)])]  # quadratic arch standing on the border
    stroke = [(3, [(30, 40), (70, 20), (90, 90), (130, 70)])]  # open: both tips inside
    curves = _pieces([("blob", blob), ("triangle", tri), ("arch", cap), ("stroke", stroke)], domain)
    poly = {
        name: _bezier_points(curves.control_points[curves.curve == i], curves.degree[curves.curve == i])
        for i, name in enumerate(curves.names)
    }
    arch_closed = np.concatenate([poly["arch"], poly["arch"][:1]])  # closed along the border

    def value(xy: np.ndarray) -> np.ndarray:
        x, y = xy[:, 0] / 256.0, xy[:, 1] / 256.0
        out = np.stack([0.15 + 0.5 * x, 0.2 + 0.4 * y, 0.55 - 0.3 * x * y], axis=1)
        blob_in = inside(xy, poly["blob"])
        out[blob_in] = np.stack([0.9 - 0.3 * y, 0.35 + 0.2 * x, 0.1 + 0.1 * np.sin(6 * x)], 1)[blob_in]
        tri_in = inside(xy, poly["triangle"])
        out[tri_in] = np.stack([0.1 + 0.2 * y, 0.7 - 0.3 * x, 0.9 - 0.2 * y], 1)[tri_in]
        arch_in = inside(xy, arch_closed)
        out[arch_in] = np.stack([0.95 - 0.2 * x, 0.85 - 0.3 * y, 0.3 + 0.3 * x], 1)[arch_in]
        out += 0.25 * subtended(xy, poly["stroke"])[:, None] * np.array([1.0, -0.6, 0.4])
        return out

    return AnalyticScene("sample", curves, ["R", "G", "B"], value)
