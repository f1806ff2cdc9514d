"""``dfc mesh CURVES -o preview.png|svg``: triangulate a curves file, validate it and draw the mesh."""

from __future__ import annotations

import time
from pathlib import Path

import click

from .options import json_option, positive, quiet_option, read_curves_checked, stdout_taken, write_json


@click.command()
@click.argument("curves_path", metavar="CURVES", type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("--max-area", type=float, callback=positive, help="Largest triangle area, in the curves' units².")
@click.option("--edge-length", type=float, callback=positive, help="Target edge length, in the curves' units.")
@click.option("--grading", type=click.FloatRange(min=0.0), help="Growth of the edge length per unit distance from the curves.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on the number of triangles.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Preview image to write: .png (1024 px on the long side) or .svg.")
@json_option
@quiet_option
def command(curves_path, max_area, edge_length, grading, max_triangles, output, json_path, quiet):
    """Triangulate CURVES (SVG, JSON or diffusion-curve XML; - reads standard input), check the mesh and draw it
    to OUTPUT.

    Without size options the mesh aims at about 2,000 triangles over the domain plus those the curves force.
    """
    from ..io.preview import FORMATS, draw_mesh
    from ..geometry.triangulate import triangulate

    if Path(output).suffix.lower() not in FORMATS:
        raise click.BadParameter(f"must end in {' or '.join(FORMATS)}", param_hint="'-o' / '--output'")
    if max_area is not None and edge_length is not None:
        raise click.BadParameter("give --max-area or --edge-length, not both", param_hint="'--edge-length'")
    clock = time.perf_counter()
    curves = read_curves_checked(curves_path, quiet)
    stats: dict = {}
    mesh = triangulate(curves, max_area=max_area, edge_length=edge_length, grading=grading,
                       max_triangles=max_triangles, stats=stats)
    mesh.validate()
    elapsed = time.perf_counter() - clock
    draw_mesh(mesh, output)
    figures = {"pieces_in": stats["pieces_in"], "pieces_clean": stats["pieces_clean"], "vertices": mesh.n_vertices,
               "triangles": mesh.n_triangles, "discontinuous_vertices": mesh.n_disc_vertices,
               "curved_triangles": len(mesh.curved_triangles), "seconds": elapsed, "output": output}
    err = stdout_taken(json_path)
    for label, key in (("pieces in", "pieces_in"), ("pieces after clean-up", "pieces_clean"), ("vertices", "vertices"),
                       ("triangles", "triangles"), ("discontinuous vertices", "discontinuous_vertices"),
                       ("curved triangles", "curved_triangles")):
        click.echo(f"{label + ':':<24}{figures[key]}", err=err)
    click.echo(f"{'time:':<24}{elapsed:.2f} s", err=err)
    click.echo(f"wrote {output}", err=err)
    if json_path:
        write_json(json_path, figures)
