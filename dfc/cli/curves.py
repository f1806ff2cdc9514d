"""``dfc curves INPUT -o CURVES.json``: find the discontinuity curves of an input and write them as JSON curves.

The input's kind picks the extractor (``SOURCES``): an image (EXR, PNG, JPEG) goes to the raster extractor.
Another kind of input slots in as one more entry of ``SOURCES`` and its own options."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from .options import positive

_EXTRA = "curves"


def _is_image(path: Path) -> bool:
    """EXR, PNG or JPEG, by extension or by the file's first bytes."""
    from ..io.image import EXR_EXTENSIONS, PIL_EXTENSIONS

    if path.suffix.lower() in EXR_EXTENSIONS + PIL_EXTENSIONS:
        return True
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return False
    return head.startswith((b"\x76\x2f\x31\x01", b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff"))


SOURCES = [("image", _is_image)]
"""(kind, test) pairs tried in order on the input path; the first that accepts it decides the extractor."""


def _kind(path: Path) -> str:
    for kind, test in SOURCES:
        if test(path):
            return kind
    accepted = ", ".join(kind for kind, _ in SOURCES)
    raise click.BadParameter(f"{path}: not an input dfc can find curves in (accepted: {accepted}: .exr, .png, .jpg)",
                             param_hint="'INPUT'")


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Curves file to write (.json).")
@click.option("--sigma", type=float, callback=positive, default=1.0, show_default=True,
              help="Canny's Gaussian σ in pixels; larger for noisy images.")
@click.option("--low", type=float, callback=positive, default=0.05, show_default=True,
              help="Smallest step (perceptual units, ≈ relative contrast: 0.05 = 5 %) an edge continues over; "
                   "also the smallest jump kept.")
@click.option("--high", type=float, callback=positive, default=0.1, show_default=True,
              help="Smallest step (same units) that starts an edge.")
@click.option("--min-length", type=click.FloatRange(min=0.0), default=8.0, show_default=True, metavar="PX",
              help="Drop edge chains shorter than this many pixels.")
@click.option("--tolerance", type=float, callback=positive, default=0.05, show_default=True, metavar="PX",
              help="Largest distance in pixels from the edge points to the fitted lines and Béziers.")
@click.option("--max-blur", type=click.FloatRange(min=0.0), default=0.6, show_default=True, metavar="PX",
              help="Jumps only: an edge blurred more than a Gaussian of this σ (a ramp, a soft shadow) is not a curve.")
@click.option("--corner-angle", type=click.FloatRange(min=0.0, max=180.0, max_open=True), default=40.0,
              show_default=True, help="Turns sharper than this many degrees are corners.")
@click.option("--preview", type=click.Path(dir_okay=False), help="Also draw the curves over the image to this PNG.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Write a summary as JSON to this file ('-' for standard output).")
@click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")
def command(input_path, output, sigma, low, high, min_length, tolerance, max_blur, corner_angle, preview, json_path,
            quiet):
    """Find the discontinuity curves of INPUT and write them to OUTPUT as JSON curves (spec/curves.md).

    INPUT is an image (EXR, PNG or JPEG): curves are placed where its jumps are, to a fraction of a pixel, in
    pixel units over [0, W] × [0, H] (y down). Smooth ramps and steps below --low are not curves.
    """
    if not output.lower().endswith(".json"):
        raise click.BadParameter(f"must end in .json, got {output!r}", param_hint="'-o' / '--output'")
    if preview is not None and not preview.lower().endswith(".png"):
        raise click.BadParameter(f"must end in .png, got {preview!r}", param_hint="'--preview'")
    if low > high:
        raise click.BadParameter(f"--low ({low}) must not exceed --high ({high})", param_hint="'--low'")
    path = Path(input_path)
    kind = _kind(path)
    clock = time.perf_counter()
    if kind == "image":
        curves, summary, draw = _from_image(path, dict(sigma=sigma, low=low, high=high, min_length=min_length,
                                                       tolerance=tolerance, max_blur=max_blur,
                                                       corner_angle=corner_angle))
    from ..geometry.sources import write_json

    write_json(curves, output)
    if preview is not None:
        draw(curves, preview)
    summary.update(input=str(path), kind=kind, output=output, curves=curves.n_curves, pieces=len(curves),
                   lines=int((curves.degree == 1).sum()), cubics=int((curves.degree == 3).sum()),
                   length_px=_length(curves), seconds=round(time.perf_counter() - clock, 3))
    if not quiet:
        if not len(curves):
            click.echo("no jumps found: wrote an empty curve set (a valid curves file with no curves)", err=True)
        else:
            click.echo(f"{summary['curves']} curves, {summary['pieces']} pieces ({summary['lines']} lines, "
                       f"{summary['cubics']} cubics), {summary['length_px']:.0f} px long, "
                       f"in {summary['seconds']:.2f} s", err=True)
        click.echo(f"wrote {output}" + (f" and {preview}" if preview else ""), err=True)
    if json_path == "-":
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    elif json_path:
        from ..io.atomic import write_bytes_atomic

        write_bytes_atomic(json_path, (json.dumps(summary, indent=2) + "\n").encode())


def _from_image(path: Path, options: dict):
    """Curves of an image file, the summary's image fields, and a function drawing the preview."""
    try:
        import skimage  # noqa: F401
    except ImportError:
        raise click.ClickException(f"finding curves in images needs scikit-image: pip install 'dfc[{_EXTRA}]'")
    from ..errors import InputError
    from ..geometry.preview import draw_curves
    from ..geometry.sources.raster import RasterSettings, image_curves
    from ..io.image import read_image

    image = read_image(path)
    if image.width < 2 or image.height < 2:
        raise InputError(f"{path}: image is {image.width} × {image.height} pixels: curves need at least 2 × 2")
    settings = RasterSettings(**options)
    try:
        curves = image_curves(image.pixels, settings)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None
    summary = {"width": image.width, "height": image.height, "channels": image.channels,
               "settings": settings.to_dict()}

    def draw(curves, preview):
        draw_curves(curves, preview, background=image.pixels, hdr=image.hdr)

    return curves, summary, draw


def _length(curves) -> float:
    import numpy as np

    from ..geometry import bezier

    if not len(curves):
        return 0.0
    poly = bezier.flatten(curves.control_points, 16)
    return round(float(np.linalg.norm(np.diff(poly, axis=1), axis=2).sum()), 1)
