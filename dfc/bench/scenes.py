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

from ..geometry.curves import Curves, elevate
from ..geometry.plane import cross

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


def subtended(xy: np.ndarray, polyline: np.ndarray, run: int = 16) -> np.ndarray:
    """Signed angle subtended by a polyline at points, divided by 2π.

    xy : (N, 2) float64 query points; polyline : (M, 2) float64 vertices
    returns (N,) float64; integer (winding number) for closed polylines

    The polyline is taken ``run`` segments at a time. A point outside a run's bounding box sees the whole run
    within less than a half-turn (a line separates them), so the run subtends exactly the angle between its first
    and its last vertex as seen from there; only points inside the box sum the run's segments one by one.
    """
    xy = np.asarray(xy, dtype=np.float64)
    polyline = np.asarray(polyline, dtype=np.float64)
    out = np.zeros(len(xy))
    for start in range(0, len(polyline) - 1, run):
        part = polyline[start : start + run + 1]
        lo, hi = part.min(axis=0), part.max(axis=0)
        near = np.all((xy >= lo) & (xy <= hi), axis=1)
        far = ~near
        a, b = part[0] - xy[far], part[-1] - xy[far]
        out[far] += np.arctan2(cross(a, b), (a * b).sum(-1))
        if near.any():
            d = part[None, :, :] - xy[near, None, :]  # (n, run + 1, 2)
            a, b = d[:, :-1], d[:, 1:]
            out[near] += np.arctan2(cross(a, b), (a * b).sum(-1)).sum(-1)
    return out / (2 * np.pi)


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


def _polylines(curves: Curves) -> dict[str, np.ndarray]:
    """Flattened polyline (M, 2) of every input curve, by name."""
    return {
        name: _bezier_points(curves.control_points[curves.curve == i], curves.degree[curves.curve == i])
        for i, name in enumerate(curves.names)
    }


def _circle(cx: float, cy: float, r: float) -> list[tuple[int, list]]:
    """A closed chain of four cubics approximating a circle (the usual κ = 0.5523 construction)."""
    k = 0.5522847498 * r
    pts = [(cx + r, cy), (cx, cy + r), (cx - r, cy), (cx, cy - r), (cx + r, cy)]
    tan = [(0, k), (-k, 0), (0, -k), (k, 0), (0, k)]
    return [(3, [pts[i], (pts[i][0] + tan[i][0], pts[i][1] + tan[i][1]),
                 (pts[i + 1][0] - tan[i + 1][0], pts[i + 1][1] - tan[i + 1][1]), pts[i + 1]]) for i in range(4)]


def _polygon(points: list[tuple[float, float]]) -> list[tuple[int, list]]:
    return [(1, [points[i], points[(i + 1) % len(points)]]) for i in range(len(points))]


def _shapes_layout():
    """Curves and region masks of the ``shapes`` geometry: 256 × 256, four disjoint closed shapes (a cubic
    blob holding a circle, a five-pointed star of lines, a quadratic lens) over a smooth background."""
    domain = (0.0, 0.0, 256.0, 256.0)
    blob = [
        (3, [(40, 60), (50, 20), (120, 15), (125, 60)]),
        (3, [(125, 60), (130, 100), (110, 130), (75, 125)]),
        (3, [(75, 125), (40, 120), (30, 95), (40, 60)]),
    ]
    c, r_out, r_in = (190.0, 80.0), 50.0, 20.0
    angles = -np.pi / 2 + np.arange(10) * np.pi / 5
    radii = np.where(np.arange(10) % 2 == 0, r_out, r_in)
    star = _polygon([(c[0] + rr * np.cos(a), c[1] + rr * np.sin(a)) for a, rr in zip(angles, radii)])
    lens = [(2, [(60, 200), (120, 150), (180, 200)]), (2, [(180, 200), (120, 250), (60, 200)])]
    ring = _circle(82.0, 75.0, 18.0)
    curves = _pieces([("blob", blob), ("star", star), ("lens", lens), ("circle", ring)], domain)
    poly = _polylines(curves)

    def regions(xy: np.ndarray) -> dict[str, np.ndarray]:
        circle = inside(xy, poly["circle"])
        return {"blob": inside(xy, poly["blob"]) & ~circle, "circle": circle, "star": inside(xy, poly["star"]),
                "lens": inside(xy, poly["lens"])}

    return curves, regions


