"""Classical image codecs at equal bytes (through ``imagecodecs``, a dependency of dfc): JPEG XL, AVIF, WebP and
JPEG 2000, each given the same raster as the fields and the same byte budget.

Every codec tries a few *configurations* (``configurations``): how the values become the codec's samples. JPEG XL
takes float input (linear values, HDR included) or 16-bit integers; AVIF 10- or 12-bit integers (colour images
in libavif's default YUV and, 4:4:4, with the identity matrix: the RGB planes coded as they are, which decode
exactly and win at high rates on clean content); WebP 8-bit (SDR input only); JPEG 2000 16-bit. Integer samples
come from a *transfer*: ``identity`` for SDR input (values in [0, 1] scaled to the code range), ``linear`` (the
values' [min, max] mapped onto the code range), ``log`` (log of the values plus 1e-4 of their maximum, for
non-negative HDR input) or ``tonemap`` (HDR input: ``v / (1 + |v|)``, the space its PSNR is measured in and a
dfc residual raster is coded in, ``dfc.field.residual.tone_map``, its [min, max] mapped onto the code range); the two
numbers a non-identity transfer needs are counted as ``SIDE_BYTES``. For each configuration the quality is found
by bisection: the highest quality whose stream fits the budget; JPEG XL's and WebP's lossless streams are tried
too. Of the configurations, the stream with the best 1× PSNR on the training raster is kept, measured on the input's
``dfc.metrics.quality_scale`` (tone-mapped for HDR colours), as every PSNR of the comparison.

Two codecs cannot always spend the budget. AVIF's quality has 64 steps (libavif's quantisers), which at high rates
are 30–50 % apart in size: its stream may stay well below the budget, and ``Coded.next_bytes`` records the size of
the next step up, which does not fit. Such a stream is also tried at the next step with its samples spanning less
of the code range (a *gain* below 1, stored as a linear transfer: ``SIDE_BYTES``), a finer step in between; the
better scoring one is kept. (Filling the gap by coding a slightly downscaled raster at the next step scores far
lower than the smaller full-size stream, so it is not done: CHANGELOG.md, "Measured and not made default".) A
codec whose top quality still fits is *saturated* (WebP's lossy streams saturate early; small images saturate every
codec).

The decoded raster is shown at zoom through ``dfc.bench.baselines.upsample.PixelImage``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..field.residual import TONE_LIMIT, tone_map
from ..io.residual import GAIN_FILL, largest_gain
from ..metrics import QualityScale

__all__ = ["AVIF_SPEED", "CODECS", "Coded", "JXL_EFFORT", "SDR_ONLY", "SIDE_BYTES", "configurations", "decode",
           "encode", "encode_to_budget", "quality_parameters", "require_imagecodecs", "stream_bytes"]

CODECS = ("jpegxl", "avif", "webp", "jpeg2k")
SDR_ONLY = ("webp",)
LOSSLESS = "lossless"
"""The knob value of a lossless configuration."""
SIDE_BYTES = 8
"""Bytes counted for a non-identity transfer's two numbers (two float32)."""
JXL_EFFORT = 7
"""libjxl's effort (its default)."""
AVIF_SPEED = 2
"""libavif's speed (0 slowest … 10): about as good as its slowest setting on the README sample, twice as fast
(CHANGELOG.md, "Benchmark settings")."""
BISECTION_STEPS = 14
"""Bisection steps of a continuous quality knob."""
LOG_EPS = 1e-4
"""``log`` transfer: the offset added before the log, as a fraction of the values' maximum."""


def require_imagecodecs():
    """The ``imagecodecs`` module; InputError naming the extra when it is missing."""
    try:
        import imagecodecs
    except ImportError:
        raise InputError("the classical codecs (" + ", ".join(CODECS) + ") need imagecodecs, a dependency of dfc: "
                         "pip install imagecodecs (or leave them out of --methods)") from None
    return imagecodecs


# ----------------------------------------------------------------------------------------------- samples
def _transfers(pixels: np.ndarray) -> list[str]:
    lo, hi = float(pixels.min()), float(pixels.max())
    if lo >= 0.0 and hi <= 1.0:
        return ["identity"]
    return ["linear", "log", "tonemap"] if lo >= 0.0 else ["linear", "tonemap"]


