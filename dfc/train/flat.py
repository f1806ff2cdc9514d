"""Flat regions made exact: after an image fit, the feature rows whose whole support lies in pixels of one
constant value are set to one stored feature vector, the one the decoder maps closest to that value
(docs/design.md §11).

A fit leaves every row its own value, so a region that is exactly constant in the input (a render's background, a
flat fill of vector art) decodes with the ripples of independently quantised rows: 1e-3 of the data range and more
at 6-bit features, where a codec's flat block is exact to its sample depth. A triangle whose three rows hold the same
vector decodes to one value everywhere inside it, at every zoom. The vector is a point of the lattice the file
stores (``dfc.field.quantize.feature_ranges`` of the bank at the stored bits), found by a local search around the
rows' mean; identical neighbouring rows also predict each other exactly in the feature coding (``FEAC``).

A row's support is the set of pixels one of whose points (its centre, its four corners) the row weighs; it is flat
when those pixels span at most ``FLAT_TOLERANCE`` of the data range in every channel, and it is changed only when
no point it weighs is also weighed by a row that is not flat (where a flat region meets the rest, the fit's values
stay). Rows of equal flat values form a group with one vector. The change is kept only when the squared error at
the pixel centres does not grow.

``constant_rows`` is the whole-field case the raster mode needs (``dfc.codec``): every row one vector, the field one
value everywhere.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
import torch
from torch.nn.utils import parametrize

from ..field.quantize import feature_ranges, quantize_features
from ..render import values_at, window_points

__all__ = ["FLAT_TOLERANCE", "constant_rows", "snap_flat_rows"]

FLAT_TOLERANCE = 2.0**-16
"""Largest spread of a flat support's pixel values, per channel, as a share of the data range."""
FLAT_SHARE = 0.01
"""An image with fewer pixels than this share equal to their right and lower neighbours (within the tolerance) is
left as it is without locating its pixels in the mesh."""
SEARCH_CANDIDATES = 6561
"""The lattice search tries the 5^dim (else 3^dim) neighbours of its current point, at most this many, moving while
one decodes closer to the flat value; it starts from the rows' mean and from the ``SEARCH_STARTS`` rows that decode
closest."""
SEARCH_STARTS = 4
SEARCH_MOVES = 16
"""The search moves at most this many times."""
_BLOCK = 1 << 16


