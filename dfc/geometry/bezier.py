"""Vectorised cubic Bézier geometry on stacks of control points.

Every function takes ``cp`` of shape ``(N, 4, 2)`` float64: ``N`` cubic pieces ``P0..P3`` (lines and
quadratics degree-elevated, as in ``dfc.geometry.curves.Curves``). Parameters ``t`` are in ``[0, 1]``. Evaluation
uses the Bernstein form, so ``t = 0`` and ``t = 1`` give ``P0`` and ``P3`` bit-exactly, and the pieces
made by ``split``/``subsegment`` share their cut points bit-exactly.
"""

from __future__ import annotations

import numpy as np

from .plane import cross
from .tolerances import tol

__all__ = [
    "evaluate",
    "derivative",
    "second_derivative",
    "split",
    "subsegment",
    "split_many",
    "flatten",
    "inflections",
    "chord_frame",
    "to_chord_frame",
    "end_tangents",
    "tangent_apex",
    "turning_angle",
    "total_turning",
    "monotone_over_chord",
    "self_intersections",
    "cusps",
    "bernstein_roots",
    "closest_parameter",
    "refine_intersections",
    "bounding_boxes",
]


def _as_cp(cp) -> np.ndarray:
    cp = np.asarray(cp, dtype=np.float64)
    if cp.ndim != 3 or cp.shape[1:] != (4, 2):
        raise ValueError(f"control points: expected (N, 4, 2), got {cp.shape}")
    return cp


def _params(cp: np.ndarray, t) -> tuple[np.ndarray, np.ndarray]:
    """Broadcast ``t`` ((N,) or (N, M)) against ``cp``; returns t as (N, M) and cp as (N, 1, 4, 2)."""
    t = np.asarray(t, dtype=np.float64)
    if t.ndim not in (1, 2) or t.shape[0] != cp.shape[0]:
        raise ValueError(f"t: expected (N,) or (N, M) with N = {cp.shape[0]}, got {t.shape}")
    return (t[:, None] if t.ndim == 1 else t), cp[:, None]


def _finish(out: np.ndarray, t) -> np.ndarray:
    return out[:, 0] if np.ndim(t) == 1 else out


def evaluate(cp, t) -> np.ndarray:
    """Points on the pieces.

    cp : (N, 4, 2) float; t : (N,) or (N, M) float
    returns (N, 2) or (N, M, 2) float64
    """
    cp = _as_cp(cp)
    tt, c = _params(cp, t)
    s = 1.0 - tt
    w = np.stack([s * s * s, 3.0 * s * s * tt, 3.0 * s * tt * tt, tt * tt * tt], axis=-1)  # (N, M, 4)
    return _finish(np.einsum("nmk,nokd->nmd", w, c), t)


def derivative(cp, t) -> np.ndarray:
    """First derivative dB/dt; same shapes as ``evaluate``."""
    cp = _as_cp(cp)
    tt, c = _params(cp, t)
    d = 3.0 * np.diff(c, axis=2)  # (N, 1, 3, 2)
    s = 1.0 - tt
    w = np.stack([s * s, 2.0 * s * tt, tt * tt], axis=-1)
    return _finish(np.einsum("nmk,nokd->nmd", w, d), t)


def second_derivative(cp, t) -> np.ndarray:
    """Second derivative d²B/dt²; same shapes as ``evaluate``."""
    cp = _as_cp(cp)
    tt, c = _params(cp, t)
    d = 6.0 * np.diff(c, n=2, axis=2)  # (N, 1, 2, 2)
    w = np.stack([1.0 - tt, tt], axis=-1)
    return _finish(np.einsum("nmk,nokd->nmd", w, d), t)


def _blossom(cp: np.ndarray, u1: np.ndarray, u2: np.ndarray, u3: np.ndarray) -> np.ndarray:
    """Polar form f(u1, u2, u3) of each cubic: cp (N, 4, 2), u* (N,) -> (N, 2)."""
    p = cp
    for u in (u1, u2, u3):
        u = u[:, None, None]
        p = (1.0 - u) * p[:, :-1] + u * p[:, 1:]
    return p[:, 0]