def _forward(values: np.ndarray, transfer: str, lo: float, hi: float) -> np.ndarray:
    """Values -> [0, 1] under ``transfer`` (lo, hi: the values' range)."""
    if transfer == "identity":
        return np.clip(values, 0.0, 1.0)
    if transfer == "linear":
        return (values - lo) / max(hi - lo, 1e-30)
    if transfer == "tonemap":
        a, b = tone_map(lo), tone_map(hi)
        return (tone_map(values) - a) / max(b - a, 1e-30)
    eps = LOG_EPS * max(hi, 1e-30)
    a, b = np.log(lo + eps), np.log(hi + eps)
    return (np.log(np.maximum(values, 0.0) + eps) - a) / max(b - a, 1e-30)


def _inverse(unit: np.ndarray, transfer: str, lo: float, hi: float) -> np.ndarray:
    if transfer == "identity":
        return unit
    if transfer == "linear":
        return lo + unit * (hi - lo)
    if transfer == "tonemap":
        t = np.clip(tone_map(lo) + unit * (tone_map(hi) - tone_map(lo)), -TONE_LIMIT, TONE_LIMIT)
        return t / (1.0 - np.abs(t))
    eps = LOG_EPS * max(hi, 1e-30)
    a, b = np.log(lo + eps), np.log(hi + eps)
    return np.exp(a + unit * (b - a)) - eps


def _planes(pixels: np.ndarray) -> list[np.ndarray]:
    """The images a codec is given: one RGB (C = 3) or grey (C = 1) image, else one grey image per channel."""
    c = pixels.shape[2]
    if c == 3:
        return [pixels]
    return [pixels[..., k] for k in range(c)]


# ----------------------------------------------------------------------------------------------- codecs
def configurations(codec: str, pixels: np.ndarray) -> list[dict]:
    """The configurations ``codec`` tries on ``pixels`` (H, W, C): dicts of ``input`` ("float" or "uint"),
    ``bits`` and ``transfer``."""
    transfers = _transfers(pixels)
    if codec == "jpegxl":
        return [{"input": "float", "bits": 32, "transfer": "none"}] + [
            {"input": "uint", "bits": 16, "transfer": t} for t in transfers] + [
            {"input": "float", "bits": 32, "transfer": "none", "lossless": True}]
    if codec == "avif":  # colour images in YUV and, 4:4:4, with the identity matrix (GBR: its planes as they are)
        matrices = ("yuv", "identity") if pixels.shape[2] == 3 else ("yuv",)
        return [{"input": "uint", "bits": b, "transfer": t, **({"matrix": m} if m != "yuv" else {})}
                for m in matrices for b in (10, 12) for t in transfers]
    if codec == "webp":
        return [{"input": "uint", "bits": 8, "transfer": "identity", "lossless": False},
                {"input": "uint", "bits": 8, "transfer": "identity", "lossless": True}]
    if codec == "jpeg2k":
        return [{"input": "uint", "bits": 16, "transfer": t} for t in transfers]
    raise ValueError(f"unknown codec {codec!r}; known: {', '.join(CODECS)}")


@dataclass(frozen=True)
class _Knob:
    """A codec's quality knob q in [lo, hi], bytes growing with q; ``integer`` for a discrete one."""

    lo: float
    hi: float
    integer: bool


def _knob(codec: str, config: dict) -> _Knob | None:
    if config.get("lossless"):
        return None
    return {"jpegxl": _Knob(0.0, 1.0, False), "avif": _Knob(0, 100, True), "webp": _Knob(0.0, 100.0, False),
            "jpeg2k": _Knob(15.0, 99.0, False)}[codec]


def _jxl_distance(q: float) -> float:
    """JPEG XL's Butteraugli distance for knob q in [0, 1]: 25 (q = 0) down to 0.01 (q = 1), geometrically."""
    return float(np.exp(np.log(25.0) * (1.0 - q) + np.log(0.01) * q))


def quality_parameters(codec: str, q) -> dict:
    """The codec's own quality parameter(s) at knob ``q`` (for records)."""
    if q == LOSSLESS:
        return {"lossless": True}
    if codec == "jpegxl":
        return {"distance": _jxl_distance(q)}
    if codec == "avif":
        return {"quality": int(q)}
    if codec == "webp":
        return {"quality": float(q)}
    return {"psnr_target_db": float(q)}


