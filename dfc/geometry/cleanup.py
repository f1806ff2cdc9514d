"""Curve clean-up before meshing (docs/design.md §3 and §4 point 3).

``clean`` turns arbitrary Bézier pieces into pieces that the mesher can use as they are:

* they lie in the domain and meet only at shared end points (bit-identical coordinates);
* every curved piece (degree 2 or 3) is a graph over its chord, has no inflection and turns by at most 90°;
* no two pieces share a chord (compared by unordered end-point pair), and no piece is closed.

Every output piece keeps the map back to its input curve (``curve``, ``t_range``): a piece that covered
``[s0, s1]`` and is cut at local ``t`` gives ``[s0, s0 + t (s1 - s0)]`` and ``[s0 + t (s1 - s0), s1]``.

Working form: pieces as ``(P, 4, 2)`` float64 cubic control points plus their end-point vertex ids into a
vertex table ``(V, 2)``; cuts are lists of (piece, t, vertex) triples applied all at once.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import CurveError
from . import bezier as bz
from .curves import DEGREE_LINE, Curves, elevate
from .plane import closest_on_segments, cross
from .tolerances import Tolerances, tol

__all__ = ["clean"]

_FLAT_REL = 1e-3
"""Polylines used to find intersection candidates stay this close (× diagonal) to their pieces."""
_SEGMENT_REL = 1.0 / 64.0
"""... and their segments are at most this long (× diagonal), which bounds the grid cells one covers."""
_OVERLAP_SIN = 1e-3
"""Intersections where the tangents are closer than this (sine) to parallel are checked for overlap."""
_OVERLAP_STEP = 0.05
"""Parameter offset at which an overlap is probed on both sides of a near-parallel intersection."""
_EXACT_SIN = 1e-6
"""The pass for exact crossings after pinning skips contacts closer than this (sine) to parallel: overlaps."""
_MAX_ROUNDS = 64
"""Bound on the halving rounds (turning, shared chords); each round at least halves the offending pieces."""


@dataclass(frozen=True)
class _Pieces:
    cp: np.ndarray  # (P, 4, 2) float64
    deg: np.ndarray  # (P,) int8
    curve: np.ndarray  # (P,) int64
    trange: np.ndarray  # (P, 2) float64
    ev: np.ndarray  # (P, 2) int64 end-point vertex ids (-1 before snapping)

    def take(self, idx) -> _Pieces:
        return _Pieces(self.cp[idx], self.deg[idx], self.curve[idx], self.trange[idx], self.ev[idx])

    def __len__(self) -> int:
        return len(self.cp)


def clean(curves: Curves, *, tol: Tolerances = tol) -> Curves:
    """Clip, split, snap and simplify pieces so that they can be meshed (see the module docstring).

    curves : input pieces (any crossings, overlaps, loops, pieces outside the domain)
    tol : tolerances; ``snap_rel`` (merge distance), ``zero_length_rel``, ``min_piece_rel``
    returns a new ``Curves`` with the same domain, names, sides and source; ``curve``/``t_range`` map every
    output piece back to its input curve's parameter ``s``
    Raises ``CurveError`` if ``curves`` is not a ``Curves``.
    """
    if not isinstance(curves, Curves):
        raise CurveError(f"clean: expected a Curves object, got {type(curves).__name__}")
    diag = curves.diagonal
    snap = tol.snap_rel * diag
    min_size = tol.min_piece_rel * diag
    n = len(curves)
    p = _Pieces(curves.control_points.copy(), curves.degree.copy(), curves.curve.copy(),
                curves.t_range.copy(), np.full((n, 2), -1, dtype=np.int64))
    p = p.take(_extent(p.cp) > tol.zero_length_rel * diag)
    p = _clip(p, curves.domain, snap)
    if len(p):
        p, verts = _split_at_crossings(p, curves.domain, snap, diag)
        # pinning moved end points by up to ``snap``, and straightening moves nearly straight pieces as far: where two
        # pieces touch tangentially, that turns one a little and it can cross the other again near the contact, closer
        # than ``snap`` to it (unseen by the pass above)
        p = _demote_straight(p, snap)
        p, verts = _split_at_crossings(p, curves.domain, snap, diag, exact=tol.touch_rel * diag)
        p = _dedupe(_demote_straight(p, snap), snap)
        p, verts = _split_shapes(p, verts, snap, min_size)
        p, verts, halved = _unshare_chords(p, verts, snap)
        if halved:  # the halves of two curves that shared a chord, straightened, can cross each other the same way
            p, verts = _split_at_crossings(p, curves.domain, snap, diag, exact=tol.touch_rel * diag)
            p, verts, _ = _unshare_chords(_dedupe(p, snap), verts, snap)
            p = p.take(~_on_border(p, verts, curves.domain))
        p = _pin(p.take(np.lexsort((p.trange[:, 0], p.curve))), verts)
    return replace(curves, control_points=p.cp, degree=p.deg, curve=p.curve, t_range=p.trange,
                   names=list(curves.names), sides=list(curves.sides))


# ----------------------------------------------------------------------------------------------- helpers


def _extent(cp: np.ndarray) -> np.ndarray:
    """Diagonal of each control polygon's bounding box: (P, 4, 2) -> (P,)."""
    span = cp.max(axis=1) - cp.min(axis=1)
    return np.hypot(span[:, 0], span[:, 1])


