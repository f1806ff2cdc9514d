"""``dfc benchmark curves-auto``: how well the raster extractor finds the exact curves of the analytic scenes.

Each scene of ``dfc.bench.scenes.SCENES`` is rasterised box-filtered as the comparison harness does
(``AnalyticScene.render``, longer side ``--size``, ``--spp`` × ``--spp`` points per pixel) and its curves are
extracted with ``image_curves`` at its default settings. Both curve sets are flattened into segments of at most
0.01 px; distances run from the midpoints of one set's segments to the other set's segments; printed:

- distance from the true curves to the extracted ones (px): mean and 95th percentile over the true length
  (``all``), and the same over the true length within 1 px of an extracted curve (``matched``);
- recall: share of the true length within 0.5 px of an extracted curve;
- false: share of the extracted length farther than 1 px from every true curve;
- probe: the mean distance from the middle of each true curve (where ``--zoom-steps`` puts its edge windows,
  ``dfc.bench.speed.rate.rate_probes``) to the extracted curves (each one in the JSON: ``probe_px``).

``--pixel-filter SPEC`` (repeatable) makes the rasters with that pixel filter instead
(``dfc.bench.pixel_filters.filtered_raster``), and the extractor detects the filter (``image_curves_filtered``,
"auto"). With ``--refine`` (the default) the extracted curves are refined against the pixels
(``dfc.geometry.sources.refine``; a detected filter detected again along the refined curves and the curves refined
again through it when another wins, as ``dfc encode --curves auto`` does) and measured again (stage ``refined``);
stage ``exact`` refines the scene's exact curves through the same filter and measures how far that moves them: the
refinement's own bias at the truth (a refinement from the extracted curves cannot be expected to come nearer).
``--zoom-steps N`` adds the edge zoom PSNR at 33× and 100× of four encodes at equal bytes (``zoom_row``): the
extracted, the true and the refined curves, and the true curves refined.

``--render CASE`` (repeatable) also runs on a path-traced render of a Mitsuba scene (``RENDER_CASES``: the corpus's
renders, noise and all), whose true curves are the scene's own visible curves (``dfc curves SCENE.xml``: silhouettes
and creases; reflections, shadows and texture edges count as false): the curves ``dfc encode --curves auto`` finds
there, with the filter it detects, before and after refinement. ``--image
FILE`` (repeatable) also runs the extractor on images without ground truth and prints counts.
"""

from __future__ import annotations

import json
import time

import click
import numpy as np

from ...io.atomic import write_bytes_atomic

_STEP = 0.01  # px between samples of a curve
RENDER_CASES = ("mitsuba-box", "mitsuba-gaussian-auto", "mitsuba-shapes-hdr", "mitsuba-shapes-auto",
                "mitsuba-glass-auto", "mitsuba-texture-auto")
"""The ``dfc bench --corpus`` cases whose input is a Mitsuba render and whose scene gives the true curves."""


def segments(curves) -> tuple[np.ndarray, np.ndarray]:
    """Every piece flattened into segments of at most ``_STEP`` px: their starts and ends, (M, 2) each."""
    from ...geometry import bezier

    starts, ends = [np.zeros((0, 2))], [np.zeros((0, 2))]
    for cp in curves.control_points:
        n = max(2, int(np.ceil(np.linalg.norm(np.diff(cp, axis=0), axis=1).sum() / _STEP)))
        line = bezier.flatten(cp[None], n)[0]
        starts.append(line[:-1])
        ends.append(line[1:])
    return np.concatenate(starts), np.concatenate(ends)


