"""The sampler of an image fit with a pixel filter (``dfc.pixel_filter``): each pixel compared with the field filtered
by that kernel at the pixel.

Pixels near a discontinuity (``filtered``: those the kernel of a pixel it crosses reaches) are evaluated at
``dfc.pixel_filter.TRAIN_POINTS`` quadrature points, the lattice shifted at random per pixel (exact in
expectation); every other pixel at one point — its centre, or for ``box`` a uniformly jittered point in it, as
the unfiltered fit samples: there the field is smooth and a point stands for the filtered value to first order.
``sets`` draws of all points are located once (``query``) and reused in turn, one per epoch; each epoch's point
indices are laid out once, in its order, so that a step only slices them and gathers its points.

A batch is ``(xy (N, 2) float64, target (B, C) float32, PixelWeights)``: ``dfc.train.losses.DataLoss`` sums the
model's values at the N points into the B pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..pixel_filter import TRAIN_POINTS, PixelFilter
from .samplers import QUERY_CHUNK, _Epochs

__all__ = ["PixelWeights", "filtered_sampler"]


@dataclass
class PixelWeights:
    """Which pixel of the batch each point belongs to (``row`` (N,) int64) and its weight (``weight`` (N,)), plus
    the points' precomputed ``field.query`` (or None)."""

    row: Tensor
    weight: Tensor
    query: tuple | None = None


class _FilteredPixels:
    def __init__(self, pixels: Tensor, domain, batch_size: int, f: PixelFilter, filtered: np.ndarray,
                 query, sets: int, seed: int):
        h, w, c = pixels.shape
        self.values = pixels.reshape(-1, c)
        self.batch_size = batch_size
        self.epochs = _Epochs(h * w)
        count = np.where(filtered.ravel(), TRAIN_POINTS if f.mixes else 1, 1)
        if f.name == "box" and f.param is not None and f.param ** 2 <= TRAIN_POINTS:
            count[filtered.ravel()] = int(f.param) ** 2
        self.count = torch.from_numpy(count)
        self.start = torch.from_numpy(np.cumsum(count) - count)
        self.total = int(count.sum())
        rng = np.random.default_rng(seed)
        x0, y0, x1, y1 = domain
        size = np.array([(x1 - x0) / w, (y1 - y0) / h])
        idx = np.arange(h * w)
        centre = np.stack([idx % w + 0.5, idx // w + 0.5], axis=1)
        xy, weight = [], []
        for _ in range(sets):
            pts = np.repeat(centre, count, axis=0)
            wt = np.ones(self.total)
            mixed = np.flatnonzero(filtered.ravel())
            plain = np.flatnonzero(~filtered.ravel())
            if f.name == "box":  # unfiltered pixels: a jittered point, as the box fit always sampled
                pts[self.start.numpy()[plain]] += rng.random((len(plain), 2)) - 0.5
            if len(mixed):
                off, wm = f.nodes(TRAIN_POINTS, rng.random((len(mixed), 2)))
                k = off.shape[1]
                at = (self.start.numpy()[mixed][:, None] + np.arange(k)[None]).ravel()
                pts[at] += off.reshape(-1, 2)
                wt[at] = wm.ravel()
            pts = np.clip(pts * size + [x0, y0], [x0, y0], [x1, y1])
            xy.append(pts)
            weight.append(wt)
        device = pixels.device
        self.xy = torch.from_numpy(np.concatenate(xy)).to(device)
        self.weight = torch.from_numpy(np.concatenate(weight)).to(device, torch.float32)
        self.cache = None
        if query is not None:
            with torch.no_grad():
                parts = [query(self.xy[s:s + QUERY_CHUNK]) for s in range(0, len(self.xy), QUERY_CHUNK)]
            self.cache = (torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))
        self.sets = sets
        self.laid_out = None  # (epoch, its pixels, at, pixel_of, bounds): ``_prepare``

    def _prepare(self, order: Tensor, epoch: int) -> None:
        """Index the points of an epoch once: its pixels in ``order`` (n,) and, for the k-th point of the epoch,
        its index in the located sets (``at``, of set ``(epoch - 1) % sets``) and the position of its pixel in
        ``order`` (``pixel_of``); ``bounds`` (n + 1,) the first point of each position (a NumPy array: slicing by
        it needs no device round trip)."""
        order = order.cpu()
        count = self.count.index_select(0, order)
        ends = torch.cumsum(count, 0)
        at = (torch.repeat_interleave(self.start.index_select(0, order) - (ends - count), count)
              + ((epoch - 1) % self.sets) * self.total + torch.arange(self.total))
        device = self.xy.device
        self.laid_out = (epoch, order.to(device), at.to(device),
                      torch.repeat_interleave(torch.arange(len(order)), count).to(device),
                      np.concatenate([[0], ends.numpy()]))

    def __call__(self, step: int, generator: torch.Generator):
        ats, rows, pixels, taken = [], [], [], 0
        for order, a, b, epoch in self.epochs.runs(self.batch_size, generator):
            if self.laid_out is None or self.laid_out[0] != epoch:
                self._prepare(order, epoch)
            _, pixel_order, at, pixel_of, bounds = self.laid_out
            lo, hi = int(bounds[a]), int(bounds[b])
            ats.append(at[lo:hi])
            rows.append(pixel_of[lo:hi] + (taken - a))
            pixels.append(pixel_order[a:b])
            taken += b - a
        at, row, pixel = (parts[0] if len(parts) == 1 else torch.cat(parts) for parts in (ats, rows, pixels))
        # index_select: on the CPU about 3 times as fast as indexing with a tensor
        query = None if self.cache is None else (self.cache[0].index_select(0, at), self.cache[1].index_select(0, at))
        return (self.xy.index_select(0, at), self.values.index_select(0, pixel),
                PixelWeights(row, self.weight.index_select(0, at), query))


def filtered_sampler(pixels: np.ndarray, domain, batch_size: int, pixel_filter: PixelFilter, filtered: np.ndarray,
                     *, device: str = "cpu", query=None, sets: int = 1, seed: int = 0):
    """Sampler over a raster (H, W, C) covering ``domain`` made with ``pixel_filter``; ``filtered`` (H, W) bool marks
    the pixels evaluated with the kernel's quadrature (module notes). ``query``: ``field.query`` to locate every
    point once (about 100 bytes a point and set). Returns ``sampler(step, generator) -> (xy, target,
    PixelWeights)``."""
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    filtered = np.asarray(filtered, dtype=bool)
    if filtered.shape != pixels.shape[:2]:
        raise ValueError(f"filtered must have the image's shape {pixels.shape[:2]}, got {filtered.shape}")
    return _FilteredPixels(torch.from_numpy(np.ascontiguousarray(pixels, dtype=np.float32)).to(device),
                           tuple(float(v) for v in domain), batch_size, pixel_filter, filtered, query, sets, seed)
