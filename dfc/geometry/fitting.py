"""Fitting lines and cubic Béziers to ordered points within a tolerance (Schneider's algorithm).

P. J. Schneider, "An Algorithm for Automatically Fitting Digitized Curves", Graphics Gems (1990): with
the end points and end tangent directions fixed, the two inner control points' distances along the
tangents solve a 2 × 2 least-squares problem over chord-length parameters; parameters are improved by
Newton steps while the error is near the tolerance, and a piece that still misses is split at its worst
point, where both halves share a tangent (so the result is smooth there). Corners — a turn sharper than
``corner_angle`` between the directions just before and just after a point, or across a gap in the
points — are found first; the curve is cut there and both sides end on the intersection of their end
tangent lines, which also closes the gap a corner leaves in edge points.

Points are (n, 2) float64 in any units; lengths (tolerance, ``span``) are in the same units.
"""

from __future__ import annotations

import numpy as np

from .curves import DEGREE_CUBIC, DEGREE_LINE, elevate

__all__ = ["fit_points", "corners"]

_REPARAMETERISE = 8  # Newton passes before a piece that is close to the tolerance is split
_CLOSE = 4.0  # "close to the tolerance": error below this many tolerances


def fit_points(points, *, tolerance: float, corner_angle: float = 40.0, span: float = 3.0,
               closed: bool = False, min_points: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Lines and cubics through ordered points, the points within ``tolerance`` of the result.

    points : (n, 2) float, n ≥ 2, in order along the curve (gaps allowed); an open curve starts at the
        first point and ends at the last
    tolerance : largest distance from a point to the fitted curve
    min_points : a miss below 4 tolerances does not split a piece into parts of fewer points than this, so
        that noise in the points is not taken for shape (such points may then stay up to 4 tolerances away)
    corner_angle : degrees; a sharper turn is a corner (180: none); points within ``span / 2`` of a corner are
        left out (at an edge's corner they are the least reliable), the rest are fitted
    span : arc length over which tangents are estimated; points farther than this from both neighbours
        are outliers and dropped
    closed : the points go round a loop (the first point follows the last)
    returns degree (P,) int8 (1 line, 3 cubic) and control points (P, 4, 2) float64, consecutive pieces
    sharing their end points exactly (for ``closed``, the last piece ends where the first starts)
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(p) < 2:
        raise ValueError(f"fit_points: need at least 2 points, got {len(p)}")
    if not tolerance > 0:
        raise ValueError(f"fit_points: tolerance must be > 0, got {tolerance}")
    p = p[np.r_[True, np.any(np.diff(p, axis=0) != 0, axis=1)]]  # drop repeated points
    if closed and len(p) > 2 and np.all(p[0] == p[-1]):
        p = p[:-1]
    p = _drop_outliers(p, span, closed)
    closed = closed and len(p) >= 3
    joints, drop_lo, drop_hi = corners(p, corner_angle=corner_angle, span=span, tolerance=tolerance, closed=closed)
    n, k = len(p), len(joints)
    if closed and not k:
        m = _count(p, span)
        tangent = _direction(np.concatenate([p[n - m + 1:], p[:m]]))
        pieces = _fit(np.concatenate([p, p[:1]]), tangent, -tangent, tolerance, span, min_points)
    else:
        if closed:  # from corner to corner, round the loop
            segments = [np.concatenate([joints[i][None], p[np.arange(drop_hi[i], drop_lo[(i + 1) % k] + n * (i + 1 == k)) % n],
                                        joints[(i + 1) % k][None]]) for i in range(k)]
        else:
            starts = np.r_[0, drop_hi]
            stops = np.r_[drop_lo, n]
            heads = [p[:1]] + [j[None] for j in joints]
            tails = [j[None] for j in joints] + [p[-1:]]
            segments = [np.concatenate([heads[i], p[max(starts[i], 1 if i == 0 else 0): stops[i] - (i == k)], tails[i]])
                        for i in range(k + 1)]
        pieces = []
        for seg in segments:
            pieces += _fit(seg, _direction(seg[: _count(seg, span)]), _direction(seg[::-1][: _count(seg[::-1], span)]),
                           tolerance, span, min_points)
    degree = np.array([d for d, _ in pieces], dtype=np.int8)
    cp = np.stack([c for _, c in pieces])
    cp[1:, 0] = cp[:-1, 3]  # bit-exact joints
    if closed:
        cp[-1, 3] = cp[0, 0]
    line = degree == DEGREE_LINE
    cp[line] = elevate(cp[line][:, [0, 3]], DEGREE_LINE)
    return degree, cp


def corners(points, *, corner_angle: float, span: float, tolerance: float,
            closed: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners of an ordered point sequence, placed where the tangent lines on either side cross.

    At each point the direction of the points over ``span`` ending ``span / 2`` before it is compared with that
    of the points over ``span`` starting ``span / 2`` after it (the points right at a corner are the least
    reliable; a gap in the points is skipped). A turn above ``corner_angle`` degrees that is
    the largest within ``span`` is a corner if it is concentrated there: the same comparison ``span`` farther
    out turns less than 1.5 times as much (on a circle it turns twice as much). The corner is where the two
    tangent lines cross, each fitted over the longest straight run (within ``tolerance``) up to 16 times
    ``span``; when they cross far away (more than ``span`` beyond either side), the point itself (a cusp's tip).

    points : (n, 2) float
    returns joints (k, 2) float64 in order along the points; and for each, the points it replaces:
    indices ``lo[i] .. hi[i] - 1`` (k,) int64 (for ``closed``, modulo n: ``hi`` may exceed n, ``lo`` be negative)
    """
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    empty = np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    if n < 4:
        return empty
    ext = np.concatenate([p, p, p]) if closed else p
    off = n if closed else 0
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(ext, axis=0), axis=1))]
    idx = np.arange(n) + off
    skip = 0.5 * span

    def turn_at(near: float):
        """Turn (degrees, (n,)) between the windows [-near - span, -near] and [near, near + span] around each point,
        with the windows' index ranges."""
        b_hi = np.searchsorted(arc, arc[idx] - near, side="right")
        a_lo = np.searchsorted(arc, arc[idx] + near, side="left")
        b_lo = np.searchsorted(arc, arc[np.maximum(b_hi - 1, 0)] - span, side="left")
        a_hi = np.searchsorted(arc, arc[np.minimum(a_lo, len(arc) - 1)] + span, side="right")
        ok = (b_hi - b_lo >= 2) & (a_hi - a_lo >= 2)
        if not closed:  # both windows whole, not cut by an end
            ok &= (arc[np.maximum(b_hi - 1, 0)] - span >= 0) & (arc[np.minimum(a_lo, len(arc) - 1)] + span <= arc[-1])
        db, da = _directions(ext, b_lo, b_hi), _directions(ext, a_lo, a_hi)
        turn = np.degrees(np.arccos(np.clip((db * da).sum(1), -1.0, 1.0)))
        return np.where(ok, turn, np.nan), (b_lo, b_hi, a_lo, a_hi)

    turn, (b_lo, b_hi, a_lo, a_hi) = turn_at(skip)
    far, _ = turn_at(skip + span)
    corner = (turn > corner_angle) & ~(far >= 1.5 * turn)
    loop = arc[off + n] - arc[off] if closed else np.inf
    chosen: list[int] = []
    for i in np.argsort(-np.where(corner, turn, -1.0), kind="stable"):
        if not corner[i]:
            break
        if all(min(abs(arc[idx[i]] - arc[idx[j]]), loop - abs(arc[idx[i]] - arc[idx[j]])) > span
               and not _overlap((b_hi[i] - 1, a_lo[i]), (b_hi[j] - 1, a_lo[j]), n if closed else 0) for j in chosen):
            chosen.append(int(i))
    chosen.sort()
    if not chosen:
        return empty
    joints = np.zeros((len(chosen), 2))
    for k, i in enumerate(chosen):
        before = _straight_run(ext[b_lo[i]: b_hi[i]], ext[: b_hi[i]][::-1], tolerance)
        after = _straight_run(ext[a_lo[i]: a_hi[i]], ext[a_lo[i]:], tolerance)
        a, b = ext[b_hi[i] - 1], ext[a_lo[i]]
        cross = _intersect(before.mean(0), _direction(before), after.mean(0), _direction(after))
        opening = np.radians(180.0 - turn[i])  # the angle between the sides: a sharp tip lies far beyond the points
        reach = span + np.linalg.norm(b - a) / (2.0 * max(np.sin(0.5 * opening), 0.1))
        near = cross is not None and np.linalg.norm(cross - a) <= reach and np.linalg.norm(cross - b) <= reach
        joints[k] = cross if near else ext[idx[i]]
    sel = np.array(chosen)
    return joints, b_hi[sel] - off, a_lo[sel] - off


def _overlap(a: tuple[int, int], b: tuple[int, int], period: int) -> bool:
    """Whether index intervals ``a`` and ``b`` (inclusive) share an index, also after a shift by ±``period``."""
    return any(a[0] <= b[1] + s and b[0] + s <= a[1] for s in ((0, period, -period) if period else (0,)))


def _drop_outliers(p: np.ndarray, span: float, closed: bool) -> np.ndarray:
    """``p`` without the points farther than ``span`` from both neighbours (lone points in gaps)."""
    if len(p) < 3:
        return p
    q = np.concatenate([p[-1:], p, p[:1]]) if closed else p
    step = np.linalg.norm(np.diff(q, axis=0), axis=1)
    before, after = (step[:-1], step[1:]) if closed else (np.r_[0.0, step], np.r_[step, 0.0])
    keep = ~((before > span) & (after > span))
    return p[keep] if keep.sum() >= 2 else p


def _straight_run(window: np.ndarray, beyond: np.ndarray, tolerance: float) -> np.ndarray:
    """The longest run of ``beyond`` (points leading away from a corner, nearest first) within ``tolerance``
    of its least-squares line, tried at 2, 4, 8, 16 times the length of ``window`` (the run at ``span``);
    ``window`` itself when none is straight. Tangent lines through straight sides come out exact."""
    best = window
    for factor in (2, 4, 8, 16):
        run = beyond[: factor * len(window)]
        if len(run) <= len(best):
            break
        centred = run - run.mean(axis=0)
        d = _direction(run)
        if np.abs(centred @ np.array([-d[1], d[0]])).max() > tolerance:
            break
        best = run
    return best


def _directions(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Unit directions (m, 2) of the least-squares lines through ``p[lo:hi]`` (m ranges), oriented along p."""
    q = p - p[0]  # moments about a point of the curve stay small
    s = np.concatenate([np.zeros((1, 5)), np.cumsum(np.stack([q[:, 0], q[:, 1], q[:, 0] ** 2, q[:, 0] * q[:, 1],
                                                               q[:, 1] ** 2], axis=1), axis=0)])
    lo, hi = np.clip(lo, 0, len(p)), np.clip(hi, 0, len(p))
    m = np.maximum(hi - lo, 1)[:, None]
    mx, my, xx, xy, yy = ((s[hi] - s[lo]) / m).T
    sxx, sxy, syy = xx - mx * mx, xy - mx * my, yy - my * my
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    d = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    chord = p[np.maximum(hi - 1, 0)] - p[np.minimum(lo, len(p) - 1)]
    return np.where(((d * chord).sum(1) < 0)[:, None], -d, d)


def _intersect(p, u, q, v):
    """Crossing of lines p + s u and q + t v, or None when they are near parallel."""
    den = u[0] * v[1] - u[1] * v[0]
    if abs(den) < 1e-6:
        return None
    s = ((q[0] - p[0]) * v[1] - (q[1] - p[1]) * v[0]) / den
    return p + s * u


def _count(p: np.ndarray, span: float) -> int:
    """Number of leading points of ``p`` within arc length ``span`` of the first (at least 2)."""
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    return max(2, int(np.searchsorted(arc, span, side="right")))


def _direction(p: np.ndarray) -> np.ndarray:
    """Unit direction of the least-squares line through ordered points (n, 2), oriented first → last."""
    centred = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    d = vt[0]
    chord = p[-1] - p[0]
    if d @ chord < 0:
        d = -d
    return d


def _fit(p: np.ndarray, t0: np.ndarray, t1: np.ndarray, tol: float, span: float, min_points: int,
         depth: int = 0) -> list:
    """Pieces through ``p`` (n, 2) from ``p[0]`` to ``p[-1]`` leaving along ``t0`` and arriving from ``-t1``
    (``t1`` points back into the curve). Returns [(degree, (4, 2) control points), ...]."""
    a, b = p[0], p[-1]
    chord = b - a
    length = np.linalg.norm(chord)
    line = [(DEGREE_LINE, np.stack([a, a + chord / 3, b - chord / 3, b]))]
    if len(p) <= 2:
        return line
    if length > 0:
        dist = np.abs((p[1:-1] - a) @ np.array([-chord[1], chord[0]])) / length
        along = (p[1:-1] - a) @ chord / length**2
        if dist.max() <= tol and along.min() >= -tol / length and along.max() <= 1 + tol / length:
            return line
    u = _chord_parameters(p)
    cp = _least_squares(p, u, t0, t1)
    err, worst = _error(cp, p, u)
    if err > tol and err < _CLOSE * tol:
        for _ in range(_REPARAMETERISE):
            u = _newton(cp, p, u, 3)
            cp = _least_squares(p, u, t0, t1)
            err, worst = _error(cp, p, u)
            if err <= tol:
                break
    if length == 0:  # a loop back to the start: cut at the farthest point
        err, worst = np.inf, int(np.argmax(np.linalg.norm(p - a, axis=1)))
    few = len(p) < 2 * min_points
    if err <= tol or (few and err <= _CLOSE * tol) or len(p) < 3 or depth > 40:
        return [(DEGREE_CUBIC, cp)]
    margin = 1 if few else max(1, min_points)
    worst = int(np.clip(worst, margin, len(p) - 1 - margin))
    lo = max(0, worst - _count(p[worst::-1], span) + 1)
    hi = worst + _count(p[worst:], span)
    tangent = _direction(p[lo:hi])
    return (_fit(p[: worst + 1], t0, -tangent, tol, span, min_points, depth + 1)
            + _fit(p[worst:], tangent, t1, tol, span, min_points, depth + 1))


def _chord_parameters(p: np.ndarray) -> np.ndarray:
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    return arc / arc[-1]


def _least_squares(p: np.ndarray, u: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """Schneider's 2 × 2 solve for the tangent lengths; the Wu–Barsky third of the chord when it degenerates."""
    a, b = p[0], p[-1]
    s = 1.0 - u
    b0, b1, b2, b3 = s**3, 3 * s * s * u, 3 * s * u * u, u**3
    A1, A2 = b1[:, None] * t0, b2[:, None] * t1
    rhs = p - (b0 + b1)[:, None] * a - (b2 + b3)[:, None] * b
    m = np.array([[np.sum(A1 * A1), np.sum(A1 * A2)], [np.sum(A1 * A2), np.sum(A2 * A2)]])
    x = np.array([np.sum(A1 * rhs), np.sum(A2 * rhs)])
    length = np.linalg.norm(b - a)
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    alpha = None
    if abs(det) > 1e-12 * max(1.0, m[0, 0] * m[1, 1]):
        alpha = np.linalg.solve(m, x)
    if alpha is None or not np.all((alpha > 1e-6 * length) & (alpha < length)):  # degenerate, or a loop
        alpha = np.array([length / 3, length / 3])
    return np.stack([a, a + alpha[0] * t0, b + alpha[1] * t1, b])


def _error(cp: np.ndarray, p: np.ndarray, u: np.ndarray) -> tuple[float, int]:
    """Largest distance from the points to the curve (after refining their parameters) and where it is."""
    u = _newton(cp, p, u, 4)
    d = np.linalg.norm(_bezier(cp, u) - p, axis=1)
    worst = int(np.argmax(d))
    return float(d[worst]), worst


def _bezier(cp: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Points (n, 2) of one cubic (4, 2) at parameters (n,)."""
    s = (1.0 - u)[:, None]
    t = u[:, None]
    return s**3 * cp[0] + 3 * s * s * t * cp[1] + 3 * s * t * t * cp[2] + t**3 * cp[3]


def _newton(cp: np.ndarray, p: np.ndarray, u: np.ndarray, iterations: int) -> np.ndarray:
    """Parameters (n,) of the points of one cubic (4, 2) nearest to ``p`` (n, 2): Newton from ``u``, in [0, 1]."""
    d1, d2 = 3 * np.diff(cp, axis=0), 6 * np.diff(cp, n=2, axis=0)  # derivative and second derivative polygons
    for _ in range(iterations):
        s, t = (1.0 - u)[:, None], u[:, None]
        r = _bezier(cp, u) - p
        b1 = s * s * d1[0] + 2 * s * t * d1[1] + t * t * d1[2]
        b2 = s * d2[0] + t * d2[1]
        g = (r * b1).sum(1)
        h = (b1 * b1).sum(1) + (r * b2).sum(1)
        u = np.clip(u - np.where(h > 0, g / np.where(h > 0, h, 1.0), 0.0), 0.0, 1.0)
    return u
