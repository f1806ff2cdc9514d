"""``dfc decode IN.dfield -o OUT.exr|png``: render a file at any resolution, whole domain or a window."""

from __future__ import annotations

import click

from ._options import SIZE, WINDOW, check_device, check_output, check_size, default_size
from .render_out import check_time, render_to_file



@click.command()
@click.argument("input_path", metavar="IN", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Image to write: .exr (linear, half or float) or .png (8-bit sRGB; HDR files tone-mapped).")
@click.option("--size", type=SIZE, help="Output size WxH in pixels [default: the domain's size in its units, "
              "long side clamped to 256..4096; a window keeps that long side].")
@click.option("--window", type=WINDOW, help="Render only x0,y0,x1,y1 (domain units) [default: the whole domain].")
@click.option("--spp", type=click.IntRange(1, 1024), default=1, show_default=True,
              help="Samples per output pixel (1: the pixel centre; more: averaged low-discrepancy points).")
@click.option("--float", "full_float", is_flag=True, help="Write 32-bit float EXR channels (default: half).")
@click.option("--time", "t", type=float, help="Time to render, for a time-varying file [default: its first time].")
@click.option("--device", default="cpu", show_default=True, help="torch device for rendering.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def command(input_path, output, size, window, spp, full_float, t, device, quiet):
    """Render IN to OUTPUT. Pixels sample the field at their centres (spec/conventions.md), so any size and any
    window of the domain can be rendered; large outputs are written in row blocks with bounded memory."""
    from ..codec import load
    from ..render import check_window

    check_output(output)
    check_size(size)
    model = load(input_path, device=check_device(device))
    domain = model.field.mesh.domain
    try:
        window = check_window(window, domain)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="'--window'") from None
    size = size or default_size(window, domain)
    render_to_file(model, output, size, window, spp=spp, half=not full_float, t=check_time(model, t), quiet=quiet)
    click.echo(f"wrote {output}: {size[0]}x{size[1]} of window {tuple(round(v, 6) for v in window)}")
