"""Tiles of a field model on a deep pixel grid: the Python API behind ``dfc serve`` and ``dfc tiles``.

A file's *tile grid* is the raster it was fitted to (``dfc.render.input_pixel_size``; files without one use the
default render size of ``dfc decode``) refined ``2 ** levels_beyond`` times along each axis: with the default 10
levels a tile grid pixel is 1/1024 of an input pixel, so a viewer zooms 1000× past the input. A *region*
``(x, y, w, h)`` is a rectangle of that grid's pixels (integers or not); ``render_tile`` renders it at any output
size exactly as ``dfc decode --window`` renders the same window at the same size (same pixels, the same default
anti-aliasing of the pixels a curve crosses at or below the input's resolution).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError

__all__ = ["LEVELS_BEYOND", "TILE_SIDE", "TileGrid", "default_time", "encode_tile", "render_tile", "scale_factors",
           "tile_grid"]

LEVELS_BEYOND = 10
"""Default pyramid depth past the input's resolution: 2¹⁰ = 1024 tile grid pixels per input pixel (≥ 1000×)."""
TILE_SIDE = 256
"""Side of a pyramid tile in output pixels."""
FORMATS = ("png", "jpg", "exr")
"""Tile formats: 8-bit sRGB PNG and JPEG, and float32 EXR (the decoded values themselves)."""
JPEG_QUALITY = 90


@dataclass(frozen=True)
class TileGrid:
    """The deep pixel grid of a file.

    domain : (x0, y0, x1, y1) the file's domain, covered exactly by the grid
    width, height : pixels of the grid (the input raster's size times ``scale``)
    scale : grid pixels per input pixel along each axis (``2 ** levels_beyond``)
    """

    domain: tuple[float, float, float, float]
    width: int
    height: int
    scale: int

    def window(self, region) -> tuple[float, float, float, float]:
        """The domain window (x0, y0, x1, y1) of a region (x, y, w, h) in grid pixels."""
        x, y, w, h = (float(v) for v in region)
        d0, e0, d1, e1 = self.domain
        sx, sy = (d1 - d0) / self.width, (e1 - e0) / self.height
        return d0 + x * sx, e0 + y * sy, d0 + (x + w) * sx, e0 + (y + h) * sy

    def to_grid(self, xy) -> tuple[float, float]:
        """A domain point (x, y) in grid pixel coordinates."""
        d0, e0, d1, e1 = self.domain
        return ((xy[0] - d0) * self.width / (d1 - d0), (xy[1] - e0) * self.height / (e1 - e0))


def tile_grid(model, levels_beyond: int = LEVELS_BEYOND) -> TileGrid:
    """The ``TileGrid`` of ``model`` refined ``2 ** levels_beyond`` times (0 ≤ levels_beyond ≤ 20; the grid's
    sides stay below 2⁵³ so its pixel coordinates are exact floats)."""
    from .render import default_size
    from .render import input_pixel_size

    if not 0 <= levels_beyond <= 20:
        raise InputError(f"levels beyond the input must be in 0..20, got {levels_beyond}")
    domain = tuple(float(v) for v in model.field.mesh.domain)
    pixel = input_pixel_size(model)
    if pixel is None:
        base = default_size(domain, domain)
    else:
        base = (max(1, round((domain[2] - domain[0]) / pixel[0])), max(1, round((domain[3] - domain[1]) / pixel[1])))
    scale = 2 ** levels_beyond
    return TileGrid(domain, base[0] * scale, base[1] * scale, scale)


def scale_factors(grid: TileGrid, tile: int = TILE_SIDE) -> list[int]:
    """Powers of two 1, 2, 4, … of the pyramid's levels: down to the level whose whole image fits in one tile
    (and at least down to the input's resolution)."""
    longest = max(grid.width, grid.height)
    top = max(math.ceil(math.log2(longest / tile)) if longest > tile else 0, round(math.log2(grid.scale)))
    return [2 ** k for k in range(top + 1)]


def default_time(model) -> float | None:
    """The time ``dfc decode`` renders a file at by default: the first of a time-varying file's times, else None."""
    times = model.config()["times"]
    return None if times is None else float(times[0])


def render_tile(model, region, size: tuple[int, int], *, grid: TileGrid | None = None, spp: int = 1,
                edge_spp: int | None = None, t: float | None = None) -> np.ndarray:
    """Pixels (h, w, C) float32 of ``region`` (x, y, w, h in ``grid`` pixels; default grid ``tile_grid(model)``)
    rendered at ``size`` (w, h) and time ``t`` (default ``default_time``): the render ``dfc decode --window`` makes
    of the same window at the same size.

    edge_spp : points averaged in the pixels a curve crosses; default ``dfc.render.default_edge_spp`` (anti-aliased
        at or below the input's resolution, as dfc decode does)
    Raises ``InputError`` for an empty region or size.
    """
    from .render import default_edge_spp, render

    width, height = (int(v) for v in size)
    if width < 1 or height < 1:
        raise InputError(f"tile size must be at least 1x1, got {width}x{height}")
    if not (float(region[2]) > 0 and float(region[3]) > 0):
        raise InputError(f"region {tuple(region)} is empty")
    window = (grid or tile_grid(model)).window(region)
    if edge_spp is None:
        edge_spp = default_edge_spp(model, width, height, window)
    return render(model, width, height, window, spp=spp, edge_spp=edge_spp, t=default_time(model) if t is None else t)


def encode_tile(pixels: np.ndarray, fmt: str, *, hdr: bool = False, channels: list[str] | None = None) -> bytes:
    """(h, w, C) linear float pixels → the bytes of an 8-bit sRGB PNG or JPEG (HDR values tone-mapped as ``dfc
    decode`` does for PNG; JPEG drops alpha; more than 4 channels are refused) or of a float32 EXR of the values
    themselves, its channels named ``channels`` (default R, G, B, A or Y for 1 to 4, else c0, c1, …)."""
    from PIL import Image as PILImage

    from .io.image import display8

    if fmt not in FORMATS:
        raise InputError(f"tile format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    n = pixels.shape[2]
    if fmt == "exr":
        return _exr_bytes(pixels, channels or _CHANNELS.get(n, [f"c{k}" for k in range(n)]))
    if n > 4:
        raise InputError(f"8-bit tiles hold 1 to 4 channels; this file has {n}: ask for exr")
    out = display8(pixels, hdr)
    if fmt == "jpg" and n in (2, 4):
        out = out[..., :-1]
    mode = {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}[out.shape[2]]
    buf = io.BytesIO()
    image = PILImage.fromarray(out[..., 0] if mode == "L" else out, mode)
    if fmt == "jpg":
        image.save(buf, format="JPEG", quality=JPEG_QUALITY)
    else:
        image.save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


_CHANNELS = {1: ["Y"], 2: ["Y", "A"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}


def _exr_bytes(pixels: np.ndarray, channels: list[str]) -> bytes:
    """A float32 ZIP EXR of ``pixels`` (OpenEXR writes files: through a temporary one)."""
    import tempfile
    from pathlib import Path

    from .io.image import write_exr

    with tempfile.TemporaryDirectory(prefix="dfc-tile-") as tmp:
        path = Path(tmp) / "tile.exr"
        write_exr(path, pixels, list(channels), half=False)
        return path.read_bytes()
