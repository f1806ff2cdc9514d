"""Walk-on-spheres (Muller 1956; Sawhney and Crane 2020) for diffusion curves (paper §6.2).

The scene is a ``Curves`` whose input curves all carry ``SideValues``: the solution ``u`` of Laplace's
equation ``Δu = 0`` takes the left value on the left of each curve and the right value on its right
(two-sided Dirichlet conditions, sides as in ``spec/conventions.md``), and no flux leaves through the canvas
border (Neumann, ``∂u/∂n = 0``).

**The Neumann border by reflection.** Mirror the domain across its four sides, again and again: the
unfolded plane is tiled with mirror images of the domain and of its curves, and ``u`` extended by the same
mirroring is harmonic across the border lines, which is exactly the zero-flux condition. A walk in the
unfolded plane, folded back into the domain (``reflect``), is a walk in the domain that bounces off its
border. For a point inside the domain, no mirror image of a curve is closer than the curve itself (each
reflection only adds distance), so the largest empty sphere in the unfolded plane has the radius
*distance to the nearest curve* — not to the border — and a step may well leave the rectangle; it is
folded back. Every walk ends within ``eps`` of a curve, where it takes the value of the closest curve
point on its own side; walks still running after ``max_steps`` steps take that value too and are counted.

**Closest points.** The pieces (cleaned up by ``dfc.geometry.cleanup.clean``: clipped to the domain, which the
mirror argument needs) are flattened into polylines whose vertices lie on the curves, at most
``SPACING_REL`` × diagonal apart and at most ``FLATNESS_REL`` × diagonal from the curves; a
``scipy.spatial.cKDTree`` over the vertices gives a conservative sphere radius far from the curves (nearest
vertex distance minus half a segment), and near them the exact distance to the segments next to the
``K_NEAR`` nearest vertices. Far from the curves a grid of such bounds, precomputed at cell centres and
lowered by half a cell diagonal, answers without a tree query. The hit point is then refined by Newton's
method on the exact Bézier, and the sign of ``cross(tangent, p − curve(s))`` picks the side;
``Curves.t_range`` maps the piece's ``t`` to the input curve's ``s`` at which its side values are
interpolated.

All active walkers advance together (vectorised numpy, CPU).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..geometry import bezier
from ..geometry.curves import Curves
from ..geometry.plane import cross
from ..geometry.tolerances import tol
from ..io.samples import SampleSet, default_channels

__all__ = [
    "DEFAULT_EPS_REL",
    "DEFAULT_MAX_STEPS",
    "Polylines",
    "Scene",
    "check_scene",
    "flatten_curves",
    "grid_size",
    "reflect",
    "sample_scene",
    "walk_on_spheres",
]

DEFAULT_EPS_REL = 1e-4
"""Default stopping distance ``eps`` of a walk, × domain diagonal (0.07 px on a 512² canvas)."""
DEFAULT_MAX_STEPS = 1000
"""Default cap on the steps of one walk (the mean is about 10–20 on the shipped scenes)."""
SPACING_REL = 1.0 / 2048.0
"""Largest gap between polyline vertices, × diagonal (bounds the kd-tree distance's slack)."""
FLATNESS_REL = 1e-6
"""Largest deviation of the polylines from the curves, × diagonal (subtracted from every sphere radius)."""
K_NEAR = 8
"""Vertices whose adjacent segments are searched exactly for walkers near a curve."""
NEAR_SEGMENTS = 4.0
"""A walker within this many segment lengths of a vertex gets the exact segment search."""
NEWTON_STEPS = 8
"""Newton iterations refining a hit point on the exact Bézier."""
GRID_CELLS = 512
"""Cells on the long side of the grid of precomputed distance bounds that answers walkers far from curves."""
WORKERS = -1
"""Threads of the kd-tree queries (-1: all cores)."""
CHUNK = 1 << 17
"""Walks run together by ``sample_scene`` (bounds memory; one progress report each)."""


def check_scene(curves: Curves) -> int:
    """Check that ``curves`` is a diffusion-curve scene; return its channel count C.

    Raises ``InputError`` when there are no curves or some input curve has no side values.
    """
    src = f"{curves.source}: " if curves.source else ""
    if len(curves) == 0:
        raise InputError(f"{src}no curves: a diffusion-curve scene needs Dirichlet values on at least one curve")
    used = np.unique(curves.curve)  # input curves that have pieces
    sides = list(curves.sides) + [None] * max(0, int(used[-1]) + 1 - len(curves.sides))
    missing = [curves.names[i] if i < len(curves.names) else f"curve {i}" for i in used if sides[i] is None]
    if missing:
        raise InputError(f"{src}{', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''}: "
                         "no side values; a diffusion-curve scene needs a left and a right value on every curve")
    return int(sides[int(curves.curve[0])].left.shape[1])


@dataclass(frozen=True)
class Polylines:
    """The pieces flattened into polylines; every vertex lies on its piece.

    vertices : (V, 2) float64; piece : (V,) int64 piece of each vertex; t : (V,) float64 its local parameter
    last : (V,) bool, the last vertex of its piece (no segment starts there); segment ``s`` joins vertices s, s + 1
    max_segment : longest segment; deviation : bound on the distance between the polylines and the pieces
    """

    vertices: np.ndarray
    piece: np.ndarray
    t: np.ndarray
    last: np.ndarray
    max_segment: float
    deviation: float


def flatten_curves(cp: np.ndarray, spacing: float, flatness: float) -> Polylines:
    """Uniform-in-t polylines of cubic pieces with segments at most ``spacing`` long and ``flatness`` off.

    cp : (P, 4, 2) float64 control points. The bounds used: ``|B'| ≤ 3 max|ΔP|`` and ``|B''| ≤ 6 max|Δ²P|``; a
    chord over a parameter step ``h`` strays at most ``h² max|B''| / 8`` from the arc.
    """
    d1 = np.linalg.norm(np.diff(cp, axis=1), axis=2).max(axis=1)
    d2 = np.linalg.norm(np.diff(cp, n=2, axis=1), axis=2).max(axis=1)
    n = np.maximum(np.ceil(3.0 * d1 / spacing), np.ceil(np.sqrt(6.0 * d2 / (8.0 * flatness))))
    n = np.maximum(n, 1).astype(np.int64)
    counts = n + 1
    piece = np.repeat(np.arange(len(cp)), counts)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    k = np.arange(len(piece)) - start[piece]
    t = k / n[piece]
    vertices = bezier.evaluate(cp[piece], t)
    last = k == n[piece]
    seg = np.flatnonzero(~last)
    lengths = np.linalg.norm(vertices[seg + 1] - vertices[seg], axis=1)
    deviation = float(np.max(6.0 * d2 / (8.0 * n * n))) if len(cp) else 0.0
    return Polylines(vertices, piece, t, last, float(lengths.max(initial=0.0)), deviation)


def reflect(xy: np.ndarray, domain) -> np.ndarray:
    """Fold points of the unfolded (mirror-tiled) plane back into the domain: (N, 2) -> (N, 2) float64.

    Identity inside the closed rectangle; a point beyond a side lands at its mirror image, and so on.
    """
    x0, y0, x1, y1 = domain
    lo = np.array([x0, y0])
    size = np.array([x1 - x0, y1 - y0])
    r = np.mod(np.asarray(xy, dtype=np.float64) - lo, 2.0 * size)
    return lo + size - np.abs(r - size)


def grid_size(domain, resolution: int) -> tuple[int, int]:
    """(width, height) of a pixel grid over ``domain`` with ``resolution`` pixels on its long side."""
    x0, y0, x1, y1 = domain
    w, h = x1 - x0, y1 - y0
    if w >= h:
        return int(resolution), max(1, round(resolution * h / w))
    return max(1, round(resolution * w / h)), int(resolution)


class Scene:
    """A diffusion-curve scene prepared for closest-point queries (see the module docstring).

    curves : Curves with ``SideValues`` on every input curve; cleaned up (``dfc.geometry.cleanup.clean``) here.
    """

    def __init__(self, curves: Curves, *, spacing_rel: float = SPACING_REL, flatness_rel: float = FLATNESS_REL):
        from ..geometry.cleanup import clean

        self.n_channels = check_scene(curves)
        self.curves = clean(curves)
        self.domain = self.curves.domain
        diag = self.curves.diagonal
        self.lines = flatten_curves(self.curves.control_points, spacing_rel * diag, flatness_rel * diag)
        if len(self.lines.vertices) == 0:
            raise InputError(f"{curves.source or 'curves'}: no curve lies inside the domain")
        self.tree = cKDTree(self.lines.vertices)
        self._half = 0.5 * self.lines.max_segment
        self._k = min(K_NEAR, len(self.lines.vertices))
        self._near = NEAR_SEGMENTS * self.lines.max_segment

    @cached_property
    def _grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Origin (2,), cell size (2,) and (gh, gw) lower bounds on the curve distance over each cell."""
        x0, y0, x1, y1 = self.domain
        gw, gh = grid_size(self.domain, GRID_CELLS)
        cell = np.array([(x1 - x0) / gw, (y1 - y0) / gh])
        jj, ii = np.mgrid[0:gh, 0:gw]
        centres = np.stack([x0 + (ii.ravel() + 0.5) * cell[0], y0 + (jj.ravel() + 0.5) * cell[1]], axis=1)
        d1, _ = self.tree.query(centres, k=1, workers=WORKERS)
        bound = d1 - self._half - 0.5 * float(np.hypot(*cell))
        return np.array([x0, y0]), cell, bound.reshape(gh, gw)

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Lower bound on the distance from points (N, 2) to the curves, (N,) float64 ≥ 0.

        Within ``lines.deviation`` of the exact distance near the curves; far from them, within half a
        segment and a grid cell's diagonal.
        """
        origin, cell, grid = self._grid
        ij = ((p - origin) / cell).astype(np.int64)
        lb = grid[np.clip(ij[:, 1], 0, grid.shape[0] - 1), np.clip(ij[:, 0], 0, grid.shape[1] - 1)]
        near = np.flatnonzero(lb < self._near)
        if near.size:
            lb[near] = self._segments(p[near])[0]
        return np.maximum(lb - self.lines.deviation, 0.0)

    def _segments(self, p: np.ndarray):
        """Exact search over the segments next to the ``K_NEAR`` nearest vertices.

        Returns bound (N,) = min(nearest candidate segment's distance, k-th vertex distance − half a segment),
        a lower bound on the polyline distance; seg (N,) int64 the nearest candidate segment; u (N,) its
        parameter in [0, 1].
        """
        dk, vk = self.tree.query(p, k=self._k, workers=WORKERS)
        dk, vk = dk.reshape(len(p), -1), vk.reshape(len(p), -1)
        cand = np.concatenate([vk - 1, vk], axis=1)  # the segments ending and starting at each vertex
        ok = cand >= 0
        cand = np.where(ok, cand, 0)
        ok &= ~self.lines.last[cand]
        a = self.lines.vertices[cand]
        ab = self.lines.vertices[np.minimum(cand + 1, len(self.lines.vertices) - 1)] - a
        ap = p[:, None, :] - a
        den = (ab * ab).sum(-1)
        u = np.clip(np.divide((ap * ab).sum(-1), den, out=np.zeros_like(den), where=den > 0), 0.0, 1.0)
        dist = np.linalg.norm(ap - u[..., None] * ab, axis=-1)
        dist[~ok] = np.inf
        best = np.argmin(dist, axis=1)
        rows = np.arange(len(p))
        bound = np.minimum(dist[rows, best], dk[:, -1] - self._half)
        return bound, cand[rows, best], u[rows, best]

    def closest(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest curve points of points (N, 2) near the curves.

        Returns piece (N,) int64, t (N,) float64 its parameter (Newton-refined on the exact Bézier) and
        left (N,) bool: p lies on the piece's left (``cross(tangent, p − B(t)) < 0``; 0 counts as left).
        """
        _, seg, u = self._segments(p)
        lines = self.lines
        piece = lines.piece[seg]
        t0 = lines.t[seg] + u * (lines.t[seg + 1] - lines.t[seg])
        cp = self.curves.control_points[piece]
        t = bezier.closest_parameter(cp, p, t0, iterations=NEWTON_STEPS)
        worse = np.linalg.norm(bezier.evaluate(cp, t) - p, axis=1) > np.linalg.norm(bezier.evaluate(cp, t0) - p, axis=1)
        t = np.where(worse, t0, t)
        tangent = bezier.derivative(cp, t)
        chord = lines.vertices[seg + 1] - lines.vertices[seg]
        flat = np.linalg.norm(tangent, axis=1) <= np.linalg.norm(chord, axis=1) * tol.distinct_rel
        tangent = np.where(flat[:, None], chord, tangent)  # a degenerate end tangent (P0 = P1)
        r = p - bezier.evaluate(cp, t)
        return piece, t, cross(tangent, r) <= 0.0

    def side_values(self, piece: np.ndarray, t: np.ndarray, left: np.ndarray) -> np.ndarray:
        """Values (N, C) float64 prescribed at pieces' parameters ``t`` on the given sides."""
        c = self.curves
        s = c.t_range[piece, 0] + t * (c.t_range[piece, 1] - c.t_range[piece, 0])
        key = 2 * c.curve[piece] + left  # one group per (input curve, side)
        order = np.argsort(key, kind="stable")
        bounds = np.flatnonzero(np.diff(key[order])) + 1
        out = np.empty((len(piece), self.n_channels))
        for group in np.split(order, bounds):
            if group.size:
                k = key[group[0]]
                out[group] = c.sides[k // 2].at(s[group], "left" if k % 2 else "right")
        return out

    def boundary_value(self, p: np.ndarray) -> np.ndarray:
        """Value (N, C) float64 of the closest curve point of points (N, 2), on each point's side."""
        return self.side_values(*self.closest(p))

    def walk(self, xy: np.ndarray, eps: float, max_steps: int, rng: np.random.Generator):
        """Walk from every point together. Returns values (N, C) float64, capped (N,) bool, steps (N,) int64."""
        p = np.array(xy, dtype=np.float64)
        n = len(p)
        values = np.empty((n, self.n_channels))
        steps = np.zeros(n, dtype=np.int64)
        capped = np.zeros(n, dtype=bool)
        active = np.arange(n)
        for step in range(max_steps + 1):
            q = p[active]
            r = self.distance(q)
            hit = r < eps
            if hit.any():
                values[active[hit]] = self.boundary_value(q[hit])
                steps[active[hit]] = step
            active, q, r = active[~hit], q[~hit], r[~hit]
            if not active.size:
                break
            if step == max_steps:
                values[active] = self.boundary_value(q)
                capped[active] = True
                steps[active] = step
                break
            angle = rng.random(len(active)) * (2.0 * np.pi)
            p[active] = reflect(q + r[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1), self.domain)
        return values, capped, steps


def _check_walk_options(scene: Scene, eps, max_steps) -> float:
    eps = DEFAULT_EPS_REL * scene.curves.diagonal if eps is None else float(eps)
    if not (np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a positive number, got {eps}")
    if not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    return eps


def walk_on_spheres(curves: Curves | Scene, xy, *, eps: float | None = None, max_steps: int = DEFAULT_MAX_STEPS,
                    seed: int = 0) -> tuple[np.ndarray, int]:
    """One walk-on-spheres estimate of the diffusion-curve solution at each point.

    Parameters
    ----------
    curves : Curves with side values on every input curve (or a prepared ``Scene``)
    xy : (N, 2) float points in the domain, domain units
    eps : stopping distance to the curves, domain units (default ``DEFAULT_EPS_REL`` × diagonal)
    max_steps : cap on the steps of a walk; a capped walk takes the value of its closest curve point
    seed : seeds numpy's default generator; the result is deterministic for a seed

    Returns
    -------
    values : (N, C) float64 unbiased (up to ``eps``) single-walk estimates
    n_capped : int, walks that hit ``max_steps``
    """
    scene = curves if isinstance(curves, Scene) else Scene(curves)
    eps = _check_walk_options(scene, eps, max_steps)
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must have shape (N, 2), got {xy.shape}")
    x0, y0, x1, y1 = scene.domain
    if not (np.isfinite(xy).all() and (xy >= [x0, y0]).all() and (xy <= [x1, y1]).all()):
        raise InputError(f"walk_on_spheres: start points must be finite and inside the domain {scene.domain}")
    values, capped, _ = scene.walk(xy, eps, int(max_steps), np.random.default_rng(seed))
    return values, int(capped.sum())


def sample_scene(curves: Curves | Scene, resolution: int, spp: int, *, eps: float | None = None,
                 max_steps: int = DEFAULT_MAX_STEPS, seed: int = 0,
                 callback: Callable[[int, int, int], None] | None = None) -> SampleSet:
    """Stratified walk-on-spheres samples of a diffusion-curve scene.

    A ``W × H`` pixel grid over the domain (``grid_size``: ``resolution`` pixels on the long side) gets
    ``spp`` passes; each pass puts one uniformly jittered point in every pixel (rows of pass 0 first, then
    pass 1, ...) and runs one walk per point.

    callback : ``callback(done, total, capped)`` after each chunk of ``CHUNK`` walks (counts so far)

    Returns
    -------
    SampleSet with xy (spp·W·H, 2), values (spp·W·H, C) float32, the scene's domain and channels
    (``dfc.io.samples.default_channels``). The callback's last ``capped`` is the number of capped walks.
    """
    scene = curves if isinstance(curves, Scene) else Scene(curves)
    eps = _check_walk_options(scene, eps, max_steps)
    if not isinstance(resolution, (int, np.integer)) or resolution < 1:
        raise ValueError(f"resolution must be a positive integer, got {resolution!r}")
    if not isinstance(spp, (int, np.integer)) or spp < 1:
        raise ValueError(f"spp must be a positive integer, got {spp!r}")
    width, height = grid_size(scene.domain, int(resolution))
    x0, y0, x1, y1 = scene.domain
    rng = np.random.default_rng(seed)
    pixel = np.arange(width * height)
    ij = np.stack([pixel % width, pixel // width], axis=1).astype(np.float64)
    cell = np.array([(x1 - x0) / width, (y1 - y0) / height])
    xy = np.concatenate([[x0, y0] + (ij + rng.random(ij.shape)) * cell for _ in range(spp)])
    xy = np.minimum(xy, [x1, y1])  # rounding at the far sides
    values = np.empty((len(xy), scene.n_channels), dtype=np.float32)
    capped = 0
    for start in range(0, len(xy), CHUNK):
        chunk = slice(start, start + CHUNK)
        v, c, _ = scene.walk(xy[chunk], eps, int(max_steps), rng)
        values[chunk] = v
        capped += int(c.sum())
        if callback is not None:
            callback(min(start + CHUNK, len(xy)), len(xy), capped)
    return SampleSet(xy, values, scene.domain, default_channels(scene.n_channels))
