"""Ellipses in space (the outlines of Mitsuba's analytic shapes) and their images as cubic Béziers.

An ellipse is ``P(θ) = centre + u cos θ + v sin θ`` (u, v (3,) float64 need not be orthogonal: the affine image of a
circle). A camera maps it to a conic in the image; each arc ``[θ0, θ1]`` of it becomes cubic Hermite pieces, halved
in ``θ`` until every piece stays within the tolerance of the exact projected conic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ....io.mitsuba import Camera

__all__ = ["Ellipses", "sphere_contours", "cylinder_outline", "disk_rim", "image_points", "arcs_to_beziers"]

_QUARTER = np.pi / 4
"""Initial pieces span at most this angle (rad), so a full conic starts as at least 8 pieces."""
_CHECKS = 17
"""Points per piece at which a Hermite cubic is compared with the conic (parameter error, ≥ the distance)."""
_MAX_HALVINGS = 30


@dataclass(frozen=True)
class Ellipses:
    """K ellipse arcs in world space.

    centre, u, v : (K, 3) float64, ``P(θ) = centre + u cos θ + v sin θ``
    start, stop : (K,) float64, the arc ``[start, stop]`` (rad); ``stop - start = 2π`` is the closed curve
    shape : (K,) int64 the Mitsuba shape each belongs to; the ray test ignores hits on it: an eye ray touches a
        sphere's contour or a disk's rim only at the point, and a cylinder's rims are tested against their own
        cylinder in closed form instead (``hider``), as Mitsuba's intersection of nearly tangent rays is too coarse
    hider : (K, 4, 4) float64 world-to-local matrix of the unit cylinder that may hide the arc, NaN where none
    kind : (K,) uint8 kind bits (``edges.SILHOUETTE``, ``edges.BOUNDARY``)
    """

    centre: np.ndarray
    u: np.ndarray
    v: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    shape: np.ndarray
    hider: np.ndarray
    kind: np.ndarray

    def __len__(self) -> int:
        return len(self.centre)

    @property
    def closed(self) -> np.ndarray:
        return np.isclose(self.stop - self.start, 2 * np.pi, rtol=0, atol=1e-12)

    def point(self, idx: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Points (N, 3) of arcs ``idx`` (N,) at angles ``theta`` (N,)."""
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        return self.centre[idx] + self.u[idx] * c + self.v[idx] * s

    def hidden_by_own_cylinder(self, idx: np.ndarray, points: np.ndarray, eye: np.ndarray) -> np.ndarray:
        """(N,) bool: the eye ray to each point (N, 3) of arcs ``idx`` (N,) crosses the arc's own cylinder wall
        before it. In the cylinder's frame the ray ``E + s (P - E)`` meets ``x² + y² = 1`` at ``s = 1`` (P is on
        the rim) and at the other root ``s = c / a`` of the quadratic, exact in closed form."""
        m = self.hider[idx]
        has = ~np.isnan(m[:, 0, 0])
        e = np.einsum("nij,j->ni", np.nan_to_num(m[:, :3, :3]), eye) + np.nan_to_num(m[:, :3, 3])
        p = np.einsum("nij,nj->ni", np.nan_to_num(m[:, :3, :3]), points) + np.nan_to_num(m[:, :3, 3])
        d = p - e
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        c = e[:, 0] ** 2 + e[:, 1] ** 2 - 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            s = c / a
            z = e[:, 2] + s * d[:, 2]
        return has & (s > 0) & (s < 1 - 1e-9) & (z >= 0) & (z <= 1)

    def outward(self, idx: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Unit directions (N, 3) from the centres of arcs ``idx`` to their points (N, 3): off a sphere (for its
        contour), out of a disk or a cylinder's end."""
        d = points - self.centre[idx]
        return d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]

    def derivative(self, idx: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """dP/dθ (N, 3) of arcs ``idx`` at ``theta``."""
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        return self.v[idx] * c - self.u[idx] * s

    @staticmethod
    def concat(parts: list[Ellipses]) -> Ellipses:
        fields = ("centre", "u", "v", "start", "stop", "shape", "hider", "kind")
        if not parts:
            empty = dict(centre=np.zeros((0, 3)), u=np.zeros((0, 3)), v=np.zeros((0, 3)), start=np.zeros(0),
                         stop=np.zeros(0), shape=np.zeros(0, np.int64), hider=np.zeros((0, 4, 4)),
                         kind=np.zeros(0, np.uint8))
            return Ellipses(**empty)
        return Ellipses(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))


