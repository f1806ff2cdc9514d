"""``dfc zoom IN.dfield --center X,Y --zoom Z -o OUT``: render the window of domain size / Z around a point."""

from __future__ import annotations

import sys

import click

from .options import (
    POINT,
    SIZE,
    binary_stream,
    check_device,
    check_size,
    default_size,
    json_option,
    quiet_option,
    shown,
    stdout_taken,
    threads_option,
    write_json,
)
from .output import FORMAT_OPTION, check_time, output_format, plan_render, render_to_file


@click.command()
@click.argument("input_path", metavar="IN", type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("--center", required=True, type=POINT, help="Centre X,Y of the window, in domain units.")
@click.option("--zoom", "zoom", required=True, type=click.FloatRange(min=1e-6, max=1e9),
              help="Magnification: the window is the domain's size divided by this (e.g. 100).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, allow_dash=True),
              help="Image to write: .exr or .png; - for standard output (with --format).")
@FORMAT_OPTION
@click.option("--size", type=SIZE, help="Output size WxH [default: as dfc decode renders the whole domain].")
@click.option("--spp", type=click.IntRange(1, 1024), default=1, show_default=True, help="Samples per output pixel.")
@click.option("--pixel-filter", "pixel_filter", metavar="FILTER",
              help="Output pixel filter (as dfc decode) [default: point when enlarging, box when shrinking].")
@click.option("--float", "full_float", is_flag=True, help="Write 32-bit float EXR channels (default: half).")
@click.option("--time", "t", type=float, help="Time to render, for a time-varying file.")
@click.option("--device", default="cpu", show_default=True, help="torch device for rendering.")
@threads_option
@json_option
@quiet_option
def command(input_path, center, zoom, output, fmt, size, spp, pixel_filter, full_float, t, device, json_path, quiet):
    """Render a zoom window of IN around --center: at --zoom 100 the window spans 1/100 of the domain in each
    direction. The centre must lie inside the domain; the window may reach past its border (values there are those
    at the nearest border point). Output, plan, pixel filter and overwriting as in dfc decode; the summary says which
    filter it used."""
    from ..codec import load, loads
    from ..errors import InputError
    from ..pixel_filter import parse
    from ..render import default_pixel_filter, zoom_window

    if pixel_filter is not None:
        try:
            pixel_filter = str(parse(pixel_filter))
        except InputError as e:
            raise click.BadParameter(str(e), param_hint="'--pixel-filter'") from None

    fmt = output_format(output, fmt, full_float)
    check_size(size)
    device = check_device(device)
    model = loads(binary_stream(sys.stdin).read(), device=device) if input_path == "-" else \
        load(input_path, device=device)
    domain = model.field.mesh.domain
    if not (domain[0] <= center[0] <= domain[2] and domain[1] <= center[1] <= domain[3]):
        raise click.BadParameter(f"{center} is outside the domain {tuple(domain)}", param_hint="'--center'")
    window = zoom_window(domain, center, zoom, inside=False)
    size = size or default_size(window, domain)
    pixel_filter, rule = (pixel_filter, "--pixel-filter") if pixel_filter else default_pixel_filter(model, *size,
                                                                                                    window)
    t = check_time(model, t)
    plan_render(model, output, size, window, spp=spp, fmt=fmt, half=not full_float, t=t, frames=1, quiet=quiet)
    render_to_file(model, output, size, window, spp=spp, half=not full_float, t=t, quiet=quiet, fmt=fmt,
                   pixel_filter=pixel_filter)
    click.echo(f"wrote {shown(output)}: {size[0]}x{size[1]}, {zoom:g}x zoom, window "
               f"{tuple(round(v, 6) for v in window)}, pixel filter {pixel_filter} ({rule})",
               err=stdout_taken(output, json_path))
    if json_path:
        write_json(json_path, {"output": output, "format": fmt, "size": list(size), "window": list(window),
                               "zoom": zoom, "spp": spp, "pixel_filter": pixel_filter})
