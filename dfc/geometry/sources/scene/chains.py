"""Polylines from image segments, and polylines as lines and cubic Béziers.

``chain`` joins segments that share an end point id into chains, passing through points where exactly two
segments meet. ``fit_polylines`` turns each chain into pieces: a stretch whose points all lie within the tolerance
of its chord becomes one line (straight mesh edges stay lines), a longer smooth stretch one cubic Bézier fitted by
least squares (Schneider, "An algorithm for automatically fitting digitized curves", Graphics Gems 1990), and a
stretch that neither fits is split at its worst point and tried again. All runs of a round are fitted at once.
"""

from __future__ import annotations

import numpy as np

from ... import bezier

__all__ = ["chain", "fit_polylines"]

_CORNER_COS = np.cos(np.radians(45.0))
"""Chains are split where they turn by more than 45° at a point: cubics never round such a corner."""
_NEWTON = 2
"""Reparametrisation rounds (Newton steps towards the closest curve point) per cubic fit."""
_SAMPLE_SPACING = 0.25
"""Cubics are fitted to, and measured at, points this far apart (in the polyline's units) along each segment ..."""
_SAMPLES_PER_SEGMENT = (4, 256)
"""... but at least 4 and at most 256 per segment."""
_CUBIC_MARGIN = 0.9
"""A cubic is kept when those points are within this fraction of the tolerance: it may stray a little farther
between them. (A line's distance to its polyline is largest at a polyline point, so lines use the tolerance.)"""


