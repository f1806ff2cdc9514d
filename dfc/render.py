"""Render a field model to a raster: any resolution, the whole domain or a window, in row blocks.

Sample positions follow ``spec/conventions.md``: pixel centres, or ``spp`` deterministic
low-discrepancy points (the R2 sequence) per output pixel, averaged. Blocks of rows keep memory
bounded: at most ``max_points`` field queries are in flight at a time.

Anti-aliasing. A raster's pixel is an area average (a box filter), and where a discontinuity crosses a pixel
that average blends both sides, which no single point of the field shows. With ``edge_spp > 0`` the pixels a
discontinuity crosses (``dfc.geometry.pixels.edge_pixels``) are averaged over ``edge_spp`` points instead: the
field is smooth inside every other pixel, so its centre stands for its average there. ``default_edge_spp`` turns
this on at or below the resolution of the raster a file was fitted to (header ``pixel_size``).
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
import torch

MAX_POINTS = 1 << 18
"""Field queries evaluated per block (≈ 100 MB of intermediate tensors for the default MLP)."""
EDGE_SPP = 64
"""Points averaged in a pixel a discontinuity crosses when anti-aliasing by default. On ``samples/sample.exr``
(its pixels are 4 × 4-point box averages) the README sample's file measures 41.2 dB at the pixel centres, 51.1 /
56.2 / 55.3 dB with 16 / 64 / 256 points in every pixel, and 56.1 dB with 64 points in its crossed pixels only
(3.8 % of the pixels)."""


def input_pixel_size(model) -> tuple[float, float] | None:
    """(width, height) in domain units of one pixel of the raster ``model`` was fitted to: the header's
    ``pixel_size``; for files written before it existed, 1 × 1 when the encoder recorded an image or frame input
    (their domain is ``[0, W] × [0, H]``); else None (sample sets, FEM, models not read from a file)."""
    header = getattr(model, "header", None) or {}
    if header.get("pixel_size") is not None:
        return tuple(float(v) for v in header["pixel_size"])
    source = str((header.get("encoder") or {}).get("input", ""))
    return (1.0, 1.0) if source.startswith(("image ", "frames ")) else None


def default_edge_spp(model, width: int, height: int, window=None) -> int:
    """``EDGE_SPP`` when a ``width × height`` render of ``window`` (default the domain) has pixels at least as large
    as the input's (``input_pixel_size``, 0.1 % slack) along both axes, else 0 (plain point samples)."""
    size = input_pixel_size(model)
    if size is None:
        return 0
    x0, y0, x1, y1 = check_window(window, model.field.mesh.domain)
    at_most = (x1 - x0) / width >= size[0] * (1 - 1e-3) and (y1 - y0) / height >= size[1] * (1 - 1e-3)
    return EDGE_SPP if at_most else 0


def check_window(window, domain) -> tuple[float, float, float, float]:
    """Validate a window (x0, y0, x1, y1); default: the domain. Raises ValueError when empty or not finite."""
    if window is None:
        return tuple(float(v) for v in domain)
    x0, y0, x1, y1 = (float(v) for v in window)
    if not (np.isfinite([x0, y0, x1, y1]).all() and x1 > x0 and y1 > y0):
        raise ValueError(f"window {window} must be finite with x1 > x0 and y1 > y0")
    return x0, y0, x1, y1


def pixel_offsets(spp: int) -> np.ndarray:
    """(spp, 2) float64 offsets in [0, 1)² inside a pixel: the centre for spp = 1, else the R2 sequence."""
    if spp < 1:
        raise ValueError(f"spp must be ≥ 1, got {spp}")
    if spp == 1:
        return np.array([[0.5, 0.5]])
    g = 1.32471795724474602596  # plastic number
    n = np.arange(spp)[:, None]
    return np.mod(0.5 + n * np.array([1 / g, 1 / g**2]), 1.0)


def zoom_window(domain, center, zoom: float, *, inside: bool = True) -> tuple[float, float, float, float]:
    """The window (x0, y0, x1, y1) of the domain's size divided by ``zoom`` around ``center`` (x, y): shifted to lie
    inside the domain (so zoom 1 is the domain itself), or with ``inside=False`` centred on it, reaching past the
    border if need be."""
    x0, y0, x1, y1 = domain
    w, h = (x1 - x0) / zoom, (y1 - y0) / zoom
    cx, cy = float(center[0]), float(center[1])
    if inside:
        cx = min(max(cx, x0 + w / 2), x1 - w / 2)
        cy = min(max(cy, y0 + h / 2), y1 - h / 2)
    return (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)


