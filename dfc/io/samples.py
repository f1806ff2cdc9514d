"""Sample sets: values of a signal at scattered points (e.g. walk-on-spheres estimates), and their ``.npz`` file.

A sample set is what ``dfc.train.fit.fit_samples`` fits a field to: positions in domain units and one value per
position and channel. Positions may repeat and values may be noisy (Monte Carlo estimates); the fit
averages them. The file format is specified in ``spec/samples.md``.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["SampleSet", "check_samples", "default_channels", "read_channels", "read_npz", "read_reference",
           "read_samples", "write_samples", "KEYS", "REFERENCE_KEYS"]

KEYS = ("xy", "values", "domain", "channels")
"""The arrays a samples file may hold; ``xy`` and ``values`` are required."""
REFERENCE_KEYS = ("image", "domain", "channels")
"""The arrays of a reference ``.npz`` (``dfc wos --reference``); ``image`` is required."""


@dataclass(frozen=True)
class SampleSet:
    """Values of a signal at points.

    xy : (N, 2) float64 positions in domain units (y down, ``spec/conventions.md``)
    values : (N, C) float32 signal values, one row per position
    domain : (x0, y0, x1, y1) the rectangle the points lie in, or None (unknown: any finite point)
    channels : C channel names, or None
    """

    xy: np.ndarray
    values: np.ndarray
    domain: tuple[float, float, float, float] | None = None
    channels: list[str] | None = None

    def __len__(self) -> int:
        return len(self.xy)

    @property
    def n_channels(self) -> int:
        return self.values.shape[1]


def default_channels(c: int) -> list[str]:
    """Channel names for C unnamed channels: Y; R, G, B; R, G, B, A; else c0, c1, ..."""
    return {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(c, [f"c{k}" for k in range(c)])


def check_samples(samples: SampleSet, source: str = "samples") -> SampleSet:
    """Validate a sample set and return it with canonical dtypes (xy float64, values float32, domain floats).

    Raises ``InputError`` starting with ``source`` for: non-float arrays, wrong shapes, no samples, NaN/Inf,
    a domain that is not a finite non-empty rectangle, points outside the domain, channel names that are not
    C distinct non-empty strings.
    """
    xy = _float_array(samples.xy, "xy", source)
    values = _float_array(samples.values, "values", source)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError(f"{source}: xy must have shape (N, 2), got {xy.shape}")
    if values.ndim != 2 or values.shape[1] < 1:
        raise InputError(f"{source}: values must have shape (N, C) with C ≥ 1, got {values.shape}")
    if len(values) != len(xy):
        raise InputError(f"{source}: xy has {len(xy)} rows but values has {len(values)}")
    if len(xy) == 0:
        raise InputError(f"{source}: no samples")
    for name, a in (("xy", xy), ("values", values)):
        bad = ~np.isfinite(a).all(axis=1)
        if bad.any():
            raise InputError(f"{source}: {name} has {int(bad.sum())} rows with NaN/Inf, the first is row "
                             f"{int(np.argmax(bad))}")
    domain = samples.domain
    if domain is not None:
        d = np.asarray(domain)
        if d.dtype.kind not in "iuf":
            raise InputError(f"{source}: domain must be 4 numbers, got dtype {d.dtype}")
        d = d.astype(np.float64)
        if d.shape != (4,):
            raise InputError(f"{source}: domain must be 4 numbers (x0, y0, x1, y1), got shape {d.shape}")
        x0, y0, x1, y1 = (float(v) for v in d)
        if not (np.isfinite(d).all() and x1 > x0 and y1 > y0):
            raise InputError(f"{source}: domain {tuple(d.tolist())} is not a finite rectangle with x1 > x0, y1 > y0")
        domain = (x0, y0, x1, y1)
        out = (xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1)
        if out.any():
            i = int(np.argmax(out))
            raise InputError(f"{source}: {int(out.sum())} points lie outside the domain {domain}, the first is "
                             f"row {i} at ({xy[i, 0]:g}, {xy[i, 1]:g})")
    channels = samples.channels
    if channels is not None:
        channels = [str(c) for c in np.asarray(channels).reshape(-1)] if _is_strings(channels) else None
        if channels is None or len(channels) != values.shape[1] or len(set(channels)) != len(channels) \
                or not all(channels):
            raise InputError(f"{source}: channels must be {values.shape[1]} distinct non-empty names, "
                             f"got {samples.channels!r}")
    return SampleSet(np.ascontiguousarray(xy, dtype=np.float64), np.ascontiguousarray(values, dtype=np.float32),
                     domain, channels)


def read_npz(path: str | Path, keys: tuple[str, ...], required: tuple[str, ...], kind: str) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` file holding only ``keys``, among them every one of ``required``.

    kind : what the file is, for the messages ("a samples file"). Raises ``InputError`` naming the file and the
    problem when it is missing, a directory, not a readable npz archive (or a corrupt one), holds pickled objects
    (never unpickled), has unknown arrays or lacks a required one.
    """
    path = Path(path)
    arrays = {}
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory")
    try:
        if not zipfile.is_zipfile(path):
            raise InputError(f"{path}: not an npz archive (no zip structure)")
        with np.load(path, allow_pickle=False) as npz:
            for key in npz.files:
                try:
                    arrays[key] = npz[key]
                except ValueError as e:
                    if "allow_pickle" in str(e):
                        raise InputError(f"{path}: array {key!r} holds Python objects; only plain numeric and "
                                         "string arrays are read") from None
                    raise InputError(f"{path}: array {key!r} is unreadable ({_reason(e)})") from None
    except InputError:
        raise
    except PermissionError:
        raise InputError(f"{path}: cannot read: permission denied") from None
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, KeyError) as e:  # truncated or corrupt members
        raise InputError(f"{path}: corrupt npz archive ({_reason(e)})") from None
    unknown = sorted(set(arrays) - set(keys))
    if unknown:
        raise InputError(f"{path}: unknown arrays {unknown}; {kind} holds {list(keys)}")
    missing = [k for k in required if k not in arrays]
    if missing:
        raise InputError(f"{path}: missing required array{'s' if len(missing) > 1 else ''} {missing}")
    return arrays


