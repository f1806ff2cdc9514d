"""``dfc bench``: dfc against equal-size baselines (hash grid, ReLU field, raster) at increasing zoom."""

from __future__ import annotations

import click

from ._options import POINT, check_device


def _zooms(ctx, param, value):
    if value and any(not z >= 1 for z in value):
        raise click.BadParameter(f"zoom factors must be ≥ 1, got {list(value)}")
    return value


@click.command()
@click.argument("input_path", metavar="[INPUT]", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", type=click.Path(exists=True, dir_okay=False),
              help="Discontinuity curves of INPUT (SVG, JSON or diffusion-curve XML).")
@click.option("--scene", help="Benchmark an analytic scene instead of INPUT (see --list-scenes).")
@click.option("--list-scenes", is_flag=True, help="List the analytic scenes and exit.")
@click.option("--probe", "probes", type=POINT, multiple=True,
              help="Zoom centre X,Y in domain units (repeatable; default for scenes: points on discontinuities).")
@click.option("-o", "--output", type=click.Path(file_okay=False), help="Directory for results.json, results.md, "
              "contact.png and dfc.dfield (created if missing).")
@click.option("--zoom", "zooms", type=float, multiple=True, callback=_zooms,
              help="Zoom factor (repeatable)  [default: 1, 10, 33, 100].")
@click.option("--methods", default=",".join(("dfc", "hashgrid", "relu", "raster")), show_default=True,
              help="Comma-separated methods to run.")
@click.option("--bytes", "target_bytes", type=click.IntRange(min=1),
              help="Byte budget; with dfc, its file is sized to it (else every method gets the .dfield's size).")
@click.option("--steps", type=click.IntRange(min=1), default=1000, show_default=True,
              help="Optimiser steps of every method.")
@click.option("--batch-size", type=click.IntRange(min=1), default=1 << 14, show_default=True, help="Samples per step.")
@click.option("--size", type=click.IntRange(min=8), help="Scenes: longer side of the raster fitted  "
              "[default: the domain's longer side in its units].")
@click.option("--render", type=click.IntRange(min=8), default=256, show_default=True,
              help="Window resolution (longer side, pixels).")
@click.option("--spp", type=click.IntRange(min=1), default=4, show_default=True, help="Points averaged per pixel.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on dfc's mesh triangle count.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds every fit and the sampling.")
@click.option("--device", default="cpu", show_default=True, help="torch device (cpu, cuda, cuda:1, ...).")
@click.option("--fit-curves-to-image", is_flag=True, help="Scale the curves' domain onto INPUT's [0, W] x [0, H].")
@click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
def command(input_path, curves_path, scene, list_scenes, probes, output, zooms, methods, target_bytes, steps,
            batch_size, size, render, spp, max_triangles, seed, device, fit_curves_to_image, quiet):
    """Fit dfc and every baseline at the .dfield's byte count, render each probe window at each zoom and
    write the PSNR table (results.json, results.md) and a contact sheet (contact.png) to OUTPUT.

    \b
    dfc bench INPUT --curves CURVES --probe X,Y [--probe ...] -o DIR
    dfc bench --scene NAME -o DIR
    dfc bench --list-scenes

    Scenes are measured against their exact value at every zoom; a user image only at zoom 1 (against
    itself, rendered at its own resolution) — larger zooms are rendered but have no reference.
    """
    from ..scenes import SCENES

    if list_scenes:
        for name, factory in SCENES.items():
            click.echo(f"{name:10s} {(factory.__doc__ or '').split(':', 1)[-1].strip().splitlines()[0]}")
        return
    if (input_path is None) == (scene is None):
        raise click.UsageError("give either INPUT (with --curves) or --scene NAME")
    if output is None:
        raise click.UsageError("missing option '-o' / '--output'")
    if input_path is not None and curves_path is None:
        raise click.UsageError("INPUT needs --curves")
    if scene is not None and (curves_path or fit_curves_to_image):
        raise click.UsageError("--curves and --fit-curves-to-image apply to INPUT, not to --scene")
    from ..bench import ZOOMS, BenchSettings, markdown_table, run_bench, run_scene, write_outputs

    settings = BenchSettings(steps=steps, batch_size=batch_size, size=size, render=render, spp=spp,
                             zooms=tuple(zooms) or ZOOMS, methods=tuple(m.strip() for m in methods.split(",") if m),
                             target_bytes=target_bytes, max_triangles=max_triangles, seed=seed,
                             device=check_device(device))
    settings.check()

    def progress(message: str) -> None:
        if not quiet:
            click.echo(f"bench: {message}", err=True)

    if scene is not None:
        from ..scenes import get_scene

        result = run_scene(get_scene(scene), settings, probes=probes, progress=progress)
    else:
        from ..codec import check_domain
        from ..curves import read_curves
        from ..imageio import read_image
        from ..scenes import curve_probes

        image = read_image(input_path)
        curves = check_domain(read_curves(curves_path), image.width, image.height, fit_curves_to_image)
        result = run_bench(image.pixels, curves, image.channels, probes=probes or curve_probes(curves),
                           settings=settings, name=input_path, progress=progress)
    for path in write_outputs(result, output):
        progress(f"wrote {path}")
    click.echo(markdown_table(result.results), nl=False)
