"""How the comparison measures a method: box-filtered renders, the mixed pixels, PSNR on the same pixels.

A *pixel render* of a window at ``width × height`` averages each method's values at ``spp`` points per pixel
(``dfc.render.window_points``: the centre for spp = 1, else the R2 sequence), the points the reference of a zoom
window is taken at too. The *1× image render* is a box filter over a centred ``grid × grid`` stratified grid in each
pixel, as an analytic scene's raster is made (``AnalyticScene.render``): the filter a render's pixel has. A method
that stores pixels on that very grid (``PixelImage``: the raster at full size, a classical codec's decoded image) is
its own box-filtered estimate and is read as stored.

*Mixed pixels* are those a discontinuity crosses (``dfc.geometry.pixels.edge_pixels`` on the input curves): their
value blends both sides. The 1× image PSNR is reported on every pixel and without them, on the same pixels for
every method, on the input's ``dfc.metrics.quality_scale`` (tone-mapped for HDR colours).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ..metrics import QualityScale
from ..render import values_at, window_points

__all__ = ["EVAL_BLOCK", "grid_points", "image_render", "image_scores", "mixed_pixels", "pixel_render"]

EVAL_BLOCK = 1 << 16
"""Points per forward pass when rendering."""


def _box_render(model, points, width: int, height: int, n: int, device: str) -> np.ndarray:
    """Mean of ``model`` over the ``n`` points per pixel ``points(rows)`` gives for rows [r0, r1) (pixel-major),
    evaluated in row blocks of about ``EVAL_BLOCK`` points: (height, width, C) float32."""
    rows = max(1, EVAL_BLOCK // (width * n))
    blocks = []
    for r0 in range(0, height, rows):
        r1 = min(height, r0 + rows)
        values = values_at(model, points((r0, r1)), device=device, block=EVAL_BLOCK)
        blocks.append(values.reshape(r1 - r0, width, n, -1).mean(axis=2))
    return np.concatenate(blocks).astype(np.float32)


def pixel_render(model, window, width: int, height: int, spp: int, device: str = "cpu") -> np.ndarray:
    """(height, width, C) float32: the mean of ``model`` (xy (N, 2) tensor -> (N, C)) over ``spp`` points
    (``window_points``) in each pixel of a ``width × height`` render of ``window``."""
    return _box_render(model, lambda rows: window_points(window, width, height, spp, rows=rows), width, height, spp,
                       device)


def grid_points(window, width: int, height: int, grid: int, rows: tuple[int, int]) -> np.ndarray:
    """(h · width · grid², 2) float64: a centred ``grid × grid`` stratified grid in each pixel of rows [r0, r1) of a
    ``width × height`` render of ``window``, row-major, a pixel's points adjacent."""
    x0, y0, x1, y1 = window
    r0, r1 = rows
    u = (np.arange(grid) + 0.5) / grid
    xs = x0 + (np.arange(width)[:, None] + u[None]) * ((x1 - x0) / width)  # (W, g)
    ys = y0 + (np.arange(r0, r1)[:, None] + u[None]) * ((y1 - y0) / height)  # (h, g)
    X = np.broadcast_to(xs[None, :, None, :], (r1 - r0, width, grid, grid))
    Y = np.broadcast_to(ys[:, None, :, None], (r1 - r0, width, grid, grid))
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def image_render(model, domain, width: int, height: int, grid: int, device: str = "cpu") -> np.ndarray:
    """The 1× render (height, width, C) float32 of the whole domain: a model with a ``size`` of exactly this size
    and ``pixels()`` as it decodes itself there (a stored raster as stored, ``PixelImage.pixels``; a dfc file as
    ``dfc decode`` renders it at its input's size), anything else as the mean over a ``grid × grid`` stratified grid
    per pixel."""
    size = getattr(model, "size", None)
    if size is not None and tuple(size) == (width, height) and hasattr(model, "pixels"):
        return model.pixels()
    return _box_render(model, lambda rows: grid_points(domain, width, height, grid, rows), width, height, grid * grid,
                       device)


def mixed_pixels(curves, height: int, width: int) -> np.ndarray:
    """(height, width) bool: pixels of a raster over ``curves.domain`` that a curve crosses (``edge_pixels`` on the
    curves themselves, so the mask does not depend on any method's mesh)."""
    from ..geometry.pixels import edge_pixels

    pieces = SimpleNamespace(domain=curves.domain, vertices=np.zeros((0, 2)), disc_edges=np.zeros((0, 2), np.int64),
                             curve_control_points=curves.control_points)
    return edge_pixels(pieces, height, width)


def image_scores(truth: np.ndarray, test: np.ndarray, mixed: np.ndarray, scale: QualityScale) -> dict[str, float]:
    """PSNR of ``test`` against ``truth`` (both (H, W, C)) on every pixel (``all``) and on the pixels not in
    ``mixed`` (H, W) bool (``unmixed``), on ``scale`` (``dfc.metrics.quality_scale`` of the input)."""
    keep = ~mixed
    return {"all": scale.psnr(truth, test),
            "unmixed": scale.psnr(truth[keep], test[keep]) if keep.any() else None}