def read_channels(arrays: dict[str, np.ndarray], path) -> list[str] | None:
    """The optional ``channels`` array of a file read by ``read_npz`` as names (``InputError`` unless strings)."""
    channels = arrays.get("channels")
    if channels is not None and not _is_strings(channels):
        raise InputError(f"{path}: channels must be an array of strings, got dtype {channels.dtype}")
    return None if channels is None else _names(channels)


def read_samples(path: str | Path) -> SampleSet:
    """Read a samples ``.npz`` file (``spec/samples.md``).

    Returns a validated ``SampleSet``. Raises ``InputError`` naming the file and the problem when ``read_npz``
    refuses it or it fails ``check_samples``.
    """
    arrays = read_npz(path, KEYS, ("xy", "values"), "a samples file")
    return check_samples(SampleSet(arrays["xy"], arrays["values"], arrays.get("domain"),
                                   read_channels(arrays, path)), str(path))


def read_reference(path: str | Path) -> tuple[np.ndarray, tuple[float, float, float, float] | None]:
    """Exact values on a pixel grid, as ``dfc wos --reference`` writes them (``spec/samples.md``): an EXR (or PNG)
    image, or an ``.npz`` with ``image`` (H, W, C) and optionally ``domain`` and ``channels``; told apart by content.

    Returns (pixels (H, W, C) float32, domain or None). Raises ``InputError`` naming the file for unreadable files,
    a misshapen image or NaN/Inf values.
    """
    from .image import read_image
    from .sniff import file_kind

    if file_kind(path) != "npz":
        return read_image(path).pixels, None
    arrays = read_npz(path, REFERENCE_KEYS, ("image",), "a reference file")
    image = _float_array(arrays["image"], "image", str(path))
    if image.ndim != 3 or min(image.shape) < 1:
        raise InputError(f"{path}: image must have shape (H, W, C), got {image.shape}")
    if not np.isfinite(image).all():
        raise InputError(f"{path}: the image has NaN/Inf values")
    domain = arrays.get("domain")
    if domain is not None and (np.shape(domain) != (4,) or not np.isfinite(domain).all()):
        raise InputError(f"{path}: domain must be 4 finite numbers, got {domain!r}")
    return image.astype(np.float32), None if domain is None else tuple(float(v) for v in domain)


def write_samples(path: str | Path, samples: SampleSet) -> None:
    """Write ``samples`` to ``path`` as a compressed npz (``spec/samples.md``), atomically.

    The set is validated first (``check_samples``); nothing is written when it is invalid.
    """
    s = check_samples(samples, str(path))
    arrays = {"xy": s.xy, "values": s.values}
    if s.domain is not None:
        arrays["domain"] = np.asarray(s.domain, dtype=np.float64)
    if s.channels is not None:
        arrays["channels"] = np.asarray(s.channels, dtype=np.str_)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:  # a file object: numpy appends no ".npz" to the name
            np.savez_compressed(f, **arrays)


def _float_array(a, name: str, source: str) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind != "f":
        raise InputError(f"{source}: {name} must be a floating-point array, got dtype {a.dtype}")
    return a


def _is_strings(a) -> bool:
    return np.asarray(a).dtype.kind in "US"


def _names(a: np.ndarray) -> list[str]:
    return [c.decode("utf-8", "replace") if isinstance(c, bytes) else str(c) for c in a.reshape(-1).tolist()]


def _reason(e: Exception) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__
