"""``dfc benchmark wave SEQUENCE.npz --curves BARRIERS``: compressing a time-varying field (the paper's Fig. 13).

``SEQUENCE`` is a frames ``.npz`` (``spec/samples.md``; e.g. the output of ``samples/make_wave.py``). The benchmark
encodes it into one time-sliced ``.dfield`` (``dfc.codec.encode_frames``) and prints the bytes of the sequence file
against the ``.dfield``, the PSNR over all frames and the worst frame's, each decoded at its own time.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from ...command import quiet_option, stdout_taken, threads_option, write_json
from ...io.atomic import write_bytes_atomic


@click.command()
@click.argument("sequence_path", metavar="SEQUENCE", type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The barrier curves, in the frames' pixel units.")
@click.option("--max-triangles", type=click.IntRange(min=2), default=4000, show_default=True, help="dfc mesh size.")
@click.option("--steps", type=click.IntRange(min=1), default=2000, show_default=True, help="Fit steps (all frames).")
@click.option("--batch-size", type=click.IntRange(min=1), default=1 << 14, show_default=True)
@click.option("--dim", type=click.IntRange(1, 64), default=5, show_default=True, help="Feature channels per vertex.")
@threads_option
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Also keep the .dfield here.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Also write the figures to this JSON file (- for standard output; the text then goes to "
                   "standard error).")
@quiet_option
def command(sequence_path, curves_path, max_triangles, steps, batch_size, dim, seed, output, json_path,
            quiet):
    """Bytes and PSNR of a frame sequence encoded as one time-sliced dfc file."""
    from ...codec import EncodeSettings, encode_frames, loads
    from ...geometry.sources import read_curves
    from ...io.frames import read_frames
    from ...metrics import psnr
    from ...render import render

    text_err = stdout_taken(json_path)
    seq = read_frames(sequence_path)
    t, h, w, c = seq.frames.shape
    in_bytes = Path(sequence_path).stat().st_size
    click.echo(f"{sequence_path}: {in_bytes} bytes, {t} frames of {w}x{h}x{c}, t = {seq.times[0]:g} .. "
               f"{seq.times[-1]:g}", err=text_err)
    settings = EncodeSettings(max_triangles=max_triangles, steps=steps, batch_size=batch_size, dim=dim, seed=seed)
    every = max(1, steps // 10)
    clock = time.perf_counter()
    blob, report = encode_frames(seq, read_curves(curves_path), settings, callback=lambda s, loss, p: (
        click.echo(f"  step {s + 1}/{steps}, batch PSNR {p:.2f} dB", err=True)
        if not quiet and (s + 1) % every == 0 else None))
    seconds = time.perf_counter() - clock
    if output:
        write_bytes_atomic(output, blob)
    model = loads(blob)
    per_frame = [psnr(seq.frames[k], render(model, w, h, t=float(tk)), data_range=report.data_range)
                 for k, tk in enumerate(seq.times)]
    click.echo(f"dfc: {len(blob)} bytes ({in_bytes / len(blob):.1f}x smaller), PSNR {report.psnr:.2f} dB over all "
               f"frames, worst frame {min(per_frame):.2f} dB (data range {report.data_range:.4g}); "
               f"{report.n_triangles} triangles, {steps} steps, {seconds:.0f} s", err=text_err)
    if json_path:
        figures = {"sequence": str(sequence_path), "sequence_bytes": in_bytes, "frames": t, "width": w, "height": h,
                   "dfield_bytes": len(blob), "ratio": in_bytes / len(blob), "psnr": report.psnr,
                   "psnr_per_frame": per_frame, "data_range": report.data_range, "triangles": report.n_triangles,
                   "steps": steps, "dim": dim, "seconds": seconds, "chunk_bytes": report.chunk_bytes}
        write_json(json_path, figures)