def _cut(p: _Pieces, piece: np.ndarray, t: np.ndarray, vid: np.ndarray | None = None,
         merge: float = 0.0) -> _Pieces:
    """Cut pieces at local parameters (all at once); ``vid`` gives the cut points' vertex ids.

    piece : (K,) int, t : (K,) float in (0, 1), vid : (K,) int or None (then ids are -1)
    Cuts at the same parameter of a piece count once, and so do consecutive cuts at the same vertex
    unless the piece goes further than ``merge`` from it in between (a loop).
    """
    if len(piece) == 0:
        return p
    vid = np.full(len(piece), -1, dtype=np.int64) if vid is None else np.asarray(vid, dtype=np.int64)
    order = np.lexsort((t, piece))
    piece, t, vid = piece[order], t[order], vid[order]
    keep = np.ones(len(piece), dtype=bool)
    keep[1:] = (piece[1:] != piece[:-1]) | (t[1:] != t[:-1])
    same = np.nonzero(~keep[1:] | ((piece[1:] == piece[:-1]) & (vid[1:] == vid[:-1]) & (vid[1:] >= 0)))[0]
    if len(same):
        cp = p.cp[piece[same]]
        away = bz.evaluate(cp, 0.5 * (t[same] + t[same + 1])) - bz.evaluate(cp, t[same])
        keep[same + 1] = np.hypot(*away.T) > merge
    piece, t, vid = piece[keep], t[keep], vid[keep]
    counts = np.bincount(piece, minlength=len(p))
    parent = np.repeat(np.arange(len(p)), counts + 1)
    first_cut = np.concatenate([[0], np.cumsum(counts)[:-1]])
    first_row = np.concatenate([[0], np.cumsum(counts + 1)[:-1]])
    k = np.arange(len(parent)) - first_row[parent]
    is_first, is_last = k == 0, k == counts[parent]
    lo = np.where(is_first, 0, first_cut[parent] + k - 1)
    hi = np.where(is_last, 0, first_cut[parent] + k)
    t0 = np.where(is_first, 0.0, t[lo])
    t1 = np.where(is_last, 1.0, t[hi])
    v0 = np.where(is_first, p.ev[parent, 0], vid[lo])
    v1 = np.where(is_last, p.ev[parent, 1], vid[hi])
    cp = bz.subsegment(p.cp[parent], t0, t1)
    s0, s1 = p.trange[parent, 0], p.trange[parent, 1]
    trange = np.stack([s0 + t0 * (s1 - s0), s0 + t1 * (s1 - s0)], axis=1)
    trange[is_first, 0], trange[is_last, 1] = s0[is_first], s1[is_last]
    return _Pieces(cp, p.deg[parent], p.curve[parent], trange, np.stack([v0, v1], axis=1))


def _pin(p: _Pieces, verts: np.ndarray) -> _Pieces:
    """Move end points exactly onto their vertices (interior control points follow); lines re-elevated."""
    cp = p.cp.copy()
    d0 = verts[p.ev[:, 0]] - cp[:, 0]
    d1 = verts[p.ev[:, 1]] - cp[:, 3]
    cp[:, 0] += d0
    cp[:, 1] += d0
    cp[:, 2] += d1
    cp[:, 3] += d1
    cp[:, 0], cp[:, 3] = verts[p.ev[:, 0]], verts[p.ev[:, 1]]
    line = p.deg == DEGREE_LINE
    cp[line] = elevate(cp[line][:, [0, 3]], 1)
    return replace(p, cp=cp)


