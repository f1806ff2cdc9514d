"""``dfc encode INPUT --curves CURVES -o OUT.dfield``: triangulate, fit and write a ``.dfield``."""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import click
import numpy as np

from ..io.atomic import write_bytes_atomic
from ..settings import FEATURE_CODINGS, LOSSES, MESH_CODINGS, FitSettings, RunSettings, StorageSettings
from .options import (
    binary_stream,
    check_device,
    json_option,
    note,
    option_names,
    progress_bar,
    quiet_option,
    read_curves_checked,
    shown,
    stdin_file,
    stdout_taken,
    threads_option,
    write_json,
)


def input_kind(paths: tuple[str, ...], times) -> str:
    """"image", "frames", "samples" or "fem" for the INPUT paths (several paths: images with --times).

    Each file is recognised by its content (magic bytes: EXR, PNG, JPEG, zip/npz, VTK, VTU, XDMF, Gmsh; see
    ``dfc.io.sniff``), else by its extension; a ``.npz`` holds a sample set or a frame sequence, told apart by its
    keys; anything else is read as a FEM mesh (meshio)."""
    from ..io.frames import npz_kind
    from ..io.sniff import IMAGE_KINDS, file_kind

    kinds = [file_kind(p) for p in paths]
    if len(paths) > 1 or times is not None:
        if not all(k in IMAGE_KINDS for k in kinds) or times is None or len(times) != len(paths):
            raise click.UsageError("several INPUTs are the frames of a sequence: give images and --times with one "
                                   "time per image")
        return "frames"
    if kinds[0] in IMAGE_KINDS:
        return "image"
    if kinds[0] == "npz":
        return npz_kind(paths[0])
    return "fem"


def _times(ctx, param, value):
    if value is None:
        return None
    try:
        return [float(v) for v in value.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {value!r}") from None


def _curves_arg(ctx, param, value):
    """``--curves``: required (the message names ``auto``); a file that exists, ``-`` or ``auto``."""
    if value is None:
        raise click.UsageError("Missing option '--curves': give the discontinuity curves (SVG, JSON or diffusion-curve "
                               "XML), or for an image --curves auto to find them in it")
    if value in ("auto", "-"):
        return value
    return click.Path(exists=True, dir_okay=False).convert(value, param, ctx)


@click.command()
@click.argument("input_paths", metavar="INPUT...", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False, allow_dash=True))
@click.option("--curves", "curves_path", callback=_curves_arg,
              help="Discontinuity curves: SVG, JSON (spec/curves.md) or diffusion-curve XML (- reads standard input); "
                   "or 'auto' (images): find them in the image with dfc curves' defaults, recorded in the file "
                   "(a file named auto: ./auto).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, allow_dash=True),
              help="The .dfield file to write (- for standard output).")
@click.option("--max-triangles", type=int, help="Cap on the mesh's triangle count (at least 2).")
@click.option("--max-area", type=float, help="Largest triangle area (domain units²).")
@click.option("--edge-length", type=float, help="Target edge length (domain units).")
@click.option("--target-bytes", type=int, help="Size the mesh so that the file is at most this big.")
@click.option("--target-psnr", type=float, metavar="DB",
              help="Image input read whole or FEM input: refine the mesh (up to 4 rounds, each refitting for half the "
                   "steps) until the file's PSNR, as the summary measures it (FEM: at the nodes), reaches DB; the "
                   "summary says when it does not.")
@click.option("--steps", type=int, default=None,
              help="Optimiser steps  [default: an image 3000; a sample set 12 passes over its samples, at least 1000; "
                   "FEM data and frames 1000].")
@click.option("--batch-size", type=int, default=None,
              help="Samples per step  [default: 16384; an image read whole: 4096 up to 1024 x 1024 pixels, 16384 "
                   "from 2048 x 2048].")
@click.option("--dim", type=int, default=FitSettings.dim, show_default=True,
              help="Feature channels per vertex (1..64).")
