"""Option types and helpers shared by the ``dfc`` commands: sizes, windows, points, threads, ``-q``, ``--json``,
progress bars, warnings and notes, ``-`` for standard input and output."""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path

import click

from ..command import DEFAULT_THREADS as DEFAULT_THREADS
from ..command import THREADS_ENV as THREADS_ENV
from ..command import json_option as json_option
from ..command import note as note
from ..command import quiet_option as quiet_option
from ..command import shown as shown
from ..command import stdout_taken as stdout_taken
from ..command import threads_option as threads_option
from ..command import warn as warn
from ..command import write_json as write_json
from ..io.image import EXR_EXTENSIONS, MAX_IMAGE_SIDE
from ..render import DEFAULT_SIDE as DEFAULT_SIDE
from ..render import default_size as default_size

OUTPUT_EXTENSIONS = EXR_EXTENSIONS + (".png",)


class _Numbers(click.ParamType):
    """``a,b,...`` → tuple of ``count`` finite floats (or ints with ``integer=True``, split on ``x`` for sizes)."""

    def __init__(self, count: int, name: str, sep: str = ",", integer: bool = False):
        self.count, self.name, self.sep, self.integer = count, name, sep, integer

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        parts = str(value).lower().split(self.sep)
        try:
            nums = tuple(int(p) if self.integer else float(p) for p in parts)
        except ValueError:
            nums = ()
        if len(nums) != self.count or not all(math.isfinite(v) for v in nums):
            self.fail(f"expected {self.name}, got {value!r}", param, ctx)
        return nums


SIZE = _Numbers(2, "WxH (e.g. 1024x768)", sep="x", integer=True)
WINDOW = _Numbers(4, "x0,y0,x1,y1")
POINT = _Numbers(2, "X,Y")


def positive(ctx, param, value):
    """click callback: None or a number > 0."""
    if value is not None and not value > 0:
        raise click.BadParameter(f"must be > 0, got {value}")
    return value


def check_size(size, param_hint="'--size'", *, limit: int = MAX_IMAGE_SIDE, why: str = "") -> tuple[int, int] | None:
    """``size`` when both sides are in 1..``limit``; else ``click.BadParameter`` (``why`` appended)."""
    if size is not None and not all(1 <= v <= limit for v in size):
        raise click.BadParameter(f"width and height must be in 1..{limit}, got {size[0]}x{size[1]}{why}",
                                 param_hint=param_hint)
    return size


def check_output(path: str, extensions=OUTPUT_EXTENSIONS, param_hint="'-o' / '--output'") -> str:
    if not path.lower().endswith(tuple(extensions)):
        raise click.BadParameter(f"must end in {' or '.join(extensions)}, got {path!r}", param_hint=param_hint)
    return path


def option_names(message: str, names) -> str:
    """``message`` (an API error naming settings) with each of ``names`` (settings, Python names) written as the
    option that sets it: ``max_area`` → ``--max-area``."""
    import re

    for name in sorted(names, key=len, reverse=True):
        message = re.sub(rf"\b{name}\b", "--" + name.replace("_", "-"), message)
    return message


def check_device(device: str) -> str:
    """Validate a torch device name; ``click.BadParameter`` when it is malformed or not available here."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError):
        raise click.BadParameter(f"not a torch device: {device!r}", param_hint="'--device'") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise click.BadParameter(f"{device!r} requested but CUDA is not available", param_hint="'--device'")
    if dev.type not in ("cpu", "cuda"):
        raise click.BadParameter(f"unsupported device {device!r}: use cpu or cuda[:N]", param_hint="'--device'")
    return str(dev)


def progress_bar(total: int, label: str, quiet: bool, *, unit: str = "step"):
    """The progress bar of every command: tqdm on stderr, only when stderr is a terminal (a log gets no carriage
    returns) and not ``quiet``."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit=unit, disable=quiet or not sys.stderr.isatty(), file=sys.stderr,
                leave=False, dynamic_ncols=True, mininterval=0.5)


# -- standard input and output -------------------------------------------------------------------------------------
def binary_stream(stream):
    """The byte stream under a text stream (``sys.stdin`` / ``sys.stdout``), or the stream itself when it has none."""
    return getattr(stream, "buffer", stream)


@contextlib.contextmanager
def stdin_file(path: str, name: str = "stdin"):
    """Yield ``path``, or for ``-`` a temporary file holding all of standard input (named ``name``, removed after):
    readers that need a file (OpenEXR, meshio) and choose by content (``dfc.io.sniff``) read it as any other."""
    if path != "-":
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="dfc-stdin-") as tmp:
        spooled = Path(tmp) / name
        with open(spooled, "wb") as f:
            shutil.copyfileobj(binary_stream(sys.stdin), f)
        yield str(spooled)


@contextlib.contextmanager
def stdout_file(path: str, suffix: str):
    """Yield ``path``, or for ``-`` a temporary file (with ``suffix``) whose bytes go to standard output once the
    block succeeds: writers that seek (the EXR writer's offset table) or write atomically work unchanged."""
    if path != "-":
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="dfc-stdout-") as tmp:
        spooled = os.path.join(tmp, "out" + suffix)
        yield spooled
        sys.stdout.flush()
        out = binary_stream(sys.stdout)
        with open(spooled, "rb") as f:
            shutil.copyfileobj(f, out)
        out.flush()


def read_curves_checked(path: str, quiet: bool):
    """The curves of ``path`` (``-``: standard input, recognised by content), with one warning line when input curves
    lie entirely outside the domain (clean-up drops them; ``dfc.geometry.curves.curves_outside``)."""
    from dataclasses import replace

    from ..errors import CurveError
    from ..geometry.curves import curves_outside
    from ..geometry.sources import read_curves

    with stdin_file(path) as real:
        try:
            curves = read_curves(real)
        except CurveError as e:
            if real == path:
                raise
            raise CurveError(str(e).replace(real, "<stdin>")) from None
    if real != path:
        curves = replace(curves, source="<stdin>")
    outside = curves_outside(curves)
    if outside:
        names = [curves.names[c] if c < len(curves.names) else f"curve {c}" for c in outside]
        listed = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
        domain = ", ".join(f"{v:g}" for v in curves.domain)
        warn(f"{len(names)} curve{'s' if len(names) > 1 else ''} entirely outside the domain ({domain}), ignored: "
             f"{listed}", quiet)
    return curves
