"""The curves ``dfc encode --curves auto`` fits an image with, in one place for the command and the benchmarks.

1. ``find_curves``: the raster extractor at its defaults (``raster.image_curves_filtered``) with the encode's pixel
   filter ("auto": the box first, then the filter ``dfc.pixel_model.detect`` finds along those curves). That filter
   is the encode's: the refinement and the fit use it rather than detect again along the fewer curves pruning
   keeps (a 2 KB target may keep too few clean edges to tell the filters apart).
2. ``ready_curves``: each curve weighed against the bytes it costs for the encode's mesh and byte target (``prune``),
   then the kept ones refined against the pixels through that filter (``refine``).

Curves over another domain than the image's ``[0, W] × [0, H]`` are scaled onto it by ``prune`` and ``refine`` and
come back over their own domain.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..curves import Curves, fit_curves_to_domain

__all__ = ["find_curves", "ready_curves"]


def find_curves(pixels: np.ndarray, pixel_filter: str = "auto"):
    """(curves, ``PixelFilter`` used, record, ``dfc.pixel_model.Detection`` or None) of ``pixels`` (H, W, C) linear
    values: the curves (``source`` "auto") over ``[0, W] × [0, H]``, the filter they were placed with, the record a
    file's encoder info keeps of them (``extracted``, ``extractor``, ``pixel_filter``, counts; the extractor's
    settings are that software version's defaults, so the record leaves them out as it leaves out every default:
    spec/dfield.md §5), and the detection that chose the filter along every curve found ("auto"; None for a given
    filter). Raises ``ImportError`` without scikit-image, ``InputError`` for an unknown filter spec or an unusable
    image."""
    from .raster import image_curves_filtered

    curves, used, detection = image_curves_filtered(pixels, None, pixel_filter)  # the extractor at its defaults
    record = {"extracted": "from the image (--curves auto)", "extractor": "dfc.geometry.sources.raster.image_curves",
              "pixel_filter": str(used), "curves": curves.n_curves, "pieces": len(curves)}
    return replace(curves, source="auto"), used, record, detection


def ready_curves(pixels: np.ndarray, curves: Curves, *, prune: bool = True, refine: bool = True,
                 n_triangles: int | None = None, target_bytes: int | None = None, pixel_filter="auto"):
    """(curves, ``Pruned`` or None, ``Refined`` or None): ``curves`` pruned (``prune``: for a mesh of about
    ``n_triangles`` triangles and a file of at most ``target_bytes``, ``prune.prune_curves``), then refined
    (``refine``: ``refine.refine_curves`` through ``pixel_filter``, a ``PixelFilter`` or a spec, "auto": detected
    along the curves as the encoder detects it). The curves keep their ``source``."""
    from ...pixel_model import resolve
    from .prune import prune_curves
    from .refine import refine_curves

    pruned = refined = None
    if prune:
        pruned = prune_curves(pixels, curves, n_triangles=n_triangles, target_bytes=target_bytes)
        curves = replace(pruned.curves, source=curves.source)
    if refine:
        used = pixel_filter
        if isinstance(pixel_filter, str):  # detected along the curves over the image's own domain
            h, w = np.shape(pixels)[:2]
            used = resolve(pixel_filter, pixels, fit_curves_to_domain(curves, (0.0, 0.0, float(w), float(h))))[0]
        refined = refine_curves(pixels, curves, used)
        curves = replace(refined.curves, source=curves.source)
    return curves, pruned, refined
