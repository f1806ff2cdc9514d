"""``dfc curves INPUT -o CURVES.json``: find the discontinuity curves of an input and write them as JSON curves.

The input's kind picks the extractor (``SOURCES``): a Mitsuba 3 scene (``.xml``) gives the visible silhouettes,
boundaries, creases and intersections of its geometry in its render's pixels (``dfc.geometry.sources.scene``); an
image (EXR, PNG, JPEG) gives the jumps of its pixels (``dfc.geometry.sources.raster``). Another kind of input slots
in as one more entry of ``SOURCES``.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import click

from .options import positive, progress_bar

SCENE_OPTIONS = ("sensor", "crease_angle", "no_creases", "no_intersections", "step")
IMAGE_OPTIONS = ("sigma", "low", "high", "min_length", "max_blur", "corner_angle")


@dataclass(frozen=True)
class Source:
    """One kind of input: ``accepts(path)`` recognises it; ``extract(path, options, stats, progress)`` returns
    (Curves, summary fields, ``draw(curves, preview_path)``); ``options`` are the command's options it reads."""

    kind: str
    accepts: Callable[[Path], bool]
    extract: Callable
    options: tuple[str, ...]


def _is_scene(path: Path) -> bool:
    """A Mitsuba 3 scene, or other XML (``dfc.io.sniff``; the scene reader says what it is instead)."""
    from ..io.sniff import XML_KINDS, file_kind

    return file_kind(path) in XML_KINDS


def _is_image(path: Path) -> bool:
    """EXR, PNG or JPEG (``dfc.io.sniff``: by content, else by extension)."""
    from ..io.sniff import IMAGE_KINDS, file_kind

    return file_kind(path) in IMAGE_KINDS


def _from_scene(path: Path, o: dict, stats: dict, progress):
    from ..io.preview import draw_curves
    from ..geometry.sources.scene import read_scene
    from ..io.mitsuba import flat_shaded

    curves = read_scene(str(path), sensor=o["sensor"], crease_angle=o["crease_angle"], creases=not o["no_creases"],
                        intersections=not o["no_intersections"], tolerance=o["tolerance"], step=o["step"],
                        stats=stats, progress=progress)

    def draw(curves, preview):
        from ..io.image import srgb_to_linear

        picture = srgb_to_linear(flat_shaded(str(path), sensor=o["sensor"]).clip(0, 1))  # display values -> linear
        draw_curves(curves, preview, background=picture, size=max(picture.shape[:2]))  # the film's own size

    return curves, {}, draw


def _from_image(path: Path, o: dict, stats: dict, progress):
    from ..errors import ExtraError, InputError
    from ..io.preview import draw_curves
    from ..io.image import read_image

    try:
        from ..geometry.sources.raster import RasterSettings, image_curves_filtered
    except ImportError:
        raise ExtraError("finding curves in images needs scikit-image: pip install 'dfc[curves]'") from None
    image = read_image(path)
    if image.width < 2 or image.height < 2:
        raise InputError(f"{path}: image is {image.width} × {image.height} pixels: curves need at least 2 × 2")
    settings = RasterSettings(tolerance=o["tolerance"], **{k: o[k] for k in IMAGE_OPTIONS})
    progress("edges")
    try:
        curves, pixel_filter, detection = image_curves_filtered(image.pixels, settings, o["pixel_filter"])
    except InputError as e:
        raise InputError(f"{path}: {e}") from None
    stats["pixel_filter"] = str(pixel_filter) + (f" (auto: {detection.evidence()})" if detection else " (as given)")
    summary = {"width": image.width, "height": image.height, "channels": image.channels,
               "settings": settings.to_dict(), "pixel_model": detection.to_dict() if detection else None}
    if o["prune_curves"]:
        from ..geometry.sources.prune import prune_curves

        progress("prune")
        pruned = prune_curves(image.pixels, curves, target_bytes=o["target_bytes"])
        curves = pruned.curves
        summary["pruned"] = pruned.to_dict()
        stats["curves_pruned"] = pruned.summary()
    before = None
    if o["refine"]:
        from ..geometry.sources.auto import ready_curves

        progress("refine")
        before = curves
        # a detected filter is detected again along the refined curves, as dfc encode --curves auto does
        curves, _, refined = ready_curves(image.pixels, curves, prune=False, pixel_filter=pixel_filter,
                                          detected=detection is not None)
        summary["refined"] = refined.to_dict()
        stats["refinement"] = refined.summary()
        if refined.pixel_filter != str(pixel_filter):
            stats["pixel_filter"] += f"; {refined.pixel_filter} along the refined curves, refined again through it"
            summary["refined"]["pixel_filter"] = refined.pixel_filter
        if refined.warning:
            stats["warning"] = refined.warning

    def draw(curves, preview):
        draw_curves(curves, preview, background=image.pixels, hdr=image.hdr, before=before)

    return curves, summary, draw


