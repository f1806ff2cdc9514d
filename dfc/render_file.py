"""Rendering a field model into an image file region by region, optionally in worker processes (docs/design.md §10).

Large EXR outputs (more than ``TILED_PIXELS`` pixels, or wider than a scanline file here takes) are written as tiled
EXR, tile by tile (``dfc.io.tiled``); smaller EXR outputs and PNG as scanline files in row blocks (``dfc.io.image``). Each region — a tile, or a block
of whole rows — is rendered by ``dfc.render.render_region``, so its pixels do not depend on who renders it: with
``workers > 1`` the regions go to that many processes (each loads the file itself, on its own device from
``devices`` in turn, e.g. one GPU each) and come back in order to the one writer; tiles come back compressed.
At most ``2 × workers`` regions are in flight, so memory stays bounded for any output size.
"""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from .errors import DfcError, InputError
from .io.bands import MAX_BAND_SIDE
from .io.image import MAX_IMAGE_SIDE, ExrBlockWriter, PngBlockWriter
from .io.tiled import ExrTileWriter, tile_chunk
from .render import MAX_POINTS, render_region

__all__ = ["TILED_PIXELS", "is_hdr", "write_render"]

TILED_PIXELS = 1 << 24
"""EXR outputs with more pixels than this (4096²) are written tiled."""


def is_hdr(model) -> bool:
    """HDR files (log transform, or an HDR input recorded by the encoder) are tone-mapped into PNG."""
    encoder = getattr(model, "header", {}).get("encoder", {})
    return model.transform == "log" or encoder.get("hdr") is True


def write_render(model, output: str, size: tuple[int, int], window, *, spp: int = 1, half: bool = True, t=None,
                 workers: int = 1, source=None, devices: list[str] | None = None, callback=None,
                 tiled: bool | None = None, edge_spp: int = 0, pixel_filter: str | None = None) -> str:
    """Render ``window`` of ``model`` at ``size`` (width, height) into ``output`` (.exr or .png); return the layout
    written: ``"tiled"`` or ``"scanline"``.

    tiled : EXR layout; None chooses tiled above ``TILED_PIXELS`` pixels or ``MAX_IMAGE_SIDE`` columns (PNG: never)

    workers : processes rendering regions (1: this process, with ``model``); more need ``source``, the ``.dfield``
        path each worker loads, on ``devices`` in turn (default ``["cpu"]``)
    callback : ``callback(done, total)`` after each region written
    edge_spp : points averaged in the pixels a discontinuity crosses (``dfc.render.render_region``)
    pixel_filter : spec string of the output's pixel filter, instead of ``edge_spp`` (``dfc.render.render_region``)
    Raises ``InputError`` for sizes a format cannot hold, ``DfcError`` when a worker dies.
    """
    width, height = size
    png = str(output).lower().endswith(".png")
    limit = MAX_IMAGE_SIDE if png else MAX_BAND_SIDE
    if not (1 <= width <= limit and 1 <= height <= limit):
        hint = f"; write .exr for larger renders (tiled, up to {MAX_BAND_SIDE} per side)" if png else ""
        raise InputError(f"{width}x{height}: {'PNG' if png else 'EXR'} output is limited to {limit} pixels per side{hint}")
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if workers > 1 and source is None:
        raise ValueError("workers > 1 need the .dfield path (source) to load in each worker")
    channels = model.channels
    if tiled is None:
        tiled = width * height > TILED_PIXELS or width > MAX_IMAGE_SIDE
    tiled = tiled and not png
    spec = (width, height, tuple(float(v) for v in window), spp, t, half, edge_spp, pixel_filter)
    if tiled:
        writer = ExrTileWriter(output, width, height, channels, half=half)
        regions = [(ty, tx, y0, y1, x0, x1) for tx, ty, x0, y0, x1, y1 in writer.tiles()]
        spec += (writer.order,)
    else:
        if png:
            if len(channels) > 4:
                raise InputError(f"PNG holds 1 to 4 channels; this file has {len(channels)}: write .exr")
            writer = PngBlockWriter(output, width, height, len(channels), hdr=is_hdr(model))
        else:
            writer = ExrBlockWriter(output, width, height, channels, half=half)
        rows = max(1, min(height, MAX_POINTS // (width * spp)))
        regions = [(y0, 0, y0, min(height, y0 + rows), 0, width) for y0 in range(0, height, rows)]
    with writer:
        for k, (region, result) in enumerate(_regions(model, spec, regions, workers, source, devices)):
            if tiled:
                writer.write_tile(region[1], region[0], result)
            else:
                writer.write_rows(region[2], result)
            if callback is not None:
                callback(k + 1, len(regions))
    return "tiled" if tiled else "scanline"


def _render(model, spec, region, mixed):
    """One region's result: compressed tile data (tiled spec) or the rows' pixels (h, width, C) float32.
    ``mixed``: the render's ``EdgeMask`` (``_edge_mask``)."""
    width, height, window, spp, t, half, edge_spp, pixel_filter, *order = spec
    _, _, y0, y1, x0, x1 = region
    block = render_region(model, width, height, window, rows=(y0, y1), cols=(x0, x1), spp=spp, t=t,
                          edge_spp=edge_spp, mixed=mixed, pixel_filter=pixel_filter)
    return tile_chunk(block, order[0], half) if order else block


def _edge_mask(model, spec):
    """The ``EdgeMask`` of ``spec``'s raster when it anti-aliases (built once per render and process, not once per
    region), else None."""
    from .geometry.pixels import EdgeMask

    width, height, window, spp, _, _, edge_spp, pixel_filter, *_ = spec
    blends = pixel_filter is not None and pixel_filter != "point" or pixel_filter is None and edge_spp > spp
    return EdgeMask(model.field.mesh, height, width, window) if blends else None


_MODEL = None
"""The model a worker process renders (``_start_worker``)."""
_MASK = None
"""(spec, ``_edge_mask``) of the render in progress in a worker process."""


def _start_worker(source: str, devices, threads: int) -> None:
    import torch

    from .io.dfield import load

    global _MODEL
    torch.set_num_threads(threads)
    _MODEL = load(source, device=devices.get())


def _work(spec, region):
    global _MASK
    if _MASK is None or _MASK[0] != spec:
        _MASK = (spec, _edge_mask(_MODEL, spec))
    return _render(_MODEL, spec, region, _MASK[1])


def _regions(model, spec, regions, workers: int, source, devices):
    """Yield (region, result) in order; with workers, at most ``2 × workers`` regions in flight."""
    if workers == 1:
        mixed = _edge_mask(model, spec)
        for region in regions:
            yield region, _render(model, spec, region, mixed)
        return
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    for k in range(workers):
        queue.put((devices or ["cpu"])[k % len(devices or ["cpu"])])
    threads = max(1, (os.cpu_count() or 1) // workers)
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker,
                               initargs=(str(source), queue, threads))
    pending: deque = deque()
    try:
        todo = iter(regions)
        for region in todo:
            pending.append((region, pool.submit(_work, spec, region)))
            if len(pending) >= 2 * workers:
                region, future = pending.popleft()
                yield region, future.result()
        while pending:
            region, future = pending.popleft()
            yield region, future.result()
    except BrokenProcessPool as e:
        raise DfcError(f"a render worker died ({e}); nothing was written") from None
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

