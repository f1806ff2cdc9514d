"""The curves ``dfc encode --curves auto`` fits an image with, in one place for the command and the benchmarks.

1. ``find_curves``: the raster extractor at its defaults (``raster.image_curves_filtered``) with the encode's pixel
   filter ("auto": the box first, then the filter ``dfc.pixel_model.detect`` finds along those curves). That filter
   is the encode's: the refinement and the fit use it rather than detect afresh along the fewer curves pruning
   keeps (a 2 KB target may keep too few clean edges to tell the filters apart); only clear evidence along the
   refined curves replaces it (2).
2. ``ready_curves``: each curve weighed against the bytes it costs for the encode's mesh and byte target (``prune``),
   then the kept ones refined against the pixels through that filter (``refine``). A detected filter is detected
   again along the refined curves (``refine_detected``): the curves found in the pixels lie a few hundredths of a
   pixel off, which hides the difference between a box of 6 × 6 and of 16 × 16 sub-samples; the refined ones show it,
   and when another filter wins there the curves are refined again through it, and the fit uses it.

Curves over another domain than the image's ``[0, W] × [0, H]`` are scaled onto it by ``prune`` and ``refine`` and
come back over their own domain.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..curves import Curves, fit_curves_to_domain

__all__ = ["find_curves", "ready_curves", "refine_detected"]


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
                 n_triangles: int | None = None, target_bytes: int | None = None, pixel_filter="auto",
                 detected: bool = False):
    """(curves, ``Pruned`` or None, ``Refined`` or None): ``curves`` pruned (``prune``: for a mesh of about
    ``n_triangles`` triangles and a file of at most ``target_bytes``, ``prune.prune_curves``), then refined
    (``refine``: ``refine.refine_curves`` through ``pixel_filter``, a ``PixelFilter`` or a spec, None: the box, "auto":
    detected along the curves as the encoder detects it). A filter detected ("auto", or ``detected``: the given one was
    detected along these curves before pruning) is detected again along the refined curves (``refine_detected``);
    the ``Refined``'s ``pixel_filter`` is the one the fit should use. The curves keep their ``source``."""
    from ...pixel_filter import parse
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
            automatic = pixel_filter.strip().lower() == "auto"
            detected = detected or automatic
            used = resolve(pixel_filter, pixels, _on_image(pixels, curves))[0] if automatic else parse(pixel_filter)
        refined = refine_detected(pixels, curves, used) if detected else refine_curves(pixels, curves, used)
        curves = replace(refined.curves, source=curves.source)
    return curves, pruned, refined


def refine_detected(pixels: np.ndarray, curves: Curves, pixel_filter):
    """``refine.refine_curves`` of ``curves`` against ``pixels`` (H, W, C) through ``pixel_filter``, a
    ``PixelFilter`` detected along the curves before they were refined; then the filter detected again along the
    refined curves (``dfc.pixel_model.detect``): when another fits them better by ``dfc.pixel_model.MIN_EVIDENCE``
    standard errors (few pixels along a pruned set cannot overturn the detection along every curve found), the curves
    are refined once more, from there, through it. Returns that last ``Refined`` (its misfits over that refinement's
    pixels and model; ``misfit_before`` and ``moved`` of ``curves``, as given)."""
    from ...pixel_model import detect
    from .refine import refine_curves

    refined = refine_curves(pixels, curves, pixel_filter)
    if not refined.pixels:
        return refined
    again = detect(pixels, _on_image(pixels, refined.curves), incumbent=str(pixel_filter))
    if not again.pixels or str(again.filter) == str(pixel_filter):
        return refined
    second = refine_curves(pixels, refined.curves, again.filter, origin=curves)
    return second if second.pixels else refined


def _on_image(pixels: np.ndarray, curves: Curves) -> Curves:
    """``curves`` over the image's own domain ``[0, W] × [0, H]``."""
    h, w = np.shape(pixels)[:2]
    return fit_curves_to_domain(curves, (0.0, 0.0, float(w), float(h)))
