"""Visible discontinuity curves of a Mitsuba 3 scene, in the pixels of its render (``dfc curves SCENE.xml``).

The paper's curves for rendered images (§6.1): the edges where a render can jump, projected into the image and
clipped against what hides them.

1. **Geometry.** Every shape Mitsuba loads as a triangle mesh (obj, ply, serialized, cube, rectangle, …; its
   ``to_world`` already applied by Mitsuba) gives its *feature edges* (``edges``): silhouettes, boundaries and
   creases. Spheres give their exact contour, disks their rim, cylinders their rims and two silhouette lines
   (``conics``). Other shape types are refused.
2. **Intersections** (optional): where two meshes cut through each other (``intersections``).
3. **Visibility.** Mesh edges are clipped to the camera's view exactly, then sampled along their image every
   ``step`` pixels and tested with Mitsuba's ray tracer; each change of visibility is located by bisection to
   ``PRECISION`` pixels (``visibility``). Conic arcs likewise, in their angle. In dense scenes a depth bound
   rendered once settles most hidden samples without a ray each.
4. **Curves.** Visible edge pieces are chained through shared mesh vertices, and each chain becomes lines and
   cubic Béziers within ``tolerance`` pixels of it (``chains``); visible conic arcs become cubics within
   ``min(tolerance, ARC_TOLERANCE)`` of the exact conic.

The result's domain is the rendered image ``[0, W] × [0, H]`` (the film's crop window when it has one), y down,
as in ``spec/conventions.md``: a point projected here lands on the pixel Mitsuba renders it in.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ....io.mitsuba import Camera, import_mitsuba, load_scene, perspective_sensor
from ...curves import Curves
from . import conics
from .candidates import Candidates
from .chains import chain, fit_polylines
from .visibility import Occlusion, visible_runs

__all__ = ["read_scene", "STAGES", "PRECISION", "ARC_TOLERANCE"]

PRECISION = 1e-3
"""Visibility changes are located to this many pixels (a tenth of the 0.01 px the curves promise)."""
ARC_TOLERANCE = 0.01
"""Cubics stay this close (px) to the exact image of a sphere contour, disk rim or cylinder rim."""
MIN_CUT_PIECE = 0.05
"""Visible pieces shorter than this (px) with an end cut by visibility are dropped: they are the stubs a hidden
edge shows next to a visible vertex, where the occluding faces meet the edge within Mitsuba's precision."""
STAGES = ("load", "edges", "bound", "intersections", "visibility", "fit")
"""The stages ``progress`` is told about, in order; ``stats`` gets ``<stage>_s`` for each."""


