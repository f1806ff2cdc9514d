"""The in-memory form of discontinuity curves, shared by every reader, the clean-up and the mesher.

Every piece is stored as a cubic Bézier: lines and quadratics are degree-elevated exactly, and
``degree`` remembers what the piece really is (1 line, 2 quadratic, 3 cubic), so that a line can
become one straight mesh edge and a quadratic keeps its exact side test.

An *input curve* is what the user drew as one thing (an SVG element, a JSON curve, an XML
``<curve>``); it is a chain of pieces. Its parameter ``s`` runs over ``[0, n]`` for a chain of ``n``
pieces: piece ``k`` covers ``[k, k + 1]``. ``Curves.t_range`` maps every (possibly split) piece back
to the stretch of ``s`` it came from, which is how per-side values along a curve survive clean-up.
Conventions (y down, which side is "left") are in ``spec/conventions.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import CurveError

DEGREE_LINE, DEGREE_QUADRATIC, DEGREE_CUBIC = 1, 2, 3


@dataclass(frozen=True)
class SideValues:
    """Values prescribed on the two sides of one input curve (diffusion curves), piecewise linear in ``s``.

    left_s : (n,) float64, non-decreasing positions along the curve, in the curve's parameter ``s``
    left : (n, C) float64 values on the left side at those positions
    right_s, right : the same for the right side ((m,), (m, C))
    """

    left_s: np.ndarray
    left: np.ndarray
    right_s: np.ndarray
    right: np.ndarray

    def at(self, s: np.ndarray, side: str) -> np.ndarray:
        """Values at curve parameters ``s`` ((N,) float) on ``side`` ('left' or 'right') -> (N, C) float64."""
        xs, vs = (self.left_s, self.left) if side == "left" else (self.right_s, self.right)
        s = np.asarray(s, dtype=np.float64)
        return np.stack([np.interp(s, xs, vs[:, c]) for c in range(vs.shape[1])], axis=-1)


@dataclass(frozen=True)
class Curves:
    """A set of Bézier pieces over a rectangular domain.

    domain : (x0, y0, x1, y1) float, the rectangle the field lives on, in the file's own units
    control_points : (P, 4, 2) float64, every piece as a cubic Bézier
    degree : (P,) int8, 1 line, 2 quadratic, 3 cubic
    curve : (P,) int64, index of the input curve each piece belongs to
    t_range : (P, 2) float64, the stretch ``[s0, s1]`` of that input curve's parameter the piece covers
    names : one label per input curve, used in messages ("path#outline", "curve 3", ...)
    sides : one ``SideValues`` or None per input curve
    source : the file the curves were read from ('' when built in memory)
    """

    domain: tuple[float, float, float, float]
    control_points: np.ndarray
    degree: np.ndarray
    curve: np.ndarray
    t_range: np.ndarray
    names: list[str] = field(default_factory=list)
    sides: list[SideValues | None] = field(default_factory=list)
    source: str = ""

    def __post_init__(self):
        cp = np.asarray(self.control_points, dtype=np.float64).reshape(-1, 4, 2)
        object.__setattr__(self, "control_points", cp)
        object.__setattr__(self, "degree", np.asarray(self.degree, dtype=np.int8).reshape(-1))
        object.__setattr__(self, "curve", np.asarray(self.curve, dtype=np.int64).reshape(-1))
        object.__setattr__(self, "t_range", np.asarray(self.t_range, dtype=np.float64).reshape(-1, 2))
        object.__setattr__(self, "domain", tuple(float(v) for v in self.domain))
        n = len(cp)
        if not (len(self.degree) == len(self.curve) == len(self.t_range) == n):
            raise CurveError("curves: control_points, degree, curve and t_range must have one row per piece")
        x0, y0, x1, y1 = self.domain
        if not (np.isfinite(self.domain).all() and x1 > x0 and y1 > y0):
            raise CurveError(f"curves: domain {self.domain} is not a non-empty finite rectangle")
        if not np.isfinite(cp).all():
            raise CurveError("curves: a control point is NaN or infinite")

    def __len__(self) -> int:
        return len(self.control_points)

    @property
    def diagonal(self) -> float:
        """Length of the domain's diagonal, the unit of the relative tolerances."""
        x0, y0, x1, y1 = self.domain
        return float(np.hypot(x1 - x0, y1 - y0))

    @property
    def n_curves(self) -> int:
        return len(self.names)


