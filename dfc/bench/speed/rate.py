"""``dfc benchmark rate SCENE``: what one encode of an analytic scene costs and what it reaches, the numbers each
rate/quality lever of the encoder is measured with before it becomes a default.

The scene (``dfc.bench.scenes``) is rendered at its domain size with 4 × 4 points per pixel (its box-filtered
raster, as ``samples/sample.exr`` is made) and encoded with ``dfc.codec.encode_image``; every setting of
``dfc.codec.EncodeSettings`` can be changed with ``--set NAME=VALUE``. The written file, decoded again, is measured:

- **bytes**, and bytes per chunk;
- **1× PSNR on all pixels** against the raster it was fitted to, rendered with the decoder's default anti-aliasing
  (``dfc.render.default_pixel_filter``: the file's pixel filter) and, for comparison, at the pixel centres only; plus the PSNR without the mixed pixels
  (``dfc.geometry.pixels.edge_pixels``) at the pixel centres;
- **edge zoom PSNR** at 33× and 100× in windows centred on the middle of every input curve (the mean, and each
  window's in curve order: ``edge_33x_windows``) and on every open curve end inside the domain (``rate_probes``),
  against the exact scene at the same points;
- **smooth-region PSNR** at 33× in windows centred on the points farthest from every curve.

Windows are rendered ``WINDOW`` pixels on their longer side with ``WINDOW_SPP`` points per pixel for the file and
the exact scene alike. Every PSNR is on ``dfc.metrics.quality_scale`` of the raster (tone-mapped for HDR scenes).
"""

from __future__ import annotations

import json
import time

import click
import numpy as np

from ...io.atomic import write_bytes_atomic

WINDOW = 128
"""Longer side of a zoom window's render, pixels."""
WINDOW_SPP = 4
"""Points per pixel of a zoom window's render (for the file and the exact scene alike)."""
EDGE_ZOOMS = (33, 100)
SMOOTH_ZOOM = 33
SMOOTH_PROBES = 4
SMOOTH_GRID = 64
"""Candidate smooth-region centres: a ``SMOOTH_GRID``² grid of the domain."""


