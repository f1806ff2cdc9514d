"""``dfc solve SCENE -o OUT.dfield``: solve a diffusion-curve scene from Laplace's equation alone (``dfc.physics.solve``)."""

from __future__ import annotations

import click

from .options import (
    check_device,
    json_option,
    progress_bar,
    quiet_option,
    read_curves_checked,
    stdout_taken,
    threads_option,
    write_json,
)


@click.command()
@click.argument("scene_path", metavar="SCENE", type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="The .dfield file to write.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on the mesh's triangle count.")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Optimiser steps  [default: 1000].")
@click.option("--batch-size", type=click.IntRange(min=1), default=None,
              help="Interior points, and boundary points, per step  [default: 4096].")
@click.option("--boundary-weight", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Weight of the boundary term against the Dirichlet energy  [default: 1000].")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Adam's starting learning rate  [default: 0.01].")
@click.option("--dim", type=click.IntRange(1, 64), default=5, show_default=True, help="Feature channels per vertex.")
@click.option("--feature-bits", type=click.IntRange(1, 16), default=None,
              help="Bits per stored feature value  [default: 10].")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds features, decoder and sampling.")
@click.option("--device", default="cpu", show_default=True, help="torch device for the solve (cpu, cuda, cuda:1, ...).")
@click.option("--compare", "compare", type=click.IntRange(min=8), default=None, metavar="N",
              help="Also solve by finite differences on a grid N pixels on the long side and print the PSNR.")
@threads_option
@json_option
@quiet_option
def command(scene_path, output, max_triangles, steps, batch_size, boundary_weight, lr, dim, feature_bits, seed,
            device, compare, json_path, quiet):
    """Solve the diffusion-curve SCENE (XML, or JSON with side values) into OUTPUT with no data: the field is
    trained on the Dirichlet energy of Laplace's equation plus a boundary term holding the curves' two-sided
    values, with a zero-flux canvas border (as in dfc wos). OUTPUT is an ordinary .dfield; an existing one is
    replaced, atomically, once the new file is complete. SCENE - reads standard input.
    """
    import time
    from dataclasses import replace

    from ..io.atomic import write_bytes_atomic
    from ..physics.solve import SolveSettings, prepare, solve_scene

    if not output.lower().endswith(".dfield"):
        raise click.BadParameter(f"must end in .dfield, got {output!r}", param_hint="'-o' / '--output'")
    given = {k: v for k, v in (("steps", steps), ("batch_size", batch_size), ("boundary_weight", boundary_weight),
                               ("lr", lr), ("feature_bits", feature_bits)) if v is not None}
    settings = replace(SolveSettings(), max_triangles=max_triangles, dim=dim, seed=seed,
                       device=check_device(device), **given)
    curves = read_curves_checked(scene_path, quiet)
    clock = time.perf_counter()
    problem = prepare(curves, settings)
    seconds = {"mesh_s": time.perf_counter() - clock}
    with progress_bar(settings.steps, "solve", quiet) as bar:
        def callback(step, energy, boundary):
            bar.update(1)
            if step % 10 == 0:
                bar.set_postfix(energy=f"{energy:.4g}", boundary=f"{boundary:.3g}", refresh=False)

        blob, report = solve_scene(curves, settings, problem=problem, callback=callback)
    write_bytes_atomic(output, blob)
    err = stdout_taken(json_path)
    click.echo(f"wrote {output}: {report.total_bytes} bytes", err=err)
    for name, size in report.chunk_bytes.items():
        click.echo(f"  {name}  {size:>10} bytes", err=err)
    click.echo(f"mesh: {report.n_vertices} vertices, {report.n_triangles} triangles; {report.n_features} features",
               err=err)
    click.echo(f"last step: energy {report.energy:.5g}, boundary {report.boundary:.4g}", err=err)
    compared = _compare(blob, problem, compare) if compare is not None else None
    if compared is not None:
        click.echo(f"PSNR of the decoded file against the finite-difference reference on a {compared[0]}", err=err)
    seconds.update(report.seconds)
    click.echo("time: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in seconds.items()), err=err)
    if json_path:
        from dataclasses import asdict

        write_json(json_path, {"output": output, **asdict(report), "seconds": seconds,
                               "psnr_reference": None if compared is None else compared[1]})


def _compare(blob: bytes, problem, size: int) -> tuple[str, float]:
    """('W x H grid: P dB (data range R)', P) for the decoded file against ``dfc.physics.reference`` at that grid's
    pixel centres."""
    from ..codec import loads
    from ..metrics import psnr
    from ..physics.reference import solve_reference
    from ..physics.wos import grid_size

    width, height = grid_size(problem.domain, size)
    reference = solve_reference(problem.scene, max(2, width), max(2, height)).values
    rendered = loads(blob).render(width, height)
    value = psnr(reference, rendered, data_range=problem.data_range)
    return f"{width} x {height} grid: {value:.2f} dB (data range {problem.data_range:.4g})", value
