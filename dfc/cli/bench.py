"""``dfc bench``: dfc against equal-size baselines (hash grid, ReLU field, raster) at increasing zoom; with
``--solve``, against the physics-informed baselines (TanH field, SIREN, MLP) on a diffusion-curve scene."""

from __future__ import annotations

import json
from pathlib import Path

import click

from .options import (
    POINT,
    check_device,
    json_option,
    quiet_option,
    read_curves_checked,
    stdout_taken,
    threads_option,
    write_json,
)


def _zooms(ctx, param, value):
    if value and any(not z >= 1 for z in value):
        raise click.BadParameter(f"zoom factors must be ≥ 1, got {list(value)}")
    return value


@click.command()
@click.argument("input_path", metavar="[INPUT]", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", type=click.Path(exists=True, dir_okay=False),
              help="Discontinuity curves of INPUT (SVG, JSON or diffusion-curve XML).")
@click.option("--scene", help="Benchmark an analytic scene instead of INPUT (see --list-scenes).")
@click.option("--solve", "solve_path", type=click.Path(exists=True, dir_okay=False),
              help="Physics-informed solve of this diffusion-curve scene (XML, or JSON with side values) by dfc "
              "and the TanH field, SIREN and MLP baselines, against the finite-difference reference.")
@click.option("--list-scenes", is_flag=True, help="List the analytic scenes and exit.")
@click.option("--probe", "probes", type=POINT, multiple=True,
              help="Zoom centre X,Y in domain units (repeatable; default for scenes: points on discontinuities).")
@click.option("-o", "--output", type=click.Path(file_okay=False), help="Directory for results.json, results.md, "
              "contact.png and dfc.dfield (created if missing).")
@click.option("--zoom", "zooms", type=float, multiple=True, callback=_zooms,
              help="Zoom factor (repeatable)  [default: 1, 10, 33, 100].")
@click.option("--methods", help="Comma-separated methods to run  [default: dfc,hashgrid,relu,raster; with "
              "--solve: dfc,tanh_field,siren,tanh_mlp].")
@click.option("--bytes", "target_bytes", type=click.IntRange(min=1),
              help="Byte budget; with dfc, its file is sized to it (else every method gets the .dfield's size).")
@click.option("--steps", type=click.IntRange(min=1), default=1000, show_default=True,
              help="Optimiser steps of every method.")
@click.option("--batch-size", type=click.IntRange(min=1), help="Samples per step  [default: 16384; with --solve: "
              "1024 interior and 1024 boundary points].")
@click.option("--size", type=click.IntRange(min=8), help="Scenes: longer side of the raster fitted  "
              "[default: the domain's longer side in its units]; --solve: of the reference grid [default: 256].")
@click.option("--render", type=click.IntRange(min=8), default=256, show_default=True,
              help="Window resolution (longer side, pixels).")