def _new_vertices(p: _Pieces, verts: np.ndarray, piece: np.ndarray, t: np.ndarray):
    """Cut pieces at new vertices placed on them: returns the cut pieces and the extended vertex table."""
    pts = bz.evaluate(p.cp[piece], t)
    vid = len(verts) + np.arange(len(piece))
    return _cut(p, piece, t, vid), np.concatenate([verts, pts])


# ------------------------------------------------------------------------------------------- 1. clipping


def _clip(p: _Pieces, domain, snap: float) -> _Pieces:
    """Cut pieces where they cross the domain's border; drop the parts outside it or lying on it.

    Pieces are also cut at their cusps, so that a piece folding back along itself becomes two pieces
    whose overlap the crossing stage resolves, and a piece that runs along the border, closer than ``snap``
    inside it, is also cut where it enters and leaves that band, so that the part lying on the border goes."""
    x0, y0, x1, y1 = domain
    cusp = bz.cusps(p.cp, snap)
    i, j = np.nonzero(np.isfinite(cusp))
    pieces, ts = [i], [cusp[i, j]]
    # pieces with two consecutive polyline points within ``snap`` of the border run along it (a piece that only
    # crosses or ends on it has no such pair, and keeps its end where it crosses)
    in_band = np.abs(_depth(bz.flatten(p.cp, 16), domain)) <= snap
    every, along = np.arange(len(p)), np.flatnonzero((in_band[:, :-1] & in_band[:, 1:]).any(axis=1))
    for axis, side, band_edge in ((0, x0, x0 + snap), (0, x1, x1 - snap), (1, y0, y0 + snap), (1, y1, y1 - snap)):
        for line, which in ((side, every), (band_edge, along)):
            r = bz.bernstein_roots(p.cp[which, :, axis] - line)
            i, j = np.nonzero(np.isfinite(r))
            pieces.append(which[i])
            ts.append(r[i, j])
    p = _cut(p, np.concatenate(pieces), np.concatenate(ts))
    # a part cut at the band's edge reaches ``snap`` give or take a rounding: the margin keeps it from counting as
    # inside
    return p.take(_depth(bz.flatten(p.cp, 8), domain).max(axis=1) > 2.0 * snap)


def _on_border(p: _Pieces, verts: np.ndarray, domain) -> np.ndarray:
    """(P,) bool: line pieces with both end points on one side of the border (a crossing put onto it, see
    ``_onto_border``): they lie on the border, like the parts ``_clip`` drops."""
    a, b = verts[p.ev[:, 0]], verts[p.ev[:, 1]]
    x0, y0, x1, y1 = domain
    same = ((a[:, 0] == b[:, 0]) & np.isin(a[:, 0], [x0, x1])) | ((a[:, 1] == b[:, 1]) & np.isin(a[:, 1], [y0, y1]))
    return (p.deg == DEGREE_LINE) & same


def _depth(pts: np.ndarray, domain) -> np.ndarray:
    """Signed distance inside the domain's border (negative outside): (..., 2) -> (...)."""
    x0, y0, x1, y1 = domain
    return np.minimum.reduce([pts[..., 0] - x0, x1 - pts[..., 0], pts[..., 1] - y0, y1 - pts[..., 1]])


# -------------------------------------------------------------------------- 2-3. crossings, snapping, T


@dataclass(frozen=True)
class _Segments:
    a: np.ndarray  # (S, 2) start
    b: np.ndarray  # (S, 2) end
    piece: np.ndarray  # (S,) int64
    t0: np.ndarray  # (S,) parameter at a
    t1: np.ndarray  # (S,) parameter at b
    err: np.ndarray  # (S,) bound on the piece's distance from the segment


