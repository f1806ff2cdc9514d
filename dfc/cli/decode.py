"""``dfc decode IN.dfield -o OUT.exr|png``: render a file at any resolution, whole domain or a window."""

from __future__ import annotations

import os
import re
import sys

import click
import numpy as np

from .options import (
    SIZE,
    WINDOW,
    binary_stream,
    check_device,
    check_size,
    default_size,
    json_option,
    quiet_option,
    shown,
    stdout_taken,
    threads_option,
    warn,
    write_json,
)
from .output import FORMAT_OPTION, check_time, output_format, plan_render, render_to_file


@click.command()
@click.argument("input_path", metavar="IN", type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, allow_dash=True),
              help="Image to write: .exr (linear, half or float) or .png (8-bit sRGB; HDR files tone-mapped); - for "
                   "standard output (with --format).")
@FORMAT_OPTION
@click.option("--size", type=SIZE, help="Output size WxH in pixels [default: the domain's size in its units, "
              "long side clamped to 256..4096; a window keeps that long side].")
@click.option("--window", type=WINDOW, help="Render only x0,y0,x1,y1 (domain units) [default: the whole domain].")
@click.option("--spp", type=click.IntRange(1, 1024), default=1, show_default=True,
              help="Samples per output pixel (1: the pixel centre; more: averaged low-discrepancy points).")
@click.option("--edge-spp", type=click.IntRange(0, 4096), default=None,
              help="Samples averaged in the pixels a discontinuity crosses (anti-aliasing; 0: off)  [default: 64 "
                   "at or below the resolution of the image the file was fitted to, else 0].")
@click.option("--pixel-filter", "pixel_filter", metavar="FILTER",
              help="Output pixel filter: point, box[:N], gaussian[:STDDEV], tent, blackman-harris[:WIDTH], mitchell "
                   "[default: the file's on the input's grid, box when shrinking, point when enlarging].")
@click.option("--float", "full_float", is_flag=True, help="Write 32-bit float EXR channels (default: half).")
@click.option("--time", "t", type=float, help="Time to render, for a time-varying file [default: its first time].")
@click.option("--frames", "n_frames", type=click.IntRange(min=1),
              help="Render N frames evenly spaced over the file's time axis into OUTPUT, a printf pattern with one "
                   "integer field (e.g. out_%04d.exr), numbered from 0.")
@click.option("--device", default="cpu", show_default=True,
              help="torch device for rendering; with --workers and cuda, worker k renders on cuda:k mod GPUs.")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="Processes rendering tiles (or row blocks) in parallel; the output is the same for any count.")
