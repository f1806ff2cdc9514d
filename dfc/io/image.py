"""Reading and writing rasters: OpenEXR (linear, HDR) and PNG / JPEG (sRGB, 8/16-bit).

Every reader returns an ``Image`` of linear float32 values, (H, W, C) with rows going down in y
(``spec/conventions.md``), and raises ``InputError`` — never crashes — on unreadable, damaged,
oversized or non-finite input. Writers are atomic (``dfc.io.atomic.atomic_path``).

Transfer functions. PNG/JPEG samples are sRGB-encoded (IEC 61966-2-1): a stored value ``s`` in
[0, 1] decodes to ``s / 12.92`` for ``s ≤ 0.04045`` and ``((s + 0.055) / 1.055) ** 2.4`` above;
writing applies the inverse (``12.92 l`` for ``l ≤ 0.0031308``, ``1.055 l ** (1/2.4) − 0.055``
above) after clipping to [0, 1], then rounds to 8 bits. Alpha channels are linear and never
sRGB-coded. EXR values are stored and returned as they are (scene-linear).

HDR to PNG. ``hdr=True`` applies the Reinhard tone map ``x / (1 + x)`` to colour channels (not
alpha) before sRGB encoding, so unbounded values keep their ordering instead of clipping at 1.

EXR data windows. The returned raster covers the *display window*; the data window's pixels are
placed at their offset inside it, pixels of the display window outside the data window are 0,
and data outside the display window is dropped. Multi-part files: the first part is read.

Damaged EXR files. Measured with the OpenEXR 3.x bindings on the 167 files of the OpenEXR
project's ``damaged/`` regression set: every one raises a Python exception (RuntimeError,
ValueError or UnicodeDecodeError) within milliseconds and small memory; none crashes or hangs, so
files are read in-process. 17 of them make the library print its own messages first (2 to 302 lines on the
process's standard error from C++, and a "Warning: …" line on Python's standard output from the bindings): reading
runs with all of these silenced (``library_output_silenced``), so a damaged file gives only dfc's one error line.
The header is read first (``header_only``) so that absurd sizes, deep data and subsampled channels are refused
before any pixel allocation.

Streaming writers. ``ExrBlockWriter`` and ``PngBlockWriter`` take row blocks in order and keep
only one block in memory, for outputs too large to hold (16384² RGB float32 is 3 GiB). The EXR
writer emits a single-part scanline file with ZIP compression (16 rows per chunk) written here
from the OpenEXR file-layout specification — the OpenEXR 3.x ``File`` API writes whole images
only, and the incremental ``OutputFile`` is deprecated; the PNG writer emits IHDR, one IDAT per
block (zlib stream, filter type 1 "Sub") and IEND. Both read back with OpenEXR / Pillow (tested).
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = [
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE",
    "ExrBlockWriter",
    "Image",
    "PngBlockWriter",
    "exr_header_bytes",
    "exr_zip_block",
    "linear_to_srgb",
    "read_image",
    "srgb_to_linear",
    "tonemap",
    "write_exr",
    "write_png",
]

MAX_IMAGE_SIDE = 1 << 16
"""Largest width or height read or written (pixels)."""
MAX_IMAGE_PIXELS = 1 << 28
"""Largest width × height read (reading allocates 4 bytes per pixel and channel)."""

EXR_EXTENSIONS = (".exr",)
PIL_EXTENSIONS = (".png", ".jpg", ".jpeg")


@dataclass
class Image:
    """A raster of linear values.

    pixels : (H, W, C) float32, row 0 at the top (smallest y)
    channels : C channel names (e.g. ["R", "G", "B"])
    hdr : True when read from EXR (scene-linear, possibly > 1), False for 8/16-bit display images
    """

    pixels: np.ndarray
    channels: list[str]
    hdr: bool

    @property
    def height(self) -> int:
        return self.pixels.shape[0]

    @property
    def width(self) -> int:
        return self.pixels.shape[1]


# -- transfer functions ---------------------------------------------------------------------------
def srgb_to_linear(s: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear, float32, same shape."""
    s = np.asarray(s, dtype=np.float32)
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Linear values → sRGB-encoded values in [0, 1] (clipped first), float32, same shape."""
    v = np.clip(np.asarray(v, dtype=np.float32), 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055).astype(np.float32)


def tonemap(v: np.ndarray) -> np.ndarray:
    """Reinhard tone map ``x / (1 + x)`` of non-negative linear values (negatives clip to 0), float32."""
    v = np.maximum(np.asarray(v, dtype=np.float32), 0.0)
    return v / (1.0 + v)


def display8(pixels: np.ndarray, hdr: bool) -> np.ndarray:
    """(..., C) linear float → (..., C) uint8 display values; the last channel is alpha when C is 2 or 4."""
    n_colour = pixels.shape[-1] - (1 if pixels.shape[-1] in (2, 4) else 0)
    out = np.empty(pixels.shape, dtype=np.uint8)
    colour = pixels[..., :n_colour]
    encoded = linear_to_srgb(tonemap(colour) if hdr else colour)
    out[..., :n_colour] = np.rint(encoded * 255.0)
    out[..., n_colour:] = np.rint(np.clip(pixels[..., n_colour:], 0.0, 1.0) * 255.0)
    return out


# -- reading --------------------------------------------------------------------------------------
def read_image(path, channels: list[str] | None = None) -> Image:
    """Read an EXR, PNG or JPEG file (told by its content, else its extension: ``dfc.io.sniff``) into linear float32.

    Parameters
    ----------
    path : str or PathLike
    channels : names to keep, in this order. Default for EXR: R, G, B (and A) when present, else every
        channel in file order; for PNG/JPEG: Y (grey), Y A, R G B or R G B A by the file's mode.

    Raises
    ------
    InputError
        Missing, unreadable or damaged file; unsupported format, data type or layout; width or
        height above ``MAX_IMAGE_SIDE`` or area above ``MAX_IMAGE_PIXELS``; a requested channel
        absent; NaN or infinite pixels (the message gives their count and the first location).
    """
    from .sniff import IMAGE_KINDS, file_kind

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such image file")
    kind = file_kind(path)
    if kind not in IMAGE_KINDS:
        raise InputError(f"{path}: unsupported image: the content is not EXR, PNG or JPEG, nor is the extension "
                         f"{path.suffix.lower()!r} one of {', '.join(EXR_EXTENSIONS + PIL_EXTENSIONS)}")
    planes, names, hdr = _read_exr(path) if kind == "exr" else _read_pil(path)
    if channels is None:
        want = ["R", "G", "B"] + (["A"] if "A" in names else []) if {"R", "G", "B"} <= set(names) else names
    else:
        want = [str(c) for c in channels]
        missing = [c for c in want if c not in names]
        if missing or not want:
            raise InputError(f"{path}: channel(s) {missing or want} not in the file, which has {names}")
    pixels = np.stack([planes[names.index(c)] for c in want], axis=-1).astype(np.float32, copy=False)
    bad = ~np.isfinite(pixels)
    if bad.any():
        j, i, c = np.argwhere(bad)[0]
        raise InputError(
            f"{path}: {int(bad.sum())} NaN/Inf sample(s); the first at row {j}, column {i}, channel {want[c]!r}"
        )
    return Image(np.ascontiguousarray(pixels), want, hdr)


def _check_size(path: Path, width: int, height: int) -> None:
    if not (1 <= width <= MAX_IMAGE_SIDE and 1 <= height <= MAX_IMAGE_SIDE and width * height <= MAX_IMAGE_PIXELS):
        raise InputError(
            f"{path}: image size {width} × {height} is outside the supported range "
            f"(1..{MAX_IMAGE_SIDE} per side, at most {MAX_IMAGE_PIXELS} pixels)"
        )


@contextlib.contextmanager
def library_output_silenced():
    """Silence the block's output on standard output and error, at both levels: the OpenEXR library prints its own
    messages about damaged files from C/C++ (to file descriptors 1 and 2, pointed at the null device here) and from
    its Python bindings (to ``sys.stdout``, swapped for a discarded buffer), before the bindings raise; dfc reports
    the error in one line of its own."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in (1, 2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in (1, 2):
            os.dup2(null, fd)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            yield
    finally:
        _flush_c_streams()  # what the library buffered goes to the null device, not to the restored streams
        for fd, copy in zip((1, 2), saved):
            os.dup2(copy, fd)
            os.close(copy)
        os.close(null)


