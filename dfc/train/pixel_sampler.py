"""The sampler of an image fit with a pixel filter (``dfc.pixel_filter``): each pixel compared with the field filtered
by that kernel at the pixel.

Pixels near a discontinuity (``filtered``: those the kernel of a pixel it crosses reaches) are evaluated at
``dfc.pixel_filter.TRAIN_POINTS`` quadrature points, the lattice shifted at random per pixel (exact in
expectation), and at ``dfc.pixel_filter.STEEP_POINTS`` where ``steep`` marks them (beside an HDR jump, where the
squared error's share of the quadrature's variance would make the fit shrink the jump); every other pixel at one
point — its centre, or for ``box`` a uniformly jittered point in it, as the unfiltered fit samples: there the field
is smooth and a point stands for the filtered value to first order.
``sets`` draws of all points are made and located once (``query``), each in its own random order of the pixels with a
pixel's points together, and reused in turn, one per epoch. An epoch visits its set in chunks of consecutive pixels
(``batch_size / CHUNKS_PER_BATCH``) taken in a fresh random order, copied ``BLOCK_CHUNKS`` at a time into one
contiguous block, so that a step slices its batch instead of gathering scattered rows (on the CPU those gathers
are mostly cache misses). A point's located query is kept without its zero-weight slots
(``dfc.field.feature_field.PackedQuery``).

A batch is ``(xy (N, 2) float64, target (B, C) float32, PixelWeights)``: ``dfc.train.losses.DataLoss`` sums the
model's values at the N points into the B pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..field.feature_field import PackedQuery, pack_query
from ..pixel_filter import STEEP_POINTS, TRAIN_POINTS, PixelFilter
from .samplers import QUERY_CHUNK

__all__ = ["BLOCK_CHUNKS", "CHUNKS_PER_BATCH", "PixelWeights", "filtered_sampler"]

CHUNKS_PER_BATCH = 8
"""A batch is drawn as this many chunks of consecutive pixels of a set's random order (module notes)."""
BLOCK_CHUNKS = 64
"""Chunks laid out together (``_Block``): a step slices its batch out of a block; bounds the block's memory."""


@dataclass
class PixelWeights:
    """Which pixel of the batch each point belongs to (``row`` (N,) int64) and its weight (``weight`` (N,)), plus
    the points' precomputed ``field.query`` as a ``dfc.field.feature_field.PackedQuery`` (or None)."""

    row: Tensor
    weight: Tensor
    query: PackedQuery | None = None


class _Block:
    """Consecutive chunks of a set laid out contiguously, in the epoch's order: ``xy`` (P, 2), ``weight`` (P,) and
    ``row`` (P,) (each point's pixel, as its position in the block) of the points, ``values`` (Q, C) of the pixels,
    ``bounds`` (Q + 1,) NumPy the first point of each pixel; with located queries ``idx``, ``w`` (S,) of the slots,
    ``offsets`` (P,) each point's first slot, ``point`` (S,) each slot's point, ``slots`` (P + 1,) NumPy. Built
    from the pixels' point counts ``counts`` (Q,) and the points' slot counts ``slot_counts`` (P,) (NumPy)."""

    def __init__(self, xy: Tensor, weight: Tensor, values: Tensor, counts: np.ndarray, idx: Tensor | None = None,
                 w: Tensor | None = None, slot_counts: np.ndarray | None = None):
        device = xy.device
        self.xy, self.weight, self.values, self.idx, self.w = xy, weight, values, idx, w
        self.pixels = len(counts)
        self.row = _owner(counts, device)
        self.bounds = np.concatenate([[0], np.cumsum(counts)])
        if slot_counts is not None:
            self.slots = np.concatenate([[0], np.cumsum(slot_counts)])
            self.offsets = torch.from_numpy(self.slots[:-1]).to(device)
            self.point = _owner(slot_counts, device)


def _owner(counts: np.ndarray, device) -> Tensor:
    """(counts.sum(),) int64: ``i`` repeated ``counts[i]`` times (NumPy's repeat: on the CPU several times as fast
    as ``torch.repeat_interleave``)."""
    return torch.from_numpy(np.repeat(np.arange(len(counts)), counts)).to(device)


