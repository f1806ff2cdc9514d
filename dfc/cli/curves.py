"""``dfc curves INPUT -o CURVES.json``: extract the discontinuity curves of an input and write them as JSON.

The input's kind picks the extractor (``SOURCES``): a Mitsuba 3 scene (``.xml``) gives the visible silhouettes,
boundaries, creases and intersections of its geometry, projected into its render's pixels.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from .options import positive, progress_bar


def _from_scene(path: str, options: dict, stats: dict, progress):
    from ..geometry.sources.scene import read_scene

    return read_scene(path, sensor=options["sensor"], crease_angle=options["crease_angle"],
                      creases=options["creases"], intersections=options["intersections"],
                      tolerance=options["tolerance"], step=options["step"], stats=stats, progress=progress)


def _scene_preview(path: str, options: dict):
    from ..io.mitsuba import flat_shaded

    return flat_shaded(path, sensor=options["sensor"])


SOURCES = {".xml": ("Mitsuba 3 scene", _from_scene, _scene_preview)}
"""Lower-case input extension -> (what it is, extractor(path, options, stats, progress) -> Curves,
preview background(path, options) -> (H, W, 3) display values in [0, 1])."""


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The curves file to write (.json, spec/curves.md).")
@click.option("--sensor", type=click.IntRange(min=0), default=0, show_default=True,
              help="Scene: which sensor (a perspective camera) to project into, by index.")
@click.option("--crease-angle", type=click.FloatRange(0, 180), default=30.0, show_default=True,
              help="Scene: mesh edges whose faces turn by at least this many degrees are creases.")
@click.option("--no-creases", is_flag=True, help="Scene: silhouettes, boundaries and intersections only.")
@click.option("--no-intersections", is_flag=True,
              help="Scene: skip the curves where two meshes cut through each other.")
@click.option("--tolerance", type=float, default=0.05, show_default=True, callback=positive,
              help="Largest distance (pixels) of the written lines and cubics from the projected mesh edges.")
@click.option("--step", type=float, default=0.5, show_default=True, callback=positive,
              help="Scene: visibility is sampled every this many pixels along each edge, then bisected.")
@click.option("--preview", type=click.Path(dir_okay=False),
              help="Also draw the curves over a flat-shaded picture of the input to this PNG.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Also write the summary as JSON to this file ('-': standard output, the text summary then "
                   "goes to standard error).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def command(input_path, output, sensor, crease_angle, no_creases, no_intersections, tolerance, step, preview,
            json_path, quiet):
    """Write the discontinuity curves of INPUT to OUTPUT (JSON curves, ready for 'dfc mesh' and 'dfc encode').

    INPUT is a Mitsuba 3 scene (.xml, needs the render extra: pip install 'dfc[render]'). Its curves are the
    visible silhouette, boundary and crease edges of its meshes (creases: faces turning by --crease-angle or
    more), the exact outlines of its spheres, disks and cylinders, and where meshes cut through each other, in
    the pixels of the image the sensor renders: the domain is [0, W] x [0, H], y down, the film's crop window
    when it has one. Visibility comes from Mitsuba's own ray tracer and every visibility change is placed to
    0.001 pixels; chains of mesh edges become lines and cubic Béziers within --tolerance.
    """
    from ..errors import InputError
    from ..geometry.preview import draw_curves
    from ..geometry.sources.jsonfile import write_json

    if not output.lower().endswith(".json"):
        raise click.BadParameter(f"must end in .json, got {output!r}", param_hint="'-o' / '--output'")
    if preview is not None and not preview.lower().endswith(".png"):
        raise click.BadParameter(f"must end in .png, got {preview!r}", param_hint="'--preview'")
    source = SOURCES.get(Path(input_path).suffix.lower())
    if source is None:
        accepted = ", ".join(f"{what} ({ext})" for ext, (what, _, _) in SOURCES.items())
        raise InputError(f"{input_path}: cannot extract curves from this kind of file; dfc curves reads {accepted}")
    what, extract, background = source
    options = dict(sensor=sensor, crease_angle=crease_angle, creases=not no_creases,
                   intersections=not no_intersections, tolerance=tolerance, step=step)
    stats: dict = {}
    with progress_bar(None, "curves", quiet) as bar:
        bar.unit = "stage"

        def progress(stage: str) -> None:
            bar.set_description_str(stage)
            bar.update(1)

        curves = extract(input_path, options, stats, progress)
    write_json(curves, output)
    if preview is not None:
        import numpy as np

        picture = (np.clip(background(input_path, options), 0, 1) * 255 + 0.5).astype(np.uint8)
        draw_curves(curves, preview, picture)
    to_stdout = json_path == "-"
    echo = (lambda line: click.echo(line, err=True)) if to_stdout else click.echo
    counts = {k: v for k, v in stats.items() if not k.endswith("_s")}
    seconds = {k[:-2]: v for k, v in stats.items() if k.endswith("_s")}
    for key, value in counts.items():
        echo(f"{key.replace('_', ' '):>22}: {value}")
    echo("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in seconds.items()))
    echo(f"wrote {output}" + (f" and {preview}" if preview else ""))
    if json_path:
        doc = json.dumps({"input": str(input_path), "kind": what, "output": str(output), **stats}, indent=2) + "\n"
        if to_stdout:
            sys.stdout.write(doc)
        else:
            from ..io.atomic import write_bytes_atomic

            write_bytes_atomic(json_path, doc.encode())
