"""``dfc benchmark scale``: a huge analytic render through encode and decode, with peak memory, time per stage and
quality against the exact scene (DESIGN §10).

Writes the ``stripes`` scene (``dfc.bench.scenes.Stripes``: ≥ 10k cubic pieces, exact at any zoom) as a
``--size``² half RGB EXR band by band, runs ``dfc encode`` on it in a child process (out of core; ``--workers``
ranks), then ``dfc decode`` of the whole domain at the same size to a tiled EXR. Prints each child's peak resident
memory (``VmHWM``; with workers also the peak total over its process tree), the time of each stage, the file size,
and the PSNR of the decoded file against the exact scene at the encode's held-out pixel centres (stratified, never
trained on) and in windows of the domain at 33× and 100× zoom around points on the curves. With ``--workers`` > 1
also the cost of the gradients' dense all-reduce: the bytes every step moves (4 per parameter, the feature bank
dominating) and the time of an all-reduce of that size between the ranks (gloo on CPU ranks, ``ALLREDUCE_REPEAT``
times after a warm-up; an upper bound of what a step waits, as DDP overlaps it with the backward pass).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import click
import numpy as np

ALLREDUCE_REPEAT = 10
"""All-reduces timed per measurement."""


def allreduce_seconds(n_values: int) -> float:
    """Mean seconds of one all-reduce of ``n_values`` float32 between the ranks of this run (``launch`` entry)."""
    import torch
    import torch.distributed as dist

    from ...train import distributed

    distributed.init("cpu")
    try:
        buffer = torch.ones(n_values)
        dist.all_reduce(buffer)
        dist.barrier()
        clock = time.perf_counter()
        for _ in range(ALLREDUCE_REPEAT):
            dist.all_reduce(buffer)
        return (time.perf_counter() - clock) / ALLREDUCE_REPEAT
    finally:
        distributed.finish()


@click.command()
@click.option("--size", type=click.IntRange(256, 1 << 20), default=16384, show_default=True,
              help="Side of the square input image, pixels.")
@click.option("--boundaries", type=click.IntRange(1), default=100, show_default=True,
              help="Wavy boundaries of the scene (each a chain of --pieces cubics).")
@click.option("--pieces", type=click.IntRange(1), default=100, show_default=True, help="Cubic pieces per boundary.")
@click.option("--steps", type=click.IntRange(1), default=1000, show_default=True, help="Encode: optimiser steps.")
@click.option("--batch-size", type=click.IntRange(1), default=1 << 16, show_default=True, help="Encode: batch.")
@click.option("--epoch-pixels", type=click.IntRange(1), help="Encode: pixels per epoch  [default: sized to memory].")
@click.option("--max-triangles", type=click.IntRange(2), default=200_000, show_default=True,
              help="Encode: cap on the mesh's triangles.")
@click.option("--workers", type=click.IntRange(1), default=1, show_default=True,
              help="Ranks of the encode and processes of the decode.")
@click.option("--render", type=click.IntRange(16), default=256, show_default=True, help="Zoom windows' side, pixels.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds the scene and the encode.")
@click.option("--dir", "work_dir", type=click.Path(file_okay=False), help="Keep the files here  [default: a "
              "temporary directory, removed].")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Also write the figures to this JSON file.")
def command(size, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles, workers, render, seed, work_dir,
            json_path):
    """Encode and decode a --size² analytic render out of core; print peak memory, times and PSNR."""
    from ...io.atomic import write_bytes_atomic

    if work_dir is not None:
        Path(work_dir).mkdir(parents=True, exist_ok=True)
        figures = _run(Path(work_dir), size, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles,
                       workers, render, seed)
    else:
        with tempfile.TemporaryDirectory(prefix="dfc-scale-") as tmp:
            figures = _run(Path(tmp), size, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles,
                           workers, render, seed)
    _print(figures)
    if json_path:
        write_bytes_atomic(json_path, (json.dumps(figures, indent=2) + "\n").encode())


def _run(tmp: Path, size, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles, workers, render, seed):
    import torch

    from ...bench.scenes import Stripes, curve_probes
    from ...codec import load
    from ...geometry.sources.jsonfile import write_json
    from ...io.image import ExrBlockWriter
    from ...metrics import psnr
    from ...render import render as render_window
    from ...render import values_at, window_points, zoom_window
    from ...train.bands import HeldOut, default_epoch_pixels
    from ..timing import run_measured

    scene = Stripes(size, boundaries, pieces, seed)
    curves = scene.curves()
    image, curves_path, dfield, out = tmp / "stripes.exr", tmp / "stripes.json", tmp / "stripes.dfield", tmp / "out.exr"
    clock = time.perf_counter()
    write_json(curves, curves_path)
    with ExrBlockWriter(image, size, size, scene.channels, half=True) as writer:
        for y0 in range(0, size, 256):
            writer.write_rows(y0, scene.rows(y0, min(size, y0 + 256), size, size))
    figures = {"size": size, "pieces": len(curves), "scene_write_s": time.perf_counter() - clock,
               "input_mb": image.stat().st_size / 2**20, "workers": workers, "steps": steps, "batch_size": batch_size,
               "threads": torch.get_num_threads()}
    report = tmp / "encode.json"
    cmd = [sys.executable, "-m", "dfc", "encode", str(image), "--curves", str(curves_path), "-o", str(dfield),
           "--steps", str(steps), "--batch-size", str(batch_size), "--max-triangles", str(max_triangles),
           "--seed", str(seed), "--workers", str(workers), "--json", str(report), "-q"]
    cmd += ["--epoch-pixels", str(epoch_pixels or default_epoch_pixels(size * size, 3))]  # out of core at any size
    enc = _measured(run_measured, cmd)
    summary = json.loads(report.read_text())
    figures.update(encode_s=enc.seconds, encode_hwm_mb=enc.hwm, encode_tree_mb=enc.tree,
                   stages_s=summary["seconds"], file_bytes=summary["total_bytes"], triangles=summary["n_triangles"],
                   features=summary["n_features"], psnr_vs_exr_held_out=summary["psnr"])
    model = load(dfield)
    if workers > 1:
        from ...train.distributed import launch

        n_params = sum(p.numel() for p in model.parameters())
        figures.update(allreduce_mb=4 * n_params / 2**20, allreduce_s=launch(workers, allreduce_seconds, n_params)[0])
    held = HeldOut(size, size, seed=seed).pixels(0, size)
    centres = held + 0.5
    figures["held_out"] = len(held)
    figures["psnr_held_out"] = psnr(scene.value(centres), values_at(model, centres), data_range=1.0)
    for zoom in (33.0, 100.0):
        values = []
        for k, centre in enumerate(curve_probes(curves, 2)):
            window = zoom_window(scene.domain, centre, zoom)
            exact = scene.value(window_points(window, render, render)).reshape(render, render, 3)
            values.append(psnr(exact, render_window(model, render, render, window), data_range=1.0))
            figures[f"psnr_{zoom:g}x_probe{k}"] = values[-1]
        figures[f"psnr_{zoom:g}x"] = float(np.mean(values))
    dec = _measured(run_measured, [sys.executable, "-m", "dfc", "decode", str(dfield), "-o", str(out), "--size",
                                   f"{size}x{size}", "--workers", str(workers), "-q"])
    figures.update(decode_s=dec.seconds, decode_hwm_mb=dec.hwm, decode_tree_mb=dec.tree,
                   output_mb=out.stat().st_size / 2**20)
    return figures


def _measured(run, cmd):
    try:
        return run(cmd, quiet=True)
    except RuntimeError as e:
        raise click.ClickException(str(e)) from None


def _print(f: dict) -> None:
    click.echo(f"scene: stripes, {f['size']}x{f['size']} half RGB EXR ({f['input_mb']:.0f} MB), {f['pieces']} cubic "
               f"pieces; written band by band in {f['scene_write_s']:.1f} s")
    tree = f" (process tree {f['encode_tree_mb']:.0f} MB)" if f["workers"] > 1 else ""
    click.echo(f"encode ({f['workers']} rank(s), {f['steps']} steps, batch {f['batch_size']}): {f['encode_s']:.1f} s, "
               f"peak RSS {f['encode_hwm_mb']:.0f} MB{tree}")
    click.echo("  stages: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in f["stages_s"].items()))
    click.echo(f"  file: {f['file_bytes']} bytes; mesh {f['triangles']} triangles, {f['features']} features")
    if "allreduce_mb" in f:
        click.echo(f"  gradients: dense all-reduce of {f['allreduce_mb']:.1f} MB per step, "
                   f"{1e3 * f['allreduce_s']:.1f} ms each between {f['workers']} gloo ranks")
    click.echo(f"PSNR against the exact scene: {f['psnr_held_out']:.2f} dB at {f['held_out']} held-out pixel centres "
               f"({f['psnr_vs_exr_held_out']:.2f} dB against the half EXR there); {f['psnr_33x']:.2f} dB at 33x, "
               f"{f['psnr_100x']:.2f} dB at 100x (mean of 2 probes on curves)")
    tree = f" (process tree {f['decode_tree_mb']:.0f} MB)" if f["workers"] > 1 else ""
    click.echo(f"decode to a tiled {f['size']}x{f['size']} EXR ({f['output_mb']:.0f} MB, {f['workers']} process(es)): "
               f"{f['decode_s']:.1f} s, peak RSS {f['decode_hwm_mb']:.0f} MB{tree}")
