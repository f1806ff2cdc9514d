"""Out-of-core rasters: images read in bands of rows, never whole (docs/design.md §10).

A *band source* has ``width``, ``height``, ``channels`` (names) and ``rows(y0, y1) -> (y1 - y0, W, C) float32``,
rows going down in y (``spec/conventions.md``). ``ExrBands`` reads an OpenEXR file that way, scanline or tiled and
any compression, through OpenEXR's ``InputFile``, which decodes only the chunks (scanline blocks or tiles) the rows
touch; ``ArrayBands`` serves an array already in memory; ``MappedBands`` serves another source's rows normalised by a
``dfc.field.units.ValueMap`` (the units an encode fits in). ``band_ranges`` cuts the rows into bands aligned with the
file's chunks, so that no chunk is decoded twice in one pass.

Checks, each an ``InputError`` naming the file: damaged or truncated files (OpenEXR's ``isComplete`` at open, and any
failure of a read later — OpenEXR's own messages on its C stderr are caught and put into the error line), deep or
subsampled data, sizes above ``MAX_BAND_SIDE``, NaN or infinite pixels (row, column and channel of the first).

Memory: one band of float32 values and OpenEXR's buffers for the chunks it touches (measured: a 16384-wide half RGB
band of 64 rows reads in under 40 MB of process memory beyond the band).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .image import read_exr_header

__all__ = ["BAND_BYTES", "MAX_BAND_SIDE", "ArrayBands", "ExrBands", "MappedBands", "band_ranges", "open_bands"]

MAX_BAND_SIDE = 1 << 20
"""Largest width or height read in bands (pixels); whole-image reads stop at ``dfc.io.image.MAX_IMAGE_SIDE``."""
BAND_BYTES = 1 << 24
"""Target size of one band of float32 values: rows per band = this / (width · channels · 4), rounded to chunks."""

_LINES_PER_CHUNK = {"NO_COMPRESSION": 1, "RLE_COMPRESSION": 1, "ZIPS_COMPRESSION": 1, "ZIP_COMPRESSION": 16,
                    "PIZ_COMPRESSION": 32, "PXR24_COMPRESSION": 16, "B44_COMPRESSION": 32, "B44A_COMPRESSION": 32,
                    "DWAA_COMPRESSION": 32, "DWAB_COMPRESSION": 256, "HTJ2K256_COMPRESSION": 256,
                    "HTJ2K32_COMPRESSION": 32}
"""Scanlines per chunk of each compression (OpenEXR file layout); unknown ones count as 32."""


def default_channel_names(names: list[str]) -> list[str]:
    """The channels read when none are asked for: R, G, B (and A) when present, else all of ``names`` in order."""
    if {"R", "G", "B"} <= set(names):
        return ["R", "G", "B"] + (["A"] if "A" in names else [])
    return list(names)


def band_ranges(height: int, rows: int) -> list[tuple[int, int]]:
    """Row ranges ``[(y0, y1), …]`` of ``rows`` rows each (the last one shorter) covering ``0 .. height``."""
    return [(y0, min(height, y0 + rows)) for y0 in range(0, height, rows)]


class ArrayBands:
    """A band source over pixels already in memory: (H, W, C) float32 with channel names."""

    def __init__(self, pixels: np.ndarray, channels: list[str]):
        self.pixels = np.asarray(pixels, dtype=np.float32)
        if self.pixels.ndim != 3 or len(channels) != self.pixels.shape[2]:
            raise ValueError(f"expected pixels (H, W, C) and C channel names, got {self.pixels.shape} and {channels}")
        self.height, self.width = self.pixels.shape[:2]
        self.channels = list(channels)
        self.chunk_rows = 1
        self.source = "array"

    def rows(self, y0: int, y1: int) -> np.ndarray:
        """(y1 - y0, W, C) float32: rows y0 .. y1 - 1."""
        return self.pixels[y0:y1]

    def band_rows(self, target_bytes: int = BAND_BYTES) -> int:
        return max(1, target_bytes // (self.width * len(self.channels) * 4))


class MappedBands:
    """The band source ``source`` with its values normalised by ``value_map`` (``ValueMap.normalise``, float32)."""

    def __init__(self, source, value_map):
        self.base, self.value_map = source, value_map
        self.width, self.height, self.channels = source.width, source.height, list(source.channels)
        self.chunk_rows, self.source = getattr(source, "chunk_rows", 1), getattr(source, "source", "")

    def rows(self, y0: int, y1: int) -> np.ndarray:
        """(y1 - y0, W, C) float32: rows y0 .. y1 - 1, normalised."""
        return self.value_map.normalise(self.base.rows(y0, y1))

    def band_rows(self, target_bytes: int = BAND_BYTES) -> int:
        return self.base.band_rows(target_bytes)


class ExrBands:
    """An OpenEXR file read in bands of rows of its display window (pixels outside the data window are 0).

    path : the file; channels : names to read, in this order (default ``default_channel_names``).
    Attributes: ``width``, ``height``, ``channels``, ``chunk_rows`` (rows OpenEXR decodes together: the
    compression's scanlines per chunk, or the tile height), ``tiled``, ``compression`` (its name), ``source``.
    """

    def __init__(self, path, channels: list[str] | None = None):
        import Imath
        import OpenEXR

        self.path = Path(path)
        self.source = str(self.path)
        if not self.path.is_file():
            raise InputError(f"{path}: no such image file")
        read_exr_header(self.path)  # refuses damaged headers that crash ``InputFile``
        try:
            with _c_stderr() as noise:
                self._file = OpenEXR.InputFile(str(self.path))
                header = self._file.header()
                complete = self._file.isComplete()
        except Exception as e:  # noqa: BLE001 — the bindings raise OSError, RuntimeError, ValueError, ...
            raise InputError(f"{path}: not a readable OpenEXR file ({_reason(e, noise)})") from None
        if not complete:
            raise InputError(f"{path}: the OpenEXR file is truncated or incomplete (some pixel chunks are missing)")
        kind = str(header.get("type", b"scanlineimage"))
        if "deep" in kind:
            raise InputError(f"{path}: deep OpenEXR images are not images of values")
        data, display = header["dataWindow"], header["displayWindow"]
        self._data = (data.min.x, data.min.y, data.max.x, data.max.y)
        self._display = (display.min.x, display.min.y, display.max.x, display.max.y)
        self.width = display.max.x - display.min.x + 1
        self.height = display.max.y - display.min.y + 1
        for w, h in ((self.width, self.height), (data.max.x - data.min.x + 1, data.max.y - data.min.y + 1)):
            if not (1 <= w <= MAX_BAND_SIDE and 1 <= h <= MAX_BAND_SIDE):
                raise InputError(f"{path}: image size {w} × {h} is outside the supported range "
                                 f"(1..{MAX_BAND_SIDE} per side)")
        file_channels = header["channels"]
        names = [str(c) for c in file_channels]
        sub = [n for n, c in file_channels.items() if (c.xSampling, c.ySampling) != (1, 1)]
        if sub:
            raise InputError(f"{path}: subsampled channels {sub} are not supported")
        if not names:
            raise InputError(f"{path}: the EXR file has no channels")
        want = default_channel_names(names) if channels is None else [str(c) for c in channels]
        missing = [c for c in want if c not in names]
        if missing or not want:
            raise InputError(f"{path}: channel(s) {missing or want} not in the file, which has {names}")
        self.channels = want
        self.compression = str(header["compression"]).split(".")[-1]
        tiles = header.get("tiles")
        self.tiled = tiles is not None
        self.chunk_rows = int(tiles.ySize) if self.tiled else _LINES_PER_CHUNK.get(self.compression, 32)
        self._float = Imath.PixelType(Imath.PixelType.FLOAT)

    def band_rows(self, target_bytes: int = BAND_BYTES) -> int:
        """Rows per band: about ``target_bytes`` of float32 values, a whole number of the file's chunks."""
        rows = max(1, target_bytes // (self.width * len(self.channels) * 4))
        return max(self.chunk_rows, rows // self.chunk_rows * self.chunk_rows)

    def rows(self, y0: int, y1: int) -> np.ndarray:
        """(y1 - y0, W, C) float32: display-window rows y0 .. y1 - 1. ``InputError`` on a damaged chunk or a
        NaN / infinite value."""
        if not 0 <= y0 < y1 <= self.height:
            raise ValueError(f"rows {y0}..{y1} outside 0..{self.height}")
        out = np.zeros((y1 - y0, self.width, len(self.channels)), dtype=np.float32)
        dx0, dy0, dx1, dy1 = self._data
        wx0, wy0, _, _ = self._display
        r0, r1 = max(y0 + wy0, dy0), min(y1 - 1 + wy0, dy1)  # file rows of the data window, inclusive
        c0, c1 = max(wx0, dx0), min(wx0 + self.width - 1, dx1)
        if r0 <= r1 and c0 <= c1:
            try:
                with _c_stderr() as noise:
                    planes = self._file.channels(self.channels, self._float, r0, r1)
            except Exception as e:  # noqa: BLE001 — a damaged chunk: any failure of the bindings
                raise InputError(f"{self.path}: damaged OpenEXR data in rows {r0 - wy0}..{r1 - wy0} "
                                 f"({_reason(e, noise)})") from None
            for k, plane in enumerate(planes):
                block = np.frombuffer(plane, dtype=np.float32).reshape(r1 - r0 + 1, dx1 - dx0 + 1)
                out[r0 - wy0 - y0 : r1 - wy0 - y0 + 1, c0 - wx0 : c1 - wx0 + 1, k] = block[:, c0 - dx0 : c1 - dx0 + 1]
        bad = ~np.isfinite(out)
        if bad.any():
            j, i, c = np.argwhere(bad)[0]
            raise InputError(f"{self.path}: NaN/Inf sample(s) in rows {y0}..{y1 - 1}; the first at row {y0 + j}, "
                             f"column {i}, channel {self.channels[c]!r}")
        return out


def open_bands(path, channels: list[str] | None = None):
    """A band source for an image file: ``ExrBands`` for EXR, else the whole image read into ``ArrayBands``."""
    from .image import read_image
    from .sniff import file_kind

    if file_kind(path) == "exr":
        return ExrBands(path, channels)
    image = read_image(path, channels)
    bands = ArrayBands(image.pixels, image.channels)
    bands.source = str(path)
    return bands


@contextlib.contextmanager
def _c_stderr():
    """Capture what C code writes to file descriptor 2 while the block runs; yields a list that receives the text."""
    captured: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no usable stderr: nothing to capture
        yield captured
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.append(sink.read().decode(errors="replace").strip())


def _reason(exc: Exception, noise: list[str]) -> str:
    """One line: the exception and the last message OpenEXR printed, if any."""
    text = f"{type(exc).__name__}: {exc}"
    last = noise[-1].splitlines()[-1] if noise and noise[-1] else ""
    return f"{text}; {last}" if last else text
