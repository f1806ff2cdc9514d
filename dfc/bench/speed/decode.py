"""``dfc benchmark decode``: decode speed against the bare MLP (target ratio ≤ 1.5) and the peak memory of a
huge EXR decode (target ≤ 1 GB).

Times, best of ``--repeat``: rendering a ``--size`` raster of the whole domain (location, interpolation and
MLP, in the renderer's row blocks), the decoder MLP alone on the same points' precomputed features, and a
full ``dfc decode`` to EXR. Then runs ``dfc decode --size BIG`` in a child process and reports its peak
resident memory (``VmHWM``, sampled every 0.1 s; Linux) and time. Without FILE the shipped sample is encoded first (``--steps``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import click
import numpy as np
import torch

from ...io.atomic import write_bytes_atomic
from ..timing import best_seconds, run_measured


@click.command()
@click.argument("dfield", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--size", type=click.IntRange(16, 8192), default=1024, show_default=True, help="Side of the timed render.")
@click.option("--big", type=click.IntRange(0, 65536), default=16384, show_default=True,
              help="Side of the memory-measured EXR decode (0 skips it).")
@click.option("--steps", type=click.IntRange(1), default=300, show_default=True,
              help="Fit steps when encoding the shipped sample (no FILE).")
@click.option("--repeat", type=click.IntRange(1), default=3, show_default=True, help="Runs per timing (best kept).")
@click.option("--device", default="cpu", show_default=True, help="torch device of the decodes (cpu, cuda, ...).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Also write the figures to this JSON file.")
def command(dfield, size, big, steps, repeat, device, json_path):
    """Time decoding DFIELD (default: the shipped sample, encoded now) against its bare MLP; measure the peak
    memory of a --big x --big EXR decode."""
    from ...codec import EncodeSettings, encode_image, load
    from ...geometry.sources import read_any
    from ...io.image import read_image
    from ...render import render

    with tempfile.TemporaryDirectory() as tmp:
        if dfield is None:
            samples = Path(__file__).resolve().parents[2] / "samples"
            image = read_image(samples / "sample.exr")
            blob, _ = encode_image(image, read_any(samples / "sample.json"), EncodeSettings(steps=steps))
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
        with torch.no_grad():
            t_render = best_seconds(lambda: render(model, size, size), repeat, dev)
            t_mlp = best_seconds(lambda: model.decoder(features), repeat, dev)
        out = Path(tmp) / "out.exr"
        cmd = [sys.executable, "-m", "dfc", "decode", str(dfield), "-o", str(out), "-q", "--device", device]
        clock = time.perf_counter()
        subprocess.run(cmd + ["--size", f"{size}x{size}"], check=True)
        t_cli = time.perf_counter() - clock
        figures = {"size": size, "points": size * size, "render_s": t_render, "mlp_s": t_mlp,
                   "ratio": t_render / t_mlp, "s_per_megapixel": t_render / (size * size / 1e6),
                   "cli_decode_s": t_cli, "threads": torch.get_num_threads(), "device": device}
        if big:
            try:
                peak = run_measured(cmd + ["--size", f"{big}x{big}"])
            except RuntimeError as e:
                raise click.ClickException(str(e)) from None
            figures.update(big=big, big_decode_s=peak.seconds, big_peak_rss_mb=peak.hwm,
                           big_file_mb=out.stat().st_size / 2**20)
    click.echo(f"render {size}x{size} (location + interpolation + MLP): {1e3 * t_render:9.1f} ms")
    click.echo(f"bare MLP on the same {size * size} features:        {1e3 * t_mlp:9.1f} ms")
    click.echo(f"ratio (target <= 1.5):                             {figures['ratio']:9.3f}")
    click.echo(f"seconds per megapixel rendered on {device}:          {figures['s_per_megapixel']:9.4f}")
    click.echo(f"dfc decode to EXR, whole process:                  {1e3 * t_cli:9.1f} ms")
    if big:
        click.echo(f"dfc decode {big}x{big} EXR: {figures['big_decode_s']:.1f} s, peak memory "
                   f"{figures['big_peak_rss_mb']:.0f} MB (target <= 1024), file {figures['big_file_mb']:.0f} MB")
    if json_path:
        write_bytes_atomic(json_path, (json.dumps(figures, indent=2) + "\n").encode())