def subsegment(cp, t0, t1) -> np.ndarray:
    """The stretch ``[t0, t1]`` of each piece as a cubic of its own (reparametrised to [0, 1]).

    cp : (N, 4, 2) float; t0, t1 : (N,) float (t0 > t1 reverses the piece)
    returns (N, 4, 2) float64; its end points equal ``evaluate(cp, t0)`` and ``evaluate(cp, t1)`` bit-exactly
    """
    cp = _as_cp(cp)
    t0 = np.broadcast_to(np.asarray(t0, dtype=np.float64), cp.shape[:1])
    t1 = np.broadcast_to(np.asarray(t1, dtype=np.float64), cp.shape[:1])
    out = np.empty_like(cp)
    out[:, 0] = evaluate(cp, t0)
    out[:, 1] = _blossom(cp, t0, t0, t1)
    out[:, 2] = _blossom(cp, t0, t1, t1)
    out[:, 3] = evaluate(cp, t1)
    return out


def split(cp, t) -> tuple[np.ndarray, np.ndarray]:
    """Split each piece at its own parameter (de Casteljau).

    cp : (N, 4, 2) float; t : (N,) float in [0, 1]
    returns left, right : (N, 4, 2) float64 with ``left[:, 3] == right[:, 0] == evaluate(cp, t)`` bit-exactly
    """
    cp = _as_cp(cp)
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if t.shape[0] != cp.shape[0]:
        raise ValueError(f"t: expected ({cp.shape[0]},), got {t.shape}")
    u = t[:, None, None]
    p1 = (1.0 - u) * cp[:, :-1] + u * cp[:, 1:]  # (N, 3, 2)
    p2 = (1.0 - u) * p1[:, :-1] + u * p1[:, 1:]  # (N, 2, 2)
    p3 = evaluate(cp, t)  # the same bits as every other evaluation at t
    left = np.stack([cp[:, 0], p1[:, 0], p2[:, 0], p3], axis=1)
    right = np.stack([p3, p2[:, 1], p1[:, 2], cp[:, 3]], axis=1)
    return left, right


def split_many(cp, ts) -> np.ndarray:
    """Cut one piece at several parameters.

    cp : (4, 2) float; ts : (k,) float, sorted, in (0, 1)
    returns (k + 1, 4, 2) float64, consecutive pieces sharing their end points bit-exactly
    """
    cp = np.asarray(cp, dtype=np.float64)
    if cp.shape != (4, 2):
        raise ValueError(f"control points: expected (4, 2), got {cp.shape}")
    knots = np.concatenate([[0.0], np.asarray(ts, dtype=np.float64).reshape(-1), [1.0]])
    return subsegment(np.broadcast_to(cp, (len(knots) - 1, 4, 2)), knots[:-1], knots[1:])


def flatten(cp, n: int) -> np.ndarray:
    """Polylines uniform in t: cp (N, 4, 2) float, n segments -> (N, n + 1, 2) float64."""
    cp = _as_cp(cp)
    t = np.broadcast_to(np.linspace(0.0, 1.0, int(n) + 1), (cp.shape[0], int(n) + 1))
    return evaluate(cp, t)