class _FilteredPixels:
    def __init__(self, pixels: Tensor, domain, batch_size: int, f: PixelFilter, filtered: np.ndarray,
                 query, sets: int, seed: int, steep: np.ndarray | None = None):
        h, w, c = pixels.shape
        n = h * w
        self.n, self.sets, self.batch_size = n, sets, batch_size
        self.chunk = max(1, batch_size // CHUNKS_PER_BATCH)
        count = np.where(filtered.ravel(), TRAIN_POINTS if f.mixes else 1, 1)
        if f.name == "box" and f.param is not None and f.param ** 2 <= TRAIN_POINTS:
            count[filtered.ravel()] = int(f.param) ** 2
        elif f.mixes and steep is not None:
            count[filtered.ravel() & steep.ravel()] = STEEP_POINTS
        self.total = int(count.sum())
        rng = np.random.default_rng(seed)
        x0, y0, x1, y1 = domain
        size = np.array([(x1 - x0) / w, (y1 - y0) / h])
        values = pixels.reshape(-1, c)
        xy, weight, counts, laid = [], [], [], []
        for _ in range(sets):  # each set in its own random pixel order, a pixel's points together
            order = rng.permutation(n)
            k = count[order]
            mixed = filtered.ravel()[order]
            start = np.cumsum(k) - k
            pts = np.repeat(np.stack([order % w + 0.5, order // w + 0.5], axis=1), k, axis=0)
            wt = np.ones(self.total)
            if f.name == "box":  # unfiltered pixels: a jittered point, as the box fit always sampled
                pts[start[~mixed]] += rng.random((int((~mixed).sum()), 2)) - 0.5
            for points in np.unique(k[mixed]):  # the pixels with a quadrature of each size
                sel = mixed & (k == points)
                off, wm = f.nodes(int(points), rng.random((int(sel.sum()), 2)))
                at = (start[sel][:, None] + np.arange(off.shape[1])[None]).ravel()
                pts[at] += off.reshape(-1, 2)
                wt[at] = wm.ravel()
            xy.append(np.clip(pts * size + [x0, y0], [x0, y0], [x1, y1]))
            weight.append(wt)
            counts.append(k)
            laid.append(values.index_select(0, torch.from_numpy(order).to(values.device)))
        device = pixels.device
        self.xy = torch.from_numpy(np.concatenate(xy)).to(device)
        self.weight = torch.from_numpy(np.concatenate(weight)).to(device, torch.float32)
        self.counts = np.concatenate(counts)  # (sets · n,) points of each pixel, set after set
        self.bounds = np.concatenate([[0], np.cumsum(self.counts)])  # the first point of each
        self.values = torch.cat(laid)
        self.cache = None
        if query is not None:
            with torch.no_grad():
                parts = [query(self.xy[s:s + QUERY_CHUNK]) for s in range(0, len(self.xy), QUERY_CHUNK)]
            self.cache = pack_query(torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))
            self.slots = np.concatenate([self.cache.offsets.cpu().numpy(), [len(self.cache.idx)]])
            self.slot_counts = np.diff(self.slots)
        self.epoch, self.chunks, self.block, self.offset = 0, [], None, 0

    def _next_block(self, generator: torch.Generator) -> None:
        """Lay out the epoch's next ``BLOCK_CHUNKS`` chunks (a fresh epoch, of the next set, when its chunks are
        used up: its chunks of ``chunk`` pixels in a random order drawn from ``generator``)."""
        if not self.chunks:
            n_chunks = -(-self.n // self.chunk)
            self.chunks = torch.randperm(n_chunks, generator=generator, device=generator.device).tolist()
            self.epoch += 1
        taken, self.chunks = self.chunks[:BLOCK_CHUNKS], self.chunks[BLOCK_CHUNKS:]
        s = (self.epoch - 1) % self.sets
        pixels = [(s * self.n + c * self.chunk, s * self.n + min(self.n, (c + 1) * self.chunk)) for c in taken]
        points = [(int(self.bounds[a]), int(self.bounds[b])) for a, b in pixels]

        def cat(table, runs):
            return (np.concatenate if isinstance(table, np.ndarray) else torch.cat)([table[a:b] for a, b in runs])

        queries = {}
        if self.cache is not None:
            slots = [(int(self.slots[a]), int(self.slots[b])) for a, b in points]
            queries = {"idx": cat(self.cache.idx, slots), "w": cat(self.cache.w, slots),
                       "slot_counts": cat(self.slot_counts, points)}
        self.block = _Block(cat(self.xy, points), cat(self.weight, points), cat(self.values, pixels),
                            cat(self.counts, pixels), **queries)
        self.offset = 0

    def __call__(self, step: int, generator: torch.Generator):
        parts, taken, points, slots = [], 0, 0, 0
        while taken < self.batch_size:
            if self.block is None or self.offset == self.block.pixels:
                self._next_block(generator)
            k = self.block
            a = self.offset
            b = min(k.pixels, a + self.batch_size - taken)
            lo, hi = int(k.bounds[a]), int(k.bounds[b])
            part = [k.xy[lo:hi], k.values[a:b], k.row[lo:hi] + (taken - a), k.weight[lo:hi]]
            if self.cache is not None:
                sa, sb = int(k.slots[lo]), int(k.slots[hi])
                part += [k.idx[sa:sb], k.w[sa:sb], k.offsets[lo:hi] + (slots - sa), k.point[sa:sb] + (points - lo)]
                slots += sb - sa
            parts.append(part)
            taken += b - a
            points += hi - lo
            self.offset = b
        xy, values, row, weight, *query = (p[0] if len(parts) == 1 else torch.cat(p) for p in zip(*parts))
        return xy, values, PixelWeights(row, weight, PackedQuery(*query) if query else None)


def filtered_sampler(pixels: np.ndarray, domain, batch_size: int, pixel_filter: PixelFilter, filtered: np.ndarray,
                     *, device: str = "cpu", query=None, sets: int = 1, seed: int = 0, steep: np.ndarray | None = None):
    """Sampler over a raster (H, W, C) covering ``domain`` made with ``pixel_filter``; ``filtered`` (H, W) bool marks
    the pixels evaluated with the kernel's quadrature, ``steep`` (H, W) bool those of them given ``STEEP_POINTS``
    (module notes). ``query``: ``field.query`` to locate every point once (about 100 bytes a point and set). Returns
    ``sampler(step, generator) -> (xy, target, PixelWeights)``."""
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    filtered = np.asarray(filtered, dtype=bool)
    if filtered.shape != pixels.shape[:2]:
        raise ValueError(f"filtered must have the image's shape {pixels.shape[:2]}, got {filtered.shape}")
    return _FilteredPixels(torch.from_numpy(np.ascontiguousarray(pixels, dtype=np.float32)).to(device),
                           tuple(float(v) for v in domain), batch_size, pixel_filter, filtered, query, sets, seed,
                           steep)
