"""Zoom centres of a comparison, one list per kind of place (``PROBE_KINDS``), found from the curves alone.

- ``edge``: the middle of an input curve (``dfc.bench.scenes.curve_probes``);
- ``junction``: where three or more piece ends meet, or two meet at a corner (their directions turn by more than
  ``CORNER_DEGREES``): the star's points, the triangle's corners, a T-junction;
- ``tip``: the free end of an open curve inside the domain, where a jump fades out;
- ``smooth``: the points farthest from every curve and from the domain's border (farthest-point sampling on a
  ``SMOOTH_GRID`` × ``SMOOTH_GRID`` grid of candidates), where a field has no jump to resolve.

A kind with no such place (no open curve: no tip) simply has no probe.
"""

from __future__ import annotations

import numpy as np

from ..geometry import bezier
from ..geometry.curves import Curves

__all__ = ["CORNER_DEGREES", "DEFAULT_COUNTS", "PROBE_KINDS", "SMOOTH_GRID", "junctions", "labelled_probes",
           "smooth_points", "tips"]

PROBE_KINDS = ("edge", "junction", "tip", "smooth")
DEFAULT_COUNTS = {"edge": 2, "junction": 1, "tip": 1, "smooth": 1}
"""Probes per kind by default."""
CORNER_DEGREES = 20.0
"""Two piece ends meeting at a point form a junction (a corner) when their directions turn by more than this."""
SMOOTH_GRID = 64
"""Candidates per axis for the smooth probes."""
FLATTEN = 32
"""Segments per piece when measuring distances to the curves."""
MERGE_REL = 1e-9
"""Piece ends closer than this fraction of the domain's diagonal are one point."""


def _ends(curves: Curves) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every piece end: points (2P, 2), directions pointing away from the end along the piece (2P, 2) and a group
    id (2P,) shared by coincident ends."""
    cp = curves.control_points
    t0, t1 = bezier.end_tangents(cp)
    points = np.concatenate([cp[:, 0], cp[:, 3]])
    away = np.concatenate([t0, -t1])
    key = np.round(points / (MERGE_REL * curves.diagonal)).astype(np.int64)
    _, group = np.unique(key, axis=0, return_inverse=True)
    return points, away, group.reshape(-1)


def _inside(points: np.ndarray, curves: Curves) -> np.ndarray:
    x0, y0, x1, y1 = curves.domain
    eps = MERGE_REL * curves.diagonal
    return ((points[:, 0] > x0 + eps) & (points[:, 0] < x1 - eps) & (points[:, 1] > y0 + eps)
            & (points[:, 1] < y1 - eps))


def junctions(curves: Curves) -> np.ndarray:
    """(J, 2) float64 junction points (module docstring) inside the domain: meetings of three or more ends first,
    then corners, each in the order the pieces come."""
    if len(curves) == 0:
        return np.zeros((0, 2))
    points, away, group = _ends(curves)
    found = []
    for g in dict.fromkeys(group.tolist()):  # groups in order of first appearance
        members = np.flatnonzero(group == g)
        if len(members) >= 3:
            found.append((0, members[0]))
        elif len(members) == 2:
            a, b = away[members]
            if np.all(np.isfinite([a, b])) and float(np.dot(a, b)) > -np.cos(np.radians(CORNER_DEGREES)):
                found.append((1, members[0]))
    idx = [m for _, m in sorted(found, key=lambda f: f[0])]
    out = points[idx].reshape(-1, 2)
    return out[_inside(out, curves)]


def tips(curves: Curves) -> np.ndarray:
    """(T, 2) float64 free ends of open curves inside the domain, in the order the pieces come."""
    if len(curves) == 0:
        return np.zeros((0, 2))
    points, _, group = _ends(curves)
    counts = np.bincount(group)
    single = np.flatnonzero(counts[group] == 1)
    out = points[np.sort(single)]
    return out[_inside(out, curves)]


def _distance_to_curves(xy: np.ndarray, curves: Curves, chunk: int = 1 << 20) -> np.ndarray:
    """(N,) float64 distance from points xy (N, 2) to the flattened curves."""
    if len(curves) == 0:
        return np.full(len(xy), np.inf)
    poly = bezier.flatten(curves.control_points, FLATTEN)  # (P, F + 1, 2)
    a, b = poly[:, :-1].reshape(-1, 2), poly[:, 1:].reshape(-1, 2)
    d = b - a
    length2 = np.maximum((d * d).sum(1), 1e-300)
    out = np.empty(len(xy))
    rows = max(1, chunk // len(a))
    for s in range(0, len(xy), rows):
        p = xy[s : s + rows, None, :] - a[None]  # (n, S, 2)
        t = np.clip((p * d[None]).sum(-1) / length2[None], 0.0, 1.0)
        out[s : s + rows] = np.sqrt(((p - t[..., None] * d[None]) ** 2).sum(-1).min(axis=1))
    return out


def smooth_points(curves: Curves, count: int) -> np.ndarray:
    """(count, 2) float64 points far from every curve and the border (module docstring), farthest first."""
    x0, y0, x1, y1 = curves.domain
    u = (np.arange(SMOOTH_GRID) + 0.5) / SMOOTH_GRID
    X, Y = np.meshgrid(x0 + u * (x1 - x0), y0 + u * (y1 - y0))
    cand = np.stack([X.ravel(), Y.ravel()], axis=1)
    border = np.minimum.reduce([cand[:, 0] - x0, x1 - cand[:, 0], cand[:, 1] - y0, y1 - cand[:, 1]])
    score = np.minimum(_distance_to_curves(cand, curves), border)
    out = []
    for _ in range(min(count, len(cand))):
        k = int(np.argmax(score))
        out.append(cand[k])
        score = np.minimum(score, np.hypot(*(cand - cand[k]).T))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def labelled_probes(curves: Curves, counts: dict[str, int] | None = None) -> tuple[np.ndarray, list[str]]:
    """Probe points (P, 2) float64 and their kinds (P,): up to ``counts[kind]`` of each of ``PROBE_KINDS``
    (default ``DEFAULT_COUNTS``), edges first."""
    from .scenes import curve_probes

    counts = DEFAULT_COUNTS if counts is None else counts
    found = {"edge": curve_probes(curves, counts.get("edge", 0)) if counts.get("edge", 0) else np.zeros((0, 2)),
             "junction": junctions(curves)[: counts.get("junction", 0)],
             "tip": tips(curves)[: counts.get("tip", 0)],
             "smooth": smooth_points(curves, counts.get("smooth", 0))}
    points = np.concatenate([found[k] for k in PROBE_KINDS])
    kinds = [k for k in PROBE_KINDS for _ in range(len(found[k]))]
    return points, kinds
