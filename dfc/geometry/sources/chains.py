"""Linking edge pixels into ordered chains of sub-pixel points.

A thinned edge map is a graph of 8-connected pixels. Pixels with three or more neighbours are junction
pixels (touching ones form one junction); removing them leaves simple paths and loops, the *branches*,
ordered by walking them. Each branch pixel carries at most one sub-pixel edge point; a branch is cut
where more than ``max_gap`` pixels in a row carry none (the profile there is not a step), and bridged
over shorter gaps (corners and junctions spoil the step model for a few pixels). At a junction the two
branch ends that continue each other best are joined into one chain (a corner when only two branches
meet); the others stay free, to be welded onto it later (a T). Where three or more branches meet and
none continue each other (a Y), they all end at the point nearest their tangent lines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

__all__ = ["Chain", "trace_skeleton", "link"]

_OFFSETS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
_STRAIGHT = np.cos(np.radians(45.0))
"""Two branch ends at a junction continue each other when their outward directions are within 45° of opposite."""


@dataclass
class Chain:
    """Ordered sub-pixel points along one edge.

    points : (n, 2) float64, image coordinates
    closed : the last point is followed by the first
    free : (start, end) — True where the end stops without meeting anything (a tip, a T stem, the border)
    rough : its points were smoothed (point-sampled or noisy: ``dfc.geometry.sources.raster``) and are fitted loosely
    """

    points: np.ndarray
    closed: bool
    free: tuple[bool, bool]
    rough: bool = False

    @property
    def length(self) -> float:
        p = np.concatenate([self.points, self.points[:1]]) if self.closed else self.points
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def trace_skeleton(skeleton: np.ndarray) -> tuple[list[np.ndarray], list[bool], np.ndarray, np.ndarray]:
    """Branches of a thinned edge map.

    skeleton : (H, W) bool, one pixel wide
    returns paths — one (m,) int64 array of flat pixel indices (row W + col) per branch, in walking order;
    closed — per branch, a loop; ends — (B, 2) int64 junction at each end of each branch (-1 none);
    junction_xy — (J, 2) float64 centres of the junctions in image coordinates
    """
    sk = np.pad(np.asarray(skeleton, dtype=bool), 1)
    Hp, Wp = sk.shape
    W = Wp - 2
    count = sum(np.roll(np.roll(sk, -dy, 0), -dx, 1).astype(np.int8) for dy, dx in _OFFSETS)
    junction = sk & (count >= 3)
    jlabel, n_junctions = ndi.label(junction, structure=np.ones((3, 3), bool))
    branch = sk & ~junction
    ys, xs = np.nonzero(branch)
    ids = np.full(sk.shape, -1, dtype=np.int64)
    ids[ys, xs] = np.arange(len(ys))
    neighbours = np.stack([ids[ys + dy, xs + dx] for dy, dx in _OFFSETS], axis=1)  # (N, 8)
    near_junction = np.stack([jlabel[ys + dy, xs + dx] for dy, dx in _OFFSETS], axis=1) - 1  # (N, 8)
    neighbours = -np.sort(-neighbours, axis=1)[:, :2]  # at most two, -1 padded
    degree = (neighbours >= 0).sum(axis=1)
    flat = (ys - 1) * W + (xs - 1)
    visited = np.zeros(len(ys), dtype=bool)
    paths, closed, ends = [], [], []

    def walk(start: int) -> list[int]:
        order, prev, cur = [start], -1, start
        visited[start] = True
        while True:
            nxt = [v for v in neighbours[cur] if v >= 0 and v != prev and not visited[v]]
            if not nxt:
                return order
            prev, cur = cur, nxt[0]
            visited[cur] = True
            order.append(cur)

    def touching(pixel: int, other: int = -1) -> int:
        found = [int(j) for j in near_junction[pixel] if j >= 0]
        distinct = [j for j in found if j != other]
        return (distinct or found or [-1])[0]

    for start in np.nonzero(degree <= 1)[0]:
        if not visited[start]:
            order = walk(int(start))
            paths.append(flat[order])
            closed.append(False)
            head = touching(order[0])
            ends.append((head, touching(order[-1], head if len(order) == 1 else -1)))
    for start in range(len(ys)):
        if not visited[start]:
            order = walk(start)
            loop = len(order) > 2 and order[0] in neighbours[order[-1]]
            paths.append(flat[order])
            closed.append(bool(loop))
            ends.append((-1, -1) if loop else (touching(order[0]), touching(order[-1])))
    centres = ndi.center_of_mass(junction, jlabel, np.arange(1, n_junctions + 1)) if n_junctions else []
    junction_xy = np.array([(c - 1 + 0.5, r - 1 + 0.5) for r, c in centres], dtype=np.float64).reshape(-1, 2)
    return paths, closed, np.array(ends, dtype=np.int64).reshape(-1, 2), junction_xy


def link(paths: list[np.ndarray], closed: list[bool], ends: np.ndarray, junction_xy: np.ndarray,
         point_of_pixel: np.ndarray, xy: np.ndarray, key: np.ndarray, *, max_gap: int, span: float,
         reach: float) -> list[Chain]:
    """Chains of sub-pixel points along the branches, joined at junctions.

    paths, closed, ends, junction_xy : as returned by ``trace_skeleton``
    point_of_pixel : (H W,) int64 index of each pixel's accepted edge point, -1 for none
    xy : (N, 2) float64 edge points; key : (N,) int64 equal for the same point fitted from two pixels
    max_gap : longest run of pixels without a point that is bridged
    span : arc length (px) over which a chain end's direction is measured
    reach : a Y junction's common point must lie within this distance (px) of every end it joins; branches
        shorter than this do not count at a junction where two or more longer ones meet
    """
    claimed = np.zeros(0, dtype=np.int64)
    pieces: list[np.ndarray] = []  # index arrays into xy
    piece_ends: list[list[int]] = []  # junction at each end
    loops: list[bool] = []
    for path, loop, (head, tail) in zip(paths, closed, ends):
        pts = point_of_pixel[path]
        pos = np.nonzero(pts >= 0)[0]
        pts = pts[pos]
        fresh = np.r_[True, key[pts[1:]] != key[pts[:-1]]] & ~np.isin(key[pts], claimed)
        pos, pts = pos[fresh], pts[fresh]
        if not len(pts):
            continue
        claimed = np.union1d(claimed, key[pts])
        cut = np.nonzero(np.diff(pos) > max_gap + 1)[0] + 1
        runs = np.split(np.arange(len(pts)), cut)
        joins_round = loop and len(path) - pos[-1] + pos[0] <= max_gap + 1
        if loop and joins_round and len(runs) == 1:
            pieces.append(pts)
            piece_ends.append([-1, -1])
            loops.append(True)
            continue
        if loop and joins_round:  # the seam lies inside a run: start after a real gap instead
            runs = runs[1:-1] + [np.r_[runs[-1], runs[0]]]
        for k, run in enumerate(runs):
            first = head if k == 0 and not loop and pos[run[0]] <= max_gap else -1
            last = tail if k == len(runs) - 1 and not loop and len(path) - 1 - pos[run[-1]] <= max_gap else -1
            pieces.append(pts[run])
            piece_ends.append([first, last])
            loops.append(False)
    return _join(pieces, piece_ends, loops, junction_xy, xy, span=span, reach=reach)


def _join(pieces, piece_ends, loops, junction_xy, xy, *, span: float, reach: float) -> list[Chain]:
    """Pair branch ends at each junction, then walk the pairs into chains."""
    at: dict[int, list[tuple[int, int]]] = {}
    for c, (a, b) in enumerate(piece_ends):
        for side, j in ((0, a), (1, b)):
            if j >= 0:
                at.setdefault(j, []).append((c, side))
    partner: dict[tuple[int, int], tuple[int, int]] = {}
    extra: dict[tuple[int, int], np.ndarray] = {}
    for j, members in at.items():
        long = [m for m in members if _arc(xy[pieces[m[0]]]) >= reach]
        if len(long) >= 2:  # spurs (a thinned tip, a speck) do not make a junction
            members = long
        outward = {m: _end_direction(xy[pieces[m[0]]], m[1], span) for m in members}
        left = list(members)
        joined = False
        while len(left) >= 2:
            best = min(((outward[a] @ outward[b], a, b) for i, a in enumerate(left) for b in left[i + 1:]),
                       key=lambda t: t[0])
            if len(members) > 2 and best[0] > -_STRAIGHT:
                break
            _, a, b = best
            partner[a], partner[b] = b, a
            left = [m for m in left if m not in (a, b)]
            joined = True
        if len(left) >= 2 and not joined:  # a Y: all meet at one point
            ends = np.array([xy[pieces[c][-1 if s else 0]] for c, s in left])
            point = _nearest_to_lines(ends, np.array([outward[m] for m in left]))
            if point is None or np.linalg.norm(ends - point, axis=1).max() > reach:
                point = junction_xy[j]
            for m in left:
                extra[m] = point
    chains, done = [], np.zeros(len(pieces), dtype=bool)

    def walk(c: int, side: int) -> tuple[list[np.ndarray], tuple[int, int]]:
        parts = []
        while True:
            done[c] = True
            p = xy[pieces[c]]
            parts.append(p if side == 0 else p[::-1])
            end = (c, 1 - side)
            nxt = partner.get(end)
            if nxt is None or done[nxt[0]]:
                return parts, end
            c, side = nxt

    for c in range(len(pieces)):
        if done[c] or loops[c]:
            continue
        for side in (0, 1):
            if (c, side) not in partner:
                parts, last = walk(c, side)
                first = (c, side)
                head = [extra[first][None]] if first in extra else []
                tail = [extra[last][None]] if last in extra else []
                chains.append(Chain(np.concatenate(head + parts + tail), False, (first not in extra, last not in extra)))
                break
    for c in range(len(pieces)):
        if not done[c]:
            parts, _ = walk(c, 0)
            chains.append(Chain(np.concatenate(parts), True, (False, False)))
    return chains


def _arc(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _end_direction(points: np.ndarray, side: int, span: float) -> np.ndarray:
    """Unit direction leaving a chain (n, 2) at its start (side 0) or end (side 1), from the points within span."""
    p = points if side == 1 else points[::-1]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p[::-1], axis=0), axis=1))]
    tail = p[len(p) - max(2, int(np.searchsorted(arc, span, side="right"))):]
    if len(tail) < 2:
        return np.zeros(2)
    centred = tail - tail.mean(axis=0)
    d = np.linalg.svd(centred, full_matrices=False)[2][0]
    return -d if d @ (tail[-1] - tail[0]) < 0 else d


def _nearest_to_lines(points: np.ndarray, directions: np.ndarray) -> np.ndarray | None:
    """The point nearest (least squares) to the lines through ``points`` (k, 2) along ``directions`` (k, 2)."""
    normals = np.stack([-directions[:, 1], directions[:, 0]], axis=1)
    m = normals.T @ normals
    if np.linalg.cond(m) > 1e6:
        return None
    return np.linalg.solve(m, normals.T @ (normals * points).sum(axis=1))
