"""``dfc benchmark field``: feature-field query speed against the MLP it feeds (target ratio ≤ 0.5).

Builds a ~50k-triangle curved mesh from random crossing cubics (``dfc.geometry.triangulate``), then times on
``--points`` uniform random queries: point location, interpolation (location + (index, weight)
pairs + feature gather, i.e. ``FeatureField.features``), a bare 5→64→64→3 ReLU MLP on the same
features, their ratio, and one training step at ``--batch`` points (features → MLP → MSE →
backward → Adam step). Each time is the best of ``--repeat`` runs.
"""

from __future__ import annotations

import json

import click
import torch
from torch import nn

from ...io.atomic import write_bytes_atomic
from ..timing import best_seconds
from .mesh import random_cubics


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
@click.option("--threads", type=click.IntRange(1), default=None, help="torch CPU threads (default: torch's).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the figures to this JSON file.")
def command(n_triangles: int, n_curves: int, n_points: int, batch: int, repeat: int, device: str,
            threads: int | None, seed: int, json_path: str | None) -> None:
    """Time point location + interpolation against the MLP, and one training step."""
    from ...field import FeatureField
    from ...geometry.triangulate import triangulate

    if threads is not None:
        torch.set_num_threads(threads)
    dev = torch.device(device)
    mesh = triangulate(random_cubics(n_curves, seed), max_area=1.3 / n_triangles)
    field = FeatureField(mesh, dim=5, seed=seed, device=dev)
    mlp = nn.Sequential(nn.Linear(5, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 3)).to(dev)
    gen = torch.Generator(device=dev).manual_seed(seed)
    xy = torch.rand((n_points, 2), generator=gen, device=dev, dtype=torch.float64)

    with torch.no_grad():
        clamped = field.locator.clamp(xy)
        feats = field.features(xy)
        locate_s = best_seconds(lambda: field.locator(clamped), repeat, dev)
        field_s = best_seconds(lambda: field.features(xy), repeat, dev)
        mlp_s = best_seconds(lambda: mlp(feats), repeat, dev)

    opt = torch.optim.Adam(list(field.parameters()) + list(mlp.parameters()), lr=1e-2, betas=(0.9, 0.99))
    xb = torch.rand((batch, 2), generator=gen, device=dev, dtype=torch.float64)
    target = torch.rand((batch, 3), generator=gen, device=dev)

    def step():
        opt.zero_grad(set_to_none=True)
        loss = nn.functional.mse_loss(mlp(field.features(xb)), target)
        loss.backward()
        opt.step()

    step_s = best_seconds(step, repeat, dev)
    stats = {
        "device": str(dev),
        "threads": torch.get_num_threads(),
        "triangles": mesh.n_triangles,
        "curved_triangles": len(mesh.curved_triangles),
        "disc_edges": len(mesh.disc_edges),
        "n_features": field.n_features,
        "points": n_points,
        "locate_s": locate_s,
        "field_s": field_s,
        "mlp_s": mlp_s,
        "ratio": field_s / mlp_s,
        "batch": batch,
        "train_step_s": step_s,
    }
    click.echo(f"mesh: {stats['triangles']} triangles, {stats['curved_triangles']} curved, "
               f"{stats['disc_edges']} discontinuous edges; {n_points} points on {dev} ({stats['threads']} threads)")
    click.echo(f"{'point location':>28}: {locate_s * 1e3:9.1f} ms")
    click.echo(f"{'location + interpolation':>28}: {field_s * 1e3:9.1f} ms")
    click.echo(f"{'MLP 5-64-64-3':>28}: {mlp_s * 1e3:9.1f} ms")
    click.echo(f"{'ratio (target <= 0.5)':>28}: {stats['ratio']:9.3f}")
    click.echo(f"{f'training step, batch {batch}':>28}: {step_s * 1e3:9.1f} ms ({batch / step_s:.3g} samples/s)")
    if json_path:
        write_bytes_atomic(json_path, json.dumps(stats, indent=2).encode())