@click.option("--spp", type=click.IntRange(min=1), default=4, show_default=True, help="Points averaged per pixel.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on dfc's mesh triangle count.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds every fit and the sampling.")
@click.option("--device", default="cpu", show_default=True, help="torch device (cpu, cuda, cuda:1, ...).")
@click.option("--fit-curves-to-image", is_flag=True, help="Scale the curves' domain onto INPUT's [0, W] x [0, H].")
@threads_option
@json_option
@quiet_option
def command(input_path, curves_path, scene, solve_path, list_scenes, probes, output, zooms, methods, target_bytes,
            steps, batch_size, size, render, spp, max_triangles, seed, device, fit_curves_to_image, json_path, quiet):
    """Compare dfc with other methods at equal file size: fit dfc and every baseline at the .dfield's byte count,
    render each probe window at each zoom and write the PSNR table (results.json, results.md) and a contact sheet
    (contact.png) to OUTPUT. (Speed and scale of dfc's own stages: dfc benchmark.)

    \b
    dfc bench INPUT --curves CURVES --probe X,Y [--probe ...] -o DIR
    dfc bench --scene NAME -o DIR
    dfc bench --solve SCENE -o DIR
    dfc bench --list-scenes

    Scenes are measured against their exact value at every zoom; a user image only at zoom 1 (against
    itself, rendered at its own resolution) — larger zooms are rendered but have no reference. --solve trains
    every method on the Laplace equation's loss alone and measures it against a finite-difference solve
    (--render, --spp and --zoom do not apply). --json also writes results.json's record to a file (- for
    standard output, the table then going to standard error).
    """
    from ..bench.scenes import SCENES, SUMMARIES

    if list_scenes:
        for name in SCENES:
            click.echo(f"{name:10s} {SUMMARIES[name]}")
        return
    if sum(v is not None for v in (input_path, scene, solve_path)) != 1:
        raise click.UsageError("give one of INPUT (with --curves), --scene NAME and --solve SCENE")
    if output is None:
        raise click.UsageError("missing option '-o' / '--output'")
    if solve_path is not None:
        if curves_path or fit_curves_to_image or probes or zooms or target_bytes:
            raise click.UsageError("--curves, --fit-curves-to-image, --probe, --zoom and --bytes do not apply to "
                                   "--solve")
        _solve(solve_path, output, methods, steps, batch_size, size, max_triangles, seed, device, json_path, quiet)
        return
    if input_path is not None and curves_path is None:
        raise click.UsageError("INPUT needs --curves")
    if scene is not None and (curves_path or fit_curves_to_image):
        raise click.UsageError("--curves and --fit-curves-to-image apply to INPUT, not to --scene")
    from ..bench.compare import METHODS, ZOOMS, BenchSettings, markdown_table, run_bench, run_scene, write_outputs

    settings = BenchSettings(steps=steps, batch_size=batch_size or 1 << 14, size=size, render=render, spp=spp,
                             zooms=tuple(zooms) or ZOOMS, methods=_methods(methods, METHODS),
                             target_bytes=target_bytes, max_triangles=max_triangles, seed=seed,
                             device=check_device(device))
    settings.check()

    def progress(message: str) -> None:
        if not quiet:
            click.echo(f"bench: {message}", err=True)

    if scene is not None:
        from ..bench.scenes import get_scene

        result = run_scene(get_scene(scene), settings, probes=probes, progress=progress)
    else:
        from ..bench.scenes import curve_probes
        from ..codec import check_domain
        from ..io.image import read_image

        image = read_image(input_path)
        curves = check_domain(read_curves_checked(curves_path, quiet), image.width, image.height,
                              fit_curves_to_image)
        result = run_bench(image.pixels, curves, image.channels, probes=probes or curve_probes(curves),
                           settings=settings, name=input_path, progress=progress)
    for path in write_outputs(result, output):
        progress(f"wrote {path}")
    _finish(markdown_table(result.results), output, json_path)


def _finish(table: str, output: str, json_path: str | None) -> None:
    """Print the table (to standard error when ``--json -`` takes standard output) and copy results.json's record to
    ``json_path``."""
    click.echo(table, nl=False, err=stdout_taken(json_path))
    if json_path:
        write_json(json_path, json.loads((Path(output) / "results.json").read_text()))


def _methods(value: str | None, default: tuple[str, ...]) -> tuple[str, ...]:
    return default if value is None else tuple(m.strip() for m in value.split(",") if m.strip())


def _solve(path, output, methods, steps, batch_size, size, max_triangles, seed, device, json_path, quiet) -> None:
    """``dfc bench --solve``: see ``dfc.bench.solve``."""
    from ..bench.solve import SOLVE_METHODS, SolveBenchSettings, markdown_table, run_solve_bench, write_outputs

    settings = SolveBenchSettings(steps=steps, batch_size=batch_size or 1 << 10, size=size or 256,
                                  methods=_methods(methods, SOLVE_METHODS), max_triangles=max_triangles, seed=seed,
                                  device=check_device(device))
    settings.check()

    def progress(message: str) -> None:
        if not quiet:
            click.echo(f"bench: {message}", err=True)

    results = run_solve_bench(read_curves_checked(path, quiet), settings, name=path, progress=progress)
    for written in write_outputs(results, output):
        progress(f"wrote {written}")
    _finish(markdown_table(results), output, json_path)
