"""Out-of-core sampling of a raster read in bands of rows (docs/design.md §10, the paper's §6.1 fit).

The image is never held: a *band source* (``dfc.io.bands``) yields rows on demand. Three pieces:

- ``HeldOut``: a stratified set of pixels kept out of training — one per square cell of ``HeldOut.cell`` pixels,
  at an offset hashed from the cell — recognised in O(1) per pixel, so any band can leave them out without a list.
- ``scan``: one pass over the bands (a rank's share of them) that checks every pixel (NaN, damaged chunks), sums
  the per-channel range and mean the model is initialised from, counts the mixed pixels along the curves
  (``dfc.geometry.pixels.EdgeMask``) and collects the held-out pixels' values.
- ``band_sampler``: each epoch draws a stratified subset of ``epoch_pixels`` pixels — one uniformly jittered point
  per cell of a grid of that many cells over the image (every pixel once when it has no more pixels) — band by
  band, leaving out mixed and held-out pixels; batches then visit the epoch's samples in a fresh random order and
  a new epoch is drawn when they are used up. Memory: ``sample_bytes`` per epoch sample plus one band. With
  ``query`` (GPU fits) each epoch's points are also located once when it is drawn, so that a step runs on the device
  without host round trips (about 84 more bytes per sample, in device memory).

Data-parallel runs: the bands are dealt to the ranks in turn (band k to rank k mod N); each rank scans, samples
and trains on its own share only.

Memory stays flat over a long fit only if freed heap memory goes back to the system: epochs, bands and the steps'
point-location temporaries are freed in varying sizes, which glibc keeps (its mmap threshold rises to 32 MB after
the first large frees). Measured on a 4096² stripes fit (epochs of 2M pixels, batch 65,536, one thread): resident
memory crept from 542 to 915 MB in 200 steps; returning the free pages (``malloc_trim``) when an epoch is drawn and
every ``TRIM_STEPS`` steps keeps it at 590–630 MB over 300 steps, for 0.5 s more system time per 60 steps (a fixed
128 KB mmap threshold also keeps it flat, but costs 9 s per 60 steps in page faults).
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from ..io.bands import band_ranges
from .samplers import QUERY_CHUNK

__all__ = ["DEFAULT_EPOCH_BYTES", "HELD_OUT_PIXELS", "BandStats", "HeldOut", "band_sampler", "default_epoch_pixels",
           "scan"]

DEFAULT_EPOCH_BYTES = 1 << 29
"""Memory an epoch's samples may take when ``epoch_pixels`` is not given (512 MiB)."""
HELD_OUT_PIXELS = 1 << 18
"""Held-out pixels of an out-of-core encode (about this many; the report's PSNR is measured on them)."""
TRIM_STEPS = 10
"""Steps between returns of the C heap's free memory to the system (module notes)."""


def release_free_memory() -> None:
    """Return the C heap's free pages to the system (glibc's ``malloc_trim``; nothing elsewhere)."""
    trim = getattr(ctypes.CDLL(None), "malloc_trim", None)
    if trim is not None:
        trim(0)


def sample_bytes(n_channels: int) -> int:
    """Memory of one epoch sample: position (2 float64), target (C float32) and its place in the epoch's order."""
    return 16 + 4 * n_channels + 8


