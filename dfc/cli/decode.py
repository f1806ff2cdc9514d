"""``dfc decode IN.dfield -o OUT.exr|png``: render a file at any resolution, whole domain or a window."""

from __future__ import annotations

import re

import click
import numpy as np

from .options import SIZE, WINDOW, check_device, check_output, check_size, default_size
from .output import check_time, render_to_file


@click.command()
@click.argument("input_path", metavar="IN", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Image to write: .exr (linear, half or float) or .png (8-bit sRGB; HDR files tone-mapped).")
@click.option("--size", type=SIZE, help="Output size WxH in pixels [default: the domain's size in its units, "
              "long side clamped to 256..4096; a window keeps that long side].")
@click.option("--window", type=WINDOW, help="Render only x0,y0,x1,y1 (domain units) [default: the whole domain].")
@click.option("--spp", type=click.IntRange(1, 1024), default=1, show_default=True,
              help="Samples per output pixel (1: the pixel centre; more: averaged low-discrepancy points).")
@click.option("--edge-spp", type=click.IntRange(0, 4096), default=None,
              help="Samples averaged in the pixels a discontinuity crosses (anti-aliasing; 0: off)  [default: 64 "
                   "at or below the resolution of the image the file was fitted to, else 0].")
@click.option("--float", "full_float", is_flag=True, help="Write 32-bit float EXR channels (default: half).")
@click.option("--time", "t", type=float, help="Time to render, for a time-varying file [default: its first time].")
@click.option("--frames", "n_frames", type=click.IntRange(min=1),
              help="Render N frames evenly spaced over the file's time axis into OUTPUT, a printf pattern with one "
                   "integer field (e.g. out_%04d.exr), numbered from 0.")
@click.option("--device", default="cpu", show_default=True, help="torch device for rendering.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def command(input_path, output, size, window, spp, edge_spp, full_float, t, n_frames, device, quiet):
    """Render IN to OUTPUT. Pixels sample the field at their centres (spec/conventions.md), so any size and any
    window of the domain can be rendered; large outputs are written in row blocks with bounded memory.

    At or below the resolution of the image the file was fitted to, pixels that a discontinuity crosses are
    averaged over --edge-spp points, as the input's pixels were area averages (anti-aliasing); zoomed renders
    keep the edges sharp."""
    from ..codec import load
    from ..render import check_window, default_edge_spp

    if n_frames is not None and t is not None:
        raise click.UsageError("give either --time or --frames")
    pattern = check_pattern(output) if n_frames is not None else None
    check_output(output)
    check_size(size)
    model = load(input_path, device=check_device(device))
    domain = model.field.mesh.domain
    try:
        window = check_window(window, domain)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="'--window'") from None
    size = size or default_size(window, domain)
    if edge_spp is None:
        edge_spp = default_edge_spp(model, *size, window)
    options = {"spp": spp, "edge_spp": edge_spp, "half": not full_float, "quiet": quiet}
    if pattern is None:
        render_to_file(model, output, size, window, t=check_time(model, t), **options)
        click.echo(f"wrote {output}: {size[0]}x{size[1]} of window {tuple(round(v, 6) for v in window)}")
        return
    times = frame_times(model, n_frames)
    for k, tk in enumerate(times):
        render_to_file(model, pattern % k, size, window, t=tk, **options)
    click.echo(f"wrote {len(times)} frames {pattern % 0} .. {pattern % (len(times) - 1)}: {size[0]}x{size[1]}, "
               f"t = {times[0]:g} .. {times[-1]:g}")


def check_pattern(output: str) -> str:
    """``output`` when it holds exactly one printf integer field (``%d``, ``%04d``; ``%%`` is a literal %)."""
    fields = [f for f in re.findall(r"%%|%0?\d*d|%", output) if f != "%%"]
    if len(fields) != 1 or fields[0] == "%":
        raise click.BadParameter(f"with --frames, must hold one integer field such as %04d, got {output!r}",
                                 param_hint="'-o' / '--output'")
    return output


def frame_times(model, n: int) -> list[float]:
    """``n`` times evenly spaced over the file's time axis, first and last included (``n = 1``: the first)."""
    times = model.config()["times"]
    if times is None:
        raise click.BadParameter("this file has no time axis", param_hint="'--frames'")
    return [float(v) for v in np.linspace(times[0], times[-1], n)] if n > 1 else [float(times[0])]
