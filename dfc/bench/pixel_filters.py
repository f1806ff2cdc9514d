"""Rasters made with a known pixel filter from an analytic scene, and ``dfc benchmark pixel-filter``.

``polygon_scene(size)`` is a piecewise-constant scene of convex polygons whose edges are the curves (exact inside
tests, so a point sample is exact too). ``filtered_raster`` makes its raster with any ``dfc.pixel_filter``: point
samples at the centres, ``box:N`` sub-sample means, or the scene sampled ``SUPERSAMPLE``² times per pixel (and
around it, as far as the kernel reaches) and convolved with the kernel at those offsets.

The benchmark (``pixel_filter_table``) encodes each generation (``GENERATIONS``) assuming each filter of
``ASSUMED`` at one byte target, and measures the 1× PSNR against the raster and the PSNR of a ``ZOOM``× window
centred on an edge against the exact scene.
"""

from __future__ import annotations

import numpy as np

from ..pixel_filter import PixelFilter, parse
from .scenes import AnalyticScene, _pieces

__all__ = ["ASSUMED", "GENERATIONS", "SUPERSAMPLE", "filtered_raster", "pixel_filter_table", "polygon_scene"]

SUPERSAMPLE = 16
"""Sub-samples per pixel and axis of a raster made with a kernel (``filtered_raster``)."""
GENERATIONS = ("point", "box:16", "gaussian:0.5", "blackman-harris:1.5")
"""How the benchmark's and the tests' rasters are made (issue 26's four)."""
ASSUMED = ("point", "box:16", "gaussian:0.5", "blackman-harris:1.5", "auto")
"""Filters the benchmark's encodes assume."""
ZOOM = 100.0

_POLYGONS = (  # (value, vertices in units of the domain's side), convex, disjoint, no edge along an axis
    (0.85, [(0.10, 0.16), (0.52, 0.08), (0.31, 0.55)]),
    (0.30, [(0.60, 0.33), (0.91, 0.47), (0.83, 0.89), (0.52, 0.71)]),
    (0.62, [(0.09, 0.66), (0.37, 0.61), (0.44, 0.93), (0.14, 0.87)]),
    (0.05, [(0.64, 0.06), (0.93, 0.12), (0.78, 0.27)]),
)
_BACKGROUND = 0.45


def polygon_scene(size: float = 96.0) -> AnalyticScene:
    """A ``size`` × ``size`` piecewise-constant scene (one channel ``Y``): four convex polygons on a background,
    six grey levels in all; its curves are the polygons' outlines (lines)."""
    domain = (0.0, 0.0, float(size), float(size))
    polys = [(v, np.asarray(p, dtype=np.float64) * size) for v, p in _POLYGONS]
    chains = [(f"polygon {k}", [(1, [tuple(p[i]), tuple(p[(i + 1) % len(p)])]) for i in range(len(p))])
              for k, (_, p) in enumerate(polys)]
    curves = _pieces(chains, domain)

    def value(xy: np.ndarray) -> np.ndarray:
        out = np.full(len(xy), _BACKGROUND)
        for v, p in polys:
            a, b = p, np.roll(p, -1, axis=0)
            cross = ((b[:, 0] - a[:, 0])[None] * (xy[:, 1:2] - a[:, 1][None])
                     - (b[:, 1] - a[:, 1])[None] * (xy[:, 0:1] - a[:, 0][None]))
            out[np.all(cross > 0, axis=1) | np.all(cross < 0, axis=1)] = v
        return out[:, None]

    return AnalyticScene(f"polygons {size:g}", curves, ["Y"], value)


