"""``dfc benchmark scale``: a huge analytic render through encode and decode, with peak memory, time per stage and
quality against the exact scene (docs/design.md §10).

Writes the ``stripes`` scene (``dfc.bench.scenes.Stripes``: ≥ 10k cubic pieces, exact at any zoom) as a
``--size``² half RGB EXR band by band, runs ``dfc encode`` on it in a child process (out of core; ``--workers``
ranks), then ``dfc decode`` of the whole domain at the same size to a tiled EXR. Prints each child's peak resident
memory (``VmHWM``; with workers also the peak total over its process tree), the time of each stage, the file size,
and the PSNR of the decoded file against the exact scene at the encode's held-out pixel centres (stratified, never
trained on) and in windows of the domain at 33× and 100× zoom around points on the curves. With ``--workers`` > 1
also the cost of the gradients' dense all-reduce: the bytes every step moves (4 per parameter, the feature bank
dominating) and the time of an all-reduce of that size between the ranks (gloo on CPU ranks, ``ALLREDUCE_REPEAT``
times after a warm-up; an upper bound of what a step waits, as DDP overlaps it with the backward pass).

Memory targets (checked and printed): an encode at ``TARGET_SIZE``² (or smaller) peaks at ``TARGET_MB`` or less,
and with several ``--size`` each larger encode peaks within ``TARGET_GROWTH`` times the smallest size's run (with
workers, the process tree's peak is compared).
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
TARGET_SIZE, TARGET_MB, TARGET_GROWTH = 16384, 2048.0, 1.25
"""Memory targets: an encode of a ``TARGET_SIZE``² image peaks at ``TARGET_MB`` MB or less; a larger one within
``TARGET_GROWTH`` times the smaller run's peak."""


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
@click.option("--size", "sizes", type=click.IntRange(256, 1 << 20), multiple=True,
              help="Side of the square input image, pixels; repeat to run several sizes one after the other and "
                   "compare their peak memory (e.g. --size 16384 --size 32768)  [default: 16384].")
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
def command(sizes, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles, workers, render, seed, work_dir,
            json_path):
    """Encode and decode a --size² analytic render out of core; print peak memory, times and PSNR, and whether the
    memory targets are met (an encode of 16384² within 2 GB, a larger one within 1.25x of the smallest run)."""
    from ...io.atomic import write_bytes_atomic

    runs = []
    for size in sorted(set(sizes or (TARGET_SIZE,))):
        if work_dir is not None:
            folder = Path(work_dir) / str(size)
            folder.mkdir(parents=True, exist_ok=True)
            figures = _run(folder, size, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles,
                           workers, render, seed)
        else:
            with tempfile.TemporaryDirectory(prefix="dfc-scale-") as tmp:
                figures = _run(Path(tmp), size, boundaries, pieces, steps, batch_size, epoch_pixels, max_triangles,
                               workers, render, seed)
        _print(figures)
        runs.append(figures)
    targets = memory_targets(runs)
    for line in targets:
        click.echo(line)
    if json_path:
        write_bytes_atomic(json_path, (json.dumps({"runs": runs, "memory_targets": targets}, indent=2)
                                       + "\n").encode())


def encode_peak_mb(figures: dict) -> float:
    """The encode's peak resident memory, MB: the process tree's with workers, else the process's own."""
    return figures["encode_tree_mb"] if figures["workers"] > 1 else figures["encode_hwm_mb"]


def memory_targets(runs: list[dict]) -> list[str]:
    """One line per memory target the runs (sorted by size) can check: runs at ``TARGET_SIZE``² or less against
    ``TARGET_MB``, larger ones against ``TARGET_GROWTH`` times the smallest run's peak."""
    lines = []
    first = runs[0]
    for f in runs:
        peak, side = encode_peak_mb(f), f"{f['size']}²"
        if f["size"] <= TARGET_SIZE:
            verdict = "met" if peak <= TARGET_MB else "MISSED"
            lines.append(f"memory target: encode at {side} peaks at {peak:.0f} MB <= {TARGET_MB:.0f} MB: {verdict}")
        if f is not first:
            ratio = peak / encode_peak_mb(first)
            verdict = "met" if ratio <= TARGET_GROWTH else "MISSED"
            lines.append(f"memory target: encode at {side} peaks at {ratio:.2f}x the {first['size']}² run "
                         f"<= {TARGET_GROWTH}x: {verdict}")
    return lines


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
    from ...render_file import TILED_PIXELS

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
    layout = "tiled" if f["size"] ** 2 > TILED_PIXELS else "scanline"
    click.echo(f"decode to a {layout} {f['size']}x{f['size']} EXR ({f['output_mb']:.0f} MB, {f['workers']} process(es)): "
               f"{f['decode_s']:.1f} s, peak RSS {f['decode_hwm_mb']:.0f} MB{tree}")