def _segments(cp: np.ndarray, deg: np.ndarray, diag: float) -> _Segments:
    """Polylines of all pieces, fine enough that each stays within ``_FLAT_REL × diag`` of its piece."""
    flat = _FLAT_REL * diag
    second = 6.0 * np.abs(np.diff(cp, n=2, axis=1)).max(axis=(1, 2)) * np.sqrt(2.0)  # bound on |B''|
    polylen = np.hypot(*np.diff(cp, axis=1).transpose(2, 0, 1)).sum(axis=1)
    n = np.maximum(np.ceil(np.sqrt(second / (8.0 * flat))), np.ceil(polylen / (_SEGMENT_REL * diag)))
    n = np.where(deg == DEGREE_LINE, np.ceil(polylen / (_SEGMENT_REL * diag)), n)
    n = np.clip(n, 1, 4096).astype(np.int64)
    piece = np.repeat(np.arange(len(cp)), n)
    k = np.arange(len(piece)) - np.repeat(np.cumsum(n) - n, n)
    t0, t1 = k / n[piece], (k + 1) / n[piece]
    t1[k + 1 == n[piece]] = 1.0
    a = bz.evaluate(cp[piece], t0)
    b = bz.evaluate(cp[piece], t1)
    err = np.where(deg[piece] == DEGREE_LINE, 0.0, second[piece] / (8.0 * n[piece] ** 2))
    return _Segments(a, b, piece, t0, t1, err)


def _cells(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, h: float):
    """Grid cells covered by boxes: returns (box index, cell key) for every (box, cell) pair."""
    i0 = np.floor((lo - origin) / h).astype(np.int64)
    i1 = np.floor((hi - origin) / h).astype(np.int64)
    nx, ny = i1[:, 0] - i0[:, 0] + 1, i1[:, 1] - i0[:, 1] + 1
    count = nx * ny
    box = np.repeat(np.arange(len(lo)), count)
    k = np.arange(len(box)) - np.repeat(np.cumsum(count) - count, count)
    cx = i0[box, 0] + k // ny[box]
    cy = i0[box, 1] + k % ny[box]
    return box, (cx + 1) * (1 << 31) + (cy + 1)


def _grid_size(seg: _Segments, diag: float) -> float:
    span = np.abs(seg.b - seg.a).max(axis=1) + 2.0 * seg.err
    return max(float(np.median(span)) if len(span) else 0.0, _SEGMENT_REL * diag / 8.0)


