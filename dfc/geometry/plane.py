"""Plane vector primitives shared by the geometry, the field and the applications."""

from __future__ import annotations

import numpy as np

__all__ = ["closest_on_segments", "cross", "triangle_areas"]


def cross(u, v):
    """2D cross product ``u_x v_y − u_y v_x`` of (..., 2) arrays (numpy or torch), broadcast over leading axes.

    For a triangle (a, b, c), ``cross(b − a, c − a)`` is twice its signed area; dfc's triangles have it > 0
    (``spec/conventions.md``).
    """
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def triangle_areas(corners):
    """(T,) unsigned areas of triangles given as corners (T, 3, 2) (numpy or torch)."""
    return 0.5 * abs(cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))


def closest_on_segments(p1, q1, p2, q2):
    """Closest points of segment pairs p1 -> q1 and p2 -> q2 ((K, 2) numpy arrays each; Ericson): parameters u, v in
    [0, 1] along each and their distance, all (K,). A point is a segment with p1 = q1."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = (d1 * d1).sum(1), (d2 * d2).sum(1)
    b, c, f = (d1 * d2).sum(1), (d1 * r).sum(1), (d2 * r).sum(1)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(denom > 0.0, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        v = np.where(e > 0.0, (b * u + f) / e, 0.0)
        u = np.where(v < 0.0, np.where(a > 0.0, np.clip(-c / a, 0.0, 1.0), 0.0), u)
        u = np.where(v > 1.0, np.where(a > 0.0, np.clip((b - c) / a, 0.0, 1.0), 0.0), u)
    v = np.clip(v, 0.0, 1.0)
    gap = (p1 + u[:, None] * d1) - (p2 + v[:, None] * d2)
    return u, v, np.hypot(gap[:, 0], gap[:, 1])
