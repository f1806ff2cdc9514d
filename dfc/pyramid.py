"""Static tile pyramids of a field model that any static web host and deep-zoom viewer can serve (``dfc tiles``):
IIIF Image API 3.0 level 0 (``info.json`` plus one file per tile, at the URLs OpenSeadragon and other clients ask
for) or Deep Zoom (``NAME.dzi`` plus ``NAME_files/LEVEL/COL_ROW.png``). Tiles come from ``dfc.tiles.render_tile``,
so they hold the pixels ``dfc serve`` sends for the same requests.

Layouts, for a ``W × H`` tile grid (``dfc.tiles.tile_grid``) and tiles of side ``T``:

- IIIF: for each scale factor ``s`` (``dfc.tiles.scale_factors``) the level's image is ``ceil(W / s) × ceil(H / s)``;
  its tile (i, j) covers the grid pixels ``x = i·T·s``, ``y = j·T·s``, ``w = min(T·s, W − x)``, ``h`` alike, and is
  written at ``x,y,w,h/tw,th/0/default.png`` (``full/…`` when it covers the whole image; size ``max`` at ``s = 1``);
- Deep Zoom: level ``L`` of ``0 … ceil(log2(max(W, H)))`` is the image scaled by ``2^(L − top)``, cut into ``T``
  tiles without overlap.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from .errors import InputError
from .tiles import TILE_SIDE, TileGrid, encode_tile, render_tile, scale_factors

__all__ = ["FORMATS", "count_tiles", "dzi_tiles", "iiif_tiles", "write_pyramid"]

FORMATS = ("iiif", "dzi")


def iiif_tiles(grid: TileGrid, tile: int = TILE_SIDE):
    """Yield (relative path without extension, region (x, y, w, h) in grid pixels, size (w, h)) of every IIIF tile."""
    for s in scale_factors(grid, tile):
        level_w, level_h = math.ceil(grid.width / s), math.ceil(grid.height / s)
        span = tile * s
        for j in range(math.ceil(level_h / tile)):
            for i in range(math.ceil(level_w / tile)):
                x, y = i * span, j * span
                w, h = min(span, grid.width - x), min(span, grid.height - y)
                tw, th = min(tile, level_w - i * tile), min(tile, level_h - j * tile)
                whole = (w, h) == (grid.width, grid.height)
                region = "full" if whole else f"{x},{y},{w},{h}"
                size = "max" if (tw, th) == (grid.width, grid.height) else f"{tw},{th}"
                yield f"{region}/{size}/0/default", (x, y, w, h), (tw, th)


def dzi_tiles(grid: TileGrid, tile: int = TILE_SIDE):
    """Yield (relative path without extension, region, size) of every Deep Zoom tile (overlap 0)."""
    top = math.ceil(math.log2(max(grid.width, grid.height)))
    for level in range(top + 1):
        s = 2 ** (top - level)
        level_w, level_h = math.ceil(grid.width / s), math.ceil(grid.height / s)
        for j in range(math.ceil(level_h / tile)):
            for i in range(math.ceil(level_w / tile)):
                tw, th = min(tile, level_w - i * tile), min(tile, level_h - j * tile)
                # the level's pixel (c, r) covers grid pixels [c·W/level_w, (c+1)·W/level_w) (exact at s = 1)
                sx, sy = grid.width / level_w, grid.height / level_h
                region = (i * tile * sx, j * tile * sy, tw * sx, th * sy)
                yield f"{level}/{i}_{j}", region, (tw, th)


def count_tiles(grid: TileGrid, fmt: str, tile: int = TILE_SIDE) -> int:
    """Number of tiles ``write_pyramid`` writes."""
    return sum(1 for _ in (iiif_tiles(grid, tile) if fmt == "iiif" else dzi_tiles(grid, tile)))


def write_pyramid(model, directory, grid: TileGrid, *, fmt: str = "iiif", name: str = "image",
                  base_url: str | None = None, tile_format: str = "png", callback=None) -> int:
    """Write the pyramid of ``model`` on ``grid`` into ``directory`` (created; existing tiles replaced) and return the
    number of tiles.

    fmt : "iiif" (``info.json`` whose ``id`` is ``base_url``, default ``name``: a URL relative to the page that shows
        it) or "dzi" (``NAME.dzi`` and ``NAME_files/``)
    tile_format : "png" or "jpg"; callback : ``callback(done, total)`` after each tile
    Raises ``InputError`` for an unknown ``fmt``.
    """
    from .io.atomic import write_bytes_atomic
    from .render_file import is_hdr

    if fmt not in FORMATS:
        raise InputError(f"pyramid format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    root = Path(directory)
    hdr = is_hdr(model)
    if fmt == "iiif":
        from .serve.iiif import info

        tiles = list(iiif_tiles(grid))
        folder = root
        doc = info(base_url or name, grid.width, grid.height, scale_factors(grid), TILE_SIDE, level0=True)
        doc["preferredFormats"] = doc["extraFormats"] = [tile_format]
        index = ("info.json", json.dumps(doc, indent=1) + "\n")
    else:
        tiles = list(dzi_tiles(grid))
        folder = root / f"{name}_files"
        index = (f"{name}.dzi", ('<?xml version="1.0" encoding="UTF-8"?>\n'
                                 f'<Image xmlns="http://schemas.microsoft.com/deepzoom/2008" Format="{tile_format}" '
                                 f'Overlap="0" TileSize="{TILE_SIDE}">\n'
                                 f'  <Size Width="{grid.width}" Height="{grid.height}"/>\n</Image>\n'))
    for k, (path, region, size) in enumerate(tiles):
        target = folder / f"{path}.{tile_format}"
        os.makedirs(target.parent, exist_ok=True)
        pixels = render_tile(model, region, size, grid=grid)
        write_bytes_atomic(target, encode_tile(pixels, tile_format, hdr=hdr, channels=list(model.channels)))
        if callback is not None:
            callback(k + 1, len(tiles))
    write_bytes_atomic(root / index[0], index[1].encode())  # last: a pyramid with an index is complete
    return len(tiles)