@click.option("--feature-bits", type=int, default=None,
              help="Bits per stored feature value  [default: 10; with --target-bytes, 8 when storing the first fit "
                   "with 8 costs it less than 0.5 dB (the bytes saved buy triangles), and 8, else 6, when the target "
                   "is too small for the smallest mesh at 10].")
@click.option("--mesh-bits", type=int, default=StorageSettings.mesh_bits, show_default=True,
              help="Quantisation bits of the vertex positions on the curves (1..23).")
@click.option("--mesh-coding", type=click.Choice(MESH_CODINGS), default=StorageSettings.mesh_coding,
              show_default=True,
              help="derived: free vertices on a coarse lattice, triangles rebuilt by the decoder (content 1.3); "
                   "draco: every vertex at --mesh-bits, triangles in a Draco stream (1.2).")
@click.option("--residual-bytes", default=StorageSettings.residual_bytes, show_default=True, metavar="N|auto",
              callback=lambda ctx, param, value: value if value == "auto" else _count(value, param),
              help="Image input read whole: after the fit, store what it leaves of the input (a residual raster on "
                   "the input's pixel grid, AVIF-coded, interpolated bilinearly at other resolutions) in at most N "
                   "bytes, taken out of --target-bytes when given; 0: none; auto: for a clean image (no measurable "
                   "noise) half of --target-bytes, or more where half would leave the field over 0.5 bits per "
                   "pixel; without --target-bytes (and no other size option), the same share of a target the "
                   "encoder sets itself: the bytes of the default mesh with incompressible features; else none.")
@click.option("--weight-bits", type=int, default=StorageSettings.weight_bits, show_default=True,
              help="Bits per integer MLP weight (2..16; per-row scales, learnt in the quantisation-aware steps); "
                   "0: float16.")
@click.option("--feature-coding", type=click.Choice(FEATURE_CODINGS), default=StorageSettings.feature_coding,
              show_default=True,
              help="predicted: features predicted from their neighbours and range-coded; plain: zstd only (1.0).")
@click.option("--refine", type=int,
              help="Image input read whole or FEM input: rounds of error-driven refinement after the fit (split the "
                   "triangles with the largest error, refit: for the fit's steps with --target-bytes, else half). "
                   "Without --target-bytes each round adds triangles, so the file grows; with it a round adds as many "
                   "as the target still pays for  [default: 1 with --target-bytes, else 0].")
@click.option("--loss", type=click.Choice(LOSSES), default=FitSettings.loss, show_default=True,
              help="auto: the MSE of sign(v) log(1 + |v|) for HDR inputs (values > 1), else the MSE.")
@click.option("--seed", type=int, default=FitSettings.seed, show_default=True,
              help="Seeds features, decoder and sampling.")
@click.option("--pixel-filter", "pixel_filter", metavar="FILTER",
              help="Image: how its pixels were made from the scene: auto, point, box[:N], gaussian[:STDDEV], tent, "
                   "blackman-harris[:WIDTH] or mitchell; fitted and stored for the decoder  [default: auto, found in "
                   "the pixels near the curves].")
@click.option("--refine-curves/--no-refine-curves", "refine_curves", default=None,
              help="Image read whole: before the mesh is built, move the curves' control points until the pixels they "
                   "cross are explained by sharp steps seen through the pixel filter (dfc curves --refine)  "
                   "[default: on with --curves auto, off with a curves file].")
@click.option("--prune-curves/--no-prune-curves", "prune_curves", default=None,
              help="Image read whole: before the mesh is built, drop the curves that do not earn their bytes (the "
                   "squared error a curve removes against a continuous field across it, per byte of the mesh it "
                   "forces; fewer under a smaller --target-bytes; dfc.geometry.sources.prune)  [default: on with "
                   "--curves auto; with a curves file, on only when --target-bytes is too small for all of them]. "
                   "--no-prune-curves refuses such a target.")