def _full(centre, u, v, shape: int, kind: int, hider: np.ndarray | None = None) -> Ellipses:
    """Closed ellipses from centres, u and v ((3,) or (K, 3) each), hidden by the cylinder ``hider`` (4, 4)."""
    centre, u, v = (np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in (centre, u, v))
    k = len(centre)
    hider = np.full((4, 4), np.nan) if hider is None else hider
    return Ellipses(centre, u, v, np.zeros(k), np.full(k, 2 * np.pi), np.full(k, shape, np.int64),
                    np.broadcast_to(hider, (k, 4, 4)).copy(), np.full(k, kind, np.uint8))


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) completing the unit ``axis`` to an orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def sphere_contours(centre: np.ndarray, radius: float, eye: np.ndarray, shape: int, kind: int) -> Ellipses:
    """The contour of a sphere seen from ``eye``: the circle where the eye's rays touch it (none from inside)."""
    offset = np.asarray(eye, float) - np.asarray(centre, float)
    d2 = float(offset @ offset)
    if d2 <= radius * radius:
        return Ellipses.concat([])
    axis = offset / np.sqrt(d2)
    e1, e2 = _frame(axis)
    ring = radius * np.sqrt(1.0 - radius * radius / d2)
    return _full(centre + axis * (radius * radius / np.sqrt(d2)), ring * e1, ring * e2, shape, kind)


def disk_rim(to_world: np.ndarray, shape: int, kind: int) -> Ellipses:
    """The rim of Mitsuba's disk: the unit circle of the z = 0 plane under ``to_world`` (4, 4)."""
    return _full(to_world[:3, 3], to_world[:3, 0], to_world[:3, 1], shape, kind)


def cylinder_outline(to_world: np.ndarray, eye: np.ndarray, shape: int, rim_kind: int,
                     silhouette_kind: int) -> tuple[Ellipses, np.ndarray, np.ndarray]:
    """The outline of Mitsuba's (open) cylinder, the unit cylinder ``x² + y² = 1, 0 ≤ z ≤ 1`` under ``to_world``.

    returns its two rims; its silhouette lines (S, 2, 3) float64 (S = 2, or 0 when the eye is inside the
    infinite cylinder), the rulings where the eye's rays touch it, found in the cylinder's own frame; and their
    outward unit normals (S, 3)
    """
    to_local = np.linalg.inv(to_world)
    local_eye = to_local[:3, :3] @ eye + to_local[:3, 3]
    rho = float(np.hypot(local_eye[0], local_eye[1]))
    centres = [to_world[:3, 3], to_world[:3, 3] + to_world[:3, 2]]
    rims = _full(centres, [to_world[:3, 0]] * 2, [to_world[:3, 1]] * 2, shape, rim_kind, to_local)
    if rho <= 1.0:
        return rims, np.zeros((0, 2, 3)), np.zeros((0, 3))
    phi = np.arctan2(local_eye[1], local_eye[0]) + np.array([1.0, -1.0]) * np.arccos(1.0 / rho)
    ends = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    local = np.stack([np.c_[ends, np.zeros(2), np.ones(2)], np.c_[ends, np.ones(2), np.ones(2)]], axis=1)
    normal = np.c_[ends, np.zeros(2)] @ to_local[:3, :3]  # normals transform by the inverse transpose
    return rims, (local @ to_world.T)[..., :3], normal / np.linalg.norm(normal, axis=1, keepdims=True)