def read_scene(path: str | Path, *, sensor: int = 0, crease_angle: float = 30.0, creases: bool = True,
               intersections: bool = True, tolerance: float = 0.05, step: float = 0.5,
               depth_bound: bool | None = None,
               stats: dict | None = None, progress: Callable[[str], None] | None = None) -> Curves:
    """The visible silhouette, boundary, crease (and intersection) curves of a Mitsuba 3 scene seen by a sensor.

    Parameters
    ----------
    path : the scene's XML file
    sensor : index of the (perspective) sensor among the scene's sensors
    crease_angle : degrees; mesh edges whose faces' normals differ by at least this much are creases
    creases : False drops creases (silhouettes and boundaries remain)
    intersections : trace where meshes cut through each other
    tolerance : px, how far fitted lines and cubics may stray from the projected polylines
    step : px, the visibility sampling interval along each curve's image
    depth_bound : settle points hidden behind the surfaces at all nine pixel centres around them from one
        pixel-centre render, without a ray each (``visibility``); False traces every point; None (default) does
        it when the candidates need more samples than the film has pixels (it costs a ray per pixel)
    stats : filled with counts (``triangles``, ``edges``, ``tested``, ``rays``, ``curves``, ``pieces``, …) and
        seconds per stage (``load_s``, …, ``total_s``)
    progress : called with each stage's name (``STAGES``) as it begins

    Returns
    -------
    Curves over the rendered image's domain: one input curve per chain (named after its shape), lines and cubics.

    Raises
    ------
    InputError for a file that is not a usable Mitsuba scene (not a scene, missing mesh file, unknown plugin, no
    perspective sensor, an unsupported shape), ExtraError without Mitsuba.
    """
    if not tolerance > 0 or not step > 0 or not 0 <= crease_angle <= 180:
        raise ValueError(f"need tolerance > 0, step > 0 and crease_angle in [0, 180], got "
                         f"{tolerance}, {step}, {crease_angle}")
    stats = {} if stats is None else stats
    clock = _Clock(stats, progress)
    clock.stage("load")
    import_mitsuba()
    scene = load_scene(path)
    view = perspective_sensor(scene, sensor, path)
    camera = Camera.from_sensor(view)
    clock.stage("edges")
    candidates = Candidates(scene, camera, path, crease_angle=crease_angle, creases=creases)
    stats["triangles"] = candidates.triangles
    stats["mesh_edges"] = candidates.edges
    clock.stage("bound")
    if depth_bound is None:  # worth a ray per pixel when the segments need more samples than that
        view_part = _InView(camera, candidates.a, candidates.b)
        samples = np.sum(np.linalg.norm(view_part.pb - view_part.pa, axis=1) / step + 2)
        depth_bound = samples > camera.size[0] * camera.size[1]
    occlusion = Occlusion(scene, camera, candidates.offsets, candidates.is_mesh, view if depth_bound else None)
    stats["bound_rays"] = occlusion.bound_rays
    clock.stage("intersections")
    if intersections:
        candidates.add_intersections(occlusion)
    stats["intersection_segments"] = candidates.n_intersections
    stats["intersection_rays"] = occlusion.rays
    occlusion.rays = 0
    clock.stage("visibility")
    runs = _visible_segments(candidates, camera, occlusion, step, stats)
    arc_runs = _visible_arcs(candidates.arcs, camera, occlusion, step, stats)
    stats["visibility_rays"] = occlusion.rays
    clock.stage("fit")
    curves = _curves(candidates, camera, runs, arc_runs, tolerance, path)
    stats["curves"] = curves.n_curves
    stats["pieces"] = len(curves)
    stats["lines"] = int(np.sum(curves.degree == 1))
    stats["cubics"] = int(np.sum(curves.degree == 3))
    clock.stage(None)
    return curves


class _Clock:
    def __init__(self, stats: dict, progress):
        self.stats, self.progress, self.name = stats, progress, None
        self.start = self.t = time.perf_counter()

    def stage(self, name: str | None) -> None:
        now = time.perf_counter()
        if self.name is not None:
            self.stats[f"{self.name}_s"] = now - self.t
        self.name, self.t = name, now
        if name is None:
            self.stats["total_s"] = now - self.start
        elif self.progress is not None:
            self.progress(name)


class _InView:
    """The parts of segments ``a``–``b`` (S, 3) inside the camera's view: in front of the near plane, before the
    far one, projecting into the film (Liang–Barsky in homogeneous coordinates, where every bound is linear along
    the segment).

    index (K,) the segments with a part in view; t0, t1 (K,) that part's stretch of the segment; a, b (K, 3) its
    ends; pa, pb (K, 2) their images (put exactly on the film's border where they were clipped to it); wa, wb (K,)
    their depths
    """

    def __init__(self, camera: Camera, a: np.ndarray, b: np.ndarray):
        width, height = camera.size

        def bounds(h):  # each column >= 0 inside the view
            u, v, w = h[:, 0], h[:, 1], h[:, 2]
            return np.stack([w - camera.near, camera.far - w, u, width * w - u, v, height * w - v], axis=1)

        fa, fb = bounds(camera.homogeneous(a)), bounds(camera.homogeneous(b))
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = fa / (fa - fb)
        t0 = np.max(np.where((fa < 0) & (fb >= 0), cross, 0.0), axis=1, initial=0.0)
        t1 = np.min(np.where((fb < 0) & (fa >= 0), cross, 1.0), axis=1, initial=1.0)
        (self.index,) = np.nonzero((t1 > t0) & ~np.any((fa < 0) & (fb < 0), axis=1))
        self.t0, self.t1 = t0[self.index], t1[self.index]
        d = b[self.index] - a[self.index]
        self.a = a[self.index] + self.t0[:, None] * d
        self.b = a[self.index] + self.t1[:, None] * d
        pa, self.wa = camera.project(self.a)
        pb, self.wb = camera.project(self.b)
        self.pa, self.pb = _onto_border(pa, camera.size), _onto_border(pb, camera.size)