def _segment_pairs(seg: _Segments, pad: float, diag: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j), i < j, of segments of different pieces whose padded boxes share a grid cell."""
    r = (seg.err + pad)[:, None]
    lo, hi = np.minimum(seg.a, seg.b) - r, np.maximum(seg.a, seg.b) + r
    box, key = _cells(lo, hi, lo.min(axis=0), _grid_size(seg, diag))
    order = np.argsort(key, kind="stable")
    box, key = box[order], key[order]
    end = np.searchsorted(key, key, side="right")
    count = end - np.arange(len(key)) - 1
    i = np.repeat(np.arange(len(key)), count)
    j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(count) - count, count)
    a, b = box[i], box[j]
    a, b = np.minimum(a, b), np.maximum(a, b)
    keep = seg.piece[a] != seg.piece[b]
    pair = np.unique(a[keep] * len(seg.a) + b[keep])
    return pair // len(seg.a), pair % len(seg.a)


def _coincide(cp_a, s, cp_b, t, snap: float) -> np.ndarray:
    """Whether piece A runs along piece B on either side of the matching points A(s) ≈ B(t): (K,) bool."""
    da, db = bz.derivative(cp_a, s), bz.derivative(cp_b, t)
    na, nb = np.hypot(*da.T), np.hypot(*db.T)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.nan_to_num(na / nb) * np.sign((da * db).sum(1))
    out = np.zeros(len(s), dtype=bool)
    for step in (-_OVERLAP_STEP, _OVERLAP_STEP):
        sa = s + step
        inside = (sa >= 0.0) & (sa <= 1.0)
        tb = bz.closest_parameter(cp_b, bz.evaluate(cp_a, np.clip(sa, 0.0, 1.0)), np.clip(t + step * ratio, 0, 1))
        gap = bz.evaluate(cp_a, np.clip(sa, 0.0, 1.0)) - bz.evaluate(cp_b, tb)
        out |= inside & (np.hypot(*gap.T) <= snap)
    return out


def _crossings(p: _Pieces, seg: _Segments, snap: float, diag: float, exact: float | None = None):
    """Intersections of different pieces and self-intersections of cubics: (piece, t, point) arrays.

    ``exact``: only points where the pieces meet within this distance and cross at a sine above ``_EXACT_SIN`` (true
    crossings, near-parallel ones included; no overlap check), and no self-intersections."""
    i, j = _segment_pairs(seg, 0.5 * snap, diag)
    u, v, gap = closest_on_segments(seg.a[i], seg.b[i], seg.a[j], seg.b[j])
    near = gap <= seg.err[i] + seg.err[j] + snap
    i, j, u, v = i[near], j[near], u[near], v[near]
    # Newton from the closest points and from the corners of the two segments' parameter ranges, so that
    # two crossings near one segment pair (a shallow double crossing) are both found
    u = np.stack([u, np.zeros_like(u), np.zeros_like(u), np.ones_like(u), np.ones_like(u)], axis=1).ravel()
    v = np.stack([v, np.zeros_like(v), np.ones_like(v), np.zeros_like(v), np.ones_like(v)], axis=1).ravel()
    i, j = np.repeat(i, 5), np.repeat(j, 5)
    pa, pb = seg.piece[i], seg.piece[j]
    s0 = seg.t0[i] + u * (seg.t1[i] - seg.t0[i])
    t0 = seg.t0[j] + v * (seg.t1[j] - seg.t0[j])
    s, t, gap = bz.refine_intersections(p.cp[pa], p.cp[pb], s0, t0)
    ok = gap <= (snap if exact is None else exact)
    pa, pb, s, t = pa[ok], pb[ok], s[ok], t[ok]
    # one candidate per (pair, point): round the parameters to the snapping scale before the overlap check
    key = np.stack([pa, pb, np.round(s * diag / snap), np.round(t * diag / snap)], axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    pa, pb, s, t = pa[first], pb[first], s[first], t[first]
    ta, tb = bz.derivative(p.cp[pa], s), bz.derivative(p.cp[pb], t)
    with np.errstate(divide="ignore", invalid="ignore"):
        sine = np.abs(cross(ta, tb)) / (np.hypot(*ta.T) * np.hypot(*tb.T))
    check = ~(sine > _OVERLAP_SIN)
    drop = np.zeros(len(s), dtype=bool)
    if exact is None:
        drop[check] = _coincide(p.cp[pa[check]], s[check], p.cp[pb[check]], t[check], snap)
    else:
        drop = ~(sine > _EXACT_SIN)
    pa, pb, s, t = pa[~drop], pb[~drop], s[~drop], t[~drop]
    point = 0.5 * (bz.evaluate(p.cp[pa], s) + bz.evaluate(p.cp[pb], t))
    selfx = bz.self_intersections(p.cp)
    loop = np.nonzero(np.isfinite(selfx[:, 0]) & (p.deg == 3) & (exact is None))[0]
    loop_pt = bz.evaluate(p.cp[loop], selfx[loop, 0])
    piece = np.concatenate([pa, pb, loop, loop])
    param = np.concatenate([s, t, selfx[loop, 0], selfx[loop, 1]])
    points = np.concatenate([point, point, loop_pt, loop_pt])
    return piece, param, points


def _snap(points: np.ndarray, snap: float) -> tuple[np.ndarray, np.ndarray]:
    """Cluster points closer than ``snap`` (transitively): returns labels (M,) and one point per cluster,
    the first member in the given order."""
    pairs = cKDTree(points).query_pairs(snap, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    _, labels = connected_components(graph, directed=False)
    first = np.full(labels.max() + 1 if len(labels) else 0, len(points), dtype=np.int64)
    np.minimum.at(first, labels, np.arange(len(points)))
    rank = np.argsort(np.argsort(first))  # renumber clusters in order of their first member
    return rank[labels], points[np.sort(first)]


def _onto_border(verts: np.ndarray, domain, snap: float) -> np.ndarray:
    """Vertices within ``snap`` of the domain's border are put exactly on it."""
    x0, y0, x1, y1 = domain
    v = verts.copy()
    for axis, value in ((0, x0), (0, x1), (1, y0), (1, y1)):
        close = np.abs(v[:, axis] - value) <= snap
        v[close, axis] = value
    return v