@click.option("--raster-mode/--no-raster-mode", "raster_mode", default=True, show_default=True,
              help="Clean image read whole, --residual-bytes auto, with --target-bytes or no mesh-size option: "
                   "also make the file as a constant field and a residual raster holding the image, at the same "
                   "size, and keep it when it decodes closer to the input (content the field does not model: test "
                   "charts, textures). Such a file stores no curves: zooms interpolate its raster.")
@click.option("--device", default=FitSettings.device, show_default=True,
              help="torch device for the fit (cpu, cuda, cuda:1, ...).")
@threads_option
@click.option("--channels", help="Comma-separated image channels to encode (default: R,G,B[,A] or all).")
@click.option("--fit-curves-to-image", is_flag=True,
              help="Scale the curves' domain onto the image's [0, W] x [0, H] instead of refusing a mismatch.")
@click.option("--times", callback=_times, help="Comma-separated frame times, one per INPUT image (a sequence).")
@click.option("--fields", help="FEM input: comma-separated point-data arrays to encode [default: all].")
@click.option("--fem-sampling", type=click.Choice(["linear", "nearest"]), default="linear", show_default=True,
              help="FEM input: values of the training points inside an element (never across a barrier).")
@click.option("--reference", "reference_path", type=click.Path(exists=True, dir_okay=False),
              help="Sample sets: exact values on a pixel grid over the domain (.exr, or .npz as dfc wos --reference "
                   "writes); the summary adds the file's PSNR against them.")
@click.option("--epoch-pixels", type=int,
              help="Image input read out of core: stratified pixels drawn per epoch, band by band  [default: sized to "
                   "512 MiB of samples, at most every pixel]. EXR images above 4096 x 4096 pixels are always read so.")
@click.option("--workers", type=int, default=RunSettings.workers, show_default=True,
              help="Image input: train data-parallel on N local ranks (torch.distributed: gloo on CPU, NCCL with "
                   "--device cuda, one GPU per rank), each reading its own bands; --batch-size is split between them. "
                   "Across machines use torchrun (docs/gigapixel.md).")
