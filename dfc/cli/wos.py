"""``dfc wos SCENE -o SAMPLES.npz``: walk-on-spheres samples of a diffusion-curve scene (``dfc.physics.wos``)."""

from __future__ import annotations

from pathlib import Path

import click

from .options import json_option, positive, progress_bar, quiet_option, read_curves_checked, stdout_taken, write_json

REFERENCE_FORMATS = (".exr", ".npz")


@click.command()
@click.argument("scene_path", metavar="SCENE", type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Samples file to write (.npz, see spec/samples.md).")
@click.option("--resolution", type=click.IntRange(min=1), default=500, show_default=True,
              help="Pixels on the long side of the sampling grid (the short side follows the domain's aspect).")
@click.option("--spp", type=click.IntRange(min=1), default=11, show_default=True,
              help="Walks per pixel (one jittered point per pixel per pass).")
@click.option("--eps", type=float, callback=positive, default=None,
              help="Stopping distance to the curves, in the scene's units [default: 1e-4 × domain diagonal].")
@click.option("--max-steps", type=click.IntRange(min=1), default=None,
              help="Cap on the steps of one walk [default: 1000]; capped walks are counted.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--reference", "reference_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the finite-difference reference solution on the same grid (.exr or .npz).")
@json_option
@quiet_option
def command(scene_path, output, resolution, spp, eps, max_steps, seed, reference_path, json_path, quiet):
    """Sample the diffusion-curve SCENE (XML or JSON with side values) by walk-on-spheres into OUTPUT.

    Laplace's equation with the curves' two-sided colours as Dirichlet values and a zero-flux canvas border
    (walks reflect off it). Fit a field to the result with the codec, or compare with --reference. SCENE - reads
    standard input. The walks run on one core (vectorised numpy).
    """
    from ..io.samples import write_samples
    from ..physics.wos import DEFAULT_MAX_STEPS, Scene, grid_size, sample_scene

    if reference_path is not None and Path(reference_path).suffix.lower() not in REFERENCE_FORMATS:
        raise click.BadParameter(f"must end in {' or '.join(REFERENCE_FORMATS)}", param_hint="'--reference'")
    for path, hint in ((output, "'-o' / '--output'"), (reference_path, "'--reference'")):
        if path is not None and not Path(path).resolve().parent.is_dir():
            raise click.BadParameter(f"directory {Path(path).parent} does not exist", param_hint=hint)
    scene = Scene(read_curves_checked(scene_path, quiet))
    width, height = grid_size(scene.domain, resolution)
    total = width * height * spp
    capped = [0]
    with progress_bar(total, "walks", quiet, unit="walk") as bar:
        def progress(done, _total, n_capped):
            bar.update(done - bar.n)
            capped[0] = n_capped

        samples = sample_scene(scene, resolution, spp, eps=eps, seed=seed, callback=progress,
                               max_steps=DEFAULT_MAX_STEPS if max_steps is None else max_steps)
    reference = _solve_reference(scene, width, height) if reference_path is not None else None
    write_samples(output, samples)
    err = stdout_taken(json_path)
    click.echo(f"walks: {total} ({width} × {height} pixels × {spp} spp)", err=err)
    click.echo(f"walks that hit the step cap: {capped[0]} ({100.0 * capped[0] / total:.3g} %)", err=err)
    click.echo(f"wrote {output}", err=err)
    if reference is not None:
        _write_reference(reference_path, reference, samples.channels)
        click.echo(f"wrote {reference_path}", err=err)
    if json_path:
        write_json(json_path, {"walks": total, "width": width, "height": height, "spp": spp, "capped": capped[0],
                               "output": output, "reference": reference_path})


def _solve_reference(scene, width: int, height: int):
    from ..physics.reference import solve_reference

    return solve_reference(scene, max(2, width), max(2, height))


def _write_reference(path: str, reference, channels: list[str]) -> None:
    import numpy as np

    from ..io.atomic import atomic_path
    from ..io.image import write_exr

    if Path(path).suffix.lower() == ".exr":
        write_exr(path, reference.values.astype(np.float32), channels, half=False)
        return
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, image=reference.values.astype(np.float32),
                                domain=np.asarray(reference.domain, dtype=np.float64),
                                channels=np.asarray(channels, dtype=np.str_))