def encode(codec: str, pixels: np.ndarray, config: dict, q) -> bytes:
    """One stream: ``pixels`` (H, W, C) float32 coded by ``codec`` with ``config`` at knob ``q`` (or ``LOSSLESS``).
    Several planes (``_planes``) are concatenated, each prefixed by its length as 4 bytes; a non-identity transfer's
    range is counted as ``SIDE_BYTES`` (``encode`` returns only the codec's bytes; see ``stream_bytes``)."""
    ic = require_imagecodecs()
    lo, hi = float(pixels.min()), float(pixels.max())
    out = []
    for plane in _planes(pixels):
        if config["input"] == "float":
            data = np.ascontiguousarray(plane, dtype=np.float32)
        else:
            top = (1 << config["bits"]) - 1
            unit = _forward(plane.astype(np.float64), config["transfer"], lo, hi) * config.get("gain", 1.0)
            data = np.ascontiguousarray(np.round(np.clip(unit, 0.0, 1.0) * top).astype(
                np.uint8 if config["bits"] == 8 else np.uint16))
        if codec == "jpegxl":
            kw = {"bitspersample": config["bits"]} if config["input"] == "uint" else {}
            kw.update({"lossless": True} if q == LOSSLESS else {"distance": _jxl_distance(q)})
            out.append(ic.jpegxl_encode(data, effort=JXL_EFFORT, **kw))
        elif codec == "avif":
            kw = {"pixelformat": "444", "matrix": 0} if config.get("matrix") == "identity" else {}
            out.append(ic.avif_encode(data, level=int(q), speed=AVIF_SPEED, bitspersample=config["bits"], **kw))
        elif codec == "webp":
            rgb = data if data.ndim == 3 else np.ascontiguousarray(np.repeat(data[..., None], 3, axis=2))
            out.append(ic.webp_encode(rgb, lossless=True) if q == LOSSLESS else
                       ic.webp_encode(rgb, level=float(q), lossless=False))
        else:
            out.append(ic.jpeg2k_encode(data, level=float(q), codecformat="j2k"))
    if len(out) == 1:
        return bytes(out[0])
    return b"".join(len(s).to_bytes(4, "little") + bytes(s) for s in out)


def stream_bytes(stream: bytes, config: dict) -> int:
    """Bytes a stream costs: its length, plus ``SIDE_BYTES`` for a non-identity integer transfer or a gain."""
    return len(stream) + (SIDE_BYTES if config["transfer"] not in ("identity", "none") or "gain" in config else 0)


def decode(codec: str, stream: bytes, config: dict, channels: int, value_range: tuple[float, float]) -> np.ndarray:
    """A stream of ``encode`` back to (h, w, ``channels``) float32 values; ``value_range`` is the (min, max) of the
    encoded pixels (what the side bytes carry)."""
    ic = require_imagecodecs()
    parts = [stream]
    if channels not in (1, 3):
        parts, pos = [], 0
        while pos < len(stream):
            n = int.from_bytes(stream[pos : pos + 4], "little")
            parts.append(stream[pos + 4 : pos + 4 + n])
            pos += 4 + n
    fn = {"jpegxl": ic.jpegxl_decode, "avif": ic.avif_decode, "webp": ic.webp_decode,
          "jpeg2k": ic.jpeg2k_decode}[codec]
    planes = []
    for part in parts:
        data = np.asarray(fn(part))
        if codec == "webp" and channels != 3:
            data = data[..., 0]
        if config["input"] == "float":
            values = data.astype(np.float32)
        else:
            unit = data.astype(np.float64) / (((1 << config["bits"]) - 1) * config.get("gain", 1.0))
            values = _inverse(unit, config["transfer"], *value_range).astype(np.float32)
        planes.append(values if values.ndim == 3 else values[..., None])
    return np.concatenate(planes, axis=2)


# ----------------------------------------------------------------------------------------------- to a budget
@dataclass
class Coded:
    """A codec's stream at a budget.

    codec : one of ``CODECS``; config : the chosen configuration with its quality parameters
    n_bytes : what the stream costs (``stream_bytes``); decoded : (H, W, C) float32, the stream decoded
    score : 1× PSNR on the training raster (dB, on the scale ``encode_to_budget`` was given)
    next_bytes : the cost of the next quality step of the chosen configuration, over the budget (None when the
        top quality fits: ``saturated``)
    candidates : the best stream of every configuration (config, bytes, score)
    """

    codec: str
    config: dict
    n_bytes: int
    decoded: np.ndarray
    score: float
    next_bytes: int | None
    candidates: list[dict] = field(default_factory=list)

    @property
    def saturated(self) -> bool:
        return self.next_bytes is None