def _visible_segments(g: Candidates, camera: Camera, occlusion: Occlusion, step: float, stats: dict):
    """Visible parts of the candidate segments: (segment (R,), image ends (R, 2, 2), end ids (R, 2)); ends cut by
    the view or by an occluder get fresh ids."""
    view = _InView(camera, g.a, g.b)
    a, b, pa, pb, wa, wb = view.a, view.b, view.pa, view.pb, view.wa, view.wb
    nudge = g.nudge[view.index]
    stats["edges_tested"] = len(view.index)

    def predicate(item, s):  # s: position along the image segment; t: along the world segment
        t = s * wa[item] / (s * wa[item] + (1.0 - s) * wb[item])
        return occlusion.visible(a[item] + t[:, None] * (b[item] - a[item]), nudge[item])

    speed = np.linalg.norm(pb - pa, axis=1)
    item, s0, s1, at_lo, at_hi = visible_runs(predicate, np.zeros(len(a)), np.ones(len(a)), speed,
                                              step=step, precision=PRECISION)
    ends = np.stack([pa[item] + s0[:, None] * (pb[item] - pa[item]),
                     pa[item] + s1[:, None] * (pb[item] - pa[item])], axis=1)
    ends[at_lo, 0] = pa[item[at_lo]]
    ends[at_hi, 1] = pb[item[at_hi]]
    ids = np.full((len(item), 2), -1, np.int64)
    keep_a = at_lo & (view.t0[item] == 0.0)  # an end of the mesh edge itself: the chains meet there
    keep_b = at_hi & (view.t1[item] == 1.0)
    seg = view.index[item]
    ids[keep_a, 0] = g.ids[seg[keep_a], 0]
    ids[keep_b, 1] = g.ids[seg[keep_b], 1]
    stats["visible_pieces"] = len(item)
    return seg, ends, ids