@json_option
@quiet_option
def command(input_paths, curves_path, output, channels, fit_curves_to_image, times, fields, fem_sampling,
            reference_path, refine_curves, prune_curves, raster_mode, json_path, quiet, **setting_options):
    """Encode INPUT with the discontinuity CURVES into OUTPUT (for an image, --curves auto finds them in it with
    dfc curves' defaults and records that, with the settings, in the file). INPUT is an EXR/PNG/JPEG image; a .npz
    sample set or frame sequence (spec/samples.md); several images with --times (a sequence); or a FEM solution, any
    triangle mesh with point data that meshio reads (.vtu, .msh, .xdmf, ...; --fields, --fem-sampling). Files
    are recognised by their content, else by their extension; - reads INPUT from standard input.

    The mesh is built first (size knobs: --max-triangles, --max-area, --edge-length or --target-bytes; default
    about 2,000 triangles plus those the curves force, fewer for small inputs), then a feature field is fitted on
    it (for an image, refined where the error is largest to fill --target-bytes or reach --target-psnr) and
    written. The summary gives bytes per chunk, bits per pixel of the input, and the PSNR of the written file,
    decoded again, against the input (an image rendered at its size as dfc decode renders it, the pixels a curve
    crosses anti-aliased; FEM nodes; every frame of a sequence), for HDR images on tone-mapped values x/(1+x); for a
    sample set against the 10 % of the samples left out of the fit, and against --reference; for an image read out
    of core (--epoch-pixels, --workers, torchrun, or an EXR above 4096 x 4096) at its held-out pixels. An existing
    OUTPUT is replaced, atomically, once the new file is complete.
    """
    from ..codec import default_steps

    pixel_filter = setting_options["pixel_filter"]  # None: not given (auto)
    settings = encode_settings({**setting_options, "pixel_filter": pixel_filter or "auto"})
    target_bytes, target_psnr, refine = settings.target_bytes, settings.target_psnr, settings.refine
    epoch_pixels, workers = settings.epoch_pixels, settings.workers
    if output != "-" and not output.lower().endswith(".dfield"):
        raise click.BadParameter(f"must end in .dfield, got {output!r}", param_hint="'-o' / '--output'")
    if [*input_paths, curves_path].count("-") > 1:
        raise click.UsageError("standard input (-) can be read once: give INPUT or --curves as -, not both")
    with stdin_file("-") if input_paths == ("-",) else contextlib.nullcontext() as spooled:
        paths = (spooled,) if spooled else input_paths
        kind = input_kind(paths, times)
        if kind in ("samples", "fem") and (channels or fit_curves_to_image):
            raise click.UsageError(f"--channels and --fit-curves-to-image apply to images, not {kind} input")
        if kind == "frames" and len(paths) == 1 and channels:
            raise click.UsageError("--channels applies to images; a frames .npz is encoded with all its channels")
        if kind != "fem" and (fields or fem_sampling != "linear"):
            raise click.UsageError("--fields and --fem-sampling apply to FEM input")
        if kind != "samples" and reference_path:
            raise click.UsageError(f"--reference applies to sample sets, not {kind} input")
        if pixel_filter is not None and kind != "image":
            raise click.UsageError(f"--pixel-filter applies to images, not {kind} input")
        if curves_path == "auto" and kind != "image":
            raise click.UsageError(f"--curves auto finds curves in an image; give the curves of {kind} input")
        if refine_curves and kind != "image":
            raise click.UsageError(f"--refine-curves refines curves against an image's pixels, not {kind} input")
        if prune_curves and kind != "image":
            raise click.UsageError(f"--prune-curves weighs curves against an image's pixels, not {kind} input")
        if workers > 1 and settings.device.startswith("cuda") and workers > _gpus():
            raise click.BadParameter(f"{workers} ranks on CUDA need as many GPUs; {_gpus()} are visible",
                                     param_hint="'--workers'")
        if workers > 1 and output == "-":
            raise click.UsageError("--workers writes the file from its first rank: give -o OUT.dfield, not -")
        out_of_core = _out_of_core(kind, paths, epoch_pixels, workers)
        for name, value in (("--refine", refine), ("--target-psnr", target_psnr)):  # images read whole, FEM
            if value and (kind not in REFINED or out_of_core):
                raise click.UsageError(f"{name} applies to an image read whole (not out of core: --epoch-pixels, "
                                       "--workers, torchrun, EXR above 4096x4096)" if kind == "image" else
                                       f"{name} applies to image or FEM input, not {kind}")
        if pixel_filter is not None and out_of_core:
            raise click.UsageError("--pixel-filter applies to an image read whole, not out of core (--epoch-pixels, "
                                   "--workers, torchrun, EXR above 4096x4096)")
        if refine_curves and out_of_core:
            raise click.UsageError("--refine-curves reads the whole image; for an image read out of core "
                                   "(--epoch-pixels, --workers, torchrun, EXR above 4096x4096) refine its curves with "
                                   "dfc curves IMAGE --refine first")
        if prune_curves and out_of_core:
            raise click.UsageError("--prune-curves reads the whole image; for an image read out of core "
                                   "(--epoch-pixels, --workers, torchrun, EXR above 4096x4096) prune its curves with "
                                   "dfc curves IMAGE --prune-curves first")
        if curves_path == "auto" and out_of_core:
            raise click.UsageError("--curves auto reads the whole image; for an image read out of core (--epoch-pixels, "
                                   "--workers, torchrun, EXR above 4096x4096) find its curves with dfc curves first")
        from ..workers import encode_file_in_bands

        signal = curves_info = None
        if not out_of_core:
            signal = _read_input(kind, paths, times, channels.split(",") if channels else None,
                                 fields.split(",") if fields else None)
        if settings.steps is None:  # resolved here for the progress bar
            settings = replace(settings, steps=default_steps(kind, len(signal) if kind == "samples" else 0,
                                                             settings.batch_size))
        detection = redetected = None  # redetected: the filter the refined curves showed instead of the detected one
        clock = time.perf_counter()
        if curves_path != "auto":
            curves = read_curves_checked(curves_path, quiet)
        pruned = refined = None
        prune = prune_curves or (prune_curves is None and curves_path == "auto" and not out_of_core)
        refine = refine_curves or (refine_curves is None and curves_path == "auto" and not out_of_core)
        worked = curves_path == "auto" or prune or refine  # the curves are found, pruned or refined here
        with progress_bar(None, "curves", quiet or not worked, unit="stage") as bar:
            if curves_path == "auto":
                bar.set_description_str("finding the curves")
                curves, used, curves_info, detection = _auto_curves(signal, settings.pixel_filter)
                settings = replace(settings, pixel_filter=str(used))  # refined and fitted with the filter found
            if prune or refine:
                bar.set_description_str(" and ".join(["pruning"] * prune + ["refining"] * refine) + " the curves")
                curves, pruned, refined = _ready_curves(signal, curves, settings, prune, refine, fit_curves_to_image,
                                                        detected=detection is not None)
                if refined is not None and detection is not None and refined.pixel_filter != settings.pixel_filter:
                    redetected = refined.pixel_filter  # detected again along the refined curves, refined with it
                    settings = replace(settings, pixel_filter=redetected)
                    curves_info = {**curves_info, "pixel_filter": redetected}
        if refined is not None and refined.warning and not quiet:
            click.echo(f"dfc: warning: {refined.warning}", err=True)
        if curves_info is not None:
            curves_info = {**curves_info, **({"pruned": pruned.to_dict()} if pruned else {}),
                           **({"refined": refined.to_dict()} if refined else {})}
        curves_s = time.perf_counter() - clock
        input_bytes = sum(os.path.getsize(p) for p in paths)
        if out_of_core:
            # read band by band while the input (or its spooled copy) is there
            blob, report = encode_file_in_bands(paths[0], curves, settings, None if output == "-" else output,
                                                channels=channels.split(",") if channels else None,
                                                fit_curves=fit_curves_to_image,
                                                progress=functools.partial(_band_progress, quiet=quiet))
            if report is None:  # a rank other than 0 of a torchrun run: rank 0 writes and reports
                return
        else:
            reference = _read_reference(reference_path, curves.domain) if reference_path else None
            blob, report = _encode_in_memory(kind, signal, curves, settings, fit_curves_to_image, fem_sampling,
                                             reference, curves_info, quiet,
                                             prune_to_fit=prune_curves is None and curves_path != "auto",
                                             raster_mode=raster_mode)
    if worked:  # the time line counts finding, pruning and refining the curves too
        report = replace(report, seconds={"curves_s": curves_s, **report.seconds})
    if detection is not None:  # the filter was detected along every curve found, before pruning
        report = replace(report, pixel_evidence=detection.evidence()
                         + (f"; {redetected} along the refined curves" if redetected else ""))
    if blob is None:  # --workers: rank 0 wrote the file
        pass
    elif output == "-":
        sys.stdout.flush()
        out = binary_stream(sys.stdout)
        out.write(blob)
        out.flush()
    else:
        write_bytes_atomic(output, blob)
    _summary(output, kind, report, reference_path, curves_info, stdout_taken(output, json_path), refined, pruned)
    if report.target_psnr is not None and report.psnr < report.target_psnr:
        what = "--target-psnr" if target_psnr is not None else "the default FEM target of"
        note(f"{what} {report.target_psnr:g} dB not reached: {report.psnr:.2f} dB with {report.n_triangles} "
             "triangles after the refinement rounds (more --steps, or --refine N for more rounds, may reach it)", quiet)
    if report.fallback_from is not None:
        note(f"--target-bytes {target_bytes} is too small for the smallest mesh with {report.fallback_from}-bit "
             f"features: they are stored with {report.feature_bits} bits", quiet)
    if report.total_bytes > input_bytes:
        note(f"the file ({report.total_bytes} bytes) is larger than the input ({input_bytes} bytes): on an input this "
             f"small the header and decoder weigh more than the data", quiet)
    if json_path:
        from dataclasses import asdict

        write_json(json_path, {"output": output if output == "-" else str(Path(output)), "input_bytes": input_bytes,
                               **({"curves": curves_info} if curves_info else {}),
                               **({"refined_curves": refined.to_dict()} if refined else {}), **asdict(report),
                               **({"pruned_curves": pruned.to_dict()} if pruned else {})})


