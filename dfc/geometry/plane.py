"""Plane vector primitives shared by the geometry, the field and the applications."""

from __future__ import annotations

__all__ = ["cross", "triangle_areas"]


def cross(u, v):
    """2D cross product ``u_x v_y − u_y v_x`` of (..., 2) arrays (numpy or torch), broadcast over leading axes.

    For a triangle (a, b, c), ``cross(b − a, c − a)`` is twice its signed area; dfc's triangles have it > 0
    (``spec/conventions.md``).
    """
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def triangle_areas(corners):
    """(T,) unsigned areas of triangles given as corners (T, 3, 2) (numpy or torch)."""
    return 0.5 * abs(cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