def elevate(points: np.ndarray, degree: int) -> np.ndarray:
    """Exact degree elevation to a cubic.

    points : (N, degree + 1, 2) float control points of lines (degree 1) or quadratics (degree 2)
    returns (N, 4, 2) float64 cubic control points of the same curves
    """
    p = np.asarray(points, dtype=np.float64)
    if degree == 3:
        return p.copy()
    if degree == 1:
        a, b = p[:, 0], p[:, 1]
        return np.stack([a, a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0, b], axis=1)
    if degree == 2:
        q0, q1, q2 = p[:, 0], p[:, 1], p[:, 2]
        return np.stack([q0, q0 + 2.0 / 3.0 * (q1 - q0), q2 + 2.0 / 3.0 * (q1 - q2), q2], axis=1)
    raise ValueError(f"degree must be 1, 2 or 3, got {degree}")


def split_pieces(curves: Curves, max_length: float, *, lines: bool = False, curved: bool = True) -> Curves:
    """``curves`` with its pieces cut into equal parameter parts at most ``max_length`` long.

    Lengths are of the control polygon (≥ the arc length), in domain units; ``curved`` and ``lines`` choose
    which pieces are cut (by default only curved ones). ``t_range`` follows the cut, so names, side values and
    the input curves' parameter ``s`` are unchanged.
    """
    from . import bezier

    if not max_length > 0:
        raise ValueError(f"max_length must be positive, got {max_length!r}")
    cp = curves.control_points
    length = np.linalg.norm(np.diff(cp, axis=1), axis=2).sum(axis=1)
    chosen = np.where(curves.degree == DEGREE_LINE, lines, curved)
    parts = np.where(chosen, np.maximum(1, np.ceil(length / max_length)), 1).astype(np.int64)
    piece = np.repeat(np.arange(len(cp)), parts)
    k = np.arange(len(piece)) - np.repeat(np.cumsum(parts) - parts, parts)
    t0, t1 = k / parts[piece], (k + 1) / parts[piece]
    s0, s1 = curves.t_range[piece, 0], curves.t_range[piece, 1]
    return Curves(curves.domain, bezier.subsegment(cp[piece], t0, t1), curves.degree[piece], curves.curve[piece],
                  np.stack([s0 + t0 * (s1 - s0), s0 + t1 * (s1 - s0)], axis=1), curves.names, curves.sides,
                  curves.source)


def curves_outside(curves: Curves) -> list[int]:
    """Indices of the input curves with every piece entirely outside the domain (nothing of them reaches the mesh;
    clean-up clips pieces to the domain). A piece lies inside the bounding box of its control points, so one whose
    box does not meet the closed domain rectangle is outside."""
    x0, y0, x1, y1 = curves.domain
    lo, hi = curves.control_points.min(axis=1), curves.control_points.max(axis=1)  # (P, 2) each
    out = (hi[:, 0] < x0) | (lo[:, 0] > x1) | (hi[:, 1] < y0) | (lo[:, 1] > y1)
    n = max(curves.n_curves, int(curves.curve.max()) + 1 if len(curves) else 0)
    inside = np.bincount(curves.curve[~out], minlength=n)
    present = np.bincount(curves.curve, minlength=n)
    return [int(c) for c in np.flatnonzero((present > 0) & (inside == 0))]


def fit_curves_to_domain(curves: Curves, domain: tuple[float, float, float, float]) -> Curves:
    """``curves`` scaled and translated so that their domain maps onto ``domain`` (independently in x and y)."""
    sx0, sy0, sx1, sy1 = curves.domain
    dx0, dy0, dx1, dy1 = domain
    scale = np.array([(dx1 - dx0) / (sx1 - sx0), (dy1 - dy0) / (sy1 - sy0)])
    cp = (curves.control_points - [sx0, sy0]) * scale + [dx0, dy0]
    return Curves(domain, cp, curves.degree, curves.curve, curves.t_range, curves.names, curves.sides, curves.source)