SOURCES = (Source("Mitsuba 3 scene", _is_scene, _from_scene, SCENE_OPTIONS),
           Source("image", _is_image, _from_image, (*IMAGE_OPTIONS, "pixel_filter", "refine", "prune_curves",
                                                                       "target_bytes")))
"""Tried in order on the input path; the first that accepts it extracts the curves."""


def _source(path: Path, ctx: click.Context) -> Source:
    source = next((s for s in SOURCES if s.accepts(path)), None)
    if source is None:
        raise click.BadParameter(f"{path}: not an input dfc can find curves in (a Mitsuba 3 scene .xml, or an "
                                 "image: .exr, .png, .jpg)", param_hint="'INPUT'")
    for other in SOURCES:
        for name in set(other.options) - set(source.options):
            if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT:
                flag = "--" + name.replace("_", "-")
                raise click.UsageError(f"{flag} applies to a {other.kind}, not to a {source.kind}")
    return source


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The curves file to write (.json, spec/curves.md).")
@click.option("--tolerance", type=float, default=0.05, show_default=True, callback=positive, metavar="PX",
              help="Largest distance in pixels of the written lines and cubics from the edges found.")
@click.option("--sensor", type=click.IntRange(min=0), default=0, show_default=True,
              help="Scene: which sensor (a perspective camera) to project into, by index.")
@click.option("--crease-angle", type=click.FloatRange(0, 180), default=30.0, show_default=True,
              help="Scene: mesh edges whose faces turn by at least this many degrees are creases.")
@click.option("--no-creases", is_flag=True, help="Scene: silhouettes, boundaries and intersections only.")
@click.option("--no-intersections", is_flag=True,
              help="Scene: skip the curves where two meshes cut through each other.")
@click.option("--step", type=float, default=0.5, show_default=True, callback=positive,
              help="Scene: visibility is sampled every this many pixels along each edge, then bisected.")
@click.option("--sigma", type=float, callback=positive, default=1.0, show_default=True,
              help="Image: Canny's Gaussian σ in pixels; larger for noisy images.")
@click.option("--low", type=float, callback=positive, default=0.05, show_default=True,
              help="Image: smallest step (perceptual units, ≈ relative contrast: 0.05 = 5 %) an edge continues "
                   "over; also the smallest jump kept.")
@click.option("--high", type=float, callback=positive, default=0.1, show_default=True,
              help="Image: smallest step (same units) that starts an edge.")
@click.option("--min-length", type=click.FloatRange(min=0.0), default=8.0, show_default=True, metavar="PX",
              help="Image: drop edge chains shorter than this many pixels.")
@click.option("--max-blur", type=click.FloatRange(min=0.0), default=0.6, show_default=True, metavar="PX",
              help="Image, jumps only: an edge blurred more than a Gaussian of this σ (a ramp, a soft shadow) is "
                   "not a curve.")
@click.option("--corner-angle", type=click.FloatRange(min=0.0, max=180.0, max_open=True), default=40.0,
              show_default=True, help="Image: turns sharper than this many degrees are corners.")
@click.option("--pixel-filter", "pixel_filter", default="auto", show_default=True, metavar="FILTER",
              help="Image: how its pixels were made (auto, point, box[:N], gaussian[:STDDEV], tent, "
                   "blackman-harris[:WIDTH], mitchell): the sub-pixel step model's kernel; auto detects it along the "
                   "curves found with the box, as dfc encode does.")
@click.option("--refine", is_flag=True,
              help="Image: move the curves' control points until the pixels they cross are explained by sharp steps "
                   "seen through the pixel filter (dfc.geometry.sources.refine); the preview shows the curves before "
                   "(thin, grey) and after.")
@click.option("--prune-curves/--no-prune-curves", "prune_curves", default=False, show_default=True,
              help="Image: drop the curves that do not earn their bytes in a dfc file (the squared error a curve "
                   "removes against a continuous field across it, per byte of the mesh it forces; "
                   "dfc.geometry.sources.prune), as dfc encode --curves auto does.")
@click.option("--target-bytes", type=click.IntRange(min=1), metavar="N",
              help="Image, with --prune-curves: prune for a file of at most N bytes (fewer curves kept for smaller N), "
                   "as dfc encode --target-bytes N does.")
