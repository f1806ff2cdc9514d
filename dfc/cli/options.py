"""Option types and helpers shared by the ``dfc`` commands: sizes, windows, points, threads, ``-q``, ``--json``,
progress bars, warnings and notes, ``-`` for standard input and output."""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path

import click

from ..io.image import EXR_EXTENSIONS, MAX_IMAGE_SIDE

OUTPUT_EXTENSIONS = EXR_EXTENSIONS + (".png",)
DEFAULT_SIDE = (256, 4096)
"""Default render size: the long side is the domain's long side in its own units, clamped into this range."""


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


def default_size(window: tuple[float, float, float, float], domain) -> tuple[int, int]:
    """Render size for ``window`` when none is given: the long side as for the whole domain (its long side in
    domain units, clamped into ``DEFAULT_SIDE``), the short side by the window's aspect ratio."""
    long_side = min(max(round(max(domain[2] - domain[0], domain[3] - domain[1])), DEFAULT_SIDE[0]), DEFAULT_SIDE[1])
    w, h = window[2] - window[0], window[3] - window[1]
    scale = long_side / max(w, h)
    return max(1, round(w * scale)), max(1, round(h * scale))


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


# -- threads ------------------------------------------------------------------------------------------------------
THREADS_ENV = "DFC_THREADS"
DEFAULT_THREADS = 1
"""torch CPU threads of a computing command unless ``--threads`` or ``DFC_THREADS`` says otherwise: never far from
the best and never collapsing beside other programs (docs/cli.md, "Threads"; measured: docs/results.md, "Threads and
OpenMP wait policy")."""


def _set_threads(ctx, param, value):
    import torch

    torch.set_num_threads(value)
    return value


threads_option = click.option(
    "--threads", type=click.IntRange(1, 4096), default=DEFAULT_THREADS, show_default=True, envvar=THREADS_ENV,
    show_envvar=True, expose_value=False, callback=_set_threads,
    help="CPU threads for torch. More help only on an otherwise idle machine with cores to spare.")
"""``--threads N`` (env ``DFC_THREADS``) of every command that computes: sets torch's CPU threads before it runs.
(The entry point has already told OpenMP to sleep rather than spin while idle, ``dfc.cli.main``.)"""


# -- quiet, json, warnings ---------------------------------------------------------------------------------------
quiet_option = click.option("-q", "--quiet", is_flag=True,
                            help="No progress bar, warnings or notes (errors and the summary remain).")
json_option = click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
                           help="Also write the summary as JSON to this file (- for standard output; the text "
                                "summary then goes to standard error).")


def write_json(path: str, data: dict) -> None:
    """``data`` as indented JSON to ``path`` (atomically), or to standard output when ``path`` is ``-``."""
    from ..io.atomic import write_bytes_atomic

    text = json.dumps(data, indent=2) + "\n"
    if path == "-":
        click.echo(text, nl=False)
    else:
        write_bytes_atomic(path, text.encode())


def shown(path: str) -> str:
    """A path as a summary names it: ``-`` is standard output."""
    return "standard output" if path == "-" else path


def stdout_taken(*paths) -> bool:
    """True when one of ``paths`` (outputs, the ``--json`` path) is ``-``: standard output carries data, so the
    text summary goes to standard error (``click.echo(..., err=stdout_taken(...))``)."""
    return any(p == "-" for p in paths)


def warn(message: str, quiet: bool) -> None:
    """One ``dfc: warning:`` line on standard error (the run goes on), unless ``quiet``."""
    if not quiet:
        click.echo(f"dfc: warning: {message}", err=True)


def note(message: str, quiet: bool) -> None:
    """One ``dfc: note:`` line on standard error, unless ``quiet``."""
    if not quiet:
        click.echo(f"dfc: note: {message}", err=True)


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
    from ..geometry.curves import curves_outside, read_curves

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