def _flush_c_streams() -> None:
    """``fflush(NULL)``: flush the C library's output buffers (C++ streams synchronised with stdio write to them)."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError, TypeError):
        ctypes.CDLL(None).fflush(None)


def read_exr_header(path) -> dict:
    """The header of an OpenEXR file (``OpenEXR.File(header_only=True)``), checked as far as it goes: readable, flat
    (scanline or tiled) storage. Raises ``InputError``. Other readers of a file (``dfc.io.bands``) ask this first:
    older entry points of the bindings crash on some damaged headers that this one refuses."""
    import OpenEXR

    try:
        with library_output_silenced(), OpenEXR.File(str(path), header_only=True) as f:
            header = dict(f.header())
    except Exception as e:  # noqa: BLE001 — the bindings raise RuntimeError, ValueError, UnicodeDecodeError, ...
        raise InputError(f"{path}: not a readable OpenEXR file ({type(e).__name__}: {e})") from None
    missing = [name for name in ("dataWindow", "displayWindow", "channels") if name not in header]
    if missing:
        raise InputError(f"{path}: damaged OpenEXR header (no {', '.join(missing)})")
    storage = header.get("type", OpenEXR.scanlineimage)
    if storage not in (OpenEXR.scanlineimage, OpenEXR.tiledimage):
        raise InputError(f"{path}: unsupported EXR storage {storage} (deep images are not images of values)")
    return header


def _read_exr(path: Path) -> tuple[list[np.ndarray], list[str], bool]:
    import OpenEXR

    header = read_exr_header(path)
    (dx0, dy0), (dx1, dy1) = (np.asarray(v, dtype=np.int64) for v in header["dataWindow"])
    (wx0, wy0), (wx1, wy1) = (np.asarray(v, dtype=np.int64) for v in header["displayWindow"])
    sampling = [(c.name, c.xSampling, c.ySampling) for c in header["channels"]]
    _check_size(path, int(dx1 - dx0 + 1), int(dy1 - dy0 + 1))
    _check_size(path, int(wx1 - wx0 + 1), int(wy1 - wy0 + 1))
    sub = [name for name, sx, sy in sampling if (sx, sy) != (1, 1)]
    if sub:
        raise InputError(f"{path}: subsampled channels {sub} are not supported")
    try:
        with library_output_silenced(), OpenEXR.File(str(path), separate_channels=True) as f:
            data = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as e:  # noqa: BLE001 — as above: any failure of the bindings is a damaged file
        raise InputError(f"{path}: damaged OpenEXR file ({type(e).__name__}: {e})") from None
    height, width = int(wy1 - wy0 + 1), int(wx1 - wx0 + 1)
    shape = (int(dy1 - dy0 + 1), int(dx1 - dx0 + 1))
    # destination and source ranges of the data window clipped to the display window
    ys, ye = max(dy0, wy0), min(dy1, wy1) + 1
    xs, xe = max(dx0, wx0), min(dx1, wx1) + 1
    names, planes = [], []
    for name, arr in data.items():
        if arr.shape != shape or arr.dtype.kind not in "fu":
            raise InputError(f"{path}: channel {name!r} has shape {arr.shape} dtype {arr.dtype}, expected {shape} float")
        plane = np.zeros((height, width), dtype=np.float32)
        if ye > ys and xe > xs:
            plane[ys - wy0 : ye - wy0, xs - wx0 : xe - wx0] = arr[ys - dy0 : ye - dy0, xs - dx0 : xe - dx0]
        names.append(str(name))
        planes.append(plane)
    if not names:
        raise InputError(f"{path}: the EXR file has no channels")
    return planes, names, True


def _read_pil(path: Path) -> tuple[list[np.ndarray], list[str], bool]:
    from PIL import Image as PILImage

    try:
        with PILImage.open(path) as im:
            _check_size(path, *im.size)
            if im.format not in ("PNG", "JPEG"):
                raise InputError(f"{path}: file content is {im.format}, not PNG or JPEG")
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L", "I"):  # 16-bit grey
                grey = np.asarray(im, dtype=np.float64) / 65535.0
                return [srgb_to_linear(grey)], ["Y"], False
            if mode in ("1", "L"):
                im, names = im.convert("L"), ["Y"]
            elif mode in ("LA", "La"):
                im, names = im.convert("LA"), ["Y", "A"]
            elif mode in ("RGBA", "RGBa", "PA") or (mode == "P" and "transparency" in im.info):
                im, names = im.convert("RGBA"), ["R", "G", "B", "A"]
            else:  # RGB, P, CMYK, YCbCr, ...
                im, names = im.convert("RGB"), ["R", "G", "B"]
            arr = np.asarray(im, dtype=np.float32).reshape(im.size[1], im.size[0], len(names)) / 255.0
    except InputError:
        raise
    except PILImage.DecompressionBombError as e:
        raise InputError(f"{path}: image size is outside the supported range ({e})") from None
    except Exception as e:  # noqa: BLE001 — Pillow raises OSError, SyntaxError, ValueError, struct.error, ...
        raise InputError(f"{path}: not a readable PNG/JPEG file ({type(e).__name__}: {e})") from None
    planes = [arr[..., c] if n == "A" else srgb_to_linear(arr[..., c]) for c, n in enumerate(names)]
    return planes, names, False


def check_pixels(image) -> np.ndarray:
    """The (H, W, C) float32 pixels of an ``Image`` or array, checked: C ≥ 1 and every value finite (``InputError``)."""
    pixels = np.ascontiguousarray(getattr(image, "pixels", image), dtype=np.float32)
    if pixels.ndim != 3 or min(pixels.shape) < 1:
        raise InputError(f"expected an image (H, W, C) with H, W, C ≥ 1, got shape {pixels.shape}")
    bad = ~np.isfinite(pixels)
    if bad.any():
        j, i, c = np.argwhere(bad)[0]
        raise InputError(f"image has {int(bad.sum())} NaN/Inf values, the first at row {j}, column {i}, channel {c}")
    return pixels


# -- whole-image writers --------------------------------------------------------------------------
def _check_raster(pixels, channels=None) -> np.ndarray:
    pixels = np.asarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3 or pixels.shape[0] < 1 or pixels.shape[1] < 1 or pixels.shape[2] < 1:
        raise ValueError(f"expected pixels (H, W, C), got shape {pixels.shape}")
    if channels is not None:
        if len(channels) != pixels.shape[2] or len(set(channels)) != len(channels):
            raise ValueError(f"need {pixels.shape[2]} unique channel names, got {list(channels)}")
        for c in channels:
            if not isinstance(c, str) or not c or len(c.encode()) > 255 or "\0" in c:
                raise ValueError(f"invalid EXR channel name {c!r}")
    return pixels


def write_exr(path, pixels, channels: list[str], *, half: bool = True) -> None:
    """Write (H, W, C) linear values as a ZIP-compressed scanline EXR, half or float, atomically."""
    import OpenEXR

    pixels = _check_raster(pixels, channels)
    dtype = np.float16 if half else np.float32
    h, w = pixels.shape[:2]
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "dataWindow": ((0, 0), (w - 1, h - 1)),
        "displayWindow": ((0, 0), (w - 1, h - 1)),
    }
    data = {c: np.ascontiguousarray(pixels[..., k].astype(dtype)) for k, c in enumerate(channels)}
    with atomic_path(path) as tmp, OpenEXR.File(header, data) as f:
        f.write(str(tmp))


def write_png(path, pixels, *, hdr: bool = False) -> None:
    """Write (H, W, C) linear values, C in 1..4 (Y, YA, RGB, RGBA), as an 8-bit sRGB PNG, atomically.

    ``hdr=True`` tone-maps colour channels with ``tonemap`` first (see the module notes).
    """
    from PIL import Image as PILImage

    pixels = _check_raster(pixels)
    mode = _PNG_MODES.get(pixels.shape[2])
    if mode is None:
        raise ValueError(f"PNG needs 1 to 4 channels, got {pixels.shape[2]}")
    out = display8(pixels, hdr)
    with atomic_path(path) as tmp:
        PILImage.fromarray(out[..., 0] if mode == "L" else out, mode).save(tmp, format="PNG")


_PNG_MODES = {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}
_PNG_COLOUR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}


# -- streaming writers ----------------------------------------------------------------------------
class _BlockWriter:
    """Shared machinery: atomic temp file, in-order row blocks, completeness check on exit."""

    def __init__(self, path, width: int, height: int, channels: int):
        for name, v in (("width", width), ("height", height)):
            if not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_IMAGE_SIDE:
                raise ValueError(f"{name} must be an integer in 1..{MAX_IMAGE_SIDE}, got {v!r}")
        self.path, self.width, self.height, self.n_channels = path, int(width), int(height), channels
        self.next_row = 0
        self._stack: contextlib.ExitStack | None = None
        self._file = None

    def __enter__(self):
        with contextlib.ExitStack() as stack:
            tmp = stack.enter_context(atomic_path(self.path))
            self._file = stack.enter_context(open(tmp, "wb"))
            self._start()
            self._stack = stack.pop_all()
        return self

    def __exit__(self, exc_type, exc, tb):
        stack, self._stack = self._stack, None
        if exc_type is not None:  # discard the temporary file, let the exception propagate
            return stack.__exit__(exc_type, exc, tb)
        with stack:
            if self.next_row != self.height:
                raise ValueError(f"only {self.next_row} of {self.height} rows were written to {self.path}")
            self._finish()
        return False

    def write_rows(self, y0: int, block) -> None:
        """Append rows ``y0 .. y0 + h - 1``: block (h, width, C) linear float; y0 must be the next row."""
        if self._stack is None:
            raise ValueError("write_rows must be called inside the writer's `with` block")
        block = np.asarray(block, dtype=np.float32)
        if block.ndim == 2:
            block = block[..., None]
        if block.ndim != 3 or block.shape[1:] != (self.width, self.n_channels):
            raise ValueError(f"expected a block (h, {self.width}, {self.n_channels}), got {block.shape}")
        if y0 != self.next_row or y0 + len(block) > self.height:
            raise ValueError(
                f"rows must be written in order: expected row {self.next_row}, got {y0} (+{len(block)}) of {self.height}"
            )
        self._rows(block)
        self.next_row += len(block)


def exr_zip_block(rows: np.ndarray, order: list[int], dtype: np.dtype) -> bytes:
    """The data of one ZIP-compressed OpenEXR chunk (a scanline block or a tile): rows (h, w, C) float values,
    ``order`` the file's channel order (indices into C, channels sorted by name), ``dtype`` ``<f2`` or ``<f4``.
    Stored uncompressed when compression does not help, as the format allows."""
    # per scanline, per channel in file order, ``w`` little-endian values
    raw = np.ascontiguousarray(rows[:, :, order].transpose(0, 2, 1), dtype=dtype).view(np.uint8).ravel()
    t = np.concatenate([raw[0::2], raw[1::2]])  # OpenEXR's ZIP byte reordering ...
    t[1:] = (t[1:].astype(np.int16) - t[:-1] + 128).astype(np.uint8)  # ... and delta predictor
    packed = zlib.compress(t.tobytes(), 4)
    return packed if len(packed) < len(raw) else raw.tobytes()


def exr_header_bytes(width: int, height: int, channels: list[str], order: list[int], half: bool,
                     extra: list[tuple[str, str, bytes]] = (), flags: int = 0) -> bytes:
    """Magic, version and header attributes of a single-part OpenEXR file with ZIP compression, ``channels`` in file
    ``order``, data and display window ``[0, width) × [0, height)``, ``extra`` attributes (name, type, value) and
    version ``flags`` (e.g. 0x200 for tiles); the long-names flag is added when a name needs it."""
    long_names = any(len(c.encode()) > 31 for c in channels)
    chlist = b"".join(
        channels[k].encode() + b"\0" + struct.pack("<iB3xii", 1 if half else 2, 0, 1, 1) for k in order
    ) + b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    attrs = [
        ("channels", "chlist", chlist),
        ("compression", "compression", bytes([3])),  # ZIP_COMPRESSION
        ("dataWindow", "box2i", box),
        ("displayWindow", "box2i", box),
        ("lineOrder", "lineOrder", b"\0"),
        ("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        ("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
        ("screenWindowWidth", "float", struct.pack("<f", 1.0)),
        *extra,
    ]
    header = struct.pack("<ii", 20000630, 2 | flags | (0x400 if long_names else 0))
    header += b"".join(n.encode() + b"\0" + t.encode() + b"\0" + struct.pack("<i", len(v)) + v for n, t, v in attrs)
    return header + b"\0"


class ExrBlockWriter(_BlockWriter):
    """Streamed scanline EXR (ZIP, 16 rows per chunk, INCREASING_Y), written atomically.

    >>> with ExrBlockWriter("out.exr", 4096, 4096, ["R", "G", "B"]) as w:   # doctest: +SKIP
    ...     for y0, block in blocks:                                            # (h, 4096, 3) each
    ...         w.write_rows(y0, block)

    Memory: one chunk (16 rows) beyond the caller's block. ``half`` selects 16-bit floats.
    """

    ROWS_PER_CHUNK = 16

    def __init__(self, path, width: int, height: int, channels: list[str], *, half: bool = True):
        channels = [str(c) for c in channels]
        super().__init__(path, width, height, len(channels))
        _check_raster(np.zeros((1, 1, len(channels))), channels)
        # the file stores channels sorted by name; self.order maps file position → caller's column
        self.channels, self.half = channels, half
        self.order = sorted(range(len(channels)), key=lambda k: channels[k].encode())
        self.dtype = np.dtype("<f2" if half else "<f4")
        self.n_chunks = -(-self.height // self.ROWS_PER_CHUNK)
        self._pending = np.empty((0, self.width, len(channels)), dtype=np.float32)
        self._offsets = np.zeros(self.n_chunks, dtype="<u8")

    def _start(self) -> None:
        self._file.write(exr_header_bytes(self.width, self.height, self.channels, self.order, self.half))
        self._table_at = self._file.tell()
        self._file.write(self._offsets.tobytes())  # placeholder, rewritten in _finish

    def _rows(self, block: np.ndarray) -> None:
        self._pending = np.concatenate([self._pending, block]) if len(self._pending) else block
        first = self.next_row - (len(self._pending) - len(block))
        n = self.ROWS_PER_CHUNK
        full = len(self._pending) // n * n
        if self.next_row + len(block) == self.height:
            full = len(self._pending)
        for k in range(0, full, n):
            self._chunk(first + k, self._pending[k : k + n])
        self._pending = self._pending[full:].copy()

    def _chunk(self, y: int, rows: np.ndarray) -> None:
        data = exr_zip_block(rows, self.order, self.dtype)
        self._offsets[y // self.ROWS_PER_CHUNK] = self._file.tell()
        self._file.write(struct.pack("<ii", y, len(data)) + data)

    def _finish(self) -> None:
        self._file.seek(self._table_at)
        self._file.write(self._offsets.tobytes())


class PngBlockWriter(_BlockWriter):
    """Streamed 8-bit sRGB PNG (C in 1..4: Y, YA, RGB, RGBA), written atomically.

    Rows are converted as ``write_png`` does (``hdr`` selects the tone map) and compressed into
    one IDAT chunk per block. Memory: the caller's block plus the zlib window.
    """

    def __init__(self, path, width: int, height: int, channels: int, *, hdr: bool = False):
        if channels not in _PNG_COLOUR_TYPES:
            raise ValueError(f"PNG needs 1 to 4 channels, got {channels!r}")
        super().__init__(path, width, height, channels)
        self.hdr = hdr
        self._z = zlib.compressobj(6)

    def _chunk(self, kind: bytes, data: bytes) -> None:
        self._file.write(struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data)))

    def _start(self) -> None:
        self._file.write(b"\x89PNG\r\n\x1a\n")
        ihdr = struct.pack(">IIBBBBB", self.width, self.height, 8, _PNG_COLOUR_TYPES[self.n_channels], 0, 0, 0)
        self._chunk(b"IHDR", ihdr)

    def _rows(self, block: np.ndarray) -> None:
        px = display8(block, self.hdr).reshape(len(block), -1)  # (h, W*C) bytes
        filtered = np.empty((len(block), px.shape[1] + 1), dtype=np.uint8)
        filtered[:, 0] = 1  # filter type Sub: byte minus the same channel of the pixel to the left
        filtered[:, 1 : 1 + self.n_channels] = px[:, : self.n_channels]
        filtered[:, 1 + self.n_channels :] = px[:, self.n_channels :] - px[:, : -self.n_channels]
        data = self._z.compress(filtered.tobytes())
        if data:
            self._chunk(b"IDAT", data)

    def _finish(self) -> None:
        self._chunk(b"IDAT", self._z.flush())
        self._chunk(b"IEND", b"")
