"""Which side of a curved piece a point lies on, exactly and without implicitisation (docs/design.md §5.4).

Every curved piece is pre-split (docs/design.md §3) so that it is a graph over its chord. In the piece's
*chord frame* the chord is ``[0, 1] × {0}`` and the apex of its triangle has ``v > 0``; the piece
is then ``(x(t), y(t))`` with ``x`` increasing from 0 to 1. A query ``(u, v)`` with ``u`` clamped
into ``[0, 1]`` is in the *sliver* (between the chord and the piece) iff ``v < y(t*)`` where
``x(t*) = u``; ``t*`` is found by safeguarded Newton iteration in float64. This is exact for lines,
quadratics (degree-elevated) and cubics, stable for nearly straight pieces (``y`` just becomes
small) and blind to the algebraic curve's branches outside ``t ∈ [0, 1]``.
"""

from __future__ import annotations

import torch

__all__ = ["chord_frames", "solve_graph", "in_sliver"]

_MAX_ITER = 64
"""Newton steps at most; each step also halves the bracket when Newton leaves it, so 64 reach float64."""


_BOUND_SLACK = 1e-12
"""Relative slack on the sliver's height bound, so rounding of the bound never decides a point."""


def chord_frames(control_points: torch.Tensor, apex: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Chord frames of pieces.

    control_points : (C, 4, 2) float64 cubic Bézier control points (domain units)
    apex : (C, 2) float64, a point on the side the piece bulges to (its triangle's apex)

    Returns origin (C, 2), u_axis (C, 2), v_axis (C, 2) — so that ``u = (x − origin)·u_axis`` and
    ``v = (x − origin)·v_axis`` — and local (C, 4, 2), the control points in the frame, all float64.
    """
    origin = control_points[:, 0]
    chord = control_points[:, 3] - origin
    u_axis = chord / (chord * chord).sum(-1, keepdim=True)
    v_axis = torch.stack([-u_axis[:, 1], u_axis[:, 0]], dim=-1)
    flip = ((apex - origin) * v_axis).sum(-1, keepdim=True) < 0
    v_axis = torch.where(flip, -v_axis, v_axis)
    rel = control_points - origin[:, None]
    local = torch.stack([(rel * u_axis[:, None]).sum(-1), (rel * v_axis[:, None]).sum(-1)], dim=-1)
    return origin, u_axis, v_axis, local


def _bernstein(c: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Cubic with coefficients c (N, 4) at t (N,) -> (N,)."""
    s = 1.0 - t
    return s * s * s * c[:, 0] + 3.0 * s * s * t * c[:, 1] + 3.0 * s * t * t * c[:, 2] + t * t * t * c[:, 3]


def _bernstein_dt(c: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    s = 1.0 - t
    return 3.0 * (s * s * (c[:, 1] - c[:, 0]) + 2.0 * s * t * (c[:, 2] - c[:, 1]) + t * t * (c[:, 3] - c[:, 2]))


def solve_graph(x_coeffs: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Solve ``x(t) = u`` for increasing cubics.

    x_coeffs : (N, 4) float64 Bernstein coefficients with x(0) <= u <= x(1) (u clamped otherwise)
    u : (N,) float64; returns t (N,) float64 in [0, 1]
    """
    u = torch.minimum(torch.maximum(u, x_coeffs[:, 0]), x_coeffs[:, 3])
    lo = torch.zeros_like(u)
    hi = torch.ones_like(u)
    span = x_coeffs[:, 3] - x_coeffs[:, 0]
    t = torch.where(span > 0, (u - x_coeffs[:, 0]) / torch.where(span > 0, span, 1.0), 0.5)
    eps = torch.finfo(u.dtype).eps
    for it in range(_MAX_ITER):
        f = _bernstein(x_coeffs, t) - u
        lo = torch.where(f <= 0, t, lo)
        hi = torch.where(f >= 0, t, hi)
        step = t - f / _bernstein_dt(x_coeffs, t)
        ok = (step >= lo) & (step <= hi)
        new = torch.where(ok, step, 0.5 * (lo + hi))
        moved = (new - t).abs()
        t = new
        if it % 4 == 3 and bool((moved <= 4 * eps).all()):
            break
    return t


def in_sliver(xy: torch.Tensor, origin: torch.Tensor, u_axis: torch.Tensor, v_axis: torch.Tensor,
              local: torch.Tensor) -> torch.Tensor:
    """Whether points lie between their piece's chord and the piece (boundary: the chord counts in).

    xy : (N, 2) float64 queries; origin, u_axis, v_axis : (N, 2) and local : (N, 4, 2) float64, the
    chord frame of each query's piece (see ``chord_frames``, gathered per query). Returns (N,) bool.
    Only queries in the band between the chord and the piece's height bound run the Newton solve.
    """
    rel = xy - origin
    u = (rel * u_axis).sum(-1)
    v = (rel * v_axis).sum(-1)
    # In the chord frame y0 = y3 = 0 up to rounding, so y(t) <= 0.75 max(y1, y2) + |y0| + |y3|: points
    # below the chord are in, points above that bound are out; only the band between needs the Newton solve.
    y = local[..., 1]
    bound = (0.75 * torch.maximum(y[:, 1], y[:, 2]).clamp_min(0) * (1.0 + _BOUND_SLACK)
             + y[:, 0].abs() + y[:, 3].abs())
    out = v < 0
    band = torch.nonzero((v >= 0) & (v < bound)).squeeze(1)
    if band.numel():
        c = local.index_select(0, band)
        t = solve_graph(c[..., 0], u.index_select(0, band))
        out[band] = v.index_select(0, band) < _bernstein(c[..., 1], t)
    return out