def _points(pixels: np.ndarray, domain, ignore: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xy (N, 2), lo (N, C), hi (N, C)): every pixel centre, then every pixel corner, with the smallest and largest
    value of the pixels it belongs to (a corner: the pixels around it), leaving out those in ``ignore`` (+inf / -inf
    where none is left)."""
    h, w, c = pixels.shape
    x0, y0, x1, y1 = domain
    low = np.where(ignore[..., None], np.inf, pixels.astype(np.float64))
    high = np.where(ignore[..., None], -np.inf, pixels.astype(np.float64))
    pad_lo = np.pad(low, ((1, 1), (1, 1), (0, 0)), constant_values=np.inf)
    pad_hi = np.pad(high, ((1, 1), (1, 1), (0, 0)), constant_values=-np.inf)
    jj, ii = np.meshgrid(np.arange(w + 1), np.arange(h + 1))
    corners = np.stack([x0 + jj.ravel() * (x1 - x0) / w, y0 + ii.ravel() * (y1 - y0) / h], axis=1)
    lo = np.concatenate([low.reshape(-1, c), np.minimum.reduce(
        [pad_lo[:-1, :-1], pad_lo[:-1, 1:], pad_lo[1:, :-1], pad_lo[1:, 1:]]).reshape(-1, c)])
    hi = np.concatenate([high.reshape(-1, c), np.maximum.reduce(
        [pad_hi[:-1, :-1], pad_hi[:-1, 1:], pad_hi[1:, :-1], pad_hi[1:, 1:]]).reshape(-1, c)])
    return np.concatenate([window_points(domain, w, h), corners]), lo, hi


def _weighed(model, xy: np.ndarray):
    """Per block of ``_BLOCK`` points xy (N, 2): (first point, rows (B, k) int64, weighed (B, k) bool)."""
    for i in range(0, len(xy), _BLOCK):
        idx, w = model.field.query(torch.from_numpy(xy[i:i + _BLOCK]))
        yield i, idx.cpu().numpy(), (w != 0).cpu().numpy()


def _flat_rows(model, pixels: np.ndarray, domain, ignore: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """(flat (R,) bool, value (R, C) float64): the bank rows whose support (the pixels not in ``ignore`` (H, W) bool one
    of whose points they weigh) spans at most ``tol`` per channel and that weigh no point together with a row whose
    support does not, and the smallest value over each row's support. Two passes over the points: memory stays
    bounded."""
    xy, p_lo, p_hi = _points(pixels, domain, ignore)
    c = pixels.shape[2]
    lo = np.full((model.field.n_features, c), np.inf)
    hi = np.full((model.field.n_features, c), -np.inf)
    for i, rows, weighed in _weighed(model, xy):
        at = np.nonzero(weighed)[0] + i
        np.minimum.at(lo, rows[weighed], p_lo[at])
        np.maximum.at(hi, rows[weighed], p_hi[at])
    flat = np.isfinite(lo).all(axis=1) & ((hi - lo) <= tol).all(axis=1)
    if flat.any():
        beside = np.zeros_like(flat)  # rows that weigh a point with a row that is not flat
        for _, rows, weighed in _weighed(model, xy):
            touched = (weighed & ~flat[rows]).any(axis=1)
            beside[rows[weighed & touched[:, None]]] = True
        flat &= ~beside
    return flat, lo


def _bank(model) -> tuple[torch.Tensor, torch.Tensor]:
    """(the bank as the writer reads it (S, R, dim), the raw parameter it is computed from)."""
    field = model.field
    raw = field.parametrizations.bank.original if parametrize.is_parametrized(field, "bank") else field.bank
    return field.bank.detach(), raw


def _distances(model, F: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(N,) squared distance of the decoded values of features F (N, dim) to ``target`` (C,), decoded on the model's
    device."""
    with torch.no_grad():
        out = model.decode(torch.from_numpy(np.ascontiguousarray(F, np.float32)).to(model.field.bank.device))
    return ((out.double().cpu().numpy() - target) ** 2).sum(axis=1)


def _squared_error(model, xy: np.ndarray, values: np.ndarray) -> float:
    """Sum of the squared differences of ``model`` at xy (N, 2) from ``values`` (N, C)."""
    return float(((values_at(model, xy, device=str(model.field.bank.device), block=_BLOCK) - values) ** 2).sum())


def _search(model, starts: np.ndarray, target: np.ndarray, scale: np.ndarray, offset: np.ndarray, top: int,
            fixed: dict[int, int]):
    """(q (dim,) int64, squared distance) of the lattice point ``offset + q · scale`` whose decoded value is closest
    to ``target`` (C,) that a descent from each of ``starts`` (S, dim) finds, with ``q[k] = fixed[k]``."""
    dim = starts.shape[1]
    reach = 2 if 5**dim <= SEARCH_CANDIDATES else 1
    steps = np.array(list(itertools.product(range(-reach, reach + 1), repeat=dim)), np.int64)
    found = []
    for start in starts:
        q = np.clip(np.rint((start - offset) / scale), 0, top).astype(np.int64)
        best = np.inf
        for _ in range(SEARCH_MOVES):
            cand = np.clip(q + steps, 0, top)
            for k, v in fixed.items():
                cand[:, k] = v
            cand = np.unique(cand, axis=0)
            err = _distances(model, offset + cand.astype(np.float32) * scale, target)
            k = int(np.argmin(err))
            if err[k] >= best:
                break
            q, best = cand[k], float(err[k])
        found.append((best, q))
    return min(found, key=lambda f: f[0])[::-1]


