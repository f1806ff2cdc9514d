"""Carrying a fitted field onto another mesh of the same curves (error-driven refinement, ``dfc.rate``).

The new model takes the old model's decoder as it is, and a feature bank fitted by linear least squares to the old
feature field: ``min_B Σ_x |Φ_B(x) − Φ_old(x)|²`` over points ``x`` (the caller's, e.g. every pixel centre) plus,
for every triangle of the new mesh, its centroid, a point near each of its corners, and for a curved triangle a
point of its sliver, so that every row of the new bank is constrained. The features are linear in the bank
(``dfc.field.feature_field``), so this is one sparse least-squares problem per slice, damped by ``_DAMP`` and solved
exactly for every channel at once (a sparse LU factorisation of its normal equations); the refit then starts where
the old fit ended instead of from scratch. The rows are clipped to the old bank's range per channel: every point's
target interpolates the old features, so a row far outside it is one the points barely constrain (a curve's sliver
row), and its value would widen the quantisation range of the whole bank.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import splu

from ..geometry.bezier import evaluate

__all__ = ["CORNER_STEP", "carry_over", "support_points"]

CORNER_STEP = 0.2
"""Points near a corner lie this fraction of the way from the corner to the triangle's centroid."""
_DAMP = 1e-4


def support_points(mesh) -> np.ndarray:
    """(P, 2) float64 points that touch every bank row of ``mesh``'s layout: centroids, near-corner points, and the
    middle of every curved piece's sliver (halfway between its chord's midpoint and the curve at t = 1/2)."""
    v = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.triangles)]  # (T, 3, 2)
    centre = v.mean(axis=1)
    corners = v + CORNER_STEP * (centre[:, None] - v)
    cp = np.asarray(mesh.curve_control_points, np.float64).reshape(-1, 4, 2)
    sliver = 0.5 * (0.5 * (cp[:, 0] + cp[:, 3]) + evaluate(cp, np.full(len(cp), 0.5))) if len(cp) else np.zeros((0, 2))
    return np.concatenate([centre, corners.reshape(-1, 2), sliver])


def _features(field, xy: np.ndarray) -> np.ndarray:
    """(S, M, K) float64 features of every slice of ``field``'s bank at points xy (M, 2)."""
    with torch.no_grad():
        idx, w = field.query(torch.from_numpy(xy))
        bank = field.bank.detach()
        out = [(w[..., None].double() * bank[s][idx].double()).sum(dim=1) for s in range(bank.shape[0])]
    return torch.stack(out).cpu().numpy()


def carry_over(old, new, xy: np.ndarray) -> None:
    """Give ``new`` (a ``FieldModel`` on the new mesh, same dim, slices and decoder shape) ``old``'s decoder and the
    least-squares bank of the module docstring, fitted at ``xy`` (M, 2) and ``support_points``. ``old``'s raw
    values are carried (its quantised mode is off meanwhile and then restored: ``old`` is left as it was)."""
    saved, old.quantization = old.quantization, None
    try:
        _carry(old, new, xy)
    finally:
        old.quantization = saved


def _carry(old, new, xy: np.ndarray) -> None:
    """``carry_over`` with ``old`` in float mode."""
    points = np.concatenate([np.asarray(xy, np.float64).reshape(-1, 2), support_points(new.field.mesh)])
    target = _features(old.field, points)  # (S, M, K)
    with torch.no_grad():
        idx, w = new.field.query(torch.from_numpy(points))
    idx, w = idx.cpu().numpy(), w.cpu().numpy().astype(np.float64)
    n = new.field.n_features
    A = sp.csr_matrix((w.ravel(), (np.repeat(np.arange(len(points)), idx.shape[1]), idx.ravel())),
                      shape=(len(points), n))
    # min |A b − t|² + _DAMP² |b|²: (AᵀA + _DAMP² I) b = Aᵀ t, one factorisation for every slice and channel
    solve = splu((A.T @ A + _DAMP ** 2 * sp.identity(n, format="csr")).tocsc()).solve
    bank = np.stack([solve(A.T @ target[s]) for s in range(target.shape[0])])  # (S, n, K)
    old_bank = old.field.bank.detach().double().cpu().numpy()
    bank = np.clip(bank, old_bank.min(axis=(0, 1)), old_bank.max(axis=(0, 1)))
    with torch.no_grad():
        new.field.bank.copy_(torch.from_numpy(bank).to(new.field.bank))
        new.decoder.load_state_dict(old.decoder.state_dict())
