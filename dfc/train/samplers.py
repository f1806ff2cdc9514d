"""Samplers: the batches ``dfc.train.loop.train`` draws, one per step.

A sampler is a callable ``sampler(step, generator) -> batch`` (``dfc.train.loop.Sampler``). The data samplers
return ``(xy (B, 2) float64, target (B, C) float32[, extra])`` for ``dfc.train.losses.DataLoss``: stratified pixels
of a raster (``image_sampler``), shuffled scattered samples (``point_sampler``), the pixels of every frame of a
sequence at the frame's time (``frame_sampler``). ``physics_sampler`` draws the interior and boundary points of a
physics-informed solve (``dfc.physics.solve``). Every sampler visits its data in epochs drawn from the loop's
generator, so a run is deterministic on the CPU for a seed.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..io.image import check_pixels
from .loop import Sampler

__all__ = ["QUERY_CHUNK", "frame_sampler", "image_sampler", "physics_sampler", "point_sampler"]

QUERY_CHUNK = 1 << 16
"""Points per call when precomputing field queries (bounds the locator's temporary memory)."""


class _Epochs:
    """Every index of ``range(n)`` once per epoch, in a fresh random order drawn from the fit's generator."""

    def __init__(self, n: int):
        self.n = n
        self.order = torch.empty(0, dtype=torch.int64)
        self.pos = self.epoch = 0

    def take(self, count: int, generator: torch.Generator) -> list[tuple[Tensor, int]]:
        """The next ``count`` indices, as runs (indices (k,) int64, 1-based epoch they belong to)."""
        return [(order[a:b], epoch) for order, a, b, epoch in self.runs(count, generator)]

    def runs(self, count: int, generator: torch.Generator) -> list[tuple[Tensor, int, int, int]]:
        """The next ``count`` indices, as runs (the epoch's whole order (n,) int64, the run's start and stop in it,
        1-based epoch): ``take`` with the positions in the epoch, for samplers that prepare each epoch once."""
        parts = []
        while count:
            if self.pos == len(self.order):
                self.order, self.pos = torch.randperm(self.n, generator=generator, device=generator.device), 0
                self.epoch += 1
            k = min(count, self.n - self.pos)
            parts.append((self.order, self.pos, self.pos + k, self.epoch))
            self.pos += k
            count -= k
        return parts


class _PixelGrid:
    """Pixel (i, j) of a ``width × height`` raster over ``domain`` covers ``[x0 + i·sx, x0 + (i+1)·sx] × …``."""

    def __init__(self, domain, width: int, height: int, device="cpu"):
        x0, y0, x1, y1 = domain
        self.width = width
        self.origin = torch.tensor([x0, y0], dtype=torch.float64, device=device)
        self.pixel_size = torch.tensor([(x1 - x0) / width, (y1 - y0) / height], dtype=torch.float64, device=device)

    def points(self, pixel: Tensor, generator: torch.Generator) -> Tensor:
        """One uniformly jittered point (N, 2) float64 in each of the flat pixel indices ``pixel`` (N,), on the
        grid's device (jitter drawn on the generator's)."""
        jitter = torch.rand(len(pixel), 2, generator=generator, dtype=torch.float64, device=generator.device)
        ij = torch.stack([pixel % self.width, pixel // self.width], dim=1).to(self.origin.device, torch.float64)
        return self.origin + (ij + jitter.to(self.origin.device)) * self.pixel_size


def _kept_pixels(height: int, width: int, exclude) -> Tensor:
    """(n,) int64 flat indices of the pixels not excluded (``exclude``: None or (H, W) bool)."""
    keep = np.arange(height * width)
    if exclude is not None:
        exclude = np.asarray(exclude, dtype=bool)
        if exclude.shape != (height, width):
            raise ValueError(f"exclude must have the image's shape {(height, width)}, got {exclude.shape}")
        keep = keep[~exclude.ravel()]
        if len(keep) == 0:
            raise InputError("every pixel is excluded from sampling")
    return torch.from_numpy(keep)


class _StratifiedPixels:
    """Stateful sampler: every pixel once per epoch in a fresh random order, each at a jittered point.

    Without ``query``, each epoch draws fresh U(0, 1)² jitters. With ``query``, ``jitter_sets`` epochs'
    jittered points and their ``query(xy)`` results are computed once and reused in turn (epoch e uses
    set e mod jitter_sets, still in a fresh order), so point location is not repeated every step.
    """

    def __init__(self, pixels: Tensor, domain, batch_size: int, query, jitter_sets: int, generator: torch.Generator,
                 keep: Tensor):
        self.pixels = pixels.reshape(-1, pixels.shape[-1])
        self.keep = keep.to(pixels.device)  # (n,) int64 flat indices of the pixels sampled
        self.grid = _PixelGrid(domain, pixels.shape[1], pixels.shape[0], pixels.device)
        self.batch_size = batch_size
        self.epochs = _Epochs(len(keep))
        self.cache = None
        if query is not None:
            xy = torch.cat([self.grid.points(self.keep, generator) for _ in range(jitter_sets)])
            with torch.no_grad():
                parts = [query(xy[s : s + QUERY_CHUNK]) for s in range(0, len(xy), QUERY_CHUNK)]
            self.cache = (xy, torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))

    def __call__(self, step: int, generator: torch.Generator):
        n = len(self.keep)
        sets = len(self.cache[0]) // n if self.cache is not None else 1
        # with a cache, epoch e uses jitter set (e - 1) mod sets, whose rows start at that index times n
        rows = torch.cat([order + ((epoch - 1) % sets) * n for order, epoch in self.epochs.take(self.batch_size,
                                                                                               generator)])
        rows = rows.to(self.pixels.device)
        pixel = self.keep.index_select(0, rows % n)  # index_select: on the CPU about 3 times as fast as [rows]
        target = self.pixels.index_select(0, pixel)
        if self.cache is None:
            return self.grid.points(pixel, generator), target
        xy, idx, w = self.cache
        return xy.index_select(0, rows), target, (idx.index_select(0, rows), w.index_select(0, rows))


def image_sampler(image, domain, batch_size: int, *, device: str = "cpu", query=None, jitter_sets: int = 8,
                  seed: int = 0, exclude=None) -> Sampler:
    """Stratified sampler over a raster covering ``domain``.

    Each epoch visits every pixel (not excluded) once, in a random order, at one uniformly jittered
    point inside the pixel; the target is that pixel's value (signal space: the model applies its own transform).
    Pixel (i, j) (column i, row j) covers ``[x0 + i·sx, x0 + (i+1)·sx] × [y0 + j·sy, …]`` with
    ``sx = (x1 − x0) / W``, ``sy = (y1 − y0) / H`` (rows go down in y).

    Parameters
    ----------
    image : (H, W, C) float array (or an ``Image``); domain : (x0, y0, x1, y1)
    batch_size : samples per call
    query : optional ``field.query`` (xy (N, 2) → (idx, w)); when given, ``jitter_sets`` epochs of
        jittered points are located once (seeded by ``seed``) and reused in turn, and each call also
        returns the batch's (idx, w) for ``FieldModel.forward(query=...)``. Memory: about 100 bytes
        per pixel and jitter set.
    exclude : optional (H, W) bool, pixels never sampled (e.g. ``edge_pixels(mesh, H, W)``)

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32[, (idx, w)])``
    """
    pixels = check_pixels(image)
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    if not isinstance(jitter_sets, int) or jitter_sets < 1:
        raise ValueError(f"jitter_sets must be a positive integer, got {jitter_sets!r}")
    x0, y0, x1, y1 = (float(v) for v in domain)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"domain {tuple(domain)} must have x1 > x0 and y1 > y0")
    keep = _kept_pixels(pixels.shape[0], pixels.shape[1], exclude)
    generator = torch.Generator().manual_seed(seed)
    return _StratifiedPixels(torch.from_numpy(pixels).to(device), (x0, y0, x1, y1), batch_size, query, jitter_sets,
                             generator, keep)


class _ShuffledPoints:
    """Stateful sampler: every sample once per epoch, in a fresh random order (the fit's generator)."""

    def __init__(self, xy: Tensor, values: Tensor, batch_size: int, cache):
        self.xy, self.values, self.batch_size, self.cache = xy, values, batch_size, cache
        self.epochs = _Epochs(len(xy))

    def __call__(self, step: int, generator: torch.Generator):
        rows = torch.cat([order for order, _ in self.epochs.take(self.batch_size, generator)]).to(self.xy.device)
        xy, values = self.xy.index_select(0, rows), self.values.index_select(0, rows)
        if self.cache is None:
            return xy, values
        idx, w = self.cache
        return xy, values, (idx.index_select(0, rows), w.index_select(0, rows))


def point_sampler(xy, values, batch_size: int, *, device: str = "cpu", query=None) -> Sampler:
    """Sampler over scattered samples, e.g. walk-on-spheres estimates (``dfc.io.samples.SampleSet``).

    Each epoch visits every sample once, in a random order drawn from the generator ``fit`` hands it; the
    target is the sample's value as given (noisy values and repeated positions are fine: the MSE fit
    averages them).

    Parameters
    ----------
    xy : (N, 2) float positions in domain units; values : (N, C) float targets (signal space)
    batch_size : samples per call
    query : optional ``field.query``; when given, every sample is located once here and each call also
        returns the batch's (idx, w) for ``FieldModel.forward(query=...)`` (about 100 bytes per sample)

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32[, (idx, w)])``
    """
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    xy = torch.as_tensor(np.ascontiguousarray(xy, dtype=np.float64)).to(device)
    values = torch.as_tensor(np.ascontiguousarray(values, dtype=np.float32)).to(device)
    if xy.ndim != 2 or xy.shape[1] != 2 or values.ndim != 2 or len(values) != len(xy) or len(xy) == 0:
        raise ValueError(f"expected xy (N, 2) and values (N, C) with N ≥ 1, got {tuple(xy.shape)} and "
                         f"{tuple(values.shape)}")
    cache = None
    if query is not None:
        with torch.no_grad():
            parts = [query(xy[s : s + QUERY_CHUNK]) for s in range(0, len(xy), QUERY_CHUNK)]
        cache = (torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]))
    return _ShuffledPoints(xy, values, batch_size, cache)