@click.option("--preview", type=click.Path(dir_okay=False),
              help="Also draw the curves over the input (a scene: a flat-shaded picture of it) to this PNG.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Also write the summary as JSON to this file ('-': standard output).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar and no notes (errors and the summary remain).")
@click.pass_context
def command(ctx, input_path, output, tolerance, preview, json_path, quiet, **options):
    """Write the discontinuity curves of INPUT to OUTPUT (JSON curves, ready for 'dfc mesh' and 'dfc encode').

    \b
    A Mitsuba 3 scene (.xml; needs pip install 'dfc[render]'): the visible silhouette, boundary and crease edges
    of its meshes (creases: faces turning by --crease-angle or more), the exact outlines of its spheres, disks
    and cylinders, and where meshes cut through each other, in the pixels of the image the sensor renders:
    the domain is [0, W] x [0, H], y down, the film's crop window when it has one. Visibility comes from
    Mitsuba's own ray tracer and every visibility change is placed to 0.001 pixels.
    \b
    An image (EXR, PNG or JPEG; needs pip install 'dfc[curves]'): curves where its jumps are, to a fraction of
    a pixel, over [0, W] x [0, H]; smooth ramps and steps below --low are not curves. A constant image gives an
    empty (valid) curves file.

    Chains become lines and cubic Béziers within --tolerance.
    """
    if not output.lower().endswith(".json"):
        raise click.BadParameter(f"must end in .json, got {output!r}", param_hint="'-o' / '--output'")
    if preview is not None and not preview.lower().endswith(".png"):
        raise click.BadParameter(f"must end in .png, got {preview!r}", param_hint="'--preview'")
    if options["low"] > options["high"]:
        raise click.BadParameter(f"--low ({options['low']}) must not exceed --high ({options['high']})",
                                 param_hint="'--low'")
    if options["target_bytes"] is not None and not options["prune_curves"]:
        raise click.UsageError("--target-bytes sizes the pruning: give it with --prune-curves")
    path = Path(input_path)
    source = _source(path, ctx)
    stats: dict = {}
    clock = time.perf_counter()
    with progress_bar(None, "curves", quiet, unit="stage") as bar:
        def progress(stage: str) -> None:
            bar.set_description_str(stage)
            bar.update(1)

        curves, summary, draw = source.extract(path, {**options, "tolerance": tolerance}, stats, progress)
    from ..geometry.sources.jsonfile import write_json

    write_json(curves, output)
    if preview is not None:
        draw(curves, preview)
    summary = {"input": str(path), "kind": source.kind, "output": output, "curves": curves.n_curves,
               "pieces": len(curves), "lines": int((curves.degree == 1).sum()),
               "cubics": int((curves.degree == 3).sum()), "length_px": _length(curves), **summary, **stats,
               "seconds": round(time.perf_counter() - clock, 3)}
    if not len(curves) and not quiet:
        click.echo("dfc: note: no curves found: wrote an empty curve set (a valid curves file)", err=True)
    _print_summary(summary, stats, output, preview, err=json_path == "-")
    if json_path == "-":
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    elif json_path:
        from ..io.atomic import write_bytes_atomic

        write_bytes_atomic(json_path, (json.dumps(summary, indent=2) + "\n").encode())


def _print_summary(summary: dict, stats: dict, output: str, preview: str | None, err: bool) -> None:
    """The human summary: on standard output, or standard error when standard output carries ``--json -``."""
    def echo(line):
        click.echo(line, err=err)

    echo(f"{summary['curves']} curves, {summary['pieces']} pieces ({summary['lines']} lines, "
         f"{summary['cubics']} cubics), {summary['length_px']:.0f} px long, in {summary['seconds']:.2f} s")
    for key, value in stats.items():
        if key == "warning":
            click.echo(f"dfc: warning: {value}", err=True)
        elif not key.endswith("_s"):
            echo(f"{key.replace('_', ' '):>22}: {value}")
    seconds = {k[:-2]: v for k, v in stats.items() if k.endswith("_s")}
    if seconds:
        echo("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in seconds.items()))
    echo(f"wrote {output}" + (f" and {preview}" if preview else ""))


def _length(curves) -> float:
    """Total length in domain units of the curves' pieces (each flattened into 16 segments)."""
    import numpy as np

    from ..geometry import bezier

    if not len(curves):
        return 0.0
    poly = bezier.flatten(curves.control_points, 16)
    return round(float(np.linalg.norm(np.diff(poly, axis=1), axis=2).sum()), 1)