def chain(ends: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chains of segments.

    ends : (S, 2) int64 the end point ids of S segments (equal ids: the same point)
    returns ``ids`` (M,) int64 point ids of all chains one after the other, ``offsets`` (C + 1,) int64 (chain c is
    ``ids[offsets[c]:offsets[c + 1]]``, at least 2 points) and ``closed`` (C,) bool (first id == last id). A chain
    runs between points where other than two segments meet, or around a loop.
    """
    ends = np.asarray(ends, dtype=np.int64).reshape(-1, 2)
    point_ids, inv = np.unique(ends, return_inverse=True)
    inv = inv.reshape(-1, 2)
    degree = np.bincount(inv.ravel(), minlength=len(point_ids))
    incident = (np.argsort(inv.ravel(), kind="stable") // 2).tolist()
    first = np.r_[0, np.cumsum(degree)[:-1]].tolist()
    other = (inv[:, 0] + inv[:, 1]).tolist()  # other end = other[s] - this end
    deg = degree.tolist()
    used = [False] * len(ends)
    ids: list[int] = []
    offsets = [0]

    def walk(v: int, s: int) -> None:
        ids.append(v)
        while True:
            used[s] = True
            v = other[s] - v
            ids.append(v)
            if deg[v] != 2:
                break
            k = first[v]
            s = incident[k] if incident[k] != s else incident[k + 1]
            if used[s]:
                break
        offsets.append(len(ids))

    for v in np.nonzero(degree != 2)[0].tolist():
        for k in range(first[v], first[v] + deg[v]):
            if not used[incident[k]]:
                walk(v, incident[k])
    for s in range(len(ends)):  # what is left are loops through points of degree 2
        if not used[s]:
            walk(int(inv[s, 0]), s)
    ids_arr = point_ids[np.array(ids, dtype=np.int64)] if ids else np.zeros(0, np.int64)
    offsets_arr = np.array(offsets, dtype=np.int64)
    closed = ids_arr[offsets_arr[:-1]] == ids_arr[offsets_arr[1:] - 1] if len(ids) else np.zeros(0, bool)
    return ids_arr, offsets_arr, closed


def fit_polylines(points: np.ndarray, offsets: np.ndarray, tolerance: float) -> tuple[np.ndarray, ...]:
    """Lines and cubic Béziers within ``tolerance`` of polylines.

    points : (N, 2) float64 the polylines one after the other; offsets : (C + 1,) int64 (polyline c is
    ``points[offsets[c]:offsets[c + 1]]``, at least 2 points; a closed one repeats its first point at the end)
    returns control points (P, 4, 2) float64, degree (P,) int8 (1 or 3) and polyline (P,) int64, pieces of one
    polyline consecutive and in order, sharing end points bit-exactly with the polyline's points
    """
    points = np.asarray(points, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.int64)
    n = len(points)
    polyline = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    # break points: polyline ends, corners, and the middle of closed polylines
    brk = np.zeros(n, dtype=bool)
    brk[offsets[:-1]] = brk[offsets[1:] - 1] = True
    d = _unit(np.diff(points, axis=0))
    interior = np.nonzero(~brk)[0]
    brk[interior[np.einsum("ij,ij->i", d[interior - 1], d[interior]) < _CORNER_COS]] = True
    closed = np.nonzero(np.all(points[offsets[:-1]] == points[offsets[1:] - 1], axis=1))[0]
    brk[(offsets[closed] + offsets[closed + 1] - 1) // 2] = True
    cut = np.nonzero(brk)[0]
    same = polyline[cut[1:]] == polyline[cut[:-1]]
    lo, hi = cut[:-1][same], cut[1:][same]

    done = []
    while len(lo):
        line = _line_error(points, lo, hi) <= tolerance
        done.append((lo[line], hi[line], None))
        lo, hi = lo[~line], hi[~line]
        if not len(lo):
            break
        cp, err, worst = _fit_cubics(points, brk, lo, hi)
        ok = err <= _CUBIC_MARGIN * tolerance
        done.append((lo[ok], hi[ok], cp[ok]))
        lo, hi, worst = lo[~ok], hi[~ok], worst[~ok]
        quarter = -(-(hi - lo) // 4)
        k = np.clip(worst, lo + quarter, hi - quarter)
        lo, hi = np.r_[lo, k], np.r_[k, hi]

    run_lo = np.concatenate([lo_ for lo_, _, _ in done]) if done else np.zeros(0, np.int64)
    cps, degrees = [], []
    for lo_, hi_, cp in done:
        if cp is None:
            a, b = points[lo_], points[hi_]
            cps.append(np.stack([a, a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0, b], axis=1))
            degrees.append(np.full(len(lo_), 1, np.int8))
        else:
            cps.append(cp)
            degrees.append(np.full(len(lo_), 3, np.int8))
    if not cps:
        return np.zeros((0, 4, 2)), np.zeros(0, np.int8), np.zeros(0, np.int64)
    order = np.argsort(run_lo, kind="stable")
    return np.concatenate(cps)[order], np.concatenate(degrees)[order], polyline[run_lo[order]]


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


def _ranges(lo: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run of each element and ``lo[run] + j`` for j < count[run]: flattened index ranges."""
    run = np.repeat(np.arange(len(lo)), count)
    j = np.arange(len(run)) - np.repeat(np.cumsum(count) - count, count)
    return run, j


def _line_error(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(R,) largest distance of the points of each run ``lo..hi`` to the segment between its ends."""
    run, j = _ranges(lo, hi - lo + 1)
    p = points[lo[run] + j]
    a, b = points[lo][run], points[hi][run]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    dist = np.linalg.norm(p - a - t[:, None] * ab, axis=1)
    return np.maximum.reduceat(dist, np.r_[0, np.cumsum(hi - lo + 1)[:-1]]) if len(lo) else dist


def _fit_cubics(points: np.ndarray, brk: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Least-squares cubics with fixed ends and end tangent directions for runs ``lo..hi``.

    The polyline is sampled every ``_SAMPLE_SPACING`` along its segments (chord-length parameters, improved by
    Newton steps). End tangents: the neighbouring segment at a break point, else the central difference.
    returns control points (R, 4, 2), the largest sample distance (R,), and the point index nearest to it (R,)
    """
    last = len(points) - 1
    p0, p3 = points[lo], points[hi]
    before, after = points[np.maximum(lo - 1, 0)], points[np.minimum(hi + 1, last)]
    t1 = _unit(points[lo + 1] - np.where(brk[lo, None], p0, before))
    t2 = _unit(points[hi - 1] - np.where(brk[hi, None], p3, after))
    per = np.clip(np.ceil(np.linalg.norm(np.diff(points, axis=0), axis=1) / _SAMPLE_SPACING), *_SAMPLES_PER_SEGMENT)
    first = np.r_[0, np.cumsum(per)].astype(np.int64)  # first sample of each segment, in a global numbering
    count = first[hi] - first[lo] + 1
    run, j = _ranges(lo, count)
    end = j == count[run] - 1  # the run's last point closes its last segment
    q = first[lo][run] + j
    segment = np.where(end, hi[run] - 1, np.searchsorted(first, q, side="right") - 1)
    frac = np.where(end, 1.0, (q - first[segment]) / per[segment])
    sample = points[segment] + frac[:, None] * (points[segment + 1] - points[segment])
    step = np.linalg.norm(np.diff(sample, axis=0), axis=1)
    step = np.r_[0.0, np.where(run[1:] == run[:-1], step, 0.0)]
    along = np.cumsum(step)
    along -= np.repeat(along[np.r_[0, np.cumsum(count)[:-1]]], count)
    total = np.repeat(np.maximum(np.bincount(run, weights=step, minlength=len(lo)), 1e-300), count)
    u = along / total
    chord = np.linalg.norm(p3 - p0, axis=1)

    cp = None
    for _ in range(_NEWTON + 1):
        cp = _least_squares(sample, run, u, p0, p3, t1, t2, chord, len(lo))
        c = cp[run]
        diff = bezier.evaluate(c, u) - sample
        d1, d2 = bezier.derivative(c, u), bezier.second_derivative(c, u)
        denom = np.einsum("ij,ij->i", d1, d1) + np.einsum("ij,ij->i", diff, d2)
        u = np.clip(u - np.einsum("ij,ij->i", diff, d1) / np.where(np.abs(denom) > 1e-300, denom, np.inf), 0, 1)
    dist = np.linalg.norm(bezier.evaluate(cp[run], u) - sample, axis=1)
    starts = np.r_[0, np.cumsum(count)[:-1]]
    err = np.maximum.reduceat(dist, starts)
    # index of the worst sample in each run: sort by (run, -dist) and take each run's first
    order = np.lexsort((-dist, run))
    pick = order[starts]
    worst = segment[pick] + (frac[pick] >= 0.5)
    return cp, err, worst


def _least_squares(sample, run, u, p0, p3, t1, t2, chord, n_runs):
    """Schneider's tangent lengths alpha1, alpha2 by least squares; chord / 3 where the system is degenerate."""
    s = 1.0 - u
    b0, b1, b2, b3 = s ** 3, 3 * s * s * u, 3 * s * u * u, u ** 3
    a1, a2 = b1[:, None] * t1[run], b2[:, None] * t2[run]
    rest = sample - (b0 + b1)[:, None] * p0[run] - (b2 + b3)[:, None] * p3[run]

    def total(x, y):
        return np.bincount(run, weights=np.einsum("ij,ij->i", x, y), minlength=n_runs)

    c11, c12, c22 = total(a1, a1), total(a1, a2), total(a2, a2)
    x1, x2 = total(a1, rest), total(a2, rest)
    det = c11 * c22 - c12 * c12
    good = np.abs(det) > 1e-12 * np.maximum(c11 * c22, 1e-300)
    det = np.where(good, det, 1.0)
    alpha1 = (x1 * c22 - x2 * c12) / det
    alpha2 = (c11 * x2 - c12 * x1) / det
    bad = ~good | (alpha1 <= 1e-6 * chord) | (alpha2 <= 1e-6 * chord) | (alpha1 > 2 * chord) | (alpha2 > 2 * chord)
    alpha1 = np.where(bad, chord / 3.0, alpha1)
    alpha2 = np.where(bad, chord / 3.0, alpha2)
    return np.stack([p0, p0 + alpha1[:, None] * t1, p3 + alpha2[:, None] * t2, p3], axis=1)