def window_shape(window, longer: int) -> tuple[int, int]:
    """(width, height) in pixels of a window rendered with ``longer`` pixels along its longer side."""
    w, h = window[2] - window[0], window[3] - window[1]
    s = longer / max(w, h)
    return max(1, round(w * s)), max(1, round(h * s))


def window_points(window, width: int, height: int, spp: int = 1, *, rows: tuple[int, int] | None = None) -> np.ndarray:
    """(h · width · spp, 2) float64 sample points of rows ``[r0, r1)`` (default all, h = r1 − r0) of a
    ``width × height`` render of ``window``: row-major, a pixel's ``spp`` points (``pixel_offsets``) adjacent."""
    x0, y0, x1, y1 = window
    r0, r1 = rows or (0, height)
    off = pixel_offsets(spp)
    xs = x0 + (np.arange(width)[:, None] + off[None, :, 0]) * ((x1 - x0) / width)  # (W, spp)
    ys = y0 + (np.arange(r0, r1)[:, None] + off[None, :, 1]) * ((y1 - y0) / height)  # (h, spp)
    X = np.broadcast_to(xs[None], (r1 - r0, width, spp))
    Y = np.broadcast_to(ys[:, None], (r1 - r0, width, spp))
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def row_blocks(
    model, width: int, height: int, window=None, *, spp: int = 1, t=None, max_points: int = MAX_POINTS,
    edge_spp: int = 0,
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (first row, block (h, width, C) float32) covering a ``width × height`` render of ``window``.

    model : callable (N, 2) float64 tensor [, t] -> (N, C) tensor, e.g. ``FieldModel``
    edge_spp : when > ``spp``, pixels a discontinuity crosses average this many points (module notes)
    """
    if width < 1 or height < 1:
        raise ValueError(f"output size must be at least 1×1, got {width}×{height}")
    window = check_window(window, model.field.mesh.domain)
    rows = max(1, min(height, max_points // (width * spp)))
    device = model.field.bank.device
    mixed = None
    if edge_spp > spp:
        from .geometry.pixels import edge_pixels

        mixed = edge_pixels(model.field.mesh, height, width, window)
    with torch.no_grad():
        for r0 in range(0, height, rows):
            r1 = min(height, r0 + rows)
            xy = torch.from_numpy(window_points(window, width, height, spp, rows=(r0, r1))).to(device)
            vals = model(xy, t) if t is not None else model(xy)
            block = vals.float().reshape(r1 - r0, width, spp, -1).mean(dim=2).cpu().numpy()
            if mixed is not None and mixed[r0:r1].any():
                block[mixed[r0:r1]] = _pixel_means(model, window, width, height, edge_spp, t, r0, mixed[r0:r1],
                                                   max_points)
            yield r0, block


def _pixel_means(model, window, width, height, spp, t, r0, mask, max_points) -> np.ndarray:
    """(M, C) float32 means of ``spp`` points in each of the M pixels ``mask`` (h, width) marks, rows from ``r0``."""
    rows, cols = np.nonzero(mask)
    x0, y0, x1, y1 = window
    off = pixel_offsets(spp)
    px = x0 + (cols[:, None] + off[None, :, 0]) * ((x1 - x0) / width)
    py = y0 + (r0 + rows[:, None] + off[None, :, 1]) * ((y1 - y0) / height)
    xy = np.stack([px.ravel(), py.ravel()], axis=1)
    device = model.field.bank.device
    step = max(spp, max_points // spp * spp)
    out = []
    for i in range(0, len(xy), step):
        pts = torch.from_numpy(xy[i:i + step]).to(device)
        out.append((model(pts, t) if t is not None else model(pts)).float().cpu().numpy())
    return np.concatenate(out).reshape(len(rows), spp, -1).mean(axis=1)


def values_at(model, xy: np.ndarray, *, device: str = "cpu", block: int = MAX_POINTS) -> np.ndarray:
    """Model values (N, C) float64 at scattered points xy (N, 2) float64 in domain units, ``block`` points per call
    on ``device`` (memory stays bounded)."""
    with torch.no_grad():
        out = [model(torch.from_numpy(xy[i:i + block]).to(device)).double().cpu().numpy()
               for i in range(0, len(xy), block)]
    return np.concatenate(out)


def render(model, width: int, height: int, window=None, *, spp: int = 1, t=None, edge_spp: int = 0) -> np.ndarray:
    """Render into memory: (height, width, C) float32. For huge outputs use ``row_blocks``."""
    blocks = [b for _, b in row_blocks(model, width, height, window, spp=spp, t=t, edge_spp=edge_spp)]
    return np.concatenate(blocks, axis=0)
