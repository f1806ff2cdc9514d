"""``dfc benchmark decode``: decode speed against the bare MLP (target ratio ≤ 1.5) and the peak memory of a
huge EXR decode (target ≤ 1 GB).

Times, best of ``--repeat``: rendering a ``--size`` raster of the whole domain (location, interpolation and
MLP, in the renderer's row blocks), the decoder MLP alone on the same points' precomputed features, and a
full ``dfc decode`` to EXR. Then runs ``dfc decode --size BIG`` in a child process and reports its peak
resident memory (``VmHWM``, sampled every 0.1 s; Linux) and time. Without FILE the shipped sample is encoded first
(``--steps``). The timings are taken for each ``--threads`` count, alone and beside a busy neighbour
(``dfc.bench.neighbour``).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import click
import numpy as np
import torch

from ...command import json_option, quiet_option, stdout_taken, write_json
from ..neighbour import SAMPLES
from ..timing import best_seconds, run_measured
from .field import NEIGHBOUR_OPTION, THREADS_OPTION, conditions


@click.command()
@click.argument("dfield", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--size", type=click.IntRange(16, 8192), default=1024, show_default=True, help="Side of the timed render.")
@click.option("--big", type=click.IntRange(0, 65536), default=16384, show_default=True,
              help="Side of the memory-measured EXR decode (0 skips it).")
@click.option("--steps", type=click.IntRange(1), default=300, show_default=True,
              help="Fit steps when encoding the shipped sample (no FILE).")
@click.option("--repeat", type=click.IntRange(1), default=3, show_default=True, help="Runs per timing (best kept).")
@click.option("--device", default="cpu", show_default=True, help="torch device of the decodes (cpu, cuda, ...).")
@THREADS_OPTION
@NEIGHBOUR_OPTION
@json_option
@quiet_option
def command(dfield, size, big, steps, repeat, device, thread_counts, neighbour, json_path, quiet):
    """Time decoding DFIELD (default: the shipped sample, encoded now) against its bare MLP, and the whole dfc decode
    process, for each --threads count alone and beside a busy neighbour, with seconds per megapixel (the figure a
    GPU run reports with --device cuda); measure the peak memory of a --big x --big EXR decode (with the first
    thread count, alone)."""
    from ...codec import EncodeSettings, encode_image, load
    from ...geometry.sources import read_any
    from ...io.image import read_image
    from ...render import render

    err = stdout_taken(json_path)
    figures = {"size": size, "points": size * size, "device": device, "runs": []}
    with tempfile.TemporaryDirectory() as tmp:
        if dfield is None:
            image = read_image(SAMPLES / "sample.exr")
            blob, _ = encode_image(image, read_any(SAMPLES / "sample.json"), EncodeSettings(steps=steps))
            dfield = Path(tmp) / "sample.dfield"
            dfield.write_bytes(blob)
        dev = torch.device(device)
        model = load(dfield, device=device)
        x0, y0, x1, y1 = model.field.mesh.domain
        u = (np.arange(size) + 0.5) / size
        X, Y = np.meshgrid(x0 + u * (x1 - x0), y0 + u * (y1 - y0))
        xy = torch.from_numpy(np.stack([X.ravel(), Y.ravel()], axis=1)).to(dev)
        with torch.no_grad():
            features = model.features(xy).float()
        out = Path(tmp) / "out.exr"
        cmd = [sys.executable, "-m", "dfc", "decode", str(dfield), "-o", str(out), "-q", "--device", device]
        click.echo(f"{size}x{size} render of {dfield} on {device}", err=err)
        click.echo(f"{'threads':>7} {'neighbour':>9} {'render':>10} {'bare MLP':>10} {'ratio':>6} {'s/MP':>7} "
                   f"{'dfc decode process':>19}", err=err)
        for threads, beside in conditions(thread_counts, neighbour):
            with torch.no_grad():
                t_render = best_seconds(lambda: render(model, size, size), repeat, dev)
                t_mlp = best_seconds(lambda: model.decoder(features), repeat, dev)
            clock = time.perf_counter()
            subprocess.run(cmd + ["--size", f"{size}x{size}", "--threads", str(threads)], check=True,
                           stdout=subprocess.DEVNULL)
            t_cli = time.perf_counter() - clock
            per_mp = t_render / (size * size / 1e6)
            figures["runs"].append({"threads": threads, "neighbour": beside, "render_s": t_render, "mlp_s": t_mlp,
                                    "ratio": t_render / t_mlp, "s_per_megapixel": per_mp, "cli_decode_s": t_cli})
            click.echo(f"{threads:>7} {beside:>9} {1e3 * t_render:>7.1f} ms {1e3 * t_mlp:>7.1f} ms "
                       f"{t_render / t_mlp:>6.3f} {per_mp:>7.4f} {1e3 * t_cli:>16.1f} ms", err=err)
        click.echo("ratio: render over the bare MLP on the same points (target <= 1.5); s/MP: seconds per megapixel "
                   "rendered; neighbour busy: another dfc encode with as many threads", err=err)
        if big:
            try:
                peak = run_measured(cmd + ["--size", f"{big}x{big}", "--threads", str(thread_counts[0])], quiet=True)
            except RuntimeError as e:
                raise click.ClickException(str(e)) from None
            figures.update(big=big, big_threads=thread_counts[0], big_decode_s=peak.seconds,
                           big_peak_rss_mb=peak.hwm, big_file_mb=out.stat().st_size / 2**20)
            click.echo(f"dfc decode {big}x{big} EXR ({thread_counts[0]} threads): {figures['big_decode_s']:.1f} s, "
                       f"peak memory {figures['big_peak_rss_mb']:.0f} MB (target <= 1024), file "
                       f"{figures['big_file_mb']:.0f} MB", err=err)
    if json_path:
        write_json(json_path, figures)