def _shapes_colours(xy: np.ndarray, regions: dict[str, np.ndarray]) -> np.ndarray:
    """Piecewise-smooth RGB in [0, 1] of the ``shapes`` layout: one smooth function per region."""
    x, y = xy[:, 0] / 256.0, xy[:, 1] / 256.0
    out = np.stack([0.2 + 0.3 * x + 0.1 * np.sin(5 * y), 0.3 + 0.3 * y, 0.6 - 0.3 * x], axis=1)
    smooth = {
        "blob": (0.85 - 0.4 * y, 0.25 + 0.3 * x, 0.15 + 0.1 * np.cos(8 * x)),
        "circle": (0.1 + 0.2 * x, 0.15 + 0.1 * y, 0.35 + 0.2 * y),
        "star": (0.95 - 0.2 * y, 0.8 - 0.3 * x, 0.2 + 0.2 * np.sin(7 * x * y)),
        "lens": (0.2 + 0.3 * np.sin(4 * x), 0.75 - 0.3 * y, 0.3 + 0.4 * x),
    }
    for name, mask in regions.items():
        out[mask] = np.stack(smooth[name], axis=1)[mask]
    return out


def shapes_scene() -> AnalyticScene:
    """``shapes``: 256 × 256 px, piecewise-smooth RGB in [0, 1] separated by closed Bézier shapes (a cubic blob
    holding a cubic circle, a quadratic lens) and a polygon (a five-pointed star of lines)."""
    curves, regions = _shapes_layout()
    return AnalyticScene("shapes", curves, ["R", "G", "B"], lambda xy: _shapes_colours(xy, regions(xy)))


HDR_GAIN = {"background": 0.5, "blob": 20.0, "circle": 200.0, "star": 5.0, "lens": 60.0}
"""Per-region gain of the ``hdr`` scene over the ``shapes`` colours."""


def hdr_scene() -> AnalyticScene:
    """``hdr``: the ``shapes`` layout with per-region gains ``HDR_GAIN``: linear RGB from ≈ 0.05 to ≈ 190."""
    curves, regions = _shapes_layout()

    def value(xy: np.ndarray) -> np.ndarray:
        masks = regions(xy)
        gain = np.full(len(xy), HDR_GAIN["background"])
        for name, mask in masks.items():
            gain[mask] = HDR_GAIN[name]
        return _shapes_colours(xy, masks) * gain[:, None]

    return AnalyticScene("hdr", curves, ["R", "G", "B"], value)


STROKES_OFFSET = 0.75
"""Constant added to the ``strokes`` value so it stays positive."""


def strokes_scene() -> AnalyticScene:
    """``strokes``: 256 × 256, one channel ``Y = STROKES_OFFSET + Σ_k w_k(x)`` with ``w_k`` the angle stroke k
    subtends at x divided by 2π. Each open stroke (a cubic, a quadratic, a two-line polyline) ends inside the
    domain; ``Y`` jumps by exactly one across a stroke and is continuous (harmonic) elsewhere."""
    domain = (0.0, 0.0, 256.0, 256.0)
    strokes = [
        ("cubic", [(3, [(40, 60), (90, 10), (140, 120), (200, 50)])]),
        ("quadratic", [(2, [(50, 200), (110, 120), (170, 210)])]),
        ("polyline", [(1, [(190, 120), (225, 160)]), (1, [(225, 160), (200, 215)])]),
    ]
    curves = _pieces(strokes, domain)
    poly = _polylines(curves)

    def value(xy: np.ndarray) -> np.ndarray:
        return (STROKES_OFFSET + sum(subtended(xy, poly[name]) for name, _ in strokes))[:, None]

    return AnalyticScene("strokes", curves, ["Y"], value)