def encode_settings(options: dict):
    """The ``EncodeSettings`` of ``dfc encode``'s setting options (named as its fields; ``--weight-bits 0`` is None,
    float16 weights; ``--device`` must name a device present here): the one place the command makes them, so it
    refuses what ``EncodeSettings`` refuses, as a usage error naming the options."""
    from ..errors import SettingsError
    from ..settings import EncodeSettings

    options = {**options, "weight_bits": options["weight_bits"] or None, "device": check_device(options["device"])}
    try:
        return EncodeSettings(**options)
    except SettingsError as e:
        message = option_names(str(e), options).replace("or None for float16", "or 0 for float16")
        raise click.UsageError(message.replace(" or None,", ",")) from None


def _auto_curves(image, pixel_filter: str = "auto"):
    """``--curves auto``: (curves, filter used, record for the file's encoder info, ``Detection`` or None) of
    ``dfc.geometry.sources.auto.find_curves`` with the encode's pixel filter."""
    from ..errors import ExtraError

    try:
        from ..geometry.sources.auto import find_curves

        return find_curves(image.pixels, pixel_filter)
    except ImportError:
        raise ExtraError("--curves auto finds curves with scikit-image: pip install 'dfc[curves]'") from None


def _ready_curves(image, curves, settings, prune: bool, refine: bool, fit_curves_to_image: bool,
                  detected: bool = False):
    """(curves, ``Pruned`` or None, ``Refined`` or None) of ``--prune-curves`` and ``--refine-curves``
    (``dfc.geometry.sources.auto.ready_curves``): ``curves`` on the image's domain (as the encoder takes them:
    ``dfc.codec.check_domain``) less those that do not earn their bytes for a mesh of ``settings.max_triangles``
    (default size when None) in a file of ``settings.target_bytes`` (less a residual's share, ``dfc.rate.field_bytes``),
    then refined against the pixels through the
    filter of ``settings.pixel_filter`` (with ``--curves auto`` the one the extractor found, ``detected``; "auto":
    detected along the curves, as the encoder does); a detected filter is detected again along the refined curves
    (``dfc.geometry.sources.auto.refine_detected``)."""
    from ..codec import check_domain
    from ..geometry.sources.auto import ready_curves
    from ..rate import field_bytes

    curves = check_domain(curves, image.width, image.height, fit_curves_to_image)
    target = field_bytes(image.pixels, settings.target_bytes, settings.residual_bytes)  # a residual takes its share
    curves, pruned, refined = ready_curves(image.pixels, curves, prune=prune, refine=refine,
                                           n_triangles=settings.max_triangles, target_bytes=target,
                                           pixel_filter=settings.pixel_filter, detected=detected)
    return curves, pruned, refined