def snap_flat_rows(model, pixels: np.ndarray, domain, bits: int, data_range: float,
                   ignore: np.ndarray | None = None, accept: Callable[[object], bool] | None = None) -> int:
    """Set the bank rows of ``model`` (a one-slice ``FieldModel`` without one-blob encoding, fitted to ``pixels``
    (H, W, C) over ``domain`` (x0, y0, x1, y1), its features stored with ``bits``) whose support is flat to one
    lattice vector per flat value (module docstring), in place; the pixels in ``ignore`` (H, W) bool (those a curve
    crosses, whose values mix both sides) are left out of the supports and of the error. A group is changed only
    when its vector decodes closer to the flat value than its rows did on average. Returns the number of rows
    changed (0: the model is as it was, also when the change would raise the squared error at the pixel centres, or
    when ``accept(model)`` says False of the changed model)."""
    if model.field.n_slices != 1 or model.encoding is not None or 3**model.field.dim > SEARCH_CANDIDATES:
        return 0
    h, w, c = pixels.shape
    ignore = np.zeros((h, w), bool) if ignore is None else ignore
    tol = FLAT_TOLERANCE * data_range
    level = (np.abs(pixels[:-1, :-1] - pixels[1:, :-1]) <= tol).all(axis=2) & \
        (np.abs(pixels[:-1, :-1] - pixels[:-1, 1:]) <= tol).all(axis=2)
    if level.sum() < FLAT_SHARE * h * w:
        return 0
    flat, lo = _flat_rows(model, pixels, domain, ignore, tol)
    if not flat.any():
        return 0
    view, raw = _bank(model)
    stored = view[0].cpu().numpy().astype(np.float32)
    scale, offset = feature_ranges(stored, bits)
    top = 2**bits - 1
    q = quantize_features(stored, bits)[0].astype(np.int64)  # (R, dim): the integers the writer stores
    flat_rows = np.nonzero(flat)[0]
    _, group = np.unique(np.round(lo[flat] / max(tol, 1e-300)).astype(np.int64), axis=0, return_inverse=True)
    group = group.reshape(-1)
    changed = []
    for g in range(group.max() + 1):
        rows = flat_rows[group == g]
        others = np.ones(len(q), bool)
        others[rows] = False
        # a channel whose lattice end only these rows reach keeps it: the lattice must not move under the others
        low, high = q[others].min(axis=0, initial=top), q[others].max(axis=0, initial=0)
        if np.any((low > 0) & (high < top)):
            continue
        fixed = {int(k): 0 for k in np.nonzero(low > 0)[0]} | {int(k): top for k in np.nonzero(high < top)[0]}
        target = lo[rows[0]]
        now = _distances(model, stored[rows], target)
        closest = stored[rows[np.argsort(now, kind="stable")[:SEARCH_STARTS]]]
        starts = np.unique(np.concatenate([stored[rows].mean(axis=0, keepdims=True), closest]), axis=0)
        q_row, best = _search(model, starts, target, scale, offset, top, fixed)
        if best < now.mean():
            q[rows] = q_row
            changed.append(rows)
    if not changed:
        return 0
    changed = np.concatenate(changed)
    new = (offset + q.astype(np.float32) * scale).astype(np.float32)
    q_new, s_new, o_new = quantize_features(new, bits)
    if not (np.array_equal(s_new, scale) and np.array_equal(o_new, offset) and np.array_equal(q_new, q)):
        return 0  # float rounding moved the lattice: left as it is
    before = raw.detach().clone()
    keep = ~ignore.reshape(-1)
    centres, values = window_points(domain, w, h)[keep], pixels.reshape(-1, c)[keep]
    err_before = _squared_error(model, centres, values)
    with torch.no_grad():
        raw[0, changed] = torch.from_numpy(new[changed]).to(raw)
    written = quantize_features(_bank(model)[0][0].cpu().numpy(), bits)[0]  # what the writer will store
    if not np.array_equal(written, q_new) or _squared_error(model, centres, values) > err_before or \
            (accept is not None and not accept(model)):
        with torch.no_grad():
            raw.copy_(before)
        return 0
    return int(len(changed))


def constant_rows(model) -> int:
    """Set every bank row of ``model`` (a one-slice ``FieldModel``) to the rows' mean, in place, so that the field
    decodes one value everywhere, at every zoom: a feature channel that is constant over the bank is stored exactly
    at any bits (``dfc.field.quantize.feature_ranges``). Returns the number of rows."""
    _, raw = _bank(model)
    with torch.no_grad():
        raw.copy_(raw.mean(dim=1, keepdim=True).expand_as(raw))
    return int(raw.shape[1])
