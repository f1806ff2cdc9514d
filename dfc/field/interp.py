"""Queries -> (bank row, weight) pairs: radial + barycentric interpolation with curved triangles (docs/design.md §5).

For a query ``x`` in triangle ``T`` with barycentric coordinates ``λ`` the feature is
``F(x) = Σ_k w_k P[i_k]`` over seven slots:

* slots ``2i, 2i + 1`` — corner ``i``'s sector features at its start / end half-edge with weights
  ``λ_i (1 − φ/Θ)`` and ``λ_i φ/Θ``, ``φ`` the clamped angle of ``x − v_i`` from the sector start
  and ``Θ`` the sector angle (paper Eq. 2; both rows are the vertex's single feature and ``φ/Θ = 0``
  at a vertex without discontinuities);
* slot 6 — the curve feature, used only in a curved triangle's sliver, else row 0 with weight 0.

In the sliver of a curved triangle (between chord and piece, chord included) the two endpoint
corners use, with weight ``λ_i`` in their start slot, the chord-edge feature of the sector on the far
side of the chord — exactly what the neighbour across the chord sees on the chord — and the apex's
weight moves to the curve feature in slot 6. So the field is continuous across the chord and jumps
only across the piece. Geometry is float64; weights are differentiable w.r.t. the query points.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..geometry.mesh import Mesh
from ..geometry.plane import cross
from .layout import Layout
from .side import chord_frames, in_sliver

__all__ = ["Interpolator", "N_SLOTS"]

N_SLOTS = 7
"""(index, weight) pairs per query."""


class Interpolator(nn.Module):
    """Turns located queries into bank rows and weights; geometry tables are buffers.

    mesh : the mesh; layout : ``build_layout(mesh)``.
    """

    def __init__(self, mesh: Mesh, layout: Layout):
        super().__init__()
        verts = np.asarray(mesh.vertices, np.float64)
        tris = np.asarray(mesh.triangles, np.int64)
        pos = verts[tris]                                                  # (T, 3, 2)
        rows = np.zeros((len(tris), N_SLOTS), np.int64)
        rows[:, :6] = np.stack([layout.corner_start, layout.corner_end], axis=-1).reshape(-1, 6)
        # Per-corner tables, flattened to (3T, ...) and indexed by 3 * triangle + corner.
        self.register_buffer("corner_rows", torch.from_numpy(rows))                   # (T, 7), slot 6 padding
        self.register_buffer("corner_radial", torch.from_numpy(np.isfinite(layout.corner_theta)))
        self.register_buffer("corner_pos", torch.from_numpy(pos.reshape(-1, 2)))
        self.register_buffer("corner_edge", torch.from_numpy((np.roll(pos, -1, axis=1) - pos).reshape(-1, 2)))
        self.register_buffer("corner_alpha", torch.from_numpy(layout.corner_alpha.reshape(-1)))
        self.register_buffer("corner_beta", torch.from_numpy(layout.corner_beta.reshape(-1)))
        self.register_buffer("corner_theta", torch.from_numpy(layout.corner_theta.reshape(-1)))
        self.register_buffer("triangle_curve", torch.from_numpy(layout.triangle_curve))

        # Sliver slots per curve: row, the corner whose λ weighs it, and whether it is used.
        n_c = len(layout.curve_apex)
        cc = np.arange(n_c)
        slot_rows = np.zeros((n_c, N_SLOTS), np.int64)
        slot_corner = np.zeros((n_c, N_SLOTS), np.int64)
        slot_on = np.zeros((n_c, N_SLOTS), np.float64)
        for i in range(3):
            slot_rows[:, 2 * i] = layout.curve_sliver_rows[:, i]
            slot_corner[:, 2 * i] = i
            slot_on[:, 2 * i] = layout.curve_apex != i
        slot_rows[:, 6] = layout.curve_sliver_rows[cc, layout.curve_apex]
        slot_corner[:, 6] = layout.curve_apex
        slot_on[:, 6] = 1.0
        self.register_buffer("sliver_rows", torch.from_numpy(slot_rows))
        self.register_buffer("sliver_corner", torch.from_numpy(slot_corner))
        self.register_buffer("sliver_on", torch.from_numpy(slot_on))

        cp = torch.from_numpy(np.asarray(mesh.curve_control_points, np.float64).reshape(-1, 4, 2))
        ct = np.asarray(mesh.curved_triangles, np.int64).reshape(-1)
        apex = torch.from_numpy(pos[ct, layout.curve_apex])
        origin, u_axis, v_axis, local = chord_frames(cp, apex)
        self.register_buffer("chord_origin", origin)
        self.register_buffer("chord_u", u_axis)
        self.register_buffer("chord_v", v_axis)
        self.register_buffer("chord_local", local)

    def forward(self, xy: torch.Tensor, tri: torch.Tensor, bary: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pairs for located queries.

        xy : (N, 2) float64 points (clamped into the domain); tri : (N,) int64 their triangles;
        bary : (N, 3) float64 their barycentric coordinates in ``tri``.
        Returns idx (N, 7) int64 bank rows and w (N, 7) float32 weights summing to 1.
        """
        idx = self.corner_rows.index_select(0, tri)
        w = bary.new_zeros((len(tri), N_SLOTS), dtype=torch.float32)
        w[:, 0:6:2] = bary  # λ_i -> slot 2i
        # Radial interpolation, only at corners whose vertex has discontinuities.
        q, i = torch.nonzero(self.corner_radial.index_select(0, tri)).unbind(1)
        if q.numel():
            c = 3 * tri.index_select(0, q) + i
            d = xy.index_select(0, q) - self.corner_pos.index_select(0, c)
            e = self.corner_edge.index_select(0, c)
            turn = cross(e, d)
            dot = e[:, 0] * d[:, 0] + e[:, 1] * d[:, 1]
            at_vertex = (d == 0).all(1)
            # atan2(0, 0) has a NaN gradient: a query on the vertex is at angle 0 from the edge v -> next.
            psi = torch.atan2(torch.where(at_vertex, 0.0, turn), torch.where(at_vertex, 1.0, dot))
            psi = torch.minimum(psi.clamp(min=0.0), self.corner_beta.index_select(0, c))
            theta = self.corner_theta.index_select(0, c)
            t = torch.minimum(self.corner_alpha.index_select(0, c) + psi, theta) / theta
            lam = bary[q, i]
            w[q, 2 * i] = (lam * (1.0 - t)).to(torch.float32)
            w[q, 2 * i + 1] = (lam * t).to(torch.float32)

        curve = self.triangle_curve.index_select(0, tri)
        cand = torch.nonzero(curve >= 0).squeeze(1)
        if cand.numel():
            c = curve[cand]
            inside = in_sliver(xy[cand].detach(), self.chord_origin[c], self.chord_u[c], self.chord_v[c],
                               self.chord_local[c])
            q, c = cand[inside], c[inside]
            idx[q] = self.sliver_rows[c]
            w[q] = (bary[q].gather(1, self.sliver_corner[c]) * self.sliver_on[c]).to(torch.float32)
        return idx, w