def filtered_raster(scene: AnalyticScene, width: int, height: int, pixel_filter: PixelFilter | str) -> np.ndarray:
    """(height, width, C) float32 raster of ``scene`` over its domain made with ``pixel_filter``."""
    f = parse(pixel_filter) if isinstance(pixel_filter, str) else pixel_filter
    x0, y0, x1, y1 = scene.domain
    sx, sy = (x1 - x0) / width, (y1 - y0) / height
    if f.name == "point" or (f.name == "box" and f.param is not None):
        n = 1 if f.name == "point" else int(f.param)
        u = (np.arange(width * n) + 0.5) / n
        v = (np.arange(height * n) + 0.5) / n
        X, Y = np.meshgrid(x0 + u * sx, y0 + v * sy)
        vals = scene.value(np.stack([X.ravel(), Y.ravel()], axis=1))
        return vals.reshape(height, n, width, n, -1).mean(axis=(1, 3)).astype(np.float32)
    s = SUPERSAMPLE
    m = int(np.ceil(f.radius + 0.5))  # margin in pixels
    u = np.arange(-m * s, (width + m) * s) + 0.5
    v = np.arange(-m * s, (height + m) * s) + 0.5
    X, Y = np.meshgrid(x0 + u / s * sx, y0 + v / s * sy)
    fine = scene.value(np.stack([X.ravel(), Y.ravel()], axis=1)).reshape(len(v), len(u), -1)
    k = np.arange(-m * s, (m + 1) * s)  # sub-samples around a pixel's first one
    taps = f.taps((k + 0.5) / s - 0.5)  # offsets of those sub-samples from the pixel's centre
    out = np.zeros((height, width, fine.shape[2]))
    rows = np.zeros((height, len(u), fine.shape[2]))
    for t, w in zip(k, taps):
        if w:
            rows += w * fine[m * s + t: m * s + t + height * s: s]
    for t, w in zip(k, taps):
        if w:
            out += w * rows[:, m * s + t: m * s + t + width * s: s]
    return out.astype(np.float32)


def pixel_filter_table(size: int = 96, steps: int = 300, target_bytes: int = 8000, progress=None) -> dict:
    """The benchmark: for each of ``GENERATIONS`` a ``size``² raster of ``polygon_scene``, encoded for ``steps``
    steps under ``target_bytes`` (no refinement round) assuming each of ``ASSUMED``; then the point-sampled raster at
    the default rate (the field alone, no residual) assuming ``point`` and ``box``. Returns {"rows": [{generation,
    assumed, chosen, bytes, psnr_1x, psnr_zoom}], "default_rate": [{assumed, bytes, psnr_1x}], "size", "steps",
    "target_bytes", "zoom", "probes"};
    ``progress(row)`` after each encode. ``psnr_zoom``: the ``ZOOM``× windows centred on the middle of each polygon's
    middle edge, ``WINDOW``² pixels at their centres (``dfc decode``'s default rule: point samples), against the
    exact scene there, one PSNR over all windows."""
    from ..codec import EncodeSettings, encode_image, loads
    from ..metrics import psnr
    from ..render import render, zoom_window
    from .scenes import curve_probes

    scene = polygon_scene(float(size))
    probes = curve_probes(scene.curves, len(scene.curves.names))
    windows = [zoom_window(scene.domain, p, ZOOM, inside=False) for p in probes]
    exact = np.concatenate([_window_values(scene, w) for w in windows])
    rows, default_rate = [], []
    for gen in GENERATIONS:
        raster = filtered_raster(scene, size, size, gen)
        for assumed in ASSUMED:
            settings = EncodeSettings(steps=steps, target_bytes=target_bytes, refine=0, pixel_filter=assumed)
            blob, report = encode_image(raster, scene.curves, settings)
            model = loads(blob)
            zoomed = np.concatenate([render(model, WINDOW, WINDOW, w) for w in windows])
            rows.append({"generation": gen, "assumed": assumed, "chosen": report.pixel_filter,
                         "bytes": report.total_bytes, "psnr_1x": report.psnr, "psnr_zoom": psnr(exact, zoomed, 1.0)})
            if progress is not None:
                progress(rows[-1])
    raster = filtered_raster(scene, size, size, "point")
    for assumed in ("point", "box"):
        # the field alone: a clean image's default encode would also store a residual, which hides the filter
        _, report = encode_image(raster, scene.curves, EncodeSettings(steps=steps, pixel_filter=assumed,
                                                                      residual_bytes=0))
        default_rate.append({"assumed": assumed, "bytes": report.total_bytes, "psnr_1x": report.psnr})
        if progress is not None:
            progress({"generation": "point", "assumed": assumed, "default_rate": True, **default_rate[-1]})
    return {"rows": rows, "default_rate": default_rate, "size": size, "steps": steps, "target_bytes": target_bytes,
            "zoom": ZOOM, "probes": probes.tolist()}


WINDOW = 128
"""Pixels per side of a zoom window's render."""


def _window_values(scene: AnalyticScene, window) -> np.ndarray:
    """(WINDOW, WINDOW, C) exact values at the pixel centres of a ``WINDOW``² render of ``window``."""
    x0, y0, x1, y1 = window
    xs = x0 + (np.arange(WINDOW) + 0.5) * (x1 - x0) / WINDOW
    ys = y0 + (np.arange(WINDOW) + 0.5) * (y1 - y0) / WINDOW
    X, Y = np.meshgrid(xs, ys)
    return scene.value(np.stack([X.ravel(), Y.ravel()], axis=1)).reshape(WINDOW, WINDOW, -1)
