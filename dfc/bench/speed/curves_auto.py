"""``dfc benchmark curves-auto``: how well the raster extractor finds the exact curves of the analytic scenes.

Each scene of ``dfc.bench.scenes.SCENES`` is rasterised box-filtered as the comparison harness does
(``AnalyticScene.render``, longer side ``--size``, ``--spp`` × ``--spp`` points per pixel) and its curves are
extracted with ``image_curves`` at its default settings. Both curve sets are sampled every 0.01 px; printed:

- distance from the true curves to the extracted ones (px): mean and 95th percentile over the true length
  (``all``), and the same over the true length within 1 px of an extracted curve (``matched``);
- recall: share of the true length within 0.5 px of an extracted curve;
- false: share of the extracted length farther than 1 px from every true curve.

``--image FILE`` (repeatable) also runs the extractor on images without ground truth and prints counts.
"""

from __future__ import annotations

import json
import time

import click
import numpy as np

from ...io.atomic import write_bytes_atomic

_STEP = 0.01  # px between samples of a curve


def samples(curves) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) every ≤ ``_STEP`` along all pieces, and the length (M,) each stands for."""
    from ...geometry import bezier

    pts, weights = [], []
    for cp in curves.control_points:
        n = max(2, int(np.ceil(np.linalg.norm(np.diff(cp, axis=0), axis=1).sum() / _STEP)))
        line = bezier.flatten(cp[None], n)[0]
        pts.append(0.5 * (line[1:] + line[:-1]))
        weights.append(np.linalg.norm(np.diff(line, axis=0), axis=1))
    if not pts:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate(pts), np.concatenate(weights)


def _weighted_percentile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][min(np.searchsorted(cum, q * cum[-1]), len(values) - 1)])


def compare(true, found) -> dict:
    """Distances between two ``Curves`` over the same domain (see the module notes for the figures)."""
    from scipy.spatial import cKDTree

    tp, tw = samples(true)
    fp, fw = samples(found)
    if not len(fp):
        return {"mean_px": None, "p95_px": None, "matched_mean_px": None, "matched_p95_px": None, "recall": 0.0,
                "false": 0.0, "true_length_px": float(tw.sum()), "found_length_px": 0.0}
    to_found = cKDTree(fp).query(tp)[0]
    to_true = cKDTree(tp).query(fp)[0]
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
    }


def counts(curves) -> dict:
    length = float(samples(curves)[1].sum())
    return {"curves": curves.n_curves, "pieces": len(curves), "lines": int((curves.degree == 1).sum()),
            "cubics": int((curves.degree == 3).sum()), "length_px": round(length, 1)}


@click.command()
@click.option("--scene", "scene_names", multiple=True, help="Scene(s) to run (default: all of dfc.bench.scenes).")
@click.option("--size", type=click.IntRange(16, 4096), default=None,
              help="Longer side of the raster in pixels (default: the scene's longer side in its units).")
@click.option("--spp", type=click.IntRange(1, 64), default=4, show_default=True,
              help="Points per pixel side of the box-filtered raster (the comparison harness uses 4).")
@click.option("--image", "images", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Also extract from this image (no ground truth: counts only); repeatable.")
@click.option("--preview-dir", type=click.Path(file_okay=False), default=None,
              help="Draw each extraction over its image into this folder (NAME.png).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the figures to this JSON file.")
def command(scene_names, size, spp, images, preview_dir, json_path):
    """Distance, recall and false curves of the raster extractor against the analytic scenes' exact curves."""
    from pathlib import Path

    from ...io.preview import draw_curves
    from ...geometry.sources.raster import RasterSettings, image_curves
    from ..scenes import SCENES, get_scene

    settings = RasterSettings()
    results = {"settings": settings.to_dict(), "spp": spp, "scenes": {}, "images": {}}
    click.echo("targets: mean ≤ 0.1 px, p95 ≤ 0.3 px, recall ≥ 95 %, false ≤ 5 %")
    click.echo(f"{'scene':>8} {'size':>9} {'mean':>6} {'p95':>6} {'m.mean':>6} {'m.p95':>6} {'recall':>7} "
               f"{'false':>6} {'curves':>6} {'pieces':>6} {'s':>6}")
    for name in scene_names or list(SCENES):
        scene = get_scene(name)
        x0, y0, x1, y1 = scene.domain
        longer = size or max(8, round(max(x1 - x0, y1 - y0)))
        scale = longer / max(x1 - x0, y1 - y0)
        w, h = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
        pixels = scene.render(w, h, spp=spp)
        clock = time.perf_counter()
        found = image_curves(pixels, settings)
        seconds = time.perf_counter() - clock
        true = _to_pixels(scene.curves, w / (x1 - x0), h / (y1 - y0))
        row = {**compare(true, found), **counts(found), "width": w, "height": h, "seconds": round(seconds, 3)}
        results["scenes"][name] = row

        def fmt(v, pct=False):
            return "–" if v is None else (f"{100 * v:6.1f}%" if pct else f"{v:6.3f}")

        click.echo(f"{name:>8} {w:>4}x{h:<4} {fmt(row['mean_px'])} {fmt(row['p95_px'])} {fmt(row['matched_mean_px'])} "
                   f"{fmt(row['matched_p95_px'])} {fmt(row['recall'], True)} {fmt(row['false'], True)} "
                   f"{row['curves']:>6} {row['pieces']:>6} {seconds:6.2f}")
        if preview_dir:
            Path(preview_dir).mkdir(parents=True, exist_ok=True)
            draw_curves(found, Path(preview_dir) / f"{name}.png", background=pixels, hdr=float(pixels.max()) > 1.0)
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


def _to_pixels(curves, sx: float, sy: float):
    """``curves`` in the raster's pixel units (the domain's origin at 0)."""
    from ...geometry.curves import Curves

    x0, y0, x1, y1 = curves.domain
    cp = (curves.control_points - [x0, y0]) * [sx, sy]
    return Curves((0.0, 0.0, (x1 - x0) * sx, (y1 - y0) * sy), cp, curves.degree, curves.curve, curves.t_range,
                  curves.names, curves.sides)
