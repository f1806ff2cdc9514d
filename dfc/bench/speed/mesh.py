"""``dfc benchmark mesh``: triangulate ~10k random cubic pieces into ~200k triangles and time each stage."""

from __future__ import annotations

import time

import click
import numpy as np

from ...command import quiet_option, stdout_taken, write_json
from ...geometry.curves import Curves


def random_cubics(n: int, seed: int = 0) -> Curves:
    """``n`` random cubics in the unit square (control points uniform in [0.05, 0.95]²), crossing each other."""
    rng = np.random.default_rng(seed)
    cp = 0.05 + 0.9 * rng.random((n, 4, 2))
    return Curves(
        domain=(0.0, 0.0, 1.0, 1.0),
        control_points=cp,
        degree=np.full(n, 3, dtype=np.int8),
        curve=np.arange(n),
        t_range=np.tile([0.0, 1.0], (n, 1)),
        names=[f"cubic {i}" for i in range(n)],
        sides=[None] * n,
    )


@click.command()
@click.option("--curves", "n_curves", type=click.IntRange(1), default=110, show_default=True,
              help="Number of random input cubics (110 give about 10k pieces after clean-up).")
@click.option("--triangles", "n_triangles", type=click.IntRange(100), default=200_000, show_default=True,
              help="Triangle count to aim at; sets max_area = 1.3 × domain area / triangles.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of the curves.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Also write the figures to this JSON file (- for standard output; the text then goes to "
                   "standard error).")
@quiet_option
def command(n_curves: int, n_triangles: int, seed: int, json_path: str | None, quiet: bool) -> None:
    """Time clean-up, conflict loop, density and CDT on random crossing cubics."""
    from ...geometry.triangulate import triangulate

    text_err = stdout_taken(json_path)
    curves = random_cubics(n_curves, seed)
    stats: dict = {}
    clock = time.perf_counter()
    mesh = triangulate(curves, max_area=1.3 / n_triangles, stats=stats)
    stats["total_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    mesh.validate()
    stats["validate_s"] = time.perf_counter() - clock
    stats["curved_triangles"] = len(mesh.curved_triangles)
    stats["disc_edges"] = len(mesh.disc_edges)
    for key in ("clean_s", "conflict_s", "density_s", "cdt_s", "total_s", "validate_s"):
        click.echo(f"{key[:-2]:>18}: {stats[key]:8.3f} s", err=text_err)
    for key in ("pieces_in", "pieces_clean", "pieces_final", "apexes", "steiner", "vertices", "triangles",
                "curved_triangles", "disc_edges"):
        click.echo(f"{key:>18}: {stats[key]:8d}", err=text_err)
    if json_path:
        write_json(json_path, stats)
