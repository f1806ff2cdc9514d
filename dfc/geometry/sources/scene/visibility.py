"""Which parts of 3D curves the camera sees, decided by Mitsuba's own ray tracer.

A point is visible when it lies in the camera's view (inside the film, between the clip planes) and the ray from
the eye to it reaches it: no surface is hit before it, except the point's *owners* — the faces the point lies on
(the two faces of a mesh edge, or a whole analytic shape whose outline it is), which an eye ray can only touch at
the point itself. Owners are *global primitive ids*: ``offset[shape] + primitive`` for meshes, ``offset[shape]``
for analytic shapes.

Along a curve, visibility is sampled every ``step`` pixels (of the curve's image) and each change between two
samples is located by bisection until the bracket is below ``precision`` pixels.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ....io.mitsuba import Camera

__all__ = ["Occlusion", "visible_runs"]

_DEPTH_REL = 1e-5
"""A hit counts as in front of the target only when it is nearer than (1 - this) × the target's distance; hits
closer to the target are the surface the target lies on, seen through Mitsuba's single-precision intersection."""
_BORDER = 1e-9
"""Slack (px) of the inside-the-film test, so that points clipped onto the border count as inside."""


class Occlusion:
    """Eye-ray visibility of world points in a loaded Mitsuba scene.

    scene : the Mitsuba scene; camera : its ``Camera``; offsets : (S + 1,) int64 first global primitive id of each
    shape (``offsets[-1]`` = total); meshes : (S,) bool, which shapes are meshes (their primitive indices count)
    """

    def __init__(self, scene, camera: Camera, offsets: np.ndarray, meshes: np.ndarray):
        from ....io.mitsuba import import_mitsuba

        self.mi = import_mitsuba()
        self.scene, self.camera = scene, camera
        self._shape_index = {s.ptr: i for i, s in enumerate(scene.shapes())}  # by the C++ object's address
        self.offsets = np.asarray(offsets, dtype=np.int64)
        self._offsets, self._meshes = self.offsets.tolist(), np.asarray(meshes).tolist()
        self.rays = 0

    def hit_id(self, hit) -> int:
        """Global primitive id of a ``PreliminaryIntersection3f``; -1 when it is no hit (``ray_test`` and the
        closest-hit query can disagree on rays that graze a shape)."""
        if not hit.is_valid():
            return -1
        s = self._shape_index[hit.shape.ptr]
        return self._offsets[s] + (hit.prim_index if self._meshes[s] else 0)

    def in_view(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, 3) project inside the film, between the near and far clip planes."""
        px, w = self.camera.project(points)
        width, height = self.camera.size
        return ((w > self.camera.near) & (w < self.camera.far)
                & (px[:, 0] >= -_BORDER) & (px[:, 0] <= width + _BORDER)
                & (px[:, 1] >= -_BORDER) & (px[:, 1] <= height + _BORDER))

    def visible(self, points: np.ndarray, owners: np.ndarray) -> np.ndarray:
        """(N,) bool: points (N, 3) in view and reached by their eye ray; owners (N, 2) int64 (-1: none)."""
        points = np.asarray(points, dtype=np.float64)
        result = self.in_view(points)
        (idx,) = np.nonzero(result)
        if not len(idx):
            return result
        eye = self.camera.eye
        offset = points[idx] - eye
        dist = np.linalg.norm(offset, axis=1)
        direction = offset / dist[:, None]
        depth = self.camera.homogeneous(points[idx])[:, 2]
        start = self.camera.near * dist / depth  # Mitsuba's camera rays begin on the near plane
        origin = eye + direction * start[:, None]
        maxt = dist * (1.0 - _DEPTH_REL) - start
        ray, scene = self.mi.Ray3f, self.scene
        hidden = []
        for i, o, d, t, own in zip(idx.tolist(), origin.tolist(), direction.tolist(), maxt.tolist(),
                                   owners[idx].tolist()):
            r = ray(o, d)
            r.maxt = t  # (the constructor's third argument is the time)
            if scene.ray_test(r) and self.hit_id(scene.ray_intersect_preliminary(r)) not in own + [-1]:
                hidden.append(i)
        self.rays += len(idx)
        result[hidden] = False
        return result


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