def default_epoch_pixels(n_pixels: int, n_channels: int, budget: int = DEFAULT_EPOCH_BYTES) -> int:
    """Pixels per epoch sized to memory: at most ``budget`` bytes of samples, at most every pixel."""
    return int(max(1, min(n_pixels, budget // sample_bytes(n_channels))))


def _mix(a: np.ndarray, b: np.ndarray, seed: int) -> np.ndarray:
    """A 64-bit hash (splitmix64 finaliser) of integer pairs: (n,) uint64."""
    with np.errstate(over="ignore"):
        z = (a.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) ^ (b.astype(np.uint64) + np.uint64(seed))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


class HeldOut:
    """One held-out pixel per ``cell × cell`` square of a ``width × height`` raster (about ``count`` in all, at most
    one pixel in 64), at an offset hashed from the square and ``seed``: stratified, and recognisable in any band
    without a list."""

    def __init__(self, width: int, height: int, count: int = HELD_OUT_PIXELS, seed: int = 0):
        self.width, self.height, self.seed = width, height, seed
        count = min(count, width * height // 64)  # at most one pixel in 64
        self.cell = max(2, math.ceil(math.sqrt(width * height / max(1, count))))
        self.nx, self.ny = -(-width // self.cell), -(-height // self.cell)

    def pixels(self, y0: int, y1: int) -> np.ndarray:
        """(k, 2) int64 (column, row) of the held-out pixels in rows ``y0 .. y1 - 1``, row-major."""
        c = self.cell
        b = np.arange(y0 // c, min(self.ny, -(-y1 // c)))
        a = np.arange(self.nx)
        A, B = np.meshgrid(a, b)
        A, B = A.ravel(), B.ravel()
        h = _mix(A, B, self.seed)
        w = np.minimum(c, self.width - A * c).astype(np.uint64)
        hh = np.minimum(c, self.height - B * c).astype(np.uint64)
        i = A * c + (h % w).astype(np.int64)
        j = B * c + ((h >> np.uint64(32)) % hh).astype(np.int64)
        keep = (j >= y0) & (j < y1)
        out = np.stack([i[keep], j[keep]], axis=1)
        return out[np.lexsort((out[:, 0], out[:, 1]))]

    def mask(self, y0: int, y1: int) -> np.ndarray:
        """(y1 - y0, W) bool: the held-out pixels of rows ``y0 .. y1 - 1``."""
        out = np.zeros((y1 - y0, self.width), dtype=bool)
        p = self.pixels(y0, y1)
        out[p[:, 1] - y0, p[:, 0]] = True
        return out


@dataclass
class BandStats:
    """What ``scan`` found on its bands. lo, hi, total, log_total : (C,) float64 per-channel min, max, sum and sum
    of ``log(1 + max(v, 0))`` over ``count`` pixels; ``mixed`` : pixels on the curves; ``held_xy`` (M, 2) int64 column, row and ``held_values`` (M, C)
    float32 of the held-out pixels."""

    lo: np.ndarray
    hi: np.ndarray
    total: np.ndarray
    log_total: np.ndarray
    count: int
    mixed: int
    held_xy: np.ndarray
    held_values: np.ndarray

    @property
    def mean(self) -> np.ndarray:
        return self.total / max(1, self.count)

    @property
    def log_mean(self) -> np.ndarray:
        return self.log_total / max(1, self.count)


def own_bands(source, rank: int = 0, world: int = 1) -> list[tuple[int, int]]:
    """The row bands of ``source`` (``source.band_rows()`` rows each) that rank ``rank`` of ``world`` reads."""
    return band_ranges(source.height, source.band_rows())[rank::world]


def scan(source, *, mixed=None, held_out: HeldOut | None = None, rank: int = 0, world: int = 1,
         callback=None) -> BandStats:
    """One pass over this rank's bands of ``source`` (see the module notes). ``mixed`` : an ``EdgeMask`` or None;
    ``callback(rows)`` after each band. Raises ``InputError`` on damaged data or NaN / infinite pixels."""
    c = len(source.channels)
    lo, hi, total, log_total = np.full(c, np.inf), np.full(c, -np.inf), np.zeros(c), np.zeros(c)
    count = n_mixed = 0
    held_xy, held_values = [np.zeros((0, 2), np.int64)], [np.zeros((0, c), np.float32)]
    for y0, y1 in own_bands(source, rank, world):
        block = source.rows(y0, y1)
        flat = block.reshape(-1, c)
        lo, hi = np.minimum(lo, flat.min(axis=0)), np.maximum(hi, flat.max(axis=0))
        total += flat.sum(axis=0, dtype=np.float64)
        log_total += np.log1p(np.maximum(flat, 0.0)).sum(axis=0, dtype=np.float64)
        count += len(flat)
        if mixed is not None:
            n_mixed += int(mixed.rows(y0, y1).sum())
        if held_out is not None:
            p = held_out.pixels(y0, y1)
            held_xy.append(p)
            held_values.append(block[p[:, 1] - y0, p[:, 0]])
        if callback is not None:
            callback(y1 - y0)
    return BandStats(lo, hi, total, log_total, count, n_mixed, np.concatenate(held_xy), np.concatenate(held_values))


class _BandEpochs:
    """The out-of-core stratified sampler (``band_sampler``)."""

    def __init__(self, source, domain, batch_size: int, epoch_pixels: int, mixed, held_out, rank: int, world: int,
                 device, query):
        h, w = source.height, source.width
        n = min(int(epoch_pixels), h * w)
        s = math.sqrt(h * w / n)
        self.gx, self.gy = max(1, min(w, round(w / s))), max(1, min(h, round(h / s)))
        per_band = max(1, round(source.band_rows() * self.gy / h))  # cell rows per band: about a band of rows
        per_band = min(per_band, -(-self.gy // world))  # every rank gets a band
        self.bands = [(b, min(self.gy, b + per_band)) for b in range(0, self.gy, per_band)][rank::world]
        if not self.bands:
            raise InputError(f"rank {rank}: the image has too few rows for {world} ranks")
        x0, y0, x1, y1 = domain
        self.origin = np.array([x0, y0])
        self.pixel_size = np.array([(x1 - x0) / w, (y1 - y0) / h])
        self.source, self.batch_size, self.mixed, self.held_out = source, batch_size, mixed, held_out
        self.device, self.query = torch.device(device), query
        self.xy = self.target = self.order = self.located = None
        self.pos = self.epoch = 0

    @property
    def cells(self) -> int:
        """Cells (samples before leaving out mixed and held-out pixels) of this rank's epochs."""
        return self.gx * sum(b1 - b0 for b0, b1 in self.bands)

    def _draw(self, generator: torch.Generator) -> None:
        """A new epoch: one jittered point per cell of this rank's bands, read band by band."""
        h, w = self.source.height, self.source.width
        self.xy = self.target = self.order = self.located = None  # free the last epoch first
        release_free_memory()
        xy = np.empty((self.cells, 2))
        target = np.empty((self.cells, len(self.source.channels)), dtype=np.float32)
        k = 0
        for b0, b1 in self.bands:
            n = self.gx * (b1 - b0)
            u = torch.rand(n, 2, generator=generator, dtype=torch.float64, device=generator.device).cpu().numpy()
            cell = np.arange(n)
            p = np.stack([(cell % self.gx + u[:, 0]) * (w / self.gx),
                          (b0 + cell // self.gx + u[:, 1]) * (h / self.gy)], axis=1)  # pixel units
            i = np.minimum(p[:, 0].astype(np.int64), w - 1)
            j = np.minimum(p[:, 1].astype(np.int64), h - 1)
            r0, r1 = int(j.min()), int(j.max()) + 1
            keep = np.ones(n, dtype=bool)
            if self.mixed is not None:
                keep &= ~self.mixed.rows(r0, r1)[j - r0, i]
            if self.held_out is not None:
                keep &= ~self.held_out.mask(r0, r1)[j - r0, i]
            m = int(keep.sum())
            target[k : k + m] = self.source.rows(r0, r1)[j[keep] - r0, i[keep]]
            xy[k : k + m] = self.origin + p[keep] * self.pixel_size
            k += m
        if k == 0:
            raise InputError("every pixel of this rank's bands is left out of sampling (mixed or held out)")
        self.xy = torch.from_numpy(xy[:k]).to(self.device)
        self.target = torch.from_numpy(target[:k]).to(self.device)
        if self.query is not None:
            with torch.no_grad():
                parts = [self.query(self.xy[s : s + QUERY_CHUNK]) for s in range(0, k, QUERY_CHUNK)]
            self.located = (torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))
        self.order = torch.randperm(k, generator=generator, device=generator.device).to(self.device)
        self.pos = 0
        self.epoch += 1

    def __call__(self, step: int, generator: torch.Generator) -> tuple:
        if step % TRIM_STEPS == 0:
            release_free_memory()
        parts, need = [], self.batch_size
        while need:
            if self.order is None or self.pos == len(self.order):
                self._draw(generator)
            rows = self.order[self.pos : self.pos + need]
            located = () if self.located is None else (self.located[0][rows], self.located[1][rows])
            parts.append((self.xy[rows], self.target[rows], *located))
            self.pos += len(rows)
            need -= len(rows)
        batch = [torch.cat(column) for column in zip(*parts)] if len(parts) > 1 else list(parts[0])
        return tuple(batch[:2]) + ((tuple(batch[2:]),) if len(batch) > 2 else ())


def band_sampler(source, domain, batch_size: int, *, epoch_pixels: int | None = None, mixed=None,
                 held_out: HeldOut | None = None, rank: int = 0, world: int = 1, device="cpu", query=None):
    """Out-of-core stratified sampler over a band source covering ``domain`` (module notes).

    Parameters
    ----------
    source : band source (``dfc.io.bands``); domain : (x0, y0, x1, y1)
    batch_size : samples per call on this rank
    epoch_pixels : pixels per epoch over the whole image, all ranks together (default ``default_epoch_pixels``)
    mixed : ``EdgeMask`` of pixels never sampled, or None; held_out : ``HeldOut`` pixels never sampled, or None
    rank, world : this rank and the number of ranks (each samples its own bands)
    query : optional ``field.query``: each epoch's points are located when it is drawn, and each call also returns
        the batch's (idx, w) for ``FieldModel.forward(query=...)``

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32[, (idx, w)])`` on ``device``; its
    ``epoch`` attribute counts the epochs drawn.
    """
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    n = source.height * source.width
    epoch_pixels = default_epoch_pixels(n, len(source.channels)) if epoch_pixels is None else epoch_pixels
    if not isinstance(epoch_pixels, int) or epoch_pixels < 1:
        raise ValueError(f"epoch_pixels must be a positive integer, got {epoch_pixels!r}")
    x0, y0, x1, y1 = (float(v) for v in domain)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"domain {tuple(domain)} must have x1 > x0 and y1 > y0")
    return _BandEpochs(source, (x0, y0, x1, y1), batch_size, epoch_pixels, mixed, held_out, rank, world, device,
                       query)