def _summary(output: str, kind: str, report, reference_path, curves_info, err: bool, refined=None,
             pruned=None) -> None:
    """The text summary: bytes, chunks, mesh, PSNR (its definition said with it), times; where the curves came
    from when they were extracted, their pruning (``pruned``) and their refinement (``refined``)."""
    unit = {"samples": "sample", "fem": "node"}.get(kind, "pixel")
    lines = [f"wrote {shown(output)}: {report.total_bytes} bytes, {report.bits_per_pixel:.3f} bits per {unit}"]
    if curves_info:
        lines.append(f"curves: {curves_info['curves']} curves ({curves_info['pieces']} pieces) found in the image by "
                     "dfc curves' extractor at its defaults ("
                     + ("" if report.raster_mode else "recorded in the file; ")
                     + "see them with dfc curves IMAGE --preview P.png)")
    if pruned is not None:
        lines.append(f"curves pruned: {pruned.summary()}")
    if report.pruned_curves:
        cut = report.pruned_curves
        lines.append(f"curves pruned: {cut['dropped']} of {cut['curves']} curves left out, those earning the least per "
                     "byte: the byte target is too small for all of them (--no-prune-curves refuses it instead)")
    if refined is not None:
        lines.append(f"curves refined against the pixels: {refined.summary()}")
    if report.default_target:
        lines.append(f"no --target-bytes: a clean image gets the bytes of its default mesh ({report.default_target}) "
                     "as a target, shared with a residual raster (--residual-bytes 0 stores the field alone)")
    if report.raster_mode:
        lines.append("raster mode: a constant field and a residual raster holding the image decode closer to the input "
                     "at this size than " + ("the field could fit in it" if report.field_psnr is None else
                                            f"a fitted field's file ({report.field_psnr:.2f} dB)")
                     + "; the file stores no curves, so zooms interpolate the raster (--no-raster-mode keeps the "
                     "field)")
    elif report.flat_rows:
        lines.append(f"flat regions: {report.flat_rows} feature rows share the stored vector nearest their region's "
                     "exact value")
    lines += [f"  {name}  {size:>10} bytes" for name, size in report.chunk_bytes.items()]
    lines.append(f"mesh: {report.n_vertices} vertices, {report.n_triangles} triangles; {report.n_features} features")
    if report.units:
        lines.append(report.units)
    scale = ("tone-mapped x/(1+x), " if report.tonemapped else "") + f"data range {report.data_range:.4g}"
    if kind == "samples" and report.heldout:
        lines.append(f"PSNR of the decoded file against {report.heldout} held-out samples (left out of the fit): "
                     f"{report.psnr:.2f} dB ({scale})")
    elif kind == "samples":
        lines.append(f"PSNR of the decoded file against the samples it was fitted to (too few to hold some out): "
                     f"{report.psnr:.2f} dB ({scale})")
    elif report.heldout:
        lines.append(f"PSNR of the decoded file against the input at {report.heldout} held-out pixels (never trained "
                     f"on): {report.psnr:.2f} dB ({scale})")
    else:
        lines.append(f"PSNR of the decoded file against the input: {report.psnr:.2f} dB ({scale})")
    if report.target_psnr is not None:
        lines[-1] += f"; target {report.target_psnr:g} dB"
    if report.pixel_filter is not None:
        lines.append(f"pixel filter: {report.pixel_filter} (" + (f"auto: {report.pixel_evidence}" if
                     report.pixel_evidence else "as given") + "; stored for the decoder)")
    if report.psnr_reference is not None:
        lines.append(f"PSNR of the decoded file against the reference {reference_path}: {report.psnr_reference:.2f} dB "
                     f"({scale})")
    lines.append("time: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in report.seconds.items()))
    for line in lines:
        click.echo(line, err=err)


def _fit_callback(bar):
    """The fit's progress: one tick per step, loss and batch PSNR every 25 steps."""
    def callback(step, loss_value, psnr):
        bar.update(1)
        if step % 25 == 0:
            bar.set_postfix(loss=f"{loss_value:.3g}", psnr=f"{psnr:.1f} dB", refresh=False)

    return callback


def _encode_in_memory(kind, signal, curves, settings, fit_curves_to_image, fem_sampling, reference, curves_info,
                      quiet, prune_to_fit: bool = False, raster_mode: bool = True):
    """(blob, report) of an input read whole: an image, frames, a sample set or a FEM solution (an image's curves
    pruned when the byte target is too small for all of them and ``prune_to_fit``, and the raster mode tried unless
    ``raster_mode`` is False: ``dfc.codec.encode_image``)."""
    from ..codec import (encode_fem, encode_frames, encode_image, encode_samples, fem_settings, refine_rounds,
                         refit_steps)

    if kind == "fem":
        settings = fem_settings(settings)
    rounds = refine_rounds(settings) if kind in REFINED else 0
    total_steps = settings.steps + rounds * refit_steps(settings)
    with progress_bar(total_steps, "fit", quiet) as bar:
        callback = _fit_callback(bar)
        if kind == "samples":
            return encode_samples(signal, curves, settings, reference=reference, callback=callback)
        if kind == "fem":
            return encode_fem(signal, curves, settings, sampling=fem_sampling, callback=callback)
        if kind == "frames":
            return encode_frames(signal, curves, settings, fit_curves=fit_curves_to_image, callback=callback)
        return encode_image(signal, curves, settings, fit_curves=fit_curves_to_image, callback=callback,
                            curves_info=curves_info, prune_to_fit=prune_to_fit, raster_mode=raster_mode)


def _gpus() -> int:
    import torch

    return torch.cuda.device_count()


REFINED = ("image", "fem")
"""Input kinds whose encode refines the mesh (``--refine``, ``--target-psnr``, filling ``--target-bytes``)."""
IN_MEMORY_PIXELS = 1 << 24
"""Image inputs with more pixels than this (4096²) are encoded out of core (``dfc.codec.encode_bands``)."""


def _out_of_core(kind: str, paths, epoch_pixels, workers: int) -> bool:
    """Whether an input is encoded out of core: an image with --epoch-pixels or --workers, under torchrun, or an
    EXR above ``IN_MEMORY_PIXELS``; ``click.UsageError`` for those options with other inputs."""
    from ..io.bands import ExrBands
    from ..io.sniff import file_kind
    from ..train.distributed import launched

    asked = epoch_pixels is not None or workers > 1 or launched()
    if kind != "image":
        if asked:
            raise click.UsageError(f"--epoch-pixels, --workers and torchrun apply to one image input, not {kind}")
        return False
    if file_kind(paths[0]) == "exr":
        bands = ExrBands(paths[0])  # the header: a damaged or truncated file is refused before any rank starts
        return asked or bands.width * bands.height > IN_MEMORY_PIXELS
    return asked


def _band_progress(total: int, shown: bool, quiet: bool):
    """``dfc.workers`` progress of an out-of-core fit: the command's bar, ticked by the fit's callback."""
    import contextlib

    @contextlib.contextmanager
    def bar():
        with progress_bar(total, "fit", quiet or not shown) as b:
            yield _fit_callback(b)

    return bar()


def _read_reference(path: str, domain):
    """(H, W, C) float32 exact values of a ``--reference`` file over ``domain`` (``dfc.io.samples.read_reference``)."""
    from ..errors import InputError
    from ..io.samples import read_reference

    pixels, ref_domain = read_reference(path)
    if ref_domain is not None and not np.allclose(ref_domain, domain, rtol=1e-9, atol=0):
        raise InputError(f"{path}: the reference's domain {tuple(ref_domain)} differs from the curves' {tuple(domain)}")
    return pixels


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


def _count(value: str, param) -> int:
    """``value`` as an integer ≥ 0, else ``click.BadParameter``."""
    try:
        n = int(value)
    except ValueError:
        n = -1
    if n < 0:
        raise click.BadParameter(f"must be an integer ≥ 0 or auto, got {value!r}", param=param)
    return n
