"""Tiled OpenEXR output written tile by tile, for renders too large to hold (docs/design.md §10).

``ExrTileWriter`` writes a single-part tiled file (ONE_LEVEL, ZIP, tiles of ``tile × tile`` pixels, INCREASING_Y
order: tiles row by row, left to right), from the OpenEXR file-layout specification as ``ExrBlockWriter`` writes
scanline files: magic and header (with the ``tiles`` attribute and the single-part-tiled version flag 0x200), the
tile offset table, then per tile ``tileX, tileY, levelX, levelY, size`` (int32) and its data — per scanline of the
tile, per channel sorted by name, the tile's values — ZIP-compressed like a scanline block (``exr_zip_block``).

Tiles are compressed by ``tile_chunk``, a plain function, so that worker processes can render and compress tiles
while one writer puts them in place. Memory: the offset table (8 bytes per tile) and the chunk being written.
The file appears only when complete (``dfc.io.atomic``); a missing tile is an error on closing.
"""

from __future__ import annotations

import struct

import numpy as np

from .atomic import atomic_path
from .bands import MAX_BAND_SIDE
from .image import exr_header_bytes, exr_zip_block

__all__ = ["TILE", "ExrTileWriter", "tile_chunk"]

TILE = 256
"""Default tile side in pixels."""


def tile_chunk(block: np.ndarray, order: list[int], half: bool) -> bytes:
    """The compressed data of one tile: block (h, w, C) float values, ``order`` the file's channel order."""
    return exr_zip_block(np.asarray(block, dtype=np.float32), order, np.dtype("<f2" if half else "<f4"))


class ExrTileWriter:
    """A tiled EXR of ``width × height`` pixels with ``channels``, half or float, written atomically.

    >>> with ExrTileWriter("big.exr", 65536, 65536, ["R", "G", "B"]) as w:       # doctest: +SKIP
    ...     for tx, ty, x0, y0, x1, y1 in w.tiles():                               # row by row
    ...         w.write_tile(tx, ty, tile_chunk(render(x0, y0, x1, y1), w.order, w.half))
    """

    def __init__(self, path, width: int, height: int, channels: list[str], *, half: bool = True, tile: int = TILE):
        for name, v in (("width", width), ("height", height)):
            if not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_BAND_SIDE:
                raise ValueError(f"{name} must be an integer in 1..{MAX_BAND_SIDE}, got {v!r}")
        if not isinstance(tile, int) or tile < 1:
            raise ValueError(f"tile must be a positive integer, got {tile!r}")
        self.path, self.width, self.height, self.tile = path, int(width), int(height), tile
        self.channels, self.half = [str(c) for c in channels], half
        if not self.channels or len(set(self.channels)) != len(self.channels):
            raise ValueError(f"need unique channel names, got {channels!r}")
        self.order = sorted(range(len(self.channels)), key=lambda k: self.channels[k].encode())
        self.nx, self.ny = -(-self.width // tile), -(-self.height // tile)
        self._offsets = np.zeros(self.nx * self.ny, dtype="<u8")
        self._next = 0
        self._atomic = self._file = None

    def tiles(self) -> list[tuple[int, int, int, int, int, int]]:
        """Every tile in file order: (tile x, tile y, x0, y0, x1, y1), pixels ``[x0, x1) × [y0, y1)``."""
        t = self.tile
        return [(tx, ty, tx * t, ty * t, min(self.width, (tx + 1) * t), min(self.height, (ty + 1) * t))
                for ty in range(self.ny) for tx in range(self.nx)]

    def __enter__(self):
        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        try:
            self._file = open(tmp, "wb")
            tiles = struct.pack("<IIB", self.tile, self.tile, 0)  # ONE_LEVEL, ROUND_DOWN
            self._file.write(exr_header_bytes(self.width, self.height, self.channels, self.order, self.half,
                                              [("tiles", "tiledesc", tiles)], flags=0x200))
            self._table_at = self._file.tell()
            self._file.write(self._offsets.tobytes())  # placeholder, rewritten on closing
        except BaseException as e:
            self._close(type(e), e, e.__traceback__)
            raise
        return self

    def write_tile(self, tx: int, ty: int, data: bytes) -> None:
        """Append tile (tx, ty), the next in file order, with its ``tile_chunk`` data."""
        if self._file is None:
            raise ValueError("write_tile must be called inside the writer's `with` block")
        if ty * self.nx + tx != self._next or not (0 <= tx < self.nx and 0 <= ty < self.ny):
            raise ValueError(f"tiles must be written in order: expected tile {self._next}, got ({tx}, {ty})")
        self._offsets[self._next] = self._file.tell()
        self._file.write(struct.pack("<iiiii", tx, ty, 0, 0, len(data)) + data)
        self._next += 1

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None and self._next != len(self._offsets):
            exc = ValueError(f"only {self._next} of {len(self._offsets)} tiles were written to {self.path}")
            self._close(ValueError, exc, None)
            raise exc
        if exc_type is None:
            self._file.seek(self._table_at)
            self._file.write(self._offsets.tobytes())
        return self._close(exc_type, exc, tb)

    def _close(self, exc_type, exc, tb):
        if self._file is not None:
            self._file.close()
            self._file = None
        atomic, self._atomic = self._atomic, None
        return atomic.__exit__(exc_type, exc, tb) if atomic is not None else False
