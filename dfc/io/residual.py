"""The ``rESD`` chunk (spec/dfield.md §6.9): a residual raster, what the field leaves of the input on its pixel grid,
coded as AVIF images (through ``imagecodecs``), and back.

Payload (little-endian): ``version`` u8 = 1, ``codec`` u8 = 1 (AVIF), ``bits`` u8 (10 or 12), ``channels`` u8 C,
``space`` u8 (``SPACES``: where the residual adds to the field), 3 reserved bytes (0), ``width`` u32, ``height`` u32,
``lo`` f32, ``hi`` f32, then ⌈C / 3⌉ streams, each as u32 length and bytes of an
RGB image: channel k is plane k mod 3 of image ⌊k / 3⌋, the planes past C are 0 (libavif's quality does not act on
grey images). A sample s decodes to ``lo + (hi − lo) · s / (2^bits − 1)``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TypeVar

import numpy as np

from ..errors import FormatError, InputError, ResidualBytesError

__all__ = ["AVIF_MATRIX", "GAIN_FILL", "GAIN_MIN", "GAIN_STEPS", "RESIDUAL_BITS", "SPACES", "decode_residual",
           "encode_residual", "largest_gain", "payload_head", "payload_streams"]

T = TypeVar("T")

RESIDUAL_BITS = 12
"""Bits per coded sample."""
AVIF_SPEED = 4
"""libavif's speed (0 slowest … 10): three times as fast as speed 2, 0.02–0.2 dB lower at the same bytes
(CHANGELOG.md, "The residual's share capped, its AVIF planes coded as they are and its bytes filled")."""
AVIF_MATRIX = 0
"""The streams' matrix coefficients (ISO/IEC 23091-2): 0, identity, codes the three planes as they are (GBR,
4:4:4), so their samples decode exactly; the residual's planes are nearly independent, where YUV gains nothing
(CHANGELOG.md, "The residual's share capped, its AVIF planes coded as they are and its bytes filled")."""
SPACES = ("values", "tonemapped")
"""``space`` 0: the residual adds to the values; 1: to their tone map ``v / (1 + |v|)`` (HDR light), spec §6.9."""
GAIN_FILL = 0.97
"""``encode_residual`` tries the next quality up when the highest that fits leaves more than 3 % of its bytes."""
GAIN_MIN, GAIN_STEPS = 0.5, 6
"""... with the samples spanning a share of the code range between this and 1, found in this many halvings."""
_HEAD = struct.Struct("<BBBBB3xIIff")
_VERSION, _AVIF = 1, 1
MAX_PIXELS = 2**26
"""The largest ``width · height`` a payload may declare (spec/dfield.md §4), checked before anything is decoded."""


def _codecs():
    try:
        import imagecodecs
    except ImportError:
        raise InputError("a residual (rESD) needs imagecodecs, a dependency of dfc: pip install imagecodecs") from None
    return imagecodecs


def _images(samples: np.ndarray) -> list[np.ndarray]:
    """(H, W, C) samples as ⌈C / 3⌉ contiguous (H, W, 3) images, the planes past C zero."""
    h, w, c = samples.shape
    padded = np.zeros((h, w, -(-c // 3) * 3), samples.dtype)
    padded[..., :c] = samples
    return [np.ascontiguousarray(padded[..., k:k + 3]) for k in range(0, padded.shape[2], 3)]


def _samples(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(H, W, C) uint16 samples of ``values`` (float64) between ``lo`` and ``hi`` (float32 values)."""
    top = (1 << RESIDUAL_BITS) - 1
    return np.round((values - lo) / (hi - lo) * top).clip(0, top).astype(np.uint16)


def _pack(samples: np.ndarray, lo: float, hi: float, space: int, level: int) -> bytes:
    """The payload of ``samples`` (H, W, C, ``_samples``) between ``lo`` and ``hi`` at AVIF quality ``level``."""
    ic = _codecs()
    h, w, c = samples.shape
    streams = [bytes(ic.avif_encode(p, level=level, speed=AVIF_SPEED, bitspersample=RESIDUAL_BITS,
                                    pixelformat="444", matrix=AVIF_MATRIX)) for p in _images(samples)]
    head = _HEAD.pack(_VERSION, _AVIF, RESIDUAL_BITS, c, space, w, h, lo, hi)
    return head + b"".join(struct.pack("<I", len(s)) + s for s in streams)


