"""``dfc bench``: dfc against equal-size baselines (tuned hash grid and ReLU field, lossless raster, JPEG XL, AVIF,
WebP, JPEG 2000) at 1× and at increasing zoom, at one budget or (``--rd``) several; with ``--solve``, against the
physics-informed baselines (TanH field, SIREN, MLP) on a diffusion-curve scene."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from .options import (
    POINT,
    check_device,
    json_option,
    quiet_option,
    read_curves_checked,
    stdout_taken,
    threads_option,
    write_json,
)


def _zooms(ctx, param, value):
    if value and any(not z >= 1 for z in value):
        raise click.BadParameter(f"zoom factors must be ≥ 1, got {list(value)}")
    return value


def _budgets(ctx, param, value):
    if value is None:
        return None
    try:
        budgets = sorted({int(v) for v in value.split(",") if v.strip()})
    except ValueError:
        raise click.BadParameter(f"expected comma-separated byte counts, got {value!r}") from None
    if not budgets or budgets[0] < 1:
        raise click.BadParameter("byte budgets must be positive")
    return budgets


@click.command()
@click.argument("input_path", metavar="[INPUT]", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option("--curves", "curves_path", callback=lambda ctx, param, value: value if value in (None, "auto") else
              click.Path(exists=True, dir_okay=False).convert(value, param, ctx),
              help="Discontinuity curves of INPUT (SVG, JSON or diffusion-curve XML); or 'auto': dfc is fitted with "
                   "the curves dfc curves' extractor finds, at its defaults, in the raster it fits (INPUT, an "
                   "analytic scene's raster, a Mitsuba scene's render) while the probes and references stay those of "
                   "the scene's own curves (a file named auto: ./auto).")
@click.option("--scene", help="Benchmark an analytic scene (a name, see --list-scenes), or a Mitsuba 3 scene "
              "(SCENE.xml, pip install 'dfc[render]'): every zoom is then measured against Mitsuba rendering just "
              "that window; INPUT, when given, is its render to fit (else rendered at --size with --scene-spp) and "
              "--curves its curves (else extracted from the scene as dfc curves does).")
@click.option("--scene-spp", type=click.IntRange(min=2), default=256, show_default=True,
              help="Mitsuba scenes: samples per pixel of every render (the references, the 1x truth, the input "
              "when rendered here); each reference is two independent halves, whose difference estimates its own "
              "PSNR (the table's 'reference itself' row).")
@click.option("--scene-filter", default="box", show_default=True, metavar="FILTER",
              help="Mitsuba scene: the pixel filter of every render made (input, 1x truth, zoom references): box or "
                   "gaussian[:STDDEV] (Mitsuba's default, 0.5), tent, mitchell.")
@click.option("--sensor", type=click.IntRange(min=0), default=0, show_default=True,
              help="Mitsuba scenes: which sensor (a perspective camera) renders, by index.")
@click.option("--solve", "solve_path", type=click.Path(exists=True, dir_okay=False),
              help="Physics-informed solve of this diffusion-curve scene (XML, or JSON with side values) by dfc "
              "and the TanH field, SIREN and MLP baselines, against the finite-difference reference.")
@click.option("--corpus", is_flag=True, help="Run the real-content corpus (dfc.bench.corpus): RD curves at 0.25, "
              "0.5, 1 and 2 bits per pixel of every case, dfc encoded as dfc encode does by default, against JPEG XL, "
              "AVIF, WebP (SDR only) and JPEG 2000, and print the BD-rate table (no neural baselines unless "
              "--methods names them).")
@click.option("--corpus-cases", metavar="NAME,...", help="--corpus: the cases to run  [default: all; see "
              "--list-scenes].")
@click.option("--corpus-data", type=click.Path(file_okay=False), metavar="DIR",
              help="--corpus: the third-party data directory (exr/, diffusion-curves/); cases needing it are skipped "
                   "when it is absent  [default: shared/data beside the repository].")
@click.option("--corpus-bpp", metavar="BPP,...", help="--corpus: budgets in bits per input pixel  "
              "[default: 0.25,0.5,1,2].")
@click.option("--corpus-jobs", type=click.IntRange(min=1), default=1, show_default=True,
              help="--corpus: cases run at once, each in a process of its own on one thread.")
@click.option("--prune-curves/--no-prune-curves", "prune_curves", default=True, show_default=True,
              help="--corpus: prune the curves of the --curves auto cases for each budget, as dfc encode --curves auto "
                   "does, and the other cases' curves where a budget is too small for all of them, as dfc encode "
                   "does with a curves file (dfc.geometry.sources.prune).")
@click.option("--refine-curves/--no-refine-curves", "refine_curves", default=True, show_default=True,
              help="--corpus: refine the curves of the --curves auto cases against the pixels for each budget, after "
                   "pruning, as dfc encode --curves auto does (dfc.geometry.sources.refine).")
@click.option("--residual-share", type=click.FloatRange(0.0, 1.0, max_open=True), default=None, metavar="F",
              help="dfc at a byte budget: give this share of it to a residual raster (dfc encode --residual-bytes); "
                   "0: none  [default: the encoder's, --residual-bytes auto].")
@click.option("--raster-mode/--no-raster-mode", "raster_mode", default=True, show_default=True,
              help="dfc may store a clean image as a constant field and a residual raster when that decodes closer "
                   "at 1x, as dfc encode does (dfc encode --no-raster-mode).")
@click.option("--corpus-own-rate", is_flag=True,
              help="--corpus: also encode dfc without a byte target (the default encode) and measure every codec at "
                   "that file's size, at 1x.")
@click.option("--super-resolution", type=click.IntRange(min=0), default=2, show_default=True, metavar="K",
              help="With a reference (an analytic or Mitsuba scene, the corpus's cases with zoom windows): also render "
                   "every method over the whole image at K times the input's pixels per axis and measure it against "
                   "the reference there, beside the input itself upsampled; 0: not measured.")
@click.option("--list-scenes", is_flag=True, help="List the analytic scenes (and the corpus cases) and exit.")
@click.option("--probe", "probes", type=POINT, multiple=True,
              help="Zoom centre X,Y in domain units (repeatable; default: points on edges, at junctions and stroke "
              "tips, and in smooth regions, found from the curves).")
@click.option("-o", "--output", type=click.Path(file_okay=False), help="Directory for results.json, results.md, "
              "contact.png and dfc.dfield (created if missing).")
@click.option("--zoom", "zooms", type=float, multiple=True, callback=_zooms,
              help="Zoom factor (repeatable)  [default: 1, 10, 33, 100].")
@click.option("--methods", help="Comma-separated methods to run  [default: dfc,hashgrid,relu,raster,jpegxl,avif,"
              "webp,jpeg2k (webp only for SDR input); with --solve: dfc,tanh_field,siren,tanh_mlp].")
@click.option("--bytes", "target_bytes", type=click.IntRange(min=1),
              help="Byte budget; with dfc, its file is sized to it (else every method gets the .dfield's size).")
@click.option("--rd", is_flag=True, help="Rate-distortion sweep: run the comparison at every --budgets and write "
              "the curves (results.json) and plots of PSNR against bytes (rd.png, rd_probes.png), plus each "
              "budget's outputs in DIR/budget_<bytes>/.")
@click.option("--budgets", callback=_budgets, help="Comma-separated byte budgets of --rd  [default: 0.25, 0.5, 1, "
              "2 and 4 bits per input pixel].")
@click.option("--steps", type=click.IntRange(min=1),
              help="Optimiser steps of every trained method (the neural baselines at least; see --match-time)  "
                   "[default: dfc encode's for an image, 3000; --solve 1000].")
@click.option("--sweep/--no-sweep", default=True, show_default=True,
              help="Tune the hash grid and the ReLU field per budget: try each candidate configuration for "
              "--sweep-steps and train the best at 1x on the input in full.")
@click.option("--sweep-steps", type=click.IntRange(min=1), help="Steps of each sweep candidate  [default: --steps / 5].")
@click.option("--match-time/--no-match-time", default=True, show_default=True,
              help="Train the neural baselines at least as long as dfc's encode took (more steps than --steps "
              "when theirs are faster).")
@click.option("--pixel-grid", type=click.IntRange(min=1), default=4, show_default=True,
              help="The 1x image PSNR renders every method as the mean over a K x K grid of points in each pixel "
              "(a box filter, as the scenes' rasters are made).")
@click.option("--batch-size", type=click.IntRange(min=1), help="Samples per step  [default: 16384; with --solve: "
              "1024 interior and 1024 boundary points].")
@click.option("--size", type=click.IntRange(min=8), help="Scenes: longer side of the raster fitted  "
              "[default: the domain's longer side in its units; a Mitsuba scene's film]; --solve: of the reference "
              "grid [default: 256]; --corpus: of every case's input [default: 256].")
@click.option("--render", type=click.IntRange(min=8), help="Window resolution (longer side, pixels)  "
              "[default: 256; --corpus: 128].")
@click.option("--spp", type=click.IntRange(min=1), default=4, show_default=True, help="Points averaged per pixel.")
@click.option("--max-triangles", type=click.IntRange(min=2), help="Cap on dfc's mesh triangle count.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds every fit and the sampling.")
@click.option("--device", default="cpu", show_default=True, help="torch device (cpu, cuda, cuda:1, ...).")
@click.option("--fit-curves-to-image", is_flag=True, help="Scale the curves' domain onto INPUT's [0, W] x [0, H].")
@threads_option
@json_option
@quiet_option
def command(input_path, curves_path, scene, scene_spp, scene_filter, sensor, solve_path, corpus, corpus_cases,
            corpus_data, corpus_bpp, corpus_jobs, prune_curves, refine_curves, residual_share, raster_mode,
            corpus_own_rate,
            super_resolution, list_scenes, probes, output, zooms, methods, target_bytes, rd, budgets, steps,
            sweep, sweep_steps, match_time, pixel_grid, batch_size, size, render, spp, max_triangles, seed, device,
            fit_curves_to_image, json_path, quiet):
    """Compare dfc with other methods at equal file size: fit dfc, then size every other method to the .dfield's
    byte count (tuned neural baselines, a lossless raster, classical codecs at the highest quality that fits),
    measure each at 1x on the whole image and in a window around each probe at each zoom, and write the PSNR tables
    (results.json, results.md) and a contact sheet (contact.png) to OUTPUT. With --rd, the same at several budgets,
    with rate-distortion plots. (Speed and scale of dfc's own stages: dfc benchmark.)

    \b
    dfc bench INPUT --curves CURVES [--probe X,Y ...] -o DIR
    dfc bench --scene NAME -o DIR
    dfc bench --scene SCENE.xml [RENDER.exr] [--curves CURVES] [--scene-spp N] -o DIR
    dfc bench --scene NAME --rd [--budgets 2048,4096,...] -o DIR
    dfc bench --solve SCENE -o DIR
    dfc bench --corpus [--corpus-cases NAME,...] [--corpus-own-rate] [--json PATH] [-o DIR]
    dfc bench --list-scenes

    Probes default to points on edges, at junctions and stroke tips, and in smooth regions, found from the curves.
    Analytic scenes are measured against their exact value at every zoom, Mitsuba scenes against Mitsuba rendering
    each window (a film scaled up with a crop window); a user image alone only at zoom 1 (against itself, rendered
    at its own resolution) — larger zooms are rendered but have no reference. --solve trains every method
    on the Laplace equation's loss alone and measures it against a finite-difference solve (--render, --spp and
    --zoom do not apply). --corpus runs every case of the real-content corpus (or --corpus-cases) and prints the
    BD-rate table of dfc against each codec, the 1x PSNR per budget and the zoom margins (the tables also to
    DIR/results.md with -o); --corpus-own-rate adds dfc's default encode against the codecs at its own size.
    --json also writes results.json's record to a file (- for standard output, the table then going to standard
    error).
    """
    from ..bench.scenes import SCENES, SUMMARIES

    if list_scenes:
        from ..bench.corpus import CASES

        for name in SCENES:
            click.echo(f"{name:10s} {SUMMARIES[name]}")
        for name, case in CASES.items():
            click.echo(f"corpus case {name}: {case.summary}")
        return

    def common() -> dict:  # the BenchSettings fields of every comparison, corpus or single
        from ..bench.compare import ZOOMS, BenchSettings

        return {"steps": steps or BenchSettings.steps, "batch_size": batch_size or 1 << 14, "spp": spp,
                "zooms": tuple(zooms) or ZOOMS, "max_triangles": max_triangles, "seed": seed,
                "device": check_device(device), "pixel_grid": pixel_grid, "super_resolution": super_resolution,
                "residual_share": residual_share, "raster_mode": raster_mode}

    if corpus:
        if any(v is not None for v in (input_path, curves_path, scene, solve_path, target_bytes, budgets)) or rd \
                or probes or fit_curves_to_image:
            raise click.UsageError("--corpus takes none of INPUT, --curves, --scene, --solve, --probe, --bytes, --rd, "
                                   "--budgets and --fit-curves-to-image")
        from ..bench.compare import BenchSettings
        from ..bench.corpus import CORPUS_METHODS

        settings = BenchSettings(render=render or 128, methods=_methods(methods, CORPUS_METHODS), sweep=False,
                                 match_time=False, keep_going=True, prune_curves=prune_curves,
                                 refine_curves=refine_curves, **common())
        _corpus(settings, cases=corpus_cases, data=corpus_data, bpp=corpus_bpp, jobs=corpus_jobs,
                own_rate=corpus_own_rate, default_encode=steps is None and batch_size is None, size=size or 256,
                output=output, json_path=json_path, quiet=quiet)
        return
    if any(v is not None for v in (corpus_cases, corpus_data, corpus_bpp)) or corpus_jobs != 1 or not prune_curves \
            or not refine_curves or corpus_own_rate:
        raise click.UsageError("--corpus-cases, --corpus-data, --corpus-bpp, --corpus-jobs, --corpus-own-rate, "
                               "--no-prune-curves and --no-refine-curves apply to --corpus")
    render = render or 256
    from ..bench.rendered import is_scene_file

    mitsuba = scene is not None and is_scene_file(scene)
    if sum(v is not None for v in (None if mitsuba else input_path, scene, solve_path)) != 1:
        raise click.UsageError("give one of INPUT (with --curves), --scene NAME|SCENE.xml and --solve SCENE")
    if not mitsuba and (scene_spp != 256 or sensor != 0 or scene_filter != "box"):
        raise click.UsageError("--scene-spp, --scene-filter and --sensor apply to a Mitsuba scene (--scene SCENE.xml)")
    if output is None:
        raise click.UsageError("missing option '-o' / '--output'")
    if solve_path is not None:
        if curves_path or fit_curves_to_image or probes or zooms or target_bytes or rd or budgets:
            raise click.UsageError("--curves, --fit-curves-to-image, --probe, --zoom, --bytes, --rd and --budgets do "
                                   "not apply to --solve")
        _solve(solve_path, output, methods, steps, batch_size, size, max_triangles, seed, device, json_path, quiet)
        return
    if input_path is not None and curves_path is None and not mitsuba:
        raise click.UsageError("INPUT needs --curves")
    if scene is not None and (fit_curves_to_image or (curves_path not in (None, "auto") and not mitsuba)):
        raise click.UsageError("--curves (but auto) and --fit-curves-to-image apply to INPUT, not to --scene NAME")
    if rd and target_bytes:
        raise click.UsageError("--rd sweeps --budgets; --bytes applies to a single comparison")
    if budgets and not rd:
        raise click.UsageError("--budgets applies to --rd")
    from ..bench.compare import BenchSettings, markdown_table, run_bench, scene_inputs, write_outputs

    settings = BenchSettings(size=size, render=render, methods=_methods(methods, None), target_bytes=target_bytes,
                             sweep=sweep, sweep_steps=sweep_steps, match_time=match_time, **common())
    if rd:
        from ..bench.rd import require_matplotlib

        require_matplotlib()
    settings.check(budgeted=rd)

    def progress(message: str) -> None:
        if not quiet:
            click.echo(f"bench: {message}", err=True)

    auto = curves_path == "auto"
    if mitsuba:
        inputs = _mitsuba_inputs(scene, input_path, None if auto else curves_path, settings, probes, scene_spp,
                                 scene_filter,
                                 sensor, quiet, progress)
    elif scene is not None:
        from ..bench.scenes import get_scene

        inputs = scene_inputs(get_scene(scene), settings, probes=probes, progress=progress)
    else:
        from ..bench.probes import labelled_probes
        from ..codec import check_domain
        from ..io.image import read_image

        image = read_image(input_path)
        if auto:
            curves, used = _auto_curves(image.pixels, (0.0, 0.0, float(image.width), float(image.height)), progress)
            settings = replace(settings, pixel_filter=used)
        else:
            curves = check_domain(read_curves_checked(curves_path, quiet), image.width, image.height,
                                  fit_curves_to_image)
        points, kinds = (probes, None) if probes else labelled_probes(curves)
        inputs = {"pixels": image.pixels, "curves": curves, "channels": image.channels, "probes": points,
                  "probe_kinds": kinds, "name": input_path}
    if auto and (mitsuba or scene is not None):
        inputs["curves"], used = _auto_curves(inputs["pixels"], inputs["curves"].domain, progress)
        settings = replace(settings, pixel_filter=used)
    if auto:
        inputs["name"] = f"{inputs['name']}, dfc fitted with curves found in the raster (--curves auto)"
    if rd:
        from ..bench.rd import default_budgets, rd_markdown, run_rd, write_rd

        h, w = inputs["pixels"].shape[:2]
        result = run_rd(inputs, budgets or default_budgets(w, h), settings, progress)
        paths, text = write_rd(result, output), rd_markdown(result.results)
    else:
        result = run_bench(**inputs, settings=settings, progress=progress)
        paths, text = write_outputs(result, output), markdown_table(result.results)
    for path in paths:
        progress(f"wrote {path}")
    _finish(text, output, json_path)


def _auto_curves(pixels, domain, progress):
    """``--curves auto``: (curves, filter spec) of ``dfc.bench.corpus.found_curves``."""
    from ..bench.corpus import found_curves

    return found_curves(pixels, domain, progress)


def _mitsuba_inputs(scene, input_path, curves_path, settings, probes, spp, pixel_filter, sensor, quiet,
                    progress) -> dict:
    """``run_bench``'s inputs for a Mitsuba scene (``dfc.bench.rendered.mitsuba_inputs``), with its render and
    curves when given."""
    from pathlib import Path

    from ..bench.rendered import mitsuba_inputs

    if not Path(scene).is_file():
        raise click.BadParameter(f"{scene}: no such file", param_hint="'--scene'")
    image = None
    if input_path is not None:
        from ..io.image import read_image

        image = read_image(input_path)
    curves = read_curves_checked(curves_path, quiet) if curves_path else None
    return mitsuba_inputs(scene, settings, pixels=None if image is None else image.pixels,
                          channels=None if image is None else image.channels, curves=curves, probes=probes, spp=spp,
                          sensor=sensor, progress=progress, pixel_filter=pixel_filter)


def _finish(table: str, output: str, json_path: str | None) -> None:
    """Print the table (to standard error when ``--json -`` takes standard output) and copy results.json's record to
    ``json_path``."""
    click.echo(table, nl=False, err=stdout_taken(json_path))
    if json_path:
        write_json(json_path, json.loads((Path(output) / "results.json").read_text()))


def _methods(value: str | None, default):
    return default if value is None else tuple(m.strip() for m in value.split(",") if m.strip())


def _solve(path, output, methods, steps, batch_size, size, max_triangles, seed, device, json_path, quiet) -> None:
    """``dfc bench --solve``: see ``dfc.bench.solve``."""
    from ..bench.solve import SOLVE_METHODS, SolveBenchSettings, markdown_table, run_solve_bench, write_outputs

    settings = SolveBenchSettings(steps=steps or SolveBenchSettings.steps, batch_size=batch_size or 1 << 10,
                                  size=size or 256, methods=_methods(methods, SOLVE_METHODS),
                                  max_triangles=max_triangles, seed=seed, device=check_device(device))
    settings.check()

    def progress(message: str) -> None:
        if not quiet:
            click.echo(f"bench: {message}", err=True)

    results = run_solve_bench(read_curves_checked(path, quiet), settings, name=path, progress=progress)
    for written in write_outputs(results, output):
        progress(f"wrote {written}")
    _finish(markdown_table(results), output, json_path)


def _corpus(settings, *, cases: str | None, data: str | None, bpp: str | None, jobs: int, own_rate: bool,
            default_encode: bool, size: int, output: str | None, json_path: str | None, quiet: bool) -> None:
    """``dfc bench --corpus`` with ``settings`` (``BenchSettings``): see ``dfc.bench.corpus``. dfc is encoded as by
    default when ``default_encode`` (no --steps or --batch-size: else they apply to it too); ``cases``, ``data``,
    ``bpp``: the options' text."""
    from ..bench.corpus import (CORPUS_BPP, corpus_document, corpus_markdown, corpus_record, default_shared,
                                run_corpus, select_cases)

    try:
        bpp_values = CORPUS_BPP if bpp is None else sorted({float(v) for v in bpp.split(",") if v.strip()})
    except ValueError:
        raise click.BadParameter(f"expected comma-separated bits per pixel, got {bpp!r}",
                                 param_hint="'--corpus-bpp'") from None
    if not bpp_values or not all(0 < b < 64 for b in bpp_values):
        raise click.BadParameter("bits per pixel must be in (0, 64)", param_hint="'--corpus-bpp'")
    names = None if cases is None else [n.strip() for n in cases.split(",") if n.strip()]
    shared = Path(data) if data else default_shared()
    selected, skipped = select_cases(names, shared)
    settings.check(budgeted=True)
    progress = None if quiet else _progress
    for name, why in skipped.items():
        _progress(f"skipping corpus case {name}: {why}")
    if not selected:
        raise click.UsageError("no corpus case can run here: " + "; ".join(f"{n}: {w}" for n, w in skipped.items()))
    results = run_corpus(selected, settings, size=size, bpp=bpp_values, shared=shared, progress=progress,
                         default_encode=default_encode, own_rate=own_rate, jobs=jobs)
    record = corpus_record(results, skipped, bpp_values)
    text = corpus_markdown(record)
    doc = corpus_document(record, text)
    if output:
        from ..io.atomic import write_bytes_atomic

        Path(output).mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(Path(output) / "results.json", (json.dumps(doc, indent=2) + "\n").encode())
        write_bytes_atomic(Path(output) / "results.md", text.encode())
        if not quiet:
            _progress(f"wrote {Path(output) / 'results.json'} and results.md")
    click.echo(text, nl=False, err=stdout_taken(json_path))
    if json_path:
        write_json(json_path, doc)


def _progress(message: str) -> None:
    """``--corpus``'s progress line on standard error (a module-level function: worker processes receive it)."""
    click.echo(f"bench: {message}", err=True)