@threads_option
@json_option
@quiet_option
def command(input_path, output, fmt, size, window, spp, edge_spp, pixel_filter, full_float, t, n_frames, device, workers,
            json_path, quiet):
    """Render IN (- reads standard input) to OUTPUT. Pixels sample the field at their centres
    (spec/conventions.md), so any size and any window of the domain can be rendered. Memory stays bounded for any
    size: EXR outputs above 4096 x 4096 pixels are written as tiled EXR tile by tile (up to 1048576 pixels per side),
    smaller ones and PNG (up to 65536 per side) in row blocks. Before rendering, the output's size, its bytes at most
    and the estimated time are printed, and a render the disk cannot hold is refused. An existing OUTPUT is
    replaced, atomically, once the new file is complete.

    On the grid of the image the file was fitted to, pixels near a discontinuity are filtered with the pixel filter
    the encoder found in the input (header pixel_filter; box for older files), so the input's pixels come back;
    smaller renders average each output pixel's area near the discontinuities (box), zoomed renders keep the
    edges sharp (point). --pixel-filter or --edge-spp (box with that many points) override the rule. The output
    is the same for any --workers and tiling."""
    from ..codec import load, loads
    from ..io.bands import MAX_BAND_SIDE
    from ..errors import InputError
    from ..pixel_filter import parse
    from ..render import check_window, default_pixel_filter

    if n_frames is not None and t is not None:
        raise click.UsageError("give either --time or --frames")
    if n_frames is not None and output == "-":
        raise click.UsageError("--frames writes one file per frame: give a pattern such as out_%04d.exr, not -")
    pattern = check_pattern(output) if n_frames is not None else None
    fmt = output_format(output, fmt, full_float)
    if fmt == "png":
        check_size(size, why="; PNG output stops there: write .exr (tiled) for larger renders")
    else:
        check_size(size, limit=MAX_BAND_SIDE)
    if workers > 1 and input_path == "-":
        raise click.UsageError("--workers loads IN in each worker: give a file, not - (standard input)")
    device = check_device(device)
    model = loads(binary_stream(sys.stdin).read(), device=device) if input_path == "-" else \
        load(input_path, device=device)
    devices = _worker_devices(device, workers)
    domain = model.field.mesh.domain
    try:
        window = check_window(window, domain)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="'--window'") from None
    if window[2] <= domain[0] or window[0] >= domain[2] or window[3] <= domain[1] or window[1] >= domain[3]:
        warn(f"the window {tuple(round(v, 6) for v in window)} lies entirely outside the domain "
             f"{tuple(round(v, 6) for v in domain)}: every pixel takes the value at the nearest border point", quiet)
    size = size or default_size(window, domain)
    if pixel_filter is not None and edge_spp is not None:
        raise click.UsageError("give either --pixel-filter or --edge-spp")
    rule = "--pixel-filter"
    if pixel_filter is not None:
        try:
            pixel_filter = str(parse(pixel_filter))
        except InputError as e:
            raise click.BadParameter(str(e), param_hint="'--pixel-filter'") from None
    elif edge_spp is None:
        pixel_filter, rule = default_pixel_filter(model, *size, window)
    edge_spp = edge_spp or 0
    times = frame_times(model, n_frames) if pattern is not None else [check_time(model, t)]
    plan_render(model, output, size, window, spp=spp, fmt=fmt, half=not full_float, t=times[0], frames=len(times),
                quiet=quiet)
    outputs = [pattern % k for k in range(len(times))] if pattern is not None else [output]
    for path, tk in zip(outputs, times):
        layout = render_to_file(model, path, size, window, spp=spp, half=not full_float, t=tk, quiet=quiet, fmt=fmt,
                                workers=workers, source=input_path, devices=devices, edge_spp=edge_spp,
                                pixel_filter=pixel_filter)
    err = stdout_taken(output, json_path)
    used = f"pixel filter {pixel_filter} ({rule})" if pixel_filter else f"edge spp {edge_spp}"
    if pattern is None:
        layout_note = f" ({layout} EXR)" if fmt == "exr" else ""
        click.echo(f"wrote {shown(output)}: {size[0]}x{size[1]} of window {tuple(round(v, 6) for v in window)}"
                   f"{layout_note}, {used}", err=err)
    else:
        click.echo(f"wrote {len(times)} frames {outputs[0]} .. {outputs[-1]}: {size[0]}x{size[1]}, "
                   f"t = {times[0]:g} .. {times[-1]:g}", err=err)
    if json_path:
        write_json(json_path, {"outputs": outputs, "format": fmt, "size": list(size), "window": list(window),
                               "spp": spp, "edge_spp": edge_spp, "pixel_filter": pixel_filter, "layout": layout,
                               "times": None if times == [None] else times,
                               "bytes": None if output == "-" else [os.path.getsize(p) for p in outputs]})


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


def _worker_devices(device: str, workers: int) -> list[str]:
    """Devices of the render workers: ``device`` for each, or with CUDA every visible GPU in turn from ``device``'s."""
    import torch

    if not device.startswith("cuda") or workers == 1:
        return [device]
    first = torch.device(device).index or 0
    count = torch.cuda.device_count()
    return [f"cuda:{(first + k) % count}" for k in range(workers)]
