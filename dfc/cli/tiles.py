"""``dfc tiles FILE.dfield -o DIR [--format iiif|dzi] [--levels-beyond N]``: a static tile pyramid (``dfc.pyramid``)."""

from __future__ import annotations

from pathlib import Path

import click

from .options import json_option, progress_bar, quiet_option, threads_option, write_json

MAX_TILES = 100_000


@click.command()
@click.argument("input_path", metavar="FILE.dfield", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Directory to write (created).")
@click.option("--format", "fmt", type=click.Choice(["iiif", "dzi"]), default="iiif", show_default=True,
              help="IIIF Image API 3.0 level 0 (info.json and tiles) or Deep Zoom (NAME.dzi and NAME_files/).")
@click.option("--levels-beyond", type=click.IntRange(0, 20), default=2, show_default=True,
              help="Levels past the input's resolution: the deepest level has 2^N pixels per input pixel.")
@click.option("--tile-format", type=click.Choice(["png", "jpg"]), default="png", show_default=True)
@click.option("--base-url", help="IIIF: the id of info.json, the URL DIR is served at [default: DIR's name, relative "
                                 "to the viewer's page].")
@click.option("--max-tiles", type=click.IntRange(1), default=MAX_TILES, show_default=True,
              help="Refuse pyramids of more tiles (each level deeper has 4x as many).")
@threads_option
@json_option
@quiet_option
def command(input_path, output, fmt, levels_beyond, tile_format, base_url, max_tiles, json_path, quiet):
    """Write a static tile pyramid of FILE.dfield into DIR that any static web host and deep-zoom viewer (OpenSeadragon,
    Mirador, Leaflet-IIIF) can serve: the pixels dfc serve sends for the same tiles, down to 2^N times the input's
    resolution."""
    from ..codec import load
    from ..pyramid import count_tiles, write_pyramid
    from ..tiles import tile_grid

    model = load(input_path)
    grid = tile_grid(model, levels_beyond)
    total = count_tiles(grid, fmt)
    if total > max_tiles:
        raise click.UsageError(f"--levels-beyond {levels_beyond} makes {total} tiles, more than --max-tiles "
                               f"{max_tiles}: lower --levels-beyond or raise --max-tiles")
    name = Path(output).name or "image"
    stem = Path(input_path).stem
    with progress_bar(total, "tiles", quiet, unit="tile") as bar:
        written = write_pyramid(model, output, grid, fmt=fmt, name=name if fmt == "iiif" else stem,
                                base_url=base_url, tile_format=tile_format, callback=lambda done, _: bar.update(1))
    index = "info.json" if fmt == "iiif" else f"{stem}.dzi"
    click.echo(f"wrote {written} tiles to {output} ({index}; {grid.width}x{grid.height} pixels, "
               f"{grid.scale} per input pixel)", err=json_path == "-")
    if json_path:
        write_json(json_path, {"output": output, "format": fmt, "index": index, "tiles": written,
                               "width": grid.width, "height": grid.height, "scale": grid.scale})