class Stripes:
    """``stripes``: a ``size × size`` domain cut into ``boundaries + 1`` horizontal stripes by wavy boundaries, each a
    chain of ``pieces`` cubic Béziers from the left border to the right one — ``boundaries · pieces`` curve pieces,
    10,000 by default — over RGB values in [0.1, 0.9], smooth inside each stripe and jumping across every boundary.

    Exact at any zoom and fast at any size: a piece's control points are evenly spaced in x, so the boundary is the
    graph ``y = B_k(x)`` of a cubic polynomial, and a point's stripe is the number of boundaries above it. Knot and
    control heights of boundary k lie within ``WAVE`` of the stripe spacing around ``(k + 1/2) · spacing``, and a
    Bézier lies in the hull of its control points, so boundaries never meet. ``rows`` renders whole rows at pixel
    centres without evaluating every boundary at every pixel (one boundary crossing per column and boundary).
    """

    WAVE = 0.3
    """Boundary amplitude, × the stripe spacing."""

    def __init__(self, size: float = 1024.0, boundaries: int = 100, pieces: int = 100, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.size, self.k, self.m = float(size), int(boundaries), int(pieces)
        spacing = self.size / self.k
        base = (np.arange(self.k) + 0.5)[:, None] * spacing
        knots = base + self.WAVE * spacing * rng.uniform(-1, 1, (self.k, self.m + 1))
        inner = base[:, :, None] + self.WAVE * spacing * rng.uniform(-1, 1, (self.k, self.m, 2))
        self.heights = np.stack([knots[:, :-1], inner[..., 0], inner[..., 1], knots[:, 1:]], axis=2)  # (K, M, 4)
        self.phase = rng.uniform(0, 2 * np.pi, (self.k + 1, 3))
        self.freq = rng.uniform(0.5, 3.0, (self.k + 1, 3, 2))
        self.channels = ["R", "G", "B"]

    @property
    def domain(self) -> tuple[float, float, float, float]:
        return (0.0, 0.0, self.size, self.size)

    def curves(self) -> Curves:
        dx = self.size / self.m
        x = (np.arange(self.m)[:, None] + np.arange(4)[None, :] / 3.0) * dx  # (M, 4)
        cp = np.stack([np.broadcast_to(x, self.heights.shape), self.heights], axis=-1).reshape(-1, 4, 2)
        n = self.k * self.m
        return Curves(self.domain, cp, np.full(n, 3, dtype=np.int8), np.repeat(np.arange(self.k), self.m),
                      np.tile(np.stack([np.arange(self.m), np.arange(1, self.m + 1)], 1), (self.k, 1)),
                      names=[f"boundary {k}" for k in range(self.k)], sides=[None] * self.k, source="stripes")

    def boundary_y(self, x: np.ndarray) -> np.ndarray:
        """Heights (K, N) of every boundary at abscissae x (N,)."""
        u = np.clip(np.asarray(x, dtype=np.float64) / self.size, 0.0, 1.0) * self.m
        j = np.minimum(u.astype(np.int64), self.m - 1)
        t, h = u - j, self.heights[:, j]  # (N,), (K, N, 4)
        s = 1.0 - t
        return s**3 * h[..., 0] + 3 * s * s * t * h[..., 1] + 3 * s * t * t * h[..., 2] + t**3 * h[..., 3]

    def _colour(self, stripe: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """RGB (N, 3) float64 of points x, y (N,) of one stripe."""
        f = self.freq[stripe] * (2 * np.pi / self.size)  # (3, 2)
        return 0.5 + 0.4 * np.sin(x[:, None] * f[:, 0] + y[:, None] * f[:, 1] + self.phase[stripe])

    def value(self, xy: np.ndarray) -> np.ndarray:
        """Exact RGB (N, 3) float64 at points xy (N, 2): a point on a boundary belongs to the stripe below it."""
        xy = np.asarray(xy, dtype=np.float64)
        stripe = (self.boundary_y(xy[:, 0]) < xy[:, 1]).sum(axis=0)
        out = np.empty((len(xy), 3))
        for k in np.unique(stripe):
            (i,) = np.nonzero(stripe == k)
            out[i] = self._colour(k, xy[i, 0], xy[i, 1])
        return out

    def rows(self, y0: int, y1: int, width: int, height: int) -> np.ndarray:
        """Rows ``y0 .. y1 - 1`` (y1 - y0, width, 3) float32 of a ``width × height`` raster of the domain, each pixel
        the exact value at its centre (as ``value``, computed by counting boundary crossings per column)."""
        x = (np.arange(width) + 0.5) * (self.size / width)
        y = (np.arange(y0, y1) + 0.5) * (self.size / height)
        # first row whose centre lies below each boundary, per boundary and column
        first = np.searchsorted(y, self.boundary_y(x), side="right")  # (K, W) in 0 .. y1 - y0
        events = np.bincount((first * width + np.arange(width)).ravel(), minlength=(y1 - y0 + 1) * width)
        stripe = np.cumsum(events.reshape(y1 - y0 + 1, width), axis=0)[:-1]  # (h, W)
        out = np.empty((y1 - y0, width, 3), dtype=np.float32)
        for k in np.unique(stripe):  # a band meets a few stripes
            r, c = np.nonzero(stripe == k)
            out[r, c] = self._colour(k, x[c], y[r])
        return out

    def scene(self) -> AnalyticScene:
        return AnalyticScene("stripes", self.curves(), self.channels, self.value)


SCENES: dict[str, Callable[[], AnalyticScene]] = {
    "sample": sample_scene,
    "shapes": shapes_scene,
    "strokes": strokes_scene,
    "hdr": hdr_scene,
}
"""Scene name -> factory of the analytic scenes."""
SUMMARIES = {
    "sample": "the shipped sample: 256 × 256 RGB in [0, 1]; a cubic blob, a triangle, a quadratic arch, a stroke",
    "shapes": "256 × 256 RGB in [0, 1]; a cubic blob holding a circle, a quadratic lens and a star of lines",
    "strokes": "256 × 256, one channel; three open strokes whose jump of 1 fades out inside the domain",
    "hdr": "the shapes layout with per-region gains: linear RGB from about 0.05 to 190",
}
"""Scene name -> one-line summary (``dfc bench --list-scenes``)."""


def get_scene(name: str) -> AnalyticScene:
    """The scene called ``name`` (a key of ``SCENES``); raises InputError naming the known ones."""
    from ..errors import InputError

    if name not in SCENES:
        raise InputError(f"unknown scene {name!r}; known scenes: {', '.join(sorted(SCENES))}")
    return SCENES[name]()


def curve_probes(curves: Curves, count: int = 2) -> np.ndarray:
    """(k, 2) float64 points on discontinuities, k = min(count, number of input curves): the middle
    (parameter 0.5) of the middle piece of each of the first ``count`` input curves."""
    cp, ids = curves.control_points, curves.curve
    out = []
    for c in np.unique(ids)[:count]:
        piece = cp[ids == c][(ids == c).sum() // 2]
        out.append(0.125 * piece[0] + 0.375 * piece[1] + 0.375 * piece[2] + 0.125 * piece[3])
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def default_probes(scene: AnalyticScene, count: int = 2) -> np.ndarray:
    """The default zoom centres of a scene: ``curve_probes`` of its curves (points on discontinuities)."""
    return curve_probes(scene.curves, count)
