"""Rendering a ``.dfield`` to an EXR or PNG file with a progress bar; shared by ``dfc decode`` and ``dfc zoom``."""

from __future__ import annotations

import click

from .options import progress_bar


def render_to_file(model, output: str, size: tuple[int, int], window, *, spp: int, half: bool, t, quiet: bool,
                   workers: int = 1, source=None, devices=None) -> str:
    """Render ``window`` at ``size`` into ``output`` (``dfc.render_file.write_render``: tiled EXR when large, else
    scanline EXR or PNG), ``workers`` processes rendering regions of ``source``. Memory stays bounded; the file
    appears only when complete. Returns the layout written ("tiled" or "scanline")."""
    from ..render_file import write_render

    with progress_bar(0, "render", quiet, unit="region") as bar:
        def callback(done, total):
            bar.total = total
            bar.update(1)

        return write_render(model, output, size, window, spp=spp, half=half, t=t, workers=workers, source=source,
                            devices=devices, callback=callback)


def check_time(model, t):
    """``t`` for a time-varying file (default its first time), refused for a static one."""
    times = model.config()["times"]
    if times is None:
        if t is not None:
            raise click.BadParameter("this file has no time axis", param_hint="'--time'")
        return None
    return times[0] if t is None else t