class _StratifiedFrames:
    """Stateful sampler: every (frame, pixel) pair once per epoch in a fresh random order, at a jittered point."""

    def __init__(self, frames: Tensor, times: Tensor, domain, batch_size: int, keep: Tensor):
        self.values = frames.reshape(-1, frames.shape[-1])  # row s · H · W + pixel
        self.times = times
        self.keep = keep.to(frames.device)  # (n,) flat pixel indices sampled in every frame
        self.pixels_per_frame = frames.shape[1] * frames.shape[2]
        self.grid = _PixelGrid(domain, frames.shape[2], frames.shape[1], frames.device)
        self.batch_size = batch_size
        self.epochs = _Epochs(frames.shape[0] * len(keep))

    def __call__(self, step: int, generator: torch.Generator):
        rows = torch.cat([order for order, _ in self.epochs.take(self.batch_size, generator)]).to(self.values.device)
        frame, pixel = rows // len(self.keep), self.keep[rows % len(self.keep)]
        xy = self.grid.points(pixel, generator)
        target = self.values[frame * self.pixels_per_frame + pixel]
        return xy, target, {"t": self.times[frame]}


def frame_sampler(frames, times, domain, batch_size: int, *, device: str = "cpu", exclude=None) -> Sampler:
    """Stratified sampler over a frame sequence covering ``domain``: ``image_sampler``'s pixels, in every frame.

    Each epoch visits every (frame, pixel) pair once, in a random order, at a uniformly jittered point in the
    pixel, at the frame's exact time, so each time slice of the field is trained at its own time.

    Parameters
    ----------
    frames : (T, H, W, C) float array; times : (T,) increasing; domain : (x0, y0, x1, y1)
    exclude : optional (H, W) bool, pixels never sampled (in any frame)

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, target (B, C) float32, {"t": (B,) float64})``
    """
    frames = np.ascontiguousarray(frames, dtype=np.float32)
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    keep = _kept_pixels(frames.shape[1], frames.shape[2], exclude)
    return _StratifiedFrames(torch.from_numpy(frames).to(device),
                             torch.as_tensor(np.asarray(times, dtype=np.float64)).to(device),
                             tuple(float(v) for v in domain), batch_size, keep)


class _PhysicsPoints:
    def __init__(self, problem, batch_size: int, device):
        self.problem, self.batch_size, self.device = problem, batch_size, device

    def __call__(self, step: int, generator: torch.Generator):
        xy = self.problem.interior(self.batch_size, generator).to(self.device)
        bxy, target = (v.to(self.device) for v in self.problem.boundary(self.batch_size, generator))
        return xy, bxy, target


def physics_sampler(problem, batch_size: int, *, device="cpu") -> Sampler:
    """Sampler of a physics-informed solve: ``batch_size`` interior points and as many boundary points per step.

    problem : has ``to(device)``, ``interior(n, generator) -> (n, 2)`` and ``boundary(n, generator) -> ((n, 2),
        (n, C))`` tensors drawn on the generator's device (``dfc.physics.solve.SolveProblem``); moved to ``device``

    Returns
    -------
    ``sampler(step, generator) -> (xy (B, 2) float64, boundary xy (B, 2) float64, targets (B, C) float32)``
    """
    return _PhysicsPoints(problem.to(device), batch_size, device)
