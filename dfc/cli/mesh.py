"""``dfc mesh CURVES -o preview.png|svg``: triangulate a curves file, validate it and draw the mesh."""

from __future__ import annotations

import time
from pathlib import Path

import click

from .options import positive


@click.command()
@click.argument("curves_path", metavar="CURVES", type=click.Path(exists=True, dir_okay=False))
@click.option("--max-area", type=float, callback=positive, help="Largest triangle area, in the curves' units².")
@click.option("--edge-length", type=float, callback=positive, help="Target edge length, in the curves' units.")
@click.option("--grading", type=click.FloatRange(min=0.0), help="Growth of the edge length per unit distance from the curves.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on the number of triangles.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Preview image to write: .png (1024 px on the long side) or .svg.")
def command(curves_path, max_area, edge_length, grading, max_triangles, output):
    """Triangulate CURVES (SVG, JSON or diffusion-curve XML), check the mesh and draw it to OUTPUT.

    Without size options the mesh aims at about 2,000 triangles over the domain plus those the curves force.
    """
    from ..geometry.curves import read_curves
    from ..geometry.preview import FORMATS, draw_mesh
    from ..geometry.triangulate import triangulate

    if Path(output).suffix.lower() not in FORMATS:
        raise click.BadParameter(f"must end in {' or '.join(FORMATS)}", param_hint="'-o' / '--output'")
    if max_area is not None and edge_length is not None:
        raise click.BadParameter("give --max-area or --edge-length, not both", param_hint="'--edge-length'")
    clock = time.perf_counter()
    curves = read_curves(curves_path)
    stats: dict = {}
    mesh = triangulate(curves, max_area=max_area, edge_length=edge_length, grading=grading,
                       max_triangles=max_triangles, stats=stats)
    mesh.validate()
    elapsed = time.perf_counter() - clock
    draw_mesh(mesh, output)
    click.echo(f"pieces in:              {stats['pieces_in']}")
    click.echo(f"pieces after clean-up:  {stats['pieces_clean']}")
    click.echo(f"vertices:               {mesh.n_vertices}")
    click.echo(f"triangles:              {mesh.n_triangles}")
    click.echo(f"discontinuous vertices: {mesh.n_disc_vertices}")
    click.echo(f"curved triangles:       {len(mesh.curved_triangles)}")
    click.echo(f"time:                   {elapsed:.2f} s")
    click.echo(f"wrote {output}")
