"""``dfc benchmark fem SOLUTION --curves BARRIERS``: compressing a FEM solution without leaking across barriers.

The paper's Fig. 14. ``SOLUTION`` is any triangle mesh with point data (``dfc encode``'s FEM input; e.g. the
output of ``samples/make_helmholtz.py``). The benchmark encodes it with dfc (``dfc.codec.encode_fem``) and prints

- the bytes of the solution file against the ``.dfield``, and the PSNR of the decoded file against the FEM nodal
  values (``EncodeReport.psnr``: points the fit was trained on) and, held out, against the finite element interpolant
  at the centroids of up to ``--interior-points`` elements (``interior_points``: points the fit never saw), for dfc
  and for a hash grid stored in the same bytes (``HashGrid.for_budget``, trained on the same samples for
  ``--hash-steps`` steps, by default as many as dfc's);
- the leakage check: at points ``--offset`` × the domain's longer side away from every barrier segment, on both
  sides (the middle 90 % of each segment, away from its ends), the mean and max absolute error against the FEM
  solution on that side, of dfc and of the hash grid, next to the mean jump of the FEM solution across the barrier,
  and dfc's max error as a share of the solution's max |u|;
- units (``--units``): dfc's encode of the same field with its values multiplied by each factor (default ×1e-4 and
  ×1e4 besides ×1): its nodal PSNR against the span of those values, bytes and leakage share, which should not
  depend on the factor (``dfc.field.units``).

``--fem-default`` encodes as ``dfc encode`` does without a mesh-size option (aiming at ``dfc.codec.FEM_TARGET_PSNR``
at the nodes) instead of with ``--max-triangles``.

A codec that leaks blends the two sides near the barrier: its error there approaches half the jump.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import click
import numpy as np

from ...command import quiet_option, stdout_taken, threads_option, write_json
from ...io.atomic import write_bytes_atomic

SIDE_POINTS = 200
"""Points per barrier segment and side in the leakage check."""
INTERIOR_POINTS = 100_000
"""Default number of element centroids in the held-out PSNR."""


def interior_points(solution, count: int = INTERIOR_POINTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Held-out points of a FEM solution: the centroids of ``count`` elements evenly spread over the element list
    (all when there are fewer). Returns xy (N, 2) float64, element (N,) int64 and barycentric (N, 3) float64.
    Training samples (``dfc.physics.fem.sample_fem``) are the nodes and uniformly random points, so a centroid is
    one with probability zero."""
    n = len(solution.triangles)
    tri = np.unique(np.linspace(0, n - 1, min(n, count)).round().astype(np.int64))
    bary = np.full((len(tri), 3), 1.0 / 3.0)
    xy = solution.points[solution.triangles[tri]].mean(axis=1)
    return xy, tri, bary