def _t_junctions(p: _Pieces, seg: _Segments, verts: np.ndarray, snap: float, diag: float):
    """Vertices lying on another piece's interior (within ``snap``): (piece, t, vertex) arrays."""
    r = (seg.err + snap)[:, None]
    lo, hi = np.minimum(seg.a, seg.b) - r, np.maximum(seg.a, seg.b) + r
    h = _grid_size(seg, diag)
    origin = lo.min(axis=0)
    box, key = _cells(lo, hi, origin, h)
    order = np.argsort(key, kind="stable")
    box, key = box[order], key[order]
    c = np.floor((verts - origin) / h).astype(np.int64)
    vkey = (c[:, 0] + 1) * (1 << 31) + (c[:, 1] + 1)
    start, end = np.searchsorted(key, vkey, side="left"), np.searchsorted(key, vkey, side="right")
    count = end - start
    vid = np.repeat(np.arange(len(verts)), count)
    sid = box[np.repeat(start, count) + np.arange(len(vid)) - np.repeat(np.cumsum(count) - count, count)]
    piece = seg.piece[sid]
    keep = (p.ev[piece, 0] != vid) & (p.ev[piece, 1] != vid)
    vid, sid, piece = vid[keep], sid[keep], piece[keep]
    d = seg.b[sid] - seg.a[sid]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.clip(np.nan_to_num(((verts[vid] - seg.a[sid]) * d).sum(1) / (d * d).sum(1)), 0.0, 1.0)
    near = np.hypot(*(seg.a[sid] + u[:, None] * d - verts[vid]).T) <= seg.err[sid] + snap
    vid, sid, piece, u = vid[near], sid[near], piece[near], u[near]
    t = bz.closest_parameter(p.cp[piece], verts[vid], seg.t0[sid] + u * (seg.t1[sid] - seg.t0[sid]))
    gap = np.hypot(*(bz.evaluate(p.cp[piece], t) - verts[vid]).T)
    on = (gap <= snap) & (t > 0.0) & (t < 1.0)
    return piece[on], t[on], vid[on]


def _split_at_crossings(p: _Pieces, domain, snap: float, diag: float,
                        exact: float | None = None) -> tuple[_Pieces, np.ndarray]:
    """Split pieces at crossings and T-junctions and give every end point a vertex id (``exact``: exact crossings only,
    see ``_crossings``, and no T-junctions)."""
    seg = _segments(p.cp, p.deg, diag)
    piece, param, points = _crossings(p, seg, snap, diag, exact)
    ends = np.concatenate([p.cp[:, 0], p.cp[:, 3]])
    labels, verts = _snap(np.concatenate([ends, points]), snap)
    verts = _onto_border(verts, domain, snap)
    n = len(p)
    p = replace(p, ev=np.stack([labels[:n], labels[n:2 * n]], axis=1))
    vid = labels[2 * n:]
    own = (vid == p.ev[piece, 0]) | (vid == p.ev[piece, 1])
    tj_piece, tj_t, tj_vid = _t_junctions(p, seg, verts, snap, diag) if exact is None else (piece[:0], param[:0], vid[:0])
    piece = np.concatenate([piece[~own], tj_piece])
    param = np.concatenate([param[~own], tj_t])
    vid = np.concatenate([vid[~own], tj_vid])
    inner = (param > 0.0) & (param < 1.0)
    return _pin(_cut(p, piece[inner], param[inner], vid[inner], merge=2.0 * snap), verts), verts


# ----------------------------------------------------------------------------- 4. shape of curved pieces


def _split_shapes(p: _Pieces, verts: np.ndarray, snap: float, min_size: float):
    """Split cubics at inflections, then halve curved pieces until each is a graph over its chord turning
    by at most 90°; pieces below ``min_size`` that still fail become lines. Nearly straight pieces become lines."""
    infl = bz.inflections(p.cp)
    infl[p.deg != 3] = np.nan
    i, k = np.nonzero(np.isfinite(infl))
    t = infl[i, k]
    pts = bz.evaluate(p.cp[i], t)
    clear = (np.hypot(*(pts - p.cp[i, 0]).T) > snap) & (np.hypot(*(pts - p.cp[i, 3]).T) > snap)
    p, verts = _new_vertices(p, verts, i[clear], t[clear])
    p = _pin(p, verts)
    for _ in range(_MAX_ROUNDS):
        curved = p.deg != DEGREE_LINE
        with np.errstate(invalid="ignore"):
            good = bz.monotone_over_chord(p.cp) & (bz.total_turning(p.cp) <= np.pi / 2)
        bad = np.nonzero(curved & ~good)[0]
        small = _extent(p.cp[bad]) < min_size
        p = _demote(p, bad[small])
        if not (~small).any():
            break
        p, verts = _new_vertices(p, verts, bad[~small], np.full((~small).sum(), 0.5))
        p = _pin(p, verts)
    return _demote_straight(p, snap), verts


