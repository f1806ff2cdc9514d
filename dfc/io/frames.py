"""Time-varying rasters: a sequence of frames on one pixel grid at increasing times, and its ``.npz`` file.

A sequence is what ``dfc.train.fit.fit_frames`` fits a time-sliced field to (one feature slice per frame on a shared
mesh, ``spec/field.md`` §6). Like an image, it covers ``[0, W] × [0, H]`` in pixels, y down. The file is an
``.npz`` with ``frames`` (T, H, W, C) float and ``times`` (T,) strictly increasing, optionally ``channels`` (C,)
(``spec/samples.md``, "Frame sequences"); a sequence can also be assembled from T images.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["FRAME_KEYS", "FrameSequence", "check_frames", "frames_from_images", "npz_kind", "read_frames",
           "write_frames"]

FRAME_KEYS = ("frames", "times", "channels")
"""The arrays a frames file may hold; ``frames`` and ``times`` are required."""


@dataclass(frozen=True)
class FrameSequence:
    """frames : (T, H, W, C) float32 linear values; times : (T,) float64 strictly increasing; channels : C names
    or None (then ``dfc.io.samples.default_channels``)."""

    frames: np.ndarray
    times: np.ndarray
    channels: list[str] | None = None


def check_frames(seq: FrameSequence, source: str = "frames") -> FrameSequence:
    """Validate a sequence and return it with canonical dtypes; ``InputError`` starting with ``source`` for
    non-float or mis-shaped arrays, NaN/Inf, times that are not strictly increasing, bad channel names."""
    frames, times = np.asarray(seq.frames), np.asarray(seq.times)
    if frames.dtype.kind != "f" or times.dtype.kind not in "fiu":
        raise InputError(f"{source}: frames must be float and times numeric, got {frames.dtype} and {times.dtype}")
    if frames.ndim != 4 or min(frames.shape) < 1:
        raise InputError(f"{source}: frames must have shape (T, H, W, C) with every size ≥ 1, got {frames.shape}")
    if times.shape != (len(frames),):
        raise InputError(f"{source}: times must have shape ({len(frames)},), got {times.shape}")
    times = times.astype(np.float64)
    if not np.isfinite(times).all() or np.any(np.diff(times) <= 0):
        raise InputError(f"{source}: times must be finite and strictly increasing")
    bad = ~np.isfinite(frames)
    if bad.any():
        t, j, i, c = np.argwhere(bad)[0]
        raise InputError(f"{source}: {int(bad.sum())} NaN/Inf values, the first in frame {t}, row {j}, column {i}")
    channels = None if seq.channels is None else [str(c) for c in seq.channels]
    if channels is not None and (len(channels) != frames.shape[3] or len(set(channels)) != len(channels)
                                 or not all(channels)):
        raise InputError(f"{source}: channels must be {frames.shape[3]} distinct non-empty names, got {channels}")
    return FrameSequence(np.ascontiguousarray(frames, dtype=np.float32), times, channels)


def npz_kind(path: str | Path) -> str:
    """"frames" or "samples": which ``.npz`` layout a file holds, by its keys (``InputError`` when neither)."""
    if not zipfile.is_zipfile(path):
        raise InputError(f"{path}: not an npz archive (no zip structure)")
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise InputError(f"{path}: not a readable .npz archive ({e})") from None
    if {"frames", "times"} <= keys:
        return "frames"
    if {"xy", "values"} <= keys:
        return "samples"
    raise InputError(f"{path}: neither a frame sequence (frames, times) nor a sample set (xy, values); "
                     f"keys: {', '.join(sorted(keys)) or 'none'}")


def read_frames(path: str | Path) -> FrameSequence:
    """Read and validate a frames ``.npz`` (``dfc.io.samples.read_npz``: no pickles; no keys besides ``FRAME_KEYS``)."""
    from .samples import read_channels, read_npz

    arrays = read_npz(path, FRAME_KEYS, ("frames", "times"), "a frames file")
    return check_frames(FrameSequence(arrays["frames"], arrays["times"], read_channels(arrays, path)), str(path))


def frames_from_images(paths: list[str], times, channels: list[str] | None = None) -> FrameSequence:
    """A sequence of T images (``dfc.io.image.read_image``) at ``times`` (T,): same size and channels throughout."""
    from .image import read_image

    if len(times) != len(paths):
        raise InputError(f"{len(paths)} images but {len(times)} times")
    images = [read_image(p, channels) for p in paths]
    first = images[0]
    for path, im in zip(paths[1:], images[1:]):
        if im.pixels.shape != first.pixels.shape or im.channels != first.channels:
            raise InputError(f"{path}: {im.pixels.shape} {im.channels} differs from the first image's "
                             f"{first.pixels.shape} {first.channels}")
    return check_frames(FrameSequence(np.stack([im.pixels for im in images]), np.asarray(times, dtype=np.float64),
                                      first.channels))


def write_frames(path: str | Path, seq: FrameSequence) -> None:
    """Validate and write a sequence uncompressed (float32 frames, float64 times), atomically."""
    seq = check_frames(seq)
    arrays = {"frames": seq.frames, "times": seq.times}
    if seq.channels is not None:
        arrays["channels"] = np.asarray(seq.channels, dtype=str)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