def side_points(segments: np.ndarray, offset: float, n: int = SIDE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Points ``offset`` to the left and to the right of segments (S, 2, 2), ``n`` per segment over the middle
    90 % of its length: left (S·n, 2), right (S·n, 2) float64 (left as in ``spec/curves.md``: y down)."""
    s = np.linspace(0.05, 0.95, n)
    a, b = segments[:, 0], segments[:, 1]
    d = b - a
    normal = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.linalg.norm(d, axis=1, keepdims=True)  # left normal
    mid = (a[:, None] + s[None, :, None] * d[:, None]).reshape(-1, 2)
    nrm = np.repeat(normal, n, axis=0)
    return mid + offset * nrm, mid - offset * nrm


@click.command()
@click.argument("solution_path", metavar="SOLUTION", type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The barrier curves (JSON or SVG).")
@click.option("--fields", help="Comma-separated point-data arrays [default: all].")
@click.option("--fem-sampling", type=click.Choice(["linear", "nearest"]), default="linear", show_default=True)
@click.option("--max-triangles", type=click.IntRange(min=2), default=8000, show_default=True,
              help="dfc mesh size.")
@click.option("--fem-default", is_flag=True,
              help="Encode as dfc encode does by default (aiming at the FEM target PSNR) instead of --max-triangles.")
@click.option("--units", "unit_factors", default="1e-4,1e4", show_default=True,
              help="Comma-separated factors: also encode the field with its values multiplied by each (empty: none).")
@click.option("--steps", type=click.IntRange(min=1), default=1000, show_default=True, help="dfc fit steps.")
@click.option("--hash-steps", type=click.IntRange(min=1), default=None,
              help="Hash-grid training steps  [default: --steps, as many as dfc's].")
@click.option("--batch-size", type=click.IntRange(min=1), default=1 << 14, show_default=True)
@click.option("--offset", type=click.FloatRange(min=0, min_open=True), default=1e-3, show_default=True,
              help="Distance of the check points from the barrier, as a fraction of the domain's longer side.")
@click.option("--interior-points", "n_interior", type=click.IntRange(min=1), default=INTERIOR_POINTS, show_default=True,
              help="Element centroids in the held-out PSNR against the finite element interpolant.")
@threads_option
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Also keep the .dfield here.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Also write the figures to this JSON file (- for standard output; the text then goes to "
                   "standard error).")
@quiet_option
def command(solution_path, curves_path, fields, fem_sampling, max_triangles, fem_default, unit_factors, steps,
            hash_steps, batch_size, offset, n_interior, seed, output, json_path, quiet):
    """Bytes, PSNR and leakage across the barriers of dfc and an equal-size hash grid on a FEM solution."""
    import torch

    from ...codec import EncodeSettings, encode_fem, loads
    from ...geometry.sources import read_curves
    from ...io.fem import read_fem
    from ...metrics import psnr
    from ...physics.fem import barrier_segments, evaluate_fem, fem_curves, interpolate, node_points, sample_fem
    from ...train.samplers import point_sampler
    from ..baselines import fit_baseline
    from ..baselines.hashgrid import HashGrid

    text_err = stdout_taken(json_path)
    solution = read_fem(solution_path, fields.split(",") if fields else None)
    curves = fem_curves(solution, read_curves(curves_path))
    in_bytes = Path(solution_path).stat().st_size
    click.echo(f"{solution_path}: {in_bytes} bytes, {len(solution.points)} nodes, {len(solution.triangles)} "
               f"triangles, channels {', '.join(solution.channels)}", err=text_err)
    try:
        factors = [float(f) for f in unit_factors.split(",") if f.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {unit_factors!r}", param_hint="--units")
    if not all(np.isfinite(f) and f != 0 for f in factors):
        raise click.BadParameter("factors must be finite and non-zero", param_hint="--units")
    settings = EncodeSettings(max_triangles=None if fem_default else max_triangles, steps=steps,
                              batch_size=batch_size, seed=seed)
    clock = time.perf_counter()
    every = max(1, steps // 10)
    blob, report = encode_fem(solution, curves, settings, sampling=fem_sampling, callback=lambda s, loss, p: (
        click.echo(f"  dfc step {s + 1}/{steps}, batch PSNR {p:.2f} dB", err=True)
        if not quiet and (s + 1) % every == 0 else None))
    dfc_s = time.perf_counter() - clock
    if output:
        write_bytes_atomic(output, blob)
    model = loads(blob)
    held_xy, held_tri, held_bary = interior_points(solution, n_interior)
    held_truth = interpolate(solution, held_tri, held_bary, held_xy, curves, fem_sampling)
    with torch.no_grad():
        dfc_held = psnr(held_truth, model(torch.from_numpy(held_xy)).numpy(), data_range=report.data_range)
    click.echo(f"dfc: {len(blob)} bytes ({in_bytes / len(blob):.1f}x smaller), PSNR {report.psnr:.2f} dB against the "
               f"nodal values (data range {report.data_range:.4g}), {dfc_held:.2f} dB held out at {len(held_xy)} "
               f"element centroids; {report.n_triangles} triangles, {dfc_s:.0f} s", err=text_err)
    click.echo(f"  {report.units}", err=text_err)
    if report.target_psnr is not None and report.psnr < report.target_psnr:
        click.echo(f"  the FEM target of {report.target_psnr:g} dB was not reached in its refinement rounds",
                   err=text_err)

    hash_steps = hash_steps or steps
    clock = time.perf_counter()
    xy, values = sample_fem(solution, curves, mode=fem_sampling, seed=seed)
    extent = max(curves.domain[2] - curves.domain[0], curves.domain[3] - curves.domain[1])
    grid = HashGrid.for_budget(len(blob), curves.domain, solution.channels, seed=seed,
                               finest_resolution=int(2 * np.sqrt(len(solution.points))))
    grid.init_mean(torch.from_numpy(values.mean(axis=0)))
    every = max(1, hash_steps // 10)
    fit_baseline(grid, point_sampler(xy, values, batch_size), hash_steps, seed=seed, callback=lambda s, loss, p: (
        click.echo(f"  hash grid step {s + 1}/{hash_steps}, batch PSNR {p:.2f} dB", err=True)
        if not quiet and (s + 1) % every == 0 else None))
    hash_s = time.perf_counter() - clock
    nodes = np.unique(solution.triangles)
    node_xy = torch.from_numpy(node_points(solution)[0])
    with torch.no_grad():
        grid_psnr = psnr(solution.values[nodes], grid(node_xy).numpy(), data_range=report.data_range)
        grid_held = psnr(held_truth, grid(torch.from_numpy(held_xy)).numpy(), data_range=report.data_range)
    click.echo(f"hash grid: {grid.stored_bytes()} bytes, PSNR {grid_psnr:.2f} dB against the nodal values, "
               f"{grid_held:.2f} dB held out; {hash_steps} steps, {hash_s:.0f} s", err=text_err)

    left, right = side_points(barrier_segments(curves), offset * extent)
    sides = (("left", left), ("right", right))
    truth = {side: evaluate_fem(solution, curves, p, mode=fem_sampling) for side, p in sides}
    jump = float(np.abs(truth["left"] - truth["right"]).mean())
    peak = float(np.abs(solution.values).max())
    leak: dict = {"offset": offset * extent, "points_per_side": len(left), "mean_jump": jump, "max_abs_u": peak}
    click.echo(f"leakage at {offset * extent:.3g} from the barrier ({len(left)} points per side), mean |jump| of the "
               f"FEM solution across it {jump:.4g}, max |u| {peak:.4g}; absolute error (mean / max):", err=text_err)
    for name, m in (("dfc", model), ("hash grid", grid)):
        row = _leakage(m, sides, truth, peak)
        leak[name] = row
        click.echo(f"  {name:<10} left {row['left']['mean']:.4g} / {row['left']['max']:.4g}   "
                   f"right {row['right']['mean']:.4g} / {row['right']['max']:.4g}   "
                   f"max / max |u| {row['share']:.4f}", err=text_err)
    units = [{"factor": 1.0, "psnr": report.psnr, "bytes": len(blob), "leakage_share": leak["dfc"]["share"],
              "triangles": report.n_triangles}]
    for factor in factors:
        if factor == 1.0:
            continue
        scaled = replace(solution, values=solution.values * factor)
        f_blob, f_report = encode_fem(scaled, curves, settings, sampling=fem_sampling)
        f_truth = {side: v * factor for side, v in truth.items()}
        units.append({"factor": factor, "psnr": f_report.psnr, "bytes": len(f_blob), "triangles": f_report.n_triangles,
                      "leakage_share": _leakage(loads(f_blob), sides, f_truth, peak * abs(factor))["share"]})
    if len(units) > 1:
        click.echo("units: the field with its values multiplied by a factor (PSNR at the nodes against the span of "
                   "those values)", err=text_err)
        for row in units:
            click.echo(f"  x{row['factor']:<8g} {row['psnr']:.2f} dB, {row['bytes']} bytes, {row['triangles']} "
                       f"triangles, leakage max / max |u| {row['leakage_share']:.4f}", err=text_err)
    if json_path:
        figures = {"solution": str(solution_path), "solution_bytes": in_bytes, "nodes": len(solution.points),
                   "fem_triangles": len(solution.triangles), "dfield_bytes": len(blob), "ratio": in_bytes / len(blob),
                   "dfc_psnr": report.psnr, "dfc_psnr_held_out": dfc_held, "held_out_points": len(held_xy),
                   "data_range": report.data_range, "dfc_triangles": report.n_triangles,
                   "dfc_steps": steps, "dfc_s": dfc_s, "hash_bytes": grid.stored_bytes(), "hash_psnr": grid_psnr,
                   "hash_psnr_held_out": grid_held, "hash_steps": hash_steps, "hash_s": hash_s, "leakage": leak,
                   "units": units, "units_text": report.units}
        write_json(json_path, figures)



def _leakage(model, sides, truth: dict, peak: float) -> dict:
    """Per side the mean and max absolute error of ``model`` at the side points (``sides``: (name, xy (N, 2))
    pairs) against ``truth[name]`` (N, C), and ``share``: the larger max divided by ``peak`` (the solution's max
    |u|)."""
    import torch

    row: dict = {}
    with torch.no_grad():
        for side, p in sides:
            err = np.abs(np.asarray(model(torch.from_numpy(p)).numpy(), np.float64) - truth[side])
            row[side] = {"mean": float(err.mean()), "max": float(err.max())}
    row["share"] = max(row[side]["max"] for side, _ in sides) / peak
    return row
