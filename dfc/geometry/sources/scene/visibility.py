"""Which parts of 3D curves the camera sees, decided by Mitsuba's own ray tracer.

A point is visible when it lies in the camera's view (inside the film, between the clip planes) and the ray from
the eye reaches it: ``scene.ray_test`` finds nothing before it. The point lies on the surfaces whose feature it
is, and a ray aimed exactly at it would graze them (a silhouette's front face) in Mitsuba's single precision, so
the ray is aimed at the point moved off them by ``NUDGE_REL`` of its distance, in a direction its curve supplies:
out of the plane through the eye and a silhouette or boundary edge, away from both faces of a crease, outwards
from a sphere or a cylinder. Rays also stop ``DEPTH_REL`` of the distance short, for other surfaces through the
point (the floor under a box's bottom edge). A cylinder's rims cannot be nudged off their own cylinder; their rays
ignore that shape (``exempt``), which the caller tests in closed form.

Most candidate points of a dense scene are hidden (a hairball's inner strands). A *depth bound* settles those
without a ray of their own: Mitsuba renders the hit distance at every pixel centre once; over the 3 × 3 pixel
centres around a point these distances span ``[lo, hi]``, and the point is hidden when it lies farther than
``hi + 2 (hi - lo)``. The margin ``2 (hi - lo)`` keeps points visible that are farther than all their neighbours,
as the bottom of a valley between two surfaces is (an intersection line, a concave crease): the surfaces reach
the point, so their distances change by at least their slope across the block. The bound only ever calls a point
hidden when surfaces in front cover all nine pixel centres around it: a point seen through a gap narrower than
about a pixel may be lost, as it may between two samples along a curve.

Along a curve, visibility is sampled every ``step`` pixels (of the curve's image) and each change between two
samples is located by bisection until the bracket is below ``precision`` pixels.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ....io.mitsuba import Camera

__all__ = ["Occlusion", "visible_runs", "BOUND_REL", "NUDGE_REL", "DEPTH_REL"]

NUDGE_REL = 1e-6
"""Targets move off their own surfaces by this fraction of their distance from the eye (16 × float32 rounding)."""
DEPTH_REL = 1e-5
"""Rays stop this fraction of the target's distance short of it."""
BOUND_REL = 1e-4
"""... and when it is this fraction of its distance farther still."""
_BORDER = 1e-9
"""Slack (px) of the inside-the-film test, so that points clipped onto the border count as inside."""