def _power_terms(cp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """a, b, c (each (N, 2)) with B'(t) = 3 (a + 2 b t + c t²)."""
    p0, p1, p2, p3 = cp[:, 0], cp[:, 1], cp[:, 2], cp[:, 3]
    return p1 - p0, p2 - 2.0 * p1 + p0, p3 - 3.0 * p2 + 3.0 * p1 - p0


def inflections(cp) -> np.ndarray:
    """Inflection parameters: roots of cross(B'(t), B''(t)) strictly inside (0, 1).

    cp : (N, 4, 2) float
    returns (N, 2) float64, sorted, NaN-padded. Lines and quadratics (and curves whose curvature sign
    never changes) give two NaNs; a curvature polynomial that vanishes identically gives no roots.
    """
    cp = _as_cp(cp)
    a, b, c = _power_terms(cp)
    # cross(a + 2bt + ct², b + ct) = cross(a, b) + cross(a, c) t + cross(b, c) t²
    k0, k1, k2 = cross(a, b), cross(a, c), cross(b, c)
    scale = np.maximum.reduce([np.abs(a).sum(1), np.abs(b).sum(1), np.abs(c).sum(1)]) ** 2
    flat = np.maximum.reduce([np.abs(k0), np.abs(k1), np.abs(k2)]) <= tol.distinct_rel * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = k1 * k1 - 4.0 * k2 * k0
        q = -0.5 * (k1 + np.where(k1 >= 0.0, 1.0, -1.0) * np.sqrt(np.maximum(disc, 0.0)))
        r = np.stack([q / k2, k0 / q], axis=1)
    r[(disc < 0.0) | flat] = np.nan
    r[~((r > 0.0) & (r < 1.0))] = np.nan
    r.sort(axis=1)
    return r


def chord_frame(cp) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame in which each piece's chord is ``[0, 1] × {0}``.

    cp : (N, 4, 2) float
    returns origin (N, 2) = P0, R (N, 2, 2) rotation taking the chord direction to +x, length (N,) chord length;
    local coordinates are ``R @ (p - origin) / length`` (see ``to_chord_frame``). A zero chord gets R = identity.
    """
    cp = _as_cp(cp)
    origin = cp[:, 0].copy()
    d = cp[:, 3] - origin
    length = np.hypot(d[:, 0], d[:, 1])
    safe = length > 0.0
    u = np.where(safe[:, None], d / np.where(safe, length, 1.0)[:, None], [1.0, 0.0])
    rot = np.stack([np.stack([u[:, 0], u[:, 1]], 1), np.stack([-u[:, 1], u[:, 0]], 1)], axis=1)
    return origin, rot, length


def to_chord_frame(cp, points) -> np.ndarray:
    """Points in each piece's chord frame: cp (N, 4, 2), points (N, M, 2) -> (N, M, 2) float64."""
    origin, rot, length = chord_frame(cp)
    p = np.asarray(points, dtype=np.float64) - origin[:, None]
    scale = np.where(length > 0.0, length, 1.0)[:, None, None]
    return np.einsum("nij,nmj->nmi", rot, p) / scale


def end_tangents(cp) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents in the direction of travel at both ends.

    Uses the first control point distinct from the end point (``P1 == P0`` is common in SVG);
    points closer than ``tol.distinct_rel`` × the control polygon's size count as coincident.
    cp : (N, 4, 2) float
    returns t0, t1 : (N, 2) float64 unit vectors at t = 0 and t = 1; NaN for a piece collapsed to a point
    """
    cp = _as_cp(cp)
    size = np.abs(cp - cp[:, :1]).max(axis=(1, 2))
    eps = tol.distinct_rel * size

    def first_distinct(diffs: np.ndarray) -> np.ndarray:  # diffs (N, 3, 2), in order of preference
        norms = np.hypot(diffs[..., 0], diffs[..., 1])
        ok = norms > eps[:, None]
        k = np.argmax(ok, axis=1)
        rows = np.arange(len(cp))
        with np.errstate(divide="ignore", invalid="ignore"):  # rows with no distinct point become NaN below
            v = diffs[rows, k] / norms[rows, k][:, None]
        v[~ok.any(axis=1)] = np.nan
        return v

    t0 = first_distinct(cp[:, 1:] - cp[:, :1])
    t1 = first_distinct(cp[:, 3:] - cp[:, 2::-1])
    return t0, t1


def tangent_apex(cp) -> np.ndarray:
    """Intersection X of the two end-tangent lines (a quadratic's control point).

    cp : (N, 4, 2) float
    returns (N, 2) float64; NaN where the tangents are parallel (within ``tol.distinct_rel``)
    """
    cp = _as_cp(cp)
    t0, t1 = end_tangents(cp)
    den = cross(t0, t1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = cross(cp[:, 3] - cp[:, 0], t1) / den
    x = cp[:, 0] + s[:, None] * t0
    x[~(np.abs(den) > tol.distinct_rel)] = np.nan
    return x


def turning_angle(cp) -> np.ndarray:
    """Angle between the end tangents, in radians in [0, π]: cp (N, 4, 2) -> (N,) float64 (NaN if degenerate)."""
    t0, t1 = end_tangents(cp)
    return np.arctan2(np.abs(cross(t0, t1)), (t0 * t1).sum(axis=1))


def bounding_boxes(cp) -> np.ndarray:
    """Boxes of the control polygons (which contain the pieces): cp (N, 4, 2) -> (N, 4) float64 (x0, y0, x1, y1)."""
    cp = _as_cp(cp)
    return np.concatenate([cp.min(axis=1), cp.max(axis=1)], axis=1)


def total_turning(cp, samples: int = 16) -> np.ndarray:
    """Total absolute turning of the tangent along each piece, in radians.

    Sums ``|Δθ|`` between ``samples + 1`` tangent directions (end tangents from ``end_tangents``). A step that
    really turns by more than π is seen as one of less than π but still counts as more than π/2, so
    ``total_turning(cp) <= π/2`` is a safe test for "turns by at most 90°" when the piece has no loop.
    cp : (N, 4, 2) float
    returns (N,) float64; NaN where a tangent vanishes inside the piece (cusp) or the piece is a point
    """
    cp = _as_cp(cp)
    t = np.broadcast_to(np.linspace(0.0, 1.0, samples + 1), (cp.shape[0], samples + 1))
    d = derivative(cp, t)
    d[:, 0], d[:, -1] = end_tangents(cp)
    steps = np.arctan2(cross(d[:, :-1], d[:, 1:]), (d[:, :-1] * d[:, 1:]).sum(axis=-1))
    with np.errstate(invalid="ignore"):
        interior_zero = ~(np.hypot(d[:, 1:-1, 0], d[:, 1:-1, 1]) > 0.0).all(axis=1)
    out = np.abs(steps).sum(axis=1)
    out[interior_zero] = np.nan
    return out


def monotone_over_chord(cp) -> np.ndarray:
    """Whether each piece is a graph over its chord: x(t) strictly increasing in the chord frame.

    Exact test on the quadratic ``dot(B'(t), P3 - P0)`` (zero allowed only at the ends). Consecutive control
    points closer than ``tol.distinct_rel`` × the control polygon's size coincide, as in ``end_tangents``: a piece
    cut at a cusp's rounded root has such a pair, whose rounding error must not count as a step backwards.
    cp : (N, 4, 2) float
    returns (N,) bool; False for a zero chord
    """
    cp = _as_cp(cp)
    d = cp[:, 3] - cp[:, 0]
    steps = np.diff(cp, axis=1)
    e = (steps * d[:, None]).sum(axis=-1)  # (N, 3) Bernstein coefficients of x'(t) / 3
    size = np.abs(cp - cp[:, :1]).max(axis=(1, 2))
    e[np.hypot(steps[..., 0], steps[..., 1]) <= tol.distinct_rel * size[:, None]] = 0.0
    e0, e1, e2 = e[:, 0], e[:, 1], e[:, 2]
    curv = e0 - 2.0 * e1 + e2
    with np.errstate(divide="ignore", invalid="ignore"):
        tv = (e0 - e1) / curv
    inside = (curv > 0.0) & (tv > 0.0) & (tv < 1.0)
    tv = np.where(inside, tv, 0.5)
    q_min = (1.0 - tv) ** 2 * e0 + 2.0 * tv * (1.0 - tv) * e1 + tv * tv * e2
    ok = (e0 >= 0.0) & (e2 >= 0.0) & ((e0 > 0.0) | (e1 > 0.0)) & ((e2 > 0.0) | (e1 > 0.0))
    ok &= ~inside | (q_min > 0.0)
    return ok & ((d * d).sum(axis=1) > 0.0)


def self_intersections(cp) -> np.ndarray:
    """Parameters (s, t), 0 < s < t < 1, where a cubic crosses itself (at most one pair; closed form).

    With B(t) = A t³ + B t² + C t + D, B(s) = B(t) for s ≠ t gives σ = s + t = -cross(A, C) / cross(A, B)
    and st = σ² + dot(A, Bσ + C) / |A|².
    cp : (N, 4, 2) float
    returns (N, 2) float64, NaN where the piece does not cross itself (always for lines and quadratics)
    """
    cp = _as_cp(cp)
    a, b, c = _power_terms(cp)
    A, B, C = c, 3.0 * b, 3.0 * a
    den = cross(A, B)
    scale = np.maximum.reduce([np.abs(A).sum(1), np.abs(B).sum(1), np.abs(C).sum(1)]) ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # den ≈ 0 rows are dropped below
        sigma = -cross(A, C) / den
        pi = sigma * sigma + (A * (B * sigma[:, None] + C)).sum(1) / (A * A).sum(1)
        root = np.sqrt(sigma * sigma - 4.0 * pi)
    out = np.stack([(sigma - root) / 2.0, (sigma + root) / 2.0], axis=1)
    good = (np.abs(den) > tol.distinct_rel * scale) & (out[:, 0] > 0.0) & (out[:, 1] < 1.0) & (root > 0.0)
    out[~good] = np.nan
    return out


def cusps(cp, atol: float) -> np.ndarray:
    """Parameters where the tangent (nearly) vanishes: local minima of |B'(t)| with |B'(t)| <= ``atol``.

    Exact cusps and fold-backs (a piece that reverses along itself) both show as such minima; near one,
    the piece stays within about ``atol`` of a true cusp.
    cp : (N, 4, 2) float; atol : float, in the control points' units per unit of t
    returns (N, 3) float64, sorted, NaN-padded, strictly inside (0, 1)
    """
    cp = _as_cp(cp)
    a, b, c = _power_terms(cp)
    # dot(B', B'') / 18 = a·b + (a·c + 2 b·b) t + 3 b·c t² + c·c t³, to Bernstein form
    k0, k1 = (a * b).sum(1), (a * c).sum(1) + 2.0 * (b * b).sum(1)
    k2, k3 = 3.0 * (b * c).sum(1), (c * c).sum(1)
    bern = np.stack([k0, k0 + k1 / 3.0, k0 + 2.0 * k1 / 3.0 + k2 / 3.0, k0 + k1 + k2 + k3], axis=1)
    r = bernstein_roots(bern)
    i, k = np.nonzero(np.isfinite(r))
    speed = np.hypot(*derivative(cp[i], r[i, k]).T)
    r[i[speed > atol], k[speed > atol]] = np.nan
    r.sort(axis=1)
    return r


def bernstein_roots(b) -> np.ndarray:
    """Sign changes of 1-D cubics in Bernstein form, strictly inside (0, 1).

    Splits [0, 1] at the roots of the derivative, so that each part is monotone, then bisects each part
    that changes sign (to the last bit). Roots where the cubic only touches zero are not reported.
    b : (N, 4) float Bernstein coefficients
    returns (N, 3) float64, sorted, NaN-padded
    """
    b = np.asarray(b, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"Bernstein coefficients: expected (N, 4), got {b.shape}")
    d0, d1, d2 = b[:, 1] - b[:, 0], b[:, 2] - b[:, 1], b[:, 3] - b[:, 2]
    k2, k1, k0 = d0 - 2.0 * d1 + d2, 2.0 * (d1 - d0), d0
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = k1 * k1 - 4.0 * k2 * k0
        q = -0.5 * (k1 + np.where(k1 >= 0.0, 1.0, -1.0) * np.sqrt(np.maximum(disc, 0.0)))
        crit = np.stack([q / k2, k0 / q], axis=1)
    crit[~((crit > 0.0) & (crit < 1.0)) | (disc < 0.0)[:, None]] = 1.0
    knots = np.concatenate([np.zeros((len(b), 1)), np.sort(crit, axis=1), np.ones((len(b), 1))], axis=1)
    lo, hi = knots[:, :-1].copy(), knots[:, 1:].copy()  # (N, 3)

    def f(t):
        s = 1.0 - t
        return s**3 * b[:, :1] + 3.0 * s * s * t * b[:, 1:2] + 3.0 * s * t * t * b[:, 2:3] + t**3 * b[:, 3:]

    f_lo, f_hi = f(lo), f(hi)
    found = np.sign(f_lo) * np.sign(f_hi) < 0.0
    s_lo = np.sign(f_lo)
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        go_right = np.sign(f(mid)) == s_lo
        lo = np.where(go_right, mid, lo)
        hi = np.where(go_right, hi, mid)
    r = np.where(found, 0.5 * (lo + hi), np.nan)
    r[~((r > 0.0) & (r < 1.0))] = np.nan
    r.sort(axis=1)
    return r


def closest_parameter(cp, points, t, iterations: int = 20) -> np.ndarray:
    """Refine parameters of the points of each piece closest to given points (Newton, clamped to [0, 1]).

    cp : (N, 4, 2) float; points : (N, 2) float; t : (N,) float starting parameters
    returns (N,) float64 parameters (a local minimum of the distance near the start)
    """
    cp = _as_cp(cp)
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).copy()
    for _ in range(iterations):
        r = evaluate(cp, t) - p
        d1, d2 = derivative(cp, t), second_derivative(cp, t)
        g = (r * d1).sum(1)
        h = (d1 * d1).sum(1) + (r * d2).sum(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(h > 0.0, g / h, 0.0)
        t = np.clip(t - np.nan_to_num(step), 0.0, 1.0)
    return t


def refine_intersections(cp_a, cp_b, s, t, iterations: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton iteration on A(s) = B(t), clamped to [0, 1]², for pairs of pieces.

    cp_a, cp_b : (N, 4, 2) float; s, t : (N,) float starting parameters
    returns s, t : (N,) float64 and the remaining gap |A(s) - B(t)| : (N,) float64
    """
    cp_a, cp_b = _as_cp(cp_a), _as_cp(cp_b)
    s = np.asarray(s, dtype=np.float64).copy()
    t = np.asarray(t, dtype=np.float64).copy()
    live = np.arange(len(s))  # pairs not yet at a fixed point of the iteration (the others would not move again)
    for _ in range(iterations):
        if not len(live):
            break
        a, b, sl, tl = cp_a[live], cp_b[live], s[live], t[live]
        f = evaluate(a, sl) - evaluate(b, tl)
        da, db = derivative(a, sl), derivative(b, tl)
        det = cross(db, da)  # det of [da, -db]
        with np.errstate(divide="ignore", invalid="ignore"):
            ds = cross(f, db) / det  # Cramer on da ds - db dt = -f
            dt = cross(f, da) / det
        ok = np.isfinite(ds) & np.isfinite(dt)
        s_new = np.clip(np.where(ok, sl + ds, sl), 0.0, 1.0)
        t_new = np.clip(np.where(ok, tl + dt, tl), 0.0, 1.0)
        s[live], t[live] = s_new, t_new
        live = live[(s_new != sl) | (t_new != tl)]
    gap = evaluate(cp_a, s) - evaluate(cp_b, t)
    return s, t, np.hypot(gap[:, 0], gap[:, 1])