def encode_residual(values: np.ndarray, n_bytes: int, space: str = "values") -> bytes | None:
    """The ``rESD`` payload of ``values`` (H, W, C) float32 (a residual in ``space``, one of ``SPACES``) in at most
    ``n_bytes``: the highest AVIF quality whose payload fits, with the values' range as ``lo`` and ``hi``; or,
    when its error is smaller, the next quality up with ``hi`` raised until it fits (the samples then span less
    than the code range: a finer step than AVIF's qualities, which are 20–30 % apart in bytes at high rates).
    None when the values are all equal (nothing to store). Raises ResidualBytesError (an InputError) when not
    even the lowest quality fits, or when the best that fits leaves a larger squared error than the values
    themselves (adding it would make the image worse)."""
    values = np.asarray(values, dtype=np.float32)
    lo, hi = float(values.min()), float(values.max())
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        return None
    lo32, hi32 = float(np.float32(lo)), float(np.float32(hi))
    wide = values.astype(np.float64)
    samples = _samples(wide, lo32, hi32)
    payloads: dict[int, bytes] = {}

    def size(level: int) -> int:
        if level not in payloads:
            payloads[level] = _pack(samples, lo32, hi32, SPACES.index(space), level)
        return len(payloads[level])

    if size(0) > n_bytes:
        raise ResidualBytesError(f"the residual's smallest stream takes {size(0)} bytes, more than the {n_bytes} it "
                                 "may take")
    lo_q, hi_q = (100, None) if size(100) <= n_bytes else (0, 100)
    while hi_q is not None and hi_q - lo_q > 1:
        mid = (lo_q + hi_q) // 2
        lo_q, hi_q = (mid, hi_q) if size(mid) <= n_bytes else (lo_q, mid)
    candidates = [payloads[lo_q]]
    if hi_q is not None and len(candidates[0]) < GAIN_FILL * n_bytes:
        def raised(gain):  # the next quality up, the samples spanning ``gain`` of the code range
            top = float(np.float32(lo32 + (hi32 - lo32) / gain))
            payload = _pack(_samples(wide, lo32, top), lo32, top, SPACES.index(space), hi_q)
            return len(payload), payload

        filled = largest_gain(raised, n_bytes)
        candidates += [] if filled is None else [filled]
    errors = [float(np.square(decode_residual(p).astype(np.float64) - wide).sum()) for p in candidates]
    if min(errors) >= float(np.square(wide).sum()):
        raise ResidualBytesError(f"a residual in {n_bytes} bytes adds more error than it removes (its best quality "
                                 "there codes it too coarsely)")
    return candidates[int(np.argmin(errors))]


def largest_gain(coded: Callable[[float], tuple[int, T]], n_bytes: int) -> T | None:
    """What ``coded(gain) -> (bytes, result)`` gives for the largest gain in [``GAIN_MIN``, 1) whose bytes fit
    ``n_bytes``, found in ``GAIN_STEPS`` halvings; None when no gain tried fits. Shared with the benchmarks' AVIF
    (``dfc.bench.codecs``), which fills its budget the same way."""
    lo, hi, best = GAIN_MIN, 1.0, None
    for _ in range(GAIN_STEPS):
        gain = 0.5 * (lo + hi)
        size, result = coded(gain)
        if size <= n_bytes:
            lo, best = gain, result
        else:
            hi = gain
    return best


def payload_head(data) -> dict:
    """The head of a payload: ``bits``, ``channels``, ``space`` (one of ``SPACES``), ``width``, ``height``, ``lo``,
    ``hi``; FormatError when it is short, unknown or invalid."""
    if len(data) < _HEAD.size:
        raise FormatError(f"rESD: {len(data)} bytes, shorter than its {_HEAD.size}-byte head")
    version, codec, bits, c, space, w, h, lo, hi = _HEAD.unpack_from(data)
    if version != _VERSION or codec != _AVIF:
        raise FormatError(f"rESD: unknown version {version} or codec {codec}")
    if any(data[5:8]):
        raise FormatError("rESD: reserved bytes are not zero")
    if bits not in (10, 12) or c < 1 or space >= len(SPACES) or w < 1 or h < 1 or w * h > MAX_PIXELS or \
            not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise FormatError(f"rESD: invalid head (bits {bits}, {c} channels, space {space}, {w}x{h}, "
                          f"range [{lo}, {hi}])")
    return {"bits": bits, "channels": c, "space": SPACES[space], "width": w, "height": h, "lo": lo, "hi": hi}


def payload_streams(data) -> list[bytes]:
    """The AVIF streams of a payload whose head ``payload_head`` accepts; FormatError when their lengths do not
    fill it exactly (checked without decoding them)."""
    c = payload_head(data)["channels"]
    pos, streams = _HEAD.size, []
    for _ in range(-(-c // 3)):
        if pos + 4 > len(data):
            raise FormatError("rESD: a stream's length runs past the payload")
        (n,) = struct.unpack_from("<I", data, pos)
        if pos + 4 + n > len(data):
            raise FormatError("rESD: a stream runs past the payload")
        streams.append(bytes(data[pos + 4:pos + 4 + n]))
        pos += 4 + n
    if pos != len(data):
        raise FormatError(f"rESD: {len(data) - pos} bytes after the last stream")
    return streams


def decode_residual(data) -> np.ndarray:
    """(H, W, C) float32 values of an ``rESD`` payload; FormatError when it is damaged or inconsistent."""
    data = bytes(data)
    head = payload_head(data)
    w, h, c, bits, lo, hi = (head[k] for k in ("width", "height", "channels", "bits", "lo", "hi"))
    streams = payload_streams(data)
    ic = _codecs()
    planes = []
    for stream in streams:
        try:
            plane = np.asarray(ic.avif_decode(stream))
        except Exception as exc:  # the codec's own error types
            raise FormatError(f"rESD: the AVIF stream does not decode ({exc})") from None
        if plane.shape != (h, w, 3) or plane.dtype != np.uint16:
            raise FormatError(f"rESD: a stream decodes to {plane.shape} {plane.dtype}, the head says {h}x{w}x3 "
                              f"images of {bits} bits")
        planes.append(plane)
    samples = np.concatenate(planes, axis=2)[..., :c]
    top = (1 << bits) - 1
    if samples.max() > top:
        raise FormatError(f"rESD: a sample exceeds {top}, the largest of {bits} bits")
    return (lo + (hi - lo) * (samples.astype(np.float64) / top)).astype(np.float32)