def _largest_fitting(size_of: Callable[[float], int], knob: _Knob, n_bytes: int) -> tuple[float | None, float | None]:
    """(q, q_next): the largest knob value whose size fits ``n_bytes`` (None when not even ``knob.lo`` does) and
    the smallest value tried above it, which does not fit (None when ``knob.hi`` fits)."""
    if size_of(knob.lo) > n_bytes:
        return None, knob.lo
    if size_of(knob.hi) <= n_bytes:
        return knob.hi, None
    lo, hi = knob.lo, knob.hi
    if knob.integer:
        lo, hi = int(lo), int(hi)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if size_of(mid) <= n_bytes else (lo, mid)
        return lo, hi
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if size_of(mid) <= n_bytes else (lo, mid)
    return lo, hi


def _with_gain(codec: str, pixels: np.ndarray, config: dict, q, n_bytes: int, scale: QualityScale,
               next_bytes: int, value_range: tuple[float, float]) -> list[dict]:
    """The stream of quality ``q`` (the step above the highest that fits) with its samples spanning the largest
    share ``gain`` of the code range that fits ``n_bytes`` (``dfc.io.residual.largest_gain``, as the residual raster
    is filled), as a candidate of ``encode_to_budget`` (``value_range``: the pixels' min and max); none when not
    even the smallest gain fits."""
    def coded(gain):
        trial = {**config, "gain": gain}
        stream = encode(codec, pixels, trial, q)
        return stream_bytes(stream, trial), (trial, stream)

    best = largest_gain(coded, n_bytes)
    if best is None:
        return []
    trial, stream = best
    decoded = decode(codec, stream, trial, pixels.shape[2], value_range)
    return [{"config": {**trial, **quality_parameters(codec, q)}, "bytes": stream_bytes(stream, trial),
             "score": scale.psnr(pixels, decoded), "decoded": decoded, "next_bytes": next_bytes}]


def encode_to_budget(codec: str, pixels: np.ndarray, n_bytes: int, scale: QualityScale) -> Coded:
    """``codec``'s best stream of ``pixels`` (H, W, C) float32 in at most ``n_bytes`` (module docstring), scored by
    PSNR on ``scale`` (``dfc.metrics.quality_scale(pixels)``) against ``pixels``. Raises InputError when WebP is
    asked for HDR input or no stream fits the budget."""

    if codec not in CODECS:
        raise InputError(f"unknown codec {codec!r}; known: {', '.join(CODECS)}")
    if codec in SDR_ONLY and (float(pixels.min()) < 0.0 or float(pixels.max()) > 1.0):
        raise InputError(f"{codec} codes 8-bit SDR images only; the input's values span "
                         f"[{float(pixels.min()):.4g}, {float(pixels.max()):.4g}]")
    channels = pixels.shape[2]
    value_range = (float(pixels.min()), float(pixels.max()))
    found, smallest = [], np.inf
    for config in configurations(codec, pixels):
        knob = _knob(codec, config)
        streams: dict = {}

        def cost(q, config=config, streams=streams):
            if q not in streams:
                streams[q] = encode(codec, pixels, config, q)
            return stream_bytes(streams[q], config)

        q, q_next = (LOSSLESS, None) if knob is None else _largest_fitting(cost, knob, n_bytes)
        smallest = min(smallest, cost(LOSSLESS if knob is None else knob.lo))
        if q is None or cost(q) > n_bytes:
            continue
        decoded = decode(codec, streams[q], config, channels, value_range)
        found.append({"config": {**config, **quality_parameters(codec, q)}, "bytes": cost(q),
                      "score": scale.psnr(pixels, decoded), "decoded": decoded,
                      "next_bytes": None if q_next is None else cost(q_next)})
        if knob is not None and knob.integer and q_next is not None and cost(q) < GAIN_FILL * n_bytes:
            found.extend(_with_gain(codec, pixels, config, q_next, n_bytes, scale, cost(q_next), value_range))
    if not found:
        raise InputError(f"a budget of {n_bytes} bytes is too small for {codec}: its smallest stream of this image "
                         f"takes {int(smallest)} bytes")
    best = max(found, key=lambda c: c["score"])
    record = [{k: c[k] for k in ("config", "bytes", "score", "next_bytes")} for c in found]
    return Coded(codec, best["config"], int(best["bytes"]), best["decoded"], float(best["score"]),
                 best["next_bytes"], record)