def rate_probes(curves, n_smooth: int = SMOOTH_PROBES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(edge (P, 2), tips (Q, 2), smooth (n_smooth, 2)) float64 probe points of a scene's curves.

    edge : the middle of the middle piece of every input curve (``dfc.bench.scenes.curve_probes``)
    tips : the ends of open input curves that lie inside the domain (not on its border)
    smooth : grid points greedily chosen to be as far as possible from every curve and from each other
    """
    from ...geometry.bezier import flatten
    from ..scenes import curve_probes

    edge = curve_probes(curves, count=len(curves.names))
    x0, y0, x1, y1 = curves.domain
    tips = []
    for c in np.unique(curves.curve):
        cp = curves.control_points[curves.curve == c]
        a, b = cp[0, 0], cp[-1, 3]
        if np.allclose(a, b):
            continue
        for p in (a, b):
            if x0 < p[0] < x1 and y0 < p[1] < y1:
                tips.append(p)
    line = flatten(curves.control_points, 64).reshape(-1, 2)
    g = (np.arange(SMOOTH_GRID) + 0.5) / SMOOTH_GRID
    X, Y = np.meshgrid(x0 + g * (x1 - x0), y0 + g * (y1 - y0))
    cand = np.stack([X.ravel(), Y.ravel()], axis=1)
    from scipy.spatial import cKDTree

    far = cKDTree(line).query(cand)[0]
    chosen = []
    for _ in range(n_smooth):
        score = far.copy()
        for p in chosen:
            score = np.minimum(score, 0.5 * np.hypot(*(cand - p).T))
        chosen.append(cand[int(np.argmax(score))])
    return edge, np.array(tips, dtype=np.float64).reshape(-1, 2), np.array(chosen)


def _window_psnr(model, scene, centre, zoom, scale) -> float:
    from ...render import values_at, window_points, window_shape, zoom_window

    window = zoom_window(scene.domain, centre, zoom)
    w, h = window_shape(window, WINDOW)
    xy = window_points(window, w, h, WINDOW_SPP)
    got = values_at(model, xy).reshape(h, w, WINDOW_SPP, -1).mean(axis=2)
    ref = np.asarray(scene.value(xy), np.float64).reshape(h, w, WINDOW_SPP, -1).mean(axis=2)
    return scale.psnr(ref, got)


def measure(scene, blob: bytes, pixels: np.ndarray) -> dict:
    """The measurements of the module docstring for the ``.dfield`` bytes ``blob`` fitted to ``pixels``."""
    from ...codec import loads
    from ...geometry.pixels import edge_pixels
    from ...metrics import quality_scale
    from ...render import default_pixel_filter, render

    model = loads(blob)
    h, w = pixels.shape[:2]
    scale = quality_scale(pixels)
    pixel_filter = default_pixel_filter(model, w, h)[0]
    centres = render(model, w, h)
    boxed = render(model, w, h, pixel_filter=pixel_filter)
    mixed = edge_pixels(model.field.mesh, h, w)
    edge, tips, smooth = rate_probes(scene.curves)
    out = {
        "bytes": len(blob),
        "psnr_1x": scale.psnr(pixels, boxed),
        "pixel_filter": pixel_filter,
        "psnr_1x_centres": scale.psnr(pixels, centres),
        "psnr_1x_unmixed": scale.psnr(pixels[~mixed], centres[~mixed]),
    }
    for z in EDGE_ZOOMS:
        windows = [_window_psnr(model, scene, p, z, scale) for p in edge]
        out[f"edge_{z}x"], out[f"edge_{z}x_windows"] = float(np.mean(windows)), [round(w, 2) for w in windows]
        if len(tips):
            out[f"tip_{z}x"] = float(np.mean([_window_psnr(model, scene, p, z, scale) for p in tips]))
    out[f"smooth_{SMOOTH_ZOOM}x"] = float(np.mean([_window_psnr(model, scene, p, SMOOTH_ZOOM, scale) for p in smooth]))
    return out


def _setting(ctx, param, values):
    from ...settings import EncodeSettings

    known = EncodeSettings.names()
    out = {}
    for item in values:
        name, _, text = item.partition("=")
        if name not in known or not _:
            raise click.BadParameter(f"expected NAME=VALUE with NAME one of {', '.join(sorted(known))}, got {item!r}")
        out[name] = None if text.lower() == "none" else json.loads(text) if text[:1] in "-0123456789[{tf" else text
    return out


@click.command()
@click.argument("scene_name", metavar="SCENE", default="sample")
@click.option("--set", "overrides", multiple=True, callback=_setting, metavar="NAME=VALUE",
              help="An EncodeSettings field, e.g. --set mesh_bits=14 --set steps=500 (repeatable).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Also write the numbers as JSON here.")
def command(scene_name, overrides, json_path):
    """Encode the analytic SCENE (sample, shapes, strokes, hdr) and print bytes, 1× PSNR, zoom PSNR on edges and
    open curve ends, and smooth-region PSNR of the written file (see the module documentation)."""
    from ...codec import EncodeSettings, encode_image
    from ...io.image import Image
    from ...metrics import is_hdr
    from ..scenes import get_scene

    scene = get_scene(scene_name)
    x0, y0, x1, y1 = scene.domain
    pixels = scene.render(round(x1 - x0), round(y1 - y0))
    settings = EncodeSettings(**overrides)
    clock = time.perf_counter()
    blob, report = encode_image(Image(pixels, scene.channels, hdr=is_hdr(pixels)), scene.curves, settings)
    seconds = time.perf_counter() - clock
    out = {"scene": scene_name, "settings": settings.to_dict(), "encode_s": seconds, "chunks": report.chunk_bytes,
           "triangles": report.n_triangles, **measure(scene, blob, pixels)}
    click.echo(f"{scene_name}: {out['bytes']} bytes ({', '.join(f'{k} {v}' for k, v in report.chunk_bytes.items())}); "
               f"{report.n_triangles} triangles; encode {seconds:.0f} s")
    click.echo("  " + ", ".join(f"{k} {v:.2f}" for k, v in out.items() if k.startswith(("psnr", "edge", "tip", "smooth"))
                                and isinstance(v, float)))
    if json_path:
        write_bytes_atomic(json_path, (json.dumps(out, indent=1) + "\n").encode())
