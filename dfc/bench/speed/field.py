"""``dfc benchmark field``: feature-field query speed against the MLP it feeds (target ratio ≤ 0.5).

Builds a ~50k-triangle curved mesh from random crossing cubics (``dfc.geometry.triangulate``), then times on
``--points`` uniform random queries: point location, interpolation (location + (index, weight)
pairs + feature gather, i.e. ``FeatureField.features``), a bare 5→64→64→3 ReLU MLP on the same
features, their ratio, and one training step at ``--batch`` points (features → MLP → MSE →
backward → Adam step). Each time is the best of ``--repeat`` runs, for each ``--threads`` count, alone and beside a
busy neighbour (``dfc.bench.neighbour``).
"""

from __future__ import annotations

import click
import torch
from torch import nn

from ...command import json_option, quiet_option, stdout_taken, write_json
from ..timing import best_seconds
from .mesh import random_cubics


def _thread_counts(ctx, param, value) -> tuple[int, ...]:
    try:
        counts = tuple(int(v) for v in value.split(","))
    except ValueError:
        counts = ()
    if not counts or min(counts) < 1:
        raise click.BadParameter(f"expected comma-separated thread counts ≥ 1, got {value!r}")
    return counts


THREADS_OPTION = click.option("--threads", "thread_counts", default="1,2", show_default=True, callback=_thread_counts,
                              help="Comma-separated torch CPU thread counts, each timed in turn.")
NEIGHBOUR_OPTION = click.option("--neighbour/--no-neighbour", default=True, show_default=True,
                                help="Also time each thread count beside a busy neighbour: another dfc encode with "
                                     "the same thread count (dfc.bench.neighbour).")


def conditions(thread_counts, neighbour: bool):
    """Yield (threads, "none" | "busy") for every timed condition, torch set to that many threads and, for "busy",
    a neighbour encode running with as many."""
    from ..neighbour import busy_neighbour

    for threads in thread_counts:
        torch.set_num_threads(threads)
        yield threads, "none"
        if neighbour:
            with busy_neighbour(threads):
                yield threads, "busy"


@click.command()
@click.option("--triangles", "n_triangles", type=click.IntRange(100), default=50_000, show_default=True,
              help="Triangle count to aim at.")
@click.option("--curves", "n_curves", type=click.IntRange(1), default=40, show_default=True,
              help="Random input cubics (curved triangles and junctions).")
@click.option("--points", "n_points", type=click.IntRange(1), default=1_000_000, show_default=True,
              help="Query points per timed call.")
@click.option("--batch", type=click.IntRange(1), default=1 << 16, show_default=True, help="Training batch size.")
@click.option("--repeat", type=click.IntRange(1), default=3, show_default=True, help="Runs per timing (best kept).")
@click.option("--device", default="cpu", show_default=True, help="torch device (cpu, cuda, ...).")
@THREADS_OPTION
@NEIGHBOUR_OPTION
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@json_option
@quiet_option
def command(n_triangles: int, n_curves: int, n_points: int, batch: int, repeat: int, device: str,
            thread_counts: tuple[int, ...], neighbour: bool, seed: int, json_path: str | None, quiet: bool) -> None:
    """Time point location + interpolation against the MLP, and one training step, for each --threads count, on
    a quiet machine and beside a busy neighbour."""
    from ...field import FeatureField
    from ...geometry.triangulate import triangulate

    dev = torch.device(device)
    mesh = triangulate(random_cubics(n_curves, seed), max_area=1.3 / n_triangles)
    field = FeatureField(mesh, dim=5, seed=seed, device=dev)
    mlp = nn.Sequential(nn.Linear(5, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 3)).to(dev)
    gen = torch.Generator(device=dev).manual_seed(seed)
    xy = torch.rand((n_points, 2), generator=gen, device=dev, dtype=torch.float64)
    opt = torch.optim.Adam(list(field.parameters()) + list(mlp.parameters()), lr=1e-2, betas=(0.9, 0.99))
    xb = torch.rand((batch, 2), generator=gen, device=dev, dtype=torch.float64)
    target = torch.rand((batch, 3), generator=gen, device=dev)

    def step():
        opt.zero_grad(set_to_none=True)
        loss = nn.functional.mse_loss(mlp(field.features(xb)), target)
        loss.backward()
        opt.step()

    stats = {"device": str(dev), "triangles": mesh.n_triangles, "curved_triangles": len(mesh.curved_triangles),
             "disc_edges": len(mesh.disc_edges), "n_features": field.n_features, "points": n_points, "batch": batch,
             "runs": []}
    err = stdout_taken(json_path)
    click.echo(f"mesh: {stats['triangles']} triangles, {stats['curved_triangles']} curved, "
               f"{stats['disc_edges']} discontinuous edges; {n_points} points, training batch {batch}, on {dev}",
               err=err)
    click.echo(f"{'threads':>7} {'neighbour':>9} {'location':>10} {'loc.+interp.':>13} {'MLP 5-64-64-3':>14} "
               f"{'ratio':>6} {'train step':>11} {'samples/s':>10}", err=err)
    for threads, beside in conditions(thread_counts, neighbour):
        with torch.no_grad():
            clamped = field.locator.clamp(xy)
            feats = field.features(xy)
            locate_s = best_seconds(lambda: field.locator(clamped), repeat, dev)
            field_s = best_seconds(lambda: field.features(xy), repeat, dev)
            mlp_s = best_seconds(lambda: mlp(feats), repeat, dev)
        step_s = best_seconds(step, repeat, dev)
        run = {"threads": threads, "neighbour": beside, "locate_s": locate_s, "field_s": field_s, "mlp_s": mlp_s,
               "ratio": field_s / mlp_s, "train_step_s": step_s, "train_samples_per_s": batch / step_s}
        stats["runs"].append(run)
        click.echo(f"{threads:>7} {beside:>9} {locate_s * 1e3:>7.1f} ms {field_s * 1e3:>10.1f} ms "
                   f"{mlp_s * 1e3:>11.1f} ms {run['ratio']:>6.3f} {step_s * 1e3:>8.1f} ms {batch / step_s:>10.3g}",
                   err=err)
    click.echo("ratio: location + interpolation over the MLP (target <= 0.5); neighbour busy: another dfc encode "
               "with as many threads", err=err)
    if json_path:
        write_json(json_path, stats)
