"""Rendering a ``.dfield`` to an EXR or PNG file in row blocks; shared by ``dfc decode`` and ``dfc zoom``."""

from __future__ import annotations

import click

from .options import progress_bar


def render_to_file(model, output: str, size: tuple[int, int], window, *, spp: int, half: bool, t, quiet: bool,
                   edge_spp: int = 0) -> None:
    """Stream a ``size`` render of ``window`` into ``output`` (.exr: half or float; .png: 8-bit sRGB, tone-mapped
    for HDR files; ``edge_spp``: see ``dfc.render.row_blocks``). Memory stays bounded by the render block; the file
    appears only when complete."""
    from ..io.image import ExrBlockWriter, PngBlockWriter
    from ..render import row_blocks

    width, height = size
    channels = model.channels
    if output.lower().endswith(".png"):
        if len(channels) > 4:
            raise click.UsageError(f"PNG holds 1 to 4 channels; this file has {len(channels)}: write .exr")
        writer = PngBlockWriter(output, width, height, len(channels), hdr=_is_hdr(model))
    else:
        writer = ExrBlockWriter(output, width, height, channels, half=half)
    with writer, progress_bar(height, "render", quiet) as bar:
        bar.unit = "row"
        for y0, block in row_blocks(model, width, height, window, spp=spp, t=t, edge_spp=edge_spp):
            writer.write_rows(y0, block)
            bar.update(len(block))


def _is_hdr(model) -> bool:
    """HDR files (log transform, or an HDR input recorded by the encoder) are tone-mapped into PNG."""
    encoder = getattr(model, "header", {}).get("encoder", {})
    return model.transform == "log" or encoder.get("hdr") is True


def check_time(model, t):
    """``t`` for a time-varying file (default its first time), refused for a static one."""
    times = model.config()["times"]
    if times is None:
        if t is not None:
            raise click.BadParameter("this file has no time axis", param_hint="'--time'")
        return None
    return times[0] if t is None else t