def image_points(camera: Camera, arcs: Ellipses, idx: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image points (N, 2) and their derivatives d/dθ (N, 2) of arcs ``idx`` at ``theta``."""
    h = camera.homogeneous(arcs.point(idx, theta))
    dh = arcs.derivative(idx, theta) @ camera.matrix[:, :3].T
    w = h[:, 2:]
    return h[:, :2] / w, (dh[:, :2] * w - h[:, :2] * dh[:, 2:]) / (w * w)


def _hermite(camera: Camera, arcs: Ellipses, idx: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cubic Hermite control points (N, 4, 2) matching the image conic's ends and end derivatives over [a, b]."""
    p0, d0 = image_points(camera, arcs, idx, a)
    p3, d3 = image_points(camera, arcs, idx, b)
    span = ((b - a) / 3.0)[:, None]
    return np.stack([p0, p0 + span * d0, p3 - span * d3, p3], axis=1)


def arcs_to_beziers(camera: Camera, arcs: Ellipses, idx: np.ndarray, a: np.ndarray, b: np.ndarray,
                    tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """The image of arcs ``idx`` (R,) over ``[a, b]`` (R,) rad as cubic Béziers within ``tolerance`` pixels.

    returns control points (P, 4, 2) float64 and the arc run (index into ``idx``) of each piece (P,) int64, pieces
    of one run consecutive and in order of θ (end points of neighbours are bit-identical)
    """
    from ... import bezier

    if not len(idx):
        return np.zeros((0, 4, 2)), np.zeros(0, np.int64)
    n = np.maximum(1, np.ceil((b - a) / _QUARTER)).astype(np.int64)
    run = np.repeat(np.arange(len(idx)), n)
    k = np.arange(len(run)) - np.repeat(np.cumsum(n) - n, n)
    edges = a[:, None] + (b - a)[:, None] * (np.arange(n.max() + 1) / np.maximum(n, 1)[:, None])
    lo, hi = edges[run, k], np.where(k + 1 == n[run], b[run], edges[run, k + 1])
    done_run, done_lo, done_cp = [], [], []
    s = np.linspace(0.0, 1.0, _CHECKS)[1:-1]
    for _ in range(_MAX_HALVINGS):
        cp = _hermite(camera, arcs, idx[run], lo, hi)
        m = len(run)
        exact, _ = image_points(camera, arcs, np.repeat(idx[run], len(s)), (lo[:, None] + (hi - lo)[:, None] * s).ravel())
        err = np.linalg.norm(bezier.evaluate(cp, np.tile(s, (m, 1))) - exact.reshape(m, len(s), 2), axis=2).max(axis=1)
        ok = err <= tolerance
        done_run.append(run[ok])
        done_lo.append(lo[ok])
        done_cp.append(cp[ok])
        if ok.all():
            break
        run, lo, hi = run[~ok], lo[~ok], hi[~ok]
        mid = 0.5 * (lo + hi)
        run, lo, hi = np.repeat(run, 2), np.stack([lo, mid], 1).ravel(), np.stack([mid, hi], 1).ravel()
    else:
        done_run.append(run)
        done_lo.append(lo)
        done_cp.append(_hermite(camera, arcs, idx[run], lo, hi))
    run, lo, cp = np.concatenate(done_run), np.concatenate(done_lo), np.concatenate(done_cp)
    order = np.lexsort((lo, run))
    cp, run = cp[order], run[order]
    last = np.nonzero(np.r_[run[1:] != run[:-1], True])[0]
    first = np.r_[0, last[:-1] + 1]
    closed = b[run[last]] - a[run[last]] >= 2 * np.pi - 1e-12
    cp[last[closed], 3] = cp[first[closed], 0]  # a closed conic ends where it starts, bit for bit
    return cp, run