class Occlusion:
    """Eye-ray visibility of world points in a loaded Mitsuba scene.

    scene : the Mitsuba scene; camera : its ``Camera``; offsets : (S + 1,) int64 first global primitive id of each
    shape, in ``ordered_shapes`` order (``offsets[-1]`` = total); meshes : (S,) bool, which shapes are meshes. A hit's *global primitive id* is
    ``offsets[shape] + primitive`` for a mesh triangle, ``offsets[shape]`` for an analytic shape. ``rays`` counts
    the rays traced. ``sensor`` given: the depth bound is rendered through it (one ray per pixel, counted).
    """

    def __init__(self, scene, camera: Camera, offsets: np.ndarray, meshes: np.ndarray, sensor=None):
        from ....io.mitsuba import import_mitsuba, ordered_shapes

        self.mi = import_mitsuba()
        self.scene, self.camera = scene, camera
        self._shape_index = {s.ptr: i for i, s in enumerate(ordered_shapes(scene))}  # by the C++ object's address
        self._offsets, self._meshes = np.asarray(offsets).tolist(), np.asarray(meshes).tolist()
        self.rays = self.bound_rays = 0
        self.bound = None if sensor is None else self._depth_bound(sensor)

    def _depth_bound(self, sensor) -> np.ndarray:
        """(H, W) float64: ``hi + 2 (hi - lo)`` of the hit distances at the pixel centres of each pixel's 3 × 3
        block (inf where any of them sees nothing); also ``bound5``, the same over 5 × 5 blocks."""
        from ....io.mitsuba import render_aovs

        aov = render_aovs(self.scene, sensor, "dd:depth,pp:position")
        self.bound_rays = aov.shape[0] * aov.shape[1]
        dist = np.where(aov[..., 0] > 0, np.linalg.norm(aov[..., 1:4] - self.camera.eye, axis=2), np.inf)
        hi3, lo3 = _block(dist, np.max), _block(np.where(np.isfinite(dist), dist, -np.inf), np.min)
        hi5, lo5 = _block(hi3, np.max), _block(lo3, np.min)
        with np.errstate(invalid="ignore"):
            self.bound5 = np.where(np.isfinite(hi5), 3 * hi5 - 2 * lo5, np.inf)
            return np.where(np.isfinite(hi3), 3 * hi3 - 2 * lo3, np.inf)

    def surely_hidden(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: points (N, 3) in view that the depth bound hides (all False without a bound)."""
        if self.bound is None:
            return np.zeros(len(points), dtype=bool)
        px, _ = self.camera.project(points)
        h, w = self.bound.shape
        i = np.clip(np.floor(px[:, 0]), 0, w - 1).astype(np.int64)
        j = np.clip(np.floor(px[:, 1]), 0, h - 1).astype(np.int64)
        dist = np.linalg.norm(points - self.camera.eye, axis=1)
        return dist * (1.0 - BOUND_REL) > self.bound[j, i]

    def hit_shape(self, hit) -> int:
        """Shape index of a ``PreliminaryIntersection3f``; -1 when it is no hit (``ray_test`` and the closest-hit
        query can disagree on rays that graze a shape)."""
        return self._shape_index[hit.shape.ptr] if hit.is_valid() else -1

    def hit_id(self, hit) -> int:
        """Global primitive id of a ``PreliminaryIntersection3f``; -1 when it is no hit."""
        s = self.hit_shape(hit)
        return -1 if s < 0 else self._offsets[s] + (hit.prim_index if self._meshes[s] else 0)

    def in_view(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, 3) project inside the film, between the near and far clip planes."""
        px, w = self.camera.project(points)
        width, height = self.camera.size
        return ((w > self.camera.near) & (w < self.camera.far)
                & (px[:, 0] >= -_BORDER) & (px[:, 0] <= width + _BORDER)
                & (px[:, 1] >= -_BORDER) & (px[:, 1] <= height + _BORDER))

    def may_show(self, a: np.ndarray, b: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
        """(E,) bool: some point of segment ``a``–``b`` (E, 3) may be visible. The segment is cut into parts at
        most a pixel long in the image; a part in view shows unless its nearest point to the eye is behind the depth
        bound over the 5 × 5 pixels around its first end (which hold every point of the part's own 3 × 3 block).
        Segments reaching behind the eye may show."""
        out = np.ones(len(a), dtype=bool)
        if self.bound is None:
            return out
        eye = self.camera.eye
        h, w = self.bound.shape
        for lo in range(0, len(a), chunk):
            a_, b_ = a[lo:lo + chunk], b[lo:lo + chunk]
            pa, wa = self.camera.project(a_)
            pb, wb = self.camera.project(b_)
            behind = (wa <= self.camera.near) | (wb <= self.camera.near)
            n = np.where(behind, 1, np.ceil(np.linalg.norm(pb - pa, axis=1)).astype(np.int64))
            n = np.clip(n, 1, 1 << 12)  # parts per segment
            edge = np.repeat(np.arange(len(n)), n)
            k = np.arange(len(edge)) - np.repeat(np.cumsum(n) - n, n)
            t0, t1 = k / n[edge], (k + 1) / n[edge]
            p0 = a_[edge] + t0[:, None] * (b_[edge] - a_[edge])
            p1 = a_[edge] + t1[:, None] * (b_[edge] - a_[edge])
            shows = self.in_view(p0) | self.in_view(p1)
            px, _ = self.camera.project(p0)
            i = np.clip(np.floor(px[:, 0]), 0, w - 1).astype(np.int64)
            j = np.clip(np.floor(px[:, 1]), 0, h - 1).astype(np.int64)
            d = p1 - p0
            u = np.clip(np.einsum("ij,ij->i", eye - p0, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0, 1)
            nearest = np.linalg.norm(p0 + u[:, None] * d - eye, axis=1)
            shows &= ~(nearest * (1.0 - BOUND_REL) > self.bound5[j, i])
            out[lo:lo + chunk] = behind | (np.bincount(edge, weights=shows, minlength=len(n)) > 0)
        return out

    def visible(self, points: np.ndarray, nudge: np.ndarray, exempt: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: points (N, 3) in view and reached by their eye ray.

        nudge : (N, 3) unit (or zero) directions that move each target off its own surfaces
        exempt : (N,) int64 a shape whose hits are ignored (-1: none), or None
        """
        points = np.asarray(points, dtype=np.float64)
        result = self.in_view(points)
        result[result] = ~self.surely_hidden(points[result])
        (idx,) = np.nonzero(result)
        if not len(idx):
            return result
        eye = self.camera.eye
        offset = points[idx] - eye
        dist = np.linalg.norm(offset, axis=1)
        offset += nudge[idx] * (NUDGE_REL * dist)[:, None]
        dist = np.linalg.norm(offset, axis=1)
        direction = offset / dist[:, None]
        start = self.camera.near * dist / self.camera.homogeneous(eye + offset)[:, 2]  # rays begin on the near plane
        origin = eye + direction * start[:, None]
        maxt = dist * (1.0 - DEPTH_REL) - start
        scene, point, vector = self.scene, self.mi.Point3f, self.mi.Vector3f
        ray = self.mi.Ray3f()
        # flat lists of floats: nested lists would make the garbage collector crawl over millions of them
        columns = (*origin.T.tolist(), *direction.T.tolist(), maxt.tolist())
        hidden = []
        if exempt is None or np.all(exempt[idx] < 0):
            for i, ox, oy, oz, dx, dy, dz, t in zip(idx.tolist(), *columns):
                ray.o, ray.d, ray.maxt = point(ox, oy, oz), vector(dx, dy, dz), t
                if scene.ray_test(ray):
                    hidden.append(i)
        else:
            for i, ox, oy, oz, dx, dy, dz, t, own in zip(idx.tolist(), *columns, exempt[idx].tolist()):
                ray.o, ray.d, ray.maxt = point(ox, oy, oz), vector(dx, dy, dz), t
                if scene.ray_test(ray) and self.hit_shape(scene.ray_intersect_preliminary(ray)) not in (own, -1):
                    hidden.append(i)
        self.rays += len(idx)
        result[hidden] = False
        return result


def _block(image: np.ndarray, reduce) -> np.ndarray:
    """``reduce`` (np.max or np.min) over each pixel's 3 × 3 block, inf beyond the border: (H, W) -> (H, W)."""
    padded = np.pad(image, 1, constant_values=np.inf)
    h, w = image.shape
    return reduce([padded[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)


def visible_runs(predicate: Callable[[np.ndarray, np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray,
                 speed: np.ndarray, *, step: float, precision: float):
    """Visible stretches of K parametric curves.

    predicate(item (N,) int64, t (N,) float64) -> (N,) bool visibility of curve ``item`` at parameter ``t``
    lo, hi : (K,) float64 parameter range of each curve
    speed : (K,) float64 an upper bound of the image speed (px per unit of t) along each curve
    step : sampling interval (px); precision : bisection stops when the bracket is below this (px)

    returns ``item`` (R,) int64, ``t0``, ``t1`` (R,) float64 and ``at_lo``, ``at_hi`` (R,) bool (the run reaches
    the curve's own end), runs of one curve in order. The end samples sit 1e-6 of the range inside the ends.
    """
    lo, hi, speed = (np.asarray(x, dtype=np.float64) for x in (lo, hi, speed))
    span = hi - lo
    n = np.maximum(2, np.ceil(span * speed / step).astype(np.int64) + 1)
    item = np.repeat(np.arange(len(lo)), n)
    j = np.arange(len(item)) - np.repeat(np.cumsum(n) - n, n)
    frac = np.clip(j / (n[item] - 1), 1e-6, 1 - 1e-6)
    t = lo[item] + span[item] * frac
    vis = predicate(item, t) if len(item) else np.zeros(0, bool)

    same = item[1:] == item[:-1]
    change = np.nonzero(same & (vis[1:] != vis[:-1]))[0]  # between samples change and change + 1
    a = np.where(vis[change], t[change], t[change + 1])  # visible side
    b = np.where(vis[change], t[change + 1], t[change])  # hidden side
    which = item[change]
    active = np.arange(len(change))
    while len(active):
        active = active[np.abs(b[active] - a[active]) * speed[which[active]] > precision]
        if not len(active):
            break
        mid = 0.5 * (a[active] + b[active])
        v = predicate(which[active], mid)
        a[active] = np.where(v, mid, a[active])
        b[active] = np.where(v, b[active], mid)
    cut = 0.5 * (a + b)

    # a run starts at a visible sample whose predecessor (same curve) is hidden or absent, and ends likewise
    first = np.r_[True, ~same]
    last = np.r_[~same, True]
    starts = np.nonzero(vis & (first | np.r_[False, ~vis[:-1]]))[0]
    stops = np.nonzero(vis & (last | np.r_[~vis[1:], False]))[0]
    cut_after = np.full(len(item), np.nan)
    cut_after[change] = cut
    at_lo, at_hi = first[starts], last[stops]
    t0 = np.where(at_lo, lo[item[starts]], cut_after[np.maximum(starts - 1, 0)])
    t1 = np.where(at_hi, hi[item[stops]], cut_after[stops])
    return item[starts], t0, t1, at_lo, at_hi