def _onto_border(p: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Points (N, 2) within rounding of the film's border put exactly on it."""
    p = p.copy()
    for axis, extent in enumerate(size):
        for edge in (0.0, float(extent)):
            near = np.abs(p[:, axis] - edge) <= 1e-7 * max(size)
            p[near, axis] = edge
    return p


def _visible_arcs(arcs: conics.Ellipses, camera: Camera, occlusion: Occlusion, step: float, stats: dict):
    """Visible runs of the arcs: (arc (R,), θ0 (R,), θ1 (R,)), a run around the closing point of a closed arc
    joined into one."""
    stats["arcs_tested"] = len(arcs)
    if not len(arcs):
        stats["visible_arcs"] = 0
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    exempt = np.where(np.isnan(arcs.hider[:, 0, 0]), -1, arcs.shape)
    probe = 256
    k = np.repeat(np.arange(len(arcs)), probe)
    theta = (arcs.start[:, None] + (arcs.stop - arcs.start)[:, None] * np.linspace(0, 1, probe)).ravel()
    _, d = conics.image_points(camera, arcs, k, theta)
    w = camera.homogeneous(arcs.point(k, theta))[:, 2]
    speed = np.where(w > camera.near, np.linalg.norm(d, axis=1), 0.0).reshape(-1, probe).max(axis=1) * 1.25

    def predicate(item, t):
        points = arcs.point(item, t)
        return (occlusion.visible(points, arcs.outward(item, points), exempt[item])
                & ~arcs.hidden_by_own_cylinder(item, points, camera.eye))

    item, t0, t1, at_lo, at_hi = visible_runs(predicate, arcs.start, arcs.stop, speed, step=step,
                                              precision=PRECISION)
    # a closed arc seen across its closing point: its last run continues into its first
    first = np.r_[True, item[1:] != item[:-1]]
    last = np.r_[item[1:] != item[:-1], True]
    head = np.nonzero(first & ~last & at_lo & arcs.closed[item])[0]
    tail = np.searchsorted(item, item[head], side="right") - 1
    join = at_hi[tail]
    head, tail = head[join], tail[join]
    t1[tail] = t1[head] + (arcs.stop - arcs.start)[item[head]]
    keep = np.ones(len(item), bool)
    keep[head] = False
    stats["visible_arcs"] = int(keep.sum())
    return item[keep], t0[keep], t1[keep]


def _curves(g: Candidates, camera: Camera, runs, arc_runs, tolerance: float, path) -> Curves:
    """Chains of visible segments fitted with lines and cubics, then the visible arcs as cubics."""
    seg, ends, ids = runs
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    keep = (length > 0) & ((length >= MIN_CUT_PIECE) | np.all(ids >= 0, axis=1))
    seg, ends, ids = seg[keep], ends[keep], ids[keep]
    fresh = ids < 0
    ids[fresh] = len(g.point_shape) + np.arange(int(fresh.sum()))
    point_shape = np.r_[g.point_shape, np.repeat(g.shape[seg], 2).reshape(-1, 2)[fresh]]
    flat_ids, flat_xy = ids.ravel(), ends.reshape(-1, 2)
    unique, first = np.unique(flat_ids, return_index=True)
    chain_ids, offsets, _ = chain(ids)
    xy = flat_xy[first[np.searchsorted(unique, chain_ids)]]
    cp, degree, polyline = fit_polylines(xy, offsets, tolerance)
    names = [f"{g.labels[s]} edges" for s in point_shape[chain_ids[offsets[:-1]]]]

    arc, th0, th1 = arc_runs
    arc_cp, arc_run = conics.arcs_to_beziers(camera, g.arcs, arc, th0, th1, min(tolerance, ARC_TOLERANCE))
    _arc_ends_onto_border(arc_cp, arc_run, camera.size)
    names += [f"{g.labels[s]} outline" for s in g.arcs.shape[arc]]
    n = len(offsets) - 1
    control_points = np.concatenate([cp, arc_cp])
    degrees = np.r_[degree, np.full(len(arc_cp), 3, np.int8)]
    curve = np.r_[polyline, n + arc_run]
    k = np.arange(len(curve)) - np.searchsorted(curve, curve)  # index of each piece within its curve
    return Curves((0.0, 0.0, float(camera.size[0]), float(camera.size[1])), control_points, degrees, curve,
                  np.stack([k, k + 1.0], axis=1), names, [None] * len(names), str(path))


def _arc_ends_onto_border(cp: np.ndarray, run: np.ndarray, size) -> None:
    """Move the ends of arc runs (pieces ``cp`` (P, 4, 2) of runs ``run`` (P,)) that the bisection left within
    twice its precision of the film's border exactly onto it, with their neighbouring control point (in place)."""
    if not len(run):
        return
    start = np.nonzero(np.r_[True, run[1:] != run[:-1]])[0]
    stop = np.nonzero(np.r_[run[1:] != run[:-1], True])[0]
    for pieces, end, inner in ((start, 0, 1), (stop, 3, 2)):
        for axis, extent in enumerate(size):
            for edge in (0.0, float(extent)):
                near = pieces[np.abs(cp[pieces, end, axis] - edge) <= 2 * PRECISION]
                cp[near, inner, axis] += edge - cp[near, end, axis]
                cp[near, end, axis] = edge
