"""``dfc encode INPUT --curves CURVES -o OUT.dfield``: triangulate, fit and write a ``.dfield``."""

from __future__ import annotations

import json
from pathlib import Path

import click

from .options import check_device, progress_bar

SAMPLE_EXTENSIONS = (".npz",)
"""``.npz`` inputs: a sample set or a frame sequence, told apart by their keys. Images go by their extension;
anything else is read as a FEM mesh (meshio)."""


def input_kind(paths: tuple[str, ...], times) -> str:
    """"image", "frames", "samples" or "fem" for the INPUT paths (several paths: images with --times)."""
    from ..io.frames import npz_kind
    from ..io.image import EXR_EXTENSIONS, PIL_EXTENSIONS

    image_extensions = EXR_EXTENSIONS + PIL_EXTENSIONS
    if len(paths) > 1 or times is not None:
        if not all(p.lower().endswith(image_extensions) for p in paths) or times is None or len(times) != len(paths):
            raise click.UsageError("several INPUTs are the frames of a sequence: give images and --times with one "
                                   "time per image")
        return "frames"
    path = paths[0].lower()
    if path.endswith(image_extensions):
        return "image"
    if path.endswith(SAMPLE_EXTENSIONS):
        return npz_kind(paths[0])
    return "fem"


def _times(ctx, param, value):
    if value is None:
        return None
    try:
        return [float(v) for v in value.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {value!r}") from None


def _weight_bits(ctx, param, value):
    if value == 1:
        raise click.BadParameter("integer weights need 2 to 16 bits (a sign and a magnitude); 0 stores float16")
    return value


@click.command()
@click.argument("input_paths", metavar="INPUT...", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Discontinuity curves: SVG, JSON (spec/curves.md) or diffusion-curve XML.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="The .dfield file to write.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on the mesh's triangle count.")
@click.option("--max-area", type=click.FloatRange(min=0, min_open=True), help="Largest triangle area (domain units²).")
@click.option("--edge-length", type=click.FloatRange(min=0, min_open=True), help="Target edge length (domain units).")
@click.option("--target-bytes", type=click.IntRange(min=1), help="Size the mesh so that the file is at most this big.")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Optimiser steps  [default: 1000].")
@click.option("--batch-size", type=click.IntRange(min=1), default=1 << 14, show_default=True, help="Samples per step.")
@click.option("--dim", type=click.IntRange(1, 64), default=5, show_default=True, help="Feature channels per vertex.")
@click.option("--feature-bits", type=click.IntRange(1, 16), default=8, show_default=True,
              help="Bits per stored feature value.")
@click.option("--mesh-bits", type=click.IntRange(1, 23), default=20, show_default=True,
              help="Draco quantisation bits of the vertex positions.")
@click.option("--weight-bits", type=click.IntRange(0, 16), default=8, show_default=True, callback=_weight_bits,
              help="Bits per integer MLP weight (per-row scales, learnt in the quantisation-aware steps); 0: float16.")
@click.option("--feature-coding", type=click.Choice(["predicted", "plain"]), default="predicted", show_default=True,
              help="predicted: features predicted from their neighbours and range-coded; plain: zstd only (1.0).")
@click.option("--refine", type=click.IntRange(0, 16), default=0, show_default=True,
              help="Image input: rounds of error-driven refinement after the fit (split the triangles with the "
                   "largest error, refit for half the steps); each round adds triangles, so the file grows.")
@click.option("--loss", type=click.Choice(["auto", "mse", "relmse"]), default="auto", show_default=True,
              help="auto: relative MSE for HDR inputs (values > 1), else MSE.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds features, decoder and sampling.")
@click.option("--device", default="cpu", show_default=True, help="torch device for the fit (cpu, cuda, cuda:1, ...).")
@click.option("--channels", help="Comma-separated image channels to encode (default: R,G,B[,A] or all).")
@click.option("--fit-curves-to-image", is_flag=True,
              help="Scale the curves' domain onto the image's [0, W] x [0, H] instead of refusing a mismatch.")
@click.option("--times", callback=_times, help="Comma-separated frame times, one per INPUT image (a sequence).")
@click.option("--fields", help="FEM input: comma-separated point-data arrays to encode [default: all].")
@click.option("--fem-sampling", type=click.Choice(["linear", "nearest"]), default="linear", show_default=True,
              help="FEM input: values of the training points inside an element (never across a barrier).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Also write the summary as JSON here.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def command(input_paths, curves_path, output, max_triangles, max_area, edge_length, target_bytes, steps, batch_size,
            dim, feature_bits, mesh_bits, weight_bits, feature_coding, refine, loss, seed, device, channels,
            fit_curves_to_image, times, fields, fem_sampling, json_path, quiet):
    """Encode INPUT with the discontinuity CURVES into OUTPUT. INPUT is an EXR/PNG/JPEG image; a .npz sample set
    or frame sequence (spec/samples.md); several images with --times (a sequence); or a FEM solution, any
    triangle mesh with point data that meshio reads (.vtu, .msh, .xdmf, ...; --fields, --fem-sampling).

    The mesh is built first (size knobs: --max-triangles, --max-area, --edge-length or --target-bytes; default
    about 2,000 triangles plus those the curves force), then a feature field is fitted on it and written. The
    summary gives bytes per chunk, bits per pixel of the input, and the PSNR of the written file, decoded again,
    against the input (images: rendered as `dfc decode` does at the input's size, averaging the pixels a curve
    crosses; sample positions, FEM nodes; every frame of a sequence).
    """
    from ..codec import EncodeSettings, encode_fem, encode_frames, encode_image, encode_samples
    from ..geometry.curves import read_curves
    from ..io.atomic import write_bytes_atomic
    from ..train.fit import DEFAULT_STEPS

    if sum(v is not None for v in (max_area, edge_length, target_bytes)) > 1:
        raise click.UsageError("give at most one of --max-area, --edge-length and --target-bytes")
    if not output.lower().endswith(".dfield"):
        raise click.BadParameter(f"must end in .dfield, got {output!r}", param_hint="'-o' / '--output'")
    kind = input_kind(input_paths, times)
    if kind in ("samples", "fem") and (channels or fit_curves_to_image):
        raise click.UsageError(f"--channels and --fit-curves-to-image apply to images, not {kind} input")
    if kind == "frames" and len(input_paths) == 1 and channels:
        raise click.UsageError("--channels applies to images; a frames .npz is encoded with all its channels")
    if kind != "fem" and (fields or fem_sampling != "linear"):
        raise click.UsageError("--fields and --fem-sampling apply to FEM input")
    settings = EncodeSettings(max_triangles=max_triangles, max_area=max_area, edge_length=edge_length,
                              target_bytes=target_bytes, steps=steps or DEFAULT_STEPS, batch_size=batch_size, dim=dim,
                              feature_bits=feature_bits, mesh_bits=mesh_bits, weight_bits=weight_bits or None,
                              feature_coding=feature_coding, refine=refine, loss=loss, seed=seed,
                              device=check_device(device))
    curves = read_curves(curves_path)
    signal = _read_input(kind, input_paths, times, channels.split(",") if channels else None,
                         fields.split(",") if fields else None)
    if refine and kind != "image":
        raise click.UsageError("--refine applies to image input")
    total_steps = settings.steps + refine * (settings.refine_steps or max(1, settings.steps // 2))
    with progress_bar(total_steps, "fit", quiet) as bar:
        def callback(step, loss_value, psnr):
            bar.update(1)
            if step % 25 == 0:
                bar.set_postfix(loss=f"{loss_value:.3g}", psnr=f"{psnr:.1f} dB", refresh=False)

        if kind == "samples":
            blob, report = encode_samples(signal, curves, settings, callback=callback)
        elif kind == "fem":
            blob, report = encode_fem(signal, curves, settings, sampling=fem_sampling, callback=callback)
        elif kind == "frames":
            blob, report = encode_frames(signal, curves, settings, fit_curves=fit_curves_to_image, callback=callback)
        else:
            blob, report = encode_image(signal, curves, settings, fit_curves=fit_curves_to_image, callback=callback)
    write_bytes_atomic(output, blob)
    unit = {"samples": "sample", "fem": "node"}.get(kind, "pixel")
    click.echo(f"wrote {output}: {report.total_bytes} bytes, {report.bits_per_pixel:.3f} bits per {unit}")
    for name, size in report.chunk_bytes.items():
        click.echo(f"  {name}  {size:>10} bytes")
    click.echo(f"mesh: {report.n_vertices} vertices, {report.n_triangles} triangles; {report.n_features} features")
    click.echo(f"PSNR of the decoded file against the input: {report.psnr:.2f} dB (data range {report.data_range:.4g})")
    click.echo("time: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in report.seconds.items()))
    if json_path:
        from dataclasses import asdict

        write_bytes_atomic(json_path, (json.dumps({"output": str(Path(output)), **asdict(report)}, indent=2)
                                       + "\n").encode())


def _read_input(kind: str, paths: tuple[str, ...], times, channels, fields):
    """The signal object the matching ``dfc.codec.encode_*`` takes."""
    if kind == "samples":
        from ..io.samples import read_samples

        return read_samples(paths[0])
    if kind == "fem":
        from ..io.fem import read_fem

        return read_fem(paths[0], fields)
    if kind == "frames" and len(paths) == 1:
        from ..io.frames import read_frames

        return read_frames(paths[0])
    if kind == "frames":
        from ..io.frames import frames_from_images

        return frames_from_images(list(paths), times, channels)
    from ..io.image import read_image

    return read_image(paths[0], channels)