def samples(curves) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) every ≤ ``_STEP`` along all pieces (the segments' midpoints), and the length (M,) each stands
    for."""
    a, b = segments(curves)
    return 0.5 * (a + b), np.linalg.norm(b - a, axis=1)


def to_curves(points: np.ndarray, curves, near: int = 8) -> np.ndarray:
    """Distance (M,) px from each of ``points`` (M, 2) to the nearest of ``curves``: to the segments of ``segments``
    (within 2e-6 px of the pieces for curvature radii of 10 px and more), checking the ``near`` segments whose
    midpoints lie nearest. Not the distance to the nearest sample: samples 0.01 px apart leave a point on the curve up
    to 0.005 px from every one of them."""
    from scipy.spatial import cKDTree

    a, b = segments(curves)
    k = min(near, len(a))
    idx = cKDTree(0.5 * (a + b)).query(points, k=k)[1].reshape(len(points), k)
    sa, ab = a[idx], b[idx] - a[idx]  # (M, k, 2)
    t = np.clip(np.einsum("mkd,mkd->mk", points[:, None] - sa, ab) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(points[:, None] - sa - t[..., None] * ab, axis=2).min(axis=1)


def _weighted_percentile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][min(np.searchsorted(cum, q * cum[-1]), len(values) - 1)])


def compare(true, found) -> dict:
    """Distances between two ``Curves`` over the same domain (see the module notes for the figures)."""
    from .rate import rate_probes

    tp, tw = samples(true)
    fp, fw = samples(found)
    if not len(fp):
        return {"mean_px": None, "p95_px": None, "matched_mean_px": None, "matched_p95_px": None, "recall": 0.0,
                "false": 0.0, "true_length_px": float(tw.sum()), "found_length_px": 0.0, "probe_px": None}
    to_found = to_curves(tp, found)
    to_true = to_curves(fp, true)
    matched = to_found <= 1.0
    return {
        "mean_px": float(np.average(to_found, weights=tw)),
        "p95_px": _weighted_percentile(to_found, tw, 0.95),
        "matched_mean_px": float(np.average(to_found[matched], weights=tw[matched])) if matched.any() else None,
        "matched_p95_px": _weighted_percentile(to_found[matched], tw[matched], 0.95) if matched.any() else None,
        "recall": float(tw[to_found <= 0.5].sum() / tw.sum()),
        "false": float(fw[to_true > 1.0].sum() / fw.sum()),
        "true_length_px": float(tw.sum()),
        "found_length_px": float(fw.sum()),
        "probe_px": [round(float(d), 5) for d in to_curves(rate_probes(true)[0], found)],
    }


def counts(curves) -> dict:
    length = float(samples(curves)[1].sum())
    return {"curves": curves.n_curves, "pieces": len(curves), "lines": int((curves.degree == 1).sum()),
            "cubics": int((curves.degree == 3).sum()), "length_px": round(length, 1)}


def _raster(scene, w: int, h: int, spec: str | None, spp: int) -> np.ndarray:
    """The scene's (h, w, C) raster: made with the pixel filter ``spec`` (``dfc.bench.pixel_filters.filtered_raster``),
    or box-filtered with ``spp`` × ``spp`` points as the comparison harness does (None)."""
    if spec is None:
        return scene.render(w, h, spp=spp)
    from ..pixel_filters import filtered_raster

    return filtered_raster(scene, w, h, spec)


def _in_pixels(scene, w: int, h: int):
    """``scene`` over the raster's pixel units: its curves and its values (the domain's origin at 0)."""
    from ..scenes import AnalyticScene

    x0, y0, x1, y1 = scene.domain
    scale = np.array([w / (x1 - x0), h / (y1 - y0)])
    return AnalyticScene(scene.name, _to_pixels(scene.curves, *scale), scene.channels,
                         lambda xy: scene.value(np.asarray(xy) / scale + [x0, y0]))


def zoom_row(scene, pixels: np.ndarray, found, refined, steps: int, exact=None) -> dict:
    """Edge zoom PSNR (``dfc.bench.speed.rate.measure``: 33× and 100× windows on the middle of every true curve,
    against the exact scene; the mean, and at 100× each window's in curve order) of encodes of ``pixels`` at equal
    bytes, ``steps`` steps each (no mesh refinement rounds): the extracted curves ``found`` at the default size (the
    field alone), then the true curves and the refined ones ``refined`` with that file's size as their byte target;
    a fourth of the curves ``exact`` when given (the true curves refined: stage ``exact``). ``scene`` is in the
    raster's pixel units."""
    from ...codec import EncodeSettings, encode_image
    from ...errors import TargetBytesError
    from .rate import measure

    row = {}
    blob, _ = encode_image(pixels, found, EncodeSettings(steps=steps, refine=0, residual_bytes=0))
    target = len(blob)
    sets = [("auto", found, blob), ("true", scene.curves, None), ("refined", refined, None)]
    for key, curves, b in sets + ([("exact", exact, None)] if exact is not None else []):
        if b is None:
            try:
                b, _ = encode_image(pixels, curves, EncodeSettings(steps=steps, target_bytes=target, refine=0))
            except TargetBytesError as e:
                row[f"{key}_refused"] = str(e)
                continue
        m = measure(scene, b, pixels)
        row.update({f"{key}_bytes": m["bytes"], f"{key}_1x": round(m["psnr_1x"], 2),
                    f"{key}_33x": round(m["edge_33x"], 2), f"{key}_100x": round(m["edge_100x"], 2),
                    f"{key}_100x_windows": m["edge_100x_windows"]})
    return row


@click.command()
@click.option("--scene", "scene_names", multiple=True, help="Scene(s) to run (default: all of dfc.bench.scenes).")
@click.option("--size", type=click.IntRange(16, 4096), default=None,
              help="Longer side of the raster in pixels (default: the scene's longer side in its units).")
@click.option("--spp", type=click.IntRange(1, 64), default=4, show_default=True,
              help="Points per pixel side of the box-filtered raster (the comparison harness uses 4).")
@click.option("--pixel-filter", "filters", multiple=True, metavar="FILTER",
              help="Make the rasters with this pixel filter instead (dfc.pixel_filter spec, e.g. box:16, gaussian:0.5, "
                   "point; repeatable: one run per filter). The extractor detects the filter itself (auto).")
@click.option("--refine/--no-refine", default=True, show_default=True,
              help="Also refine the extracted curves against the pixels (dfc.geometry.sources.refine) and measure "
                   "them again.")
@click.option("--zoom-steps", type=click.IntRange(min=0), default=0, show_default=True,
              help="With N > 0: encode each raster with the extracted, the true, the refined curves and the true "
                   "ones refined (stage exact) at equal bytes (N steps each) and print the edge PSNR at 33x and 100x "
                   "(slow: four encodes per raster).")
@click.option("--render", "renders", multiple=True, metavar="CASE", type=click.Choice(RENDER_CASES),
              help="Also measure on this path-traced render of a Mitsuba scene (a dfc bench --corpus case, rendered at "
                   "--size, default 256), against the scene's own visible curves: the curves dfc encode --curves auto "
                   "finds (the filter detected) and their refinement; repeatable; needs the render extra. Without "
                   "--scene, no analytic scene is run.")
@click.option("--image", "images", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Also extract from this image (no ground truth: counts only); repeatable.")
@click.option("--preview-dir", type=click.Path(file_okay=False), default=None,
              help="Draw each extraction over its image into this folder (NAME.png).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the figures to this JSON file.")
def command(scene_names, size, spp, filters, refine, zoom_steps, renders, images, preview_dir, json_path):
    """Distance, recall and false curves of the raster extractor against the analytic scenes' exact curves, before
    and after refining them against the pixels; with --zoom-steps, edge zoom PSNR at equal bytes too."""
    from pathlib import Path

    from ...io.preview import draw_curves
    from ...geometry.sources.auto import find_curves
    from ...geometry.sources.raster import RasterSettings, image_curves, image_curves_filtered
    from ..scenes import SCENES, get_scene

    settings = RasterSettings()
    results = {"settings": settings.to_dict(), "spp": spp, "scenes": {}, "images": {}, "localisation": [],
               "zoom": []}
    click.echo("targets: mean ≤ 0.1 px, p95 ≤ 0.3 px, recall ≥ 95 %, false ≤ 5 %; refined: mean ≤ 0.02 px, "
               "p95 ≤ 0.05 px")
    click.echo(f"{'scene':>8} {'filter':>13} {'size':>9} {'stage':>7} {'mean':>7} {'p95':>7} {'m.mean':>7} "
               f"{'m.p95':>7} {'probe':>7} {'recall':>7} {'false':>6} {'curves':>6} {'pieces':>6} {'s':>6}")

    def fmt(v, pct=False):
        return "–" if v is None else (f"{100 * v:6.1f}%" if pct else f"{v:7.4f}")

    for name in scene_names or ([] if renders else list(SCENES)):
        scene = get_scene(name)
        x0, y0, x1, y1 = scene.domain
        longer = size or max(8, round(max(x1 - x0, y1 - y0)))
        scale = longer / max(x1 - x0, y1 - y0)
        w, h = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
        exact = _in_pixels(scene, w, h)
        for spec in filters or (None,):
            label = spec or f"box:{spp}"
            pixels = _raster(scene, w, h, spec, spp)

            def find(p, spec=spec):
                if spec is None:
                    return image_curves(p, settings), None
                return image_curves_filtered(p, settings, "auto")[:2]

            stages = _stages(pixels, find, refine, f"{name} {label}")
            found = stages[0][1]
            refined = stages[-1][1]
            if refine:
                stages.append(_exact_stage(pixels, exact.curves, stages[-1][3]))
                exact_refined = stages[-1][1]
            for stage, curves, seconds, used in stages:
                row = {"scene": name, "filter": label, "detected": str(used) if used else None, "stage": stage,
                       **compare(exact.curves, curves), **counts(curves), "width": w, "height": h,
                       "seconds": round(seconds, 3)}
                results["localisation"].append(row)
                if stage == "found" and spec is None:
                    results["scenes"][name] = row
                _echo(row, fmt)
            if zoom_steps and refine:
                row = {"scene": name, "filter": label, "steps": zoom_steps,
                       **zoom_row(exact, pixels, found, refined, zoom_steps, exact_refined)}
                results["zoom"].append(row)
                click.echo(f"{name:>8} {label:>13} equal bytes ({row.get('auto_bytes')} B), edge PSNR 33x / 100x: "
                           + "; ".join(f"{k} " + (f"{row[k + '_33x']:.2f} / {row[k + '_100x']:.2f} dB"
                                                  if k + "_33x" in row else "refused")
                                       for k in ("true", "auto", "refined", "exact")))
            if preview_dir:
                Path(preview_dir).mkdir(parents=True, exist_ok=True)
                draw_curves(refined, Path(preview_dir) / f"{name}_{label.replace(':', '_')}.png",
                            background=pixels, hdr=float(pixels.max()) > 1.0, before=found if refine else None)
    for name in renders:
        pixels, true = _render(name, size or 256)
        h, w = pixels.shape[:2]
        stages = _stages(pixels, lambda p: find_curves(p)[:2], refine, name)
        for stage, curves, seconds, used in stages:
            row = {"scene": name, "filter": "render", "detected": str(used), "stage": stage,
                   **compare(true, curves), **counts(curves), "width": w, "height": h, "seconds": round(seconds, 3)}
            results["localisation"].append(row)
            _echo(row, fmt)
        if preview_dir:
            Path(preview_dir).mkdir(parents=True, exist_ok=True)
            draw_curves(stages[-1][1], Path(preview_dir) / f"{name}.png", background=pixels,
                        hdr=float(pixels.max()) > 1.0, before=stages[0][1] if refine else None)
    for path in images:
        from ...io.image import read_image

        image = read_image(path)
        clock = time.perf_counter()
        found = image_curves(image.pixels, settings)
        row = {**counts(found), "width": image.width, "height": image.height,
               "seconds": round(time.perf_counter() - clock, 3)}
        results["images"][str(path)] = row
        click.echo(f"{Path(path).name}: {image.width}x{image.height}: {row['curves']} curves, {row['pieces']} pieces "
                   f"({row['lines']} lines, {row['cubics']} cubics), {row['length_px']:.0f} px, {row['seconds']:.2f} s")
        if preview_dir:
            Path(preview_dir).mkdir(parents=True, exist_ok=True)
            draw_curves(found, Path(preview_dir) / f"{Path(path).stem}.png", background=image.pixels, hdr=image.hdr)
    if json_path:
        write_bytes_atomic(json_path, (json.dumps(results, indent=2) + "\n").encode())


def _stages(pixels: np.ndarray, find, refine: bool, label: str):
    """([(stage, curves, seconds, filter)]: the curves ``find(pixels) -> (curves, filter or None: the box)`` and the
    filter they were found with, then (``refine``) refined through it; a filter ``find`` detected (not None) is
    detected again along the refined curves as ``dfc encode --curves auto`` does
    (``dfc.geometry.sources.auto.ready_curves``), and the refined stage names the filter refined with last. A
    refinement's warning is printed after ``label``."""
    from ...geometry.sources.auto import ready_curves

    clock = time.perf_counter()
    found, used = find(pixels)
    stages = [("found", found, time.perf_counter() - clock, used)]
    if refine:
        clock = time.perf_counter()
        curves, _, refined = ready_curves(pixels, found, prune=False, pixel_filter=used, detected=used is not None)
        stages.append(("refined", curves, time.perf_counter() - clock, used and refined.pixel_filter))
        if refined.warning:
            click.echo(f"{label}: {refined.warning}")
    return stages


def _exact_stage(pixels: np.ndarray, exact, spec: str | None):
    """(stage "exact", curves, seconds, filter): the scene's exact curves ``exact`` refined through the filter the
    extracted curves were refined with last (``spec``; None: the box). Their distance from the exact curves is the
    refinement's bias at the truth: no start can be expected to end nearer."""
    from ...geometry.sources.refine import refine_curves
    from ...pixel_filter import parse

    clock = time.perf_counter()
    moved = refine_curves(pixels, exact, parse(spec) if spec else None).curves
    return "exact", moved, time.perf_counter() - clock, spec


def _echo(row: dict, fmt) -> None:
    """One printed row of the localisation table."""
    w, h = row["width"], row["height"]
    probe = float(np.mean(row["probe_px"])) if row["probe_px"] else None
    click.echo(f"{row['scene']:>8} {row['filter']:>13} {w:>4}x{h:<4} {row['stage']:>7} {fmt(row['mean_px'])} "
               f"{fmt(row['p95_px'])} {fmt(row['matched_mean_px'])} {fmt(row['matched_p95_px'])} {fmt(probe)} "
               f"{fmt(row['recall'], True)} {fmt(row['false'], True)} {row['curves']:>6} {row['pieces']:>6} "
               f"{row['seconds']:6.2f}")


def _render(name: str, size: int):
    """(pixels (H, W, C), the scene's visible curves over ``[0, W] × [0, H]``) of the Mitsuba corpus case ``name``
    rendered at longer side ``size``. Raises ``ExtraError`` without Mitsuba, ``InputError`` when the case's scene is
    missing (a source checkout has it)."""
    from ...errors import InputError
    from ...geometry.curves import fit_curves_to_domain
    from ..compare import BenchSettings
    from ..corpus import CASES, select_cases

    _, skipped = select_cases([name], None)
    if name in skipped:
        raise InputError(f"--render {name}: {skipped[name]}")
    inputs = CASES[name].build(size, BenchSettings(), None)
    pixels = inputs["pixels"]
    h, w = pixels.shape[:2]
    return pixels, fit_curves_to_domain(inputs["curves"], (0.0, 0.0, float(w), float(h)))


def _to_pixels(curves, sx: float, sy: float):
    """``curves`` in the raster's pixel units (the domain's origin at 0)."""
    from ...geometry.curves import Curves

    x0, y0, x1, y1 = curves.domain
    cp = (curves.control_points - [x0, y0]) * [sx, sy]
    return Curves((0.0, 0.0, (x1 - x0) * sx, (y1 - y0) * sy), cp, curves.degree, curves.curve, curves.t_range,
                  curves.names, curves.sides)
