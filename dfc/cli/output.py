"""Rendering a ``.dfield`` to an EXR or PNG file (``dfc.render_file``: tiled EXR when large, in worker processes
with ``--workers``) with a progress bar; shared by ``dfc decode`` and ``dfc zoom``: the output's format (by extension,
or ``--format`` for ``-``, standard output), the plan printed before a render starts (size, bytes, estimated time)
and the free-space check."""

from __future__ import annotations

import errno
import math
import os
import shutil
import tempfile
import time

import click

from .options import progress_bar, stdout_file

FORMATS = ("exr", "png")
PROBE_SIDE = 96
"""The estimate of a render's time times a ``PROBE_SIDE`` × ``PROBE_SIDE`` render of the same window."""
FORMAT_OPTION = click.option("--format", "fmt", type=click.Choice(FORMATS),
                             help="Output format [default: by OUTPUT's extension; needed for - (standard output)].")


def output_format(output: str, fmt: str | None, full_float: bool) -> str:
    """"exr" or "png" for ``output`` (``-``: standard output, which needs ``fmt``); ``click.BadParameter`` or
    ``click.UsageError`` for an extension that is neither, a ``fmt`` the extension contradicts, or ``--float`` with
    PNG (8-bit)."""
    if output == "-" and fmt is None:
        raise click.UsageError("writing to standard output (-o -) needs --format exr or --format png")
    ext = None if output == "-" else os.path.splitext(output)[1].lower().lstrip(".")
    if ext is not None and ext not in FORMATS:
        raise click.BadParameter(f"must end in .exr or .png, got {output!r}", param_hint="'-o' / '--output'")
    if fmt is not None and ext is not None and fmt != ext:
        raise click.BadParameter(f"--format {fmt} contradicts the extension of {output!r}", param_hint="'--format'")
    fmt = fmt or ext
    if full_float and fmt == "png":
        raise click.UsageError("--float applies to EXR output; PNG holds 8-bit sRGB values: write .exr")
    return fmt


def output_bytes(size: tuple[int, int], channels: int, fmt: str, half: bool) -> int:
    """Upper bound of the file's bytes: the uncompressed samples plus the format's own overhead (compression only
    ever makes the file smaller)."""
    width, height = size
    if fmt == "png":
        raw = (width * channels + 1) * height
        return raw + raw // 100 + 4096  # zlib's stored blocks, chunk headers
    return width * height * channels * (2 if half else 4) + 16 * math.ceil(height / 16) + 4096


def plan_render(model, output: str, size: tuple[int, int], window, *, spp: int, fmt: str, half: bool, t, frames: int,
                quiet: bool) -> None:
    """Before a render: print (unless ``quiet``) the output's size, its bytes at most and the estimated time, and
    refuse (``OSError`` ENOSPC, one line) when the output directory's free space cannot hold the worst case."""
    width, height = size
    channels = len(model.channels)
    need = output_bytes(size, channels, fmt, half) * frames
    directory = tempfile.gettempdir() if output == "-" else os.path.dirname(os.path.abspath(output))
    usage = shutil.disk_usage(directory) if os.path.isdir(directory) else None
    if usage is not None and usage.total > 0 and need > usage.free:  # (pseudo file systems report 0 of 0)
        raise OSError(errno.ENOSPC, f"not enough free disk space for a {width}x{height} {fmt.upper()} output: it "
                      f"needs up to {_bytes(need)} and {_bytes(usage.free)} are free in {directory} (try a smaller "
                      f"--size)", "standard output" if output == "-" else output)
    if quiet:
        return
    seconds = frames * estimate_seconds(model, size, window, spp=spp, t=t)
    kind = f"{'half' if half else 'float'} EXR" if fmt == "exr" else "8-bit PNG"
    what = f"{frames} frames of " if frames > 1 else ""
    click.echo(f"decode: {what}{width}x{height}, {channels} channel{'s' if channels > 1 else ''} "
               f"({', '.join(model.channels)}) to {kind}: at most {_bytes(need)}, {_duration(seconds)}", err=True)


def estimate_seconds(model, size: tuple[int, int], window, *, spp: int, t) -> float:
    """Seconds a ``size`` render of ``window`` takes here, from the time of a ``PROBE_SIDE``² render (after one
    warm-up) scaled by the number of points; the writer's compression adds a little."""
    from ..render import render

    side = min(PROBE_SIDE, max(size))
    render(model, 8, 8, window, spp=1, t=t)  # warm-up: first calls allocate
    clock = time.perf_counter()
    render(model, side, side, window, spp=spp, t=t)
    per_point = (time.perf_counter() - clock) / (side * side * spp)
    return per_point * size[0] * size[1] * spp


def render_to_file(model, output: str, size: tuple[int, int], window, *, spp: int, half: bool, t, quiet: bool,
                   fmt: str | None = None, workers: int = 1, source=None, devices=None, edge_spp: int = 0,
                   pixel_filter: str | None = None) -> str:
    """Render ``window`` at ``size`` into ``output`` (.exr: half or float, tiled when large; .png: 8-bit sRGB,
    tone-mapped for HDR files; ``-``: standard output in ``fmt``), ``workers`` processes rendering regions of
    ``source`` (``dfc.render_file.write_render``; ``edge_spp``, ``pixel_filter``: see ``dfc.render.render_region``). Memory stays
    bounded; the file appears only when complete. Returns the layout written ("tiled" or "scanline")."""
    from ..render_file import write_render

    fmt = fmt or os.path.splitext(output)[1].lower().lstrip(".")
    with stdout_file(output, "." + fmt) as path, progress_bar(0, "render", quiet, unit="region") as bar:
        def callback(done, total):
            bar.total = total
            bar.update(1)

        return write_render(model, path, size, window, spp=spp, half=half, t=t, workers=workers, source=source,
                            devices=devices, callback=callback, edge_spp=edge_spp, pixel_filter=pixel_filter)


def _bytes(n: int) -> str:
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} bytes"


def _duration(seconds: float) -> str:
    if seconds < 1:
        return "under a second"
    if seconds < 90:
        return f"about {seconds:.0f} s"
    if seconds < 5400:
        return f"about {seconds / 60:.0f} min"
    return f"about {int(seconds // 3600)} h {round(seconds % 3600 / 60)} min"



def check_time(model, t):
    """``t`` for a time-varying file (default its first time), refused for a static one."""
    times = model.config()["times"]
    if times is None:
        if t is not None:
            raise click.BadParameter("this file has no time axis", param_hint="'--time'")
        return None
    return times[0] if t is None else t