def _demote(p: _Pieces, idx: np.ndarray) -> _Pieces:
    """Turn pieces into lines between their end points."""
    if len(idx) == 0:
        return p
    cp, deg = p.cp.copy(), p.deg.copy()
    cp[idx] = elevate(cp[idx][:, [0, 3]], 1)
    deg[idx] = DEGREE_LINE
    return replace(p, cp=cp, deg=deg)


def _demote_straight(p: _Pieces, snap: float) -> _Pieces:
    """Curved pieces whose inner control points are within ``snap`` of the chord become lines."""
    a, d = p.cp[:, :1], (p.cp[:, 3] - p.cp[:, 0])[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.clip(np.nan_to_num(((p.cp[:, 1:3] - a) * d).sum(-1) / (d * d).sum(-1)), 0.0, 1.0)
    dist = np.hypot(*(a + u[..., None] * d - p.cp[:, 1:3]).transpose(2, 0, 1)).max(axis=1)
    return _demote(p, np.nonzero((p.deg != DEGREE_LINE) & (dist <= snap))[0])


# ------------------------------------------------------------------------- 5-6. duplicates, shared chords


def _oriented(p: _Pieces) -> tuple[np.ndarray, np.ndarray]:
    """Unordered end-point key (P,) and control points oriented from the smaller vertex id (P, 4, 2)."""
    flip = p.ev[:, 0] > p.ev[:, 1]
    cp = np.where(flip[:, None, None], p.cp[:, ::-1], p.cp)
    lo, hi = np.minimum(p.ev[:, 0], p.ev[:, 1]), np.maximum(p.ev[:, 0], p.ev[:, 1])
    return lo * (int(hi.max(initial=0)) + 1) + hi, cp


def _group_pairs(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs (i, j), i < j, with equal key."""
    order = np.argsort(key, kind="stable")
    k = key[order]
    end = np.searchsorted(k, k, side="right")
    count = end - np.arange(len(k)) - 1
    i = np.repeat(np.arange(len(k)), count)
    j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(count) - count, count)
    a, b = order[i], order[j]
    return np.minimum(a, b), np.maximum(a, b)


def _dedupe(p: _Pieces, snap: float) -> _Pieces:
    """Keep the first of pieces with the same end points whose control points agree within ``snap`` (either way)."""
    key, cp = _oriented(p)
    i, j = _group_pairs(key)
    gap = np.minimum(np.abs(cp[i] - cp[j]).max(axis=(1, 2)), np.abs(cp[i] - cp[j, ::-1]).max(axis=(1, 2)))
    same = gap <= snap
    dup = np.zeros(len(p), dtype=bool)
    dup[j[same]] = True
    return p.take(~dup)


def _unshare_chords(p: _Pieces, verts: np.ndarray, snap: float):
    """Drop closed lines and duplicates; halve curved pieces that share a chord or are closed. Returns the pieces, the
    vertices and the number of pieces halved."""
    halved = 0
    for _ in range(_MAX_ROUNDS):
        p = _dedupe(p.take(~((p.deg == DEGREE_LINE) & (p.ev[:, 0] == p.ev[:, 1]))), snap)
        key, _ = _oriented(p)
        i, j = _group_pairs(key)
        shared = np.zeros(len(p), dtype=bool)
        shared[i] = shared[j] = True
        split = np.nonzero((p.deg != DEGREE_LINE) & (shared | (p.ev[:, 0] == p.ev[:, 1])))[0]
        if len(split) == 0:
            break
        halved += len(split)
        p, verts = _new_vertices(p, verts, split, np.full(len(split), 0.5))
        p = _demote_straight(_pin(p, verts), snap)
    return p, verts, halved
