"""Render a field model to a raster: any resolution, the whole domain or a window, in row blocks.

Sample positions follow ``spec/conventions.md``: pixel centres, or ``spp`` deterministic
low-discrepancy points (the R2 sequence) per output pixel, averaged. Blocks of rows keep memory
bounded: at most ``max_points`` field queries are in flight at a time.

Anti-aliasing. A raster's pixel is an area average (a box filter), and where a discontinuity crosses a pixel
that average blends both sides, which no single point of the field shows. With ``edge_spp > 0`` the pixels a
discontinuity crosses (``dfc.geometry.pixels.edge_pixels``) are averaged over ``edge_spp`` points instead: the
field is smooth inside every other pixel, so its centre stands for its average there. ``default_edge_spp`` turns
this on at or below the resolution of the raster a file was fitted to (header ``pixel_size``). A pixel's value
depends only on its own points, so the crossed pixels of a render cut into regions (``render_region``) are those of
the whole render.
"""

from __future__ import annotations

import numpy as np
import torch

MAX_POINTS = 1 << 18
"""Field queries evaluated per block (≈ 100 MB of intermediate tensors for the default MLP)."""
EDGE_SPP = 64
"""Points averaged in a pixel a discontinuity crosses when anti-aliasing by default (``--edge-spp``); the other
pixels take their centre. Why 64: CHANGELOG.md, "Anti-aliased decode"."""


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


def default_pixel_filter(model, width: int, height: int, window=None) -> tuple[str, str]:
    """(filter spec, the rule that chose it) of a ``width × height`` render of ``window`` (default the domain):

    - on the grid of the raster the file was fitted to (``input_pixel_size``, 0.1 % slack, the window's corner on
      that grid): the file's ``pixel_filter`` (header), ``box`` for files without one;
    - coarser output pixels along both axes (shrinking): ``box`` over the output pixel;
    - otherwise (enlarging, or not a raster input): ``point``, the field at each pixel's centre: sharp edges.

    ``box`` renders exactly as ``EDGE_SPP`` anti-aliasing did before files stored a filter.
    """
    size = input_pixel_size(model)
    if size is None:
        return "point", "not fitted to a raster"
    x0, y0, x1, y1 = check_window(window, model.field.mesh.domain)
    px, py = (x1 - x0) / width, (y1 - y0) / height
    d0 = model.field.mesh.domain
    aligned = all(abs(v - round(v)) < 1e-3 for v in ((x0 - d0[0]) / size[0], (y0 - d0[1]) / size[1]))
    if abs(px / size[0] - 1) < 1e-3 and abs(py / size[1] - 1) < 1e-3 and aligned:
        stored = (getattr(model, "header", None) or {}).get("pixel_filter")
        return (stored, "the file's, on the input's grid") if stored else ("box", "on the input's grid")
    if px >= size[0] * (1 - 1e-3) and py >= size[1] * (1 - 1e-3):
        return "box", "shrinking: the output pixel's area"
    return "point", "enlarging: the field at each pixel's centre"


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


def window_points(window, width: int, height: int, spp: int = 1, *, rows: tuple[int, int] | None = None,
                  cols: tuple[int, int] | None = None) -> np.ndarray:
    """(h · w · spp, 2) float64 sample points of rows ``[r0, r1)`` and columns ``[c0, c1)`` (default all;
    h = r1 − r0, w = c1 − c0) of a ``width × height`` render of ``window``: row-major, a pixel's ``spp`` points
    (``pixel_offsets``) adjacent. A region's points are exactly those of the whole render at its pixels."""
    x0, y0, x1, y1 = window
    r0, r1 = rows or (0, height)
    c0, c1 = cols or (0, width)
    off = pixel_offsets(spp)
    xs = x0 + (np.arange(c0, c1)[:, None] + off[None, :, 0]) * ((x1 - x0) / width)  # (w, spp)
    ys = y0 + (np.arange(r0, r1)[:, None] + off[None, :, 1]) * ((y1 - y0) / height)  # (h, spp)
    X = np.broadcast_to(xs[None], (r1 - r0, c1 - c0, spp))
    Y = np.broadcast_to(ys[:, None], (r1 - r0, c1 - c0, spp))
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def render_region(model, width: int, height: int, window=None, *, rows: tuple[int, int], cols: tuple[int, int],
                  spp: int = 1, t=None, max_points: int = MAX_POINTS, edge_spp: int = 0, mixed=None,
                  pixel_filter=None) -> np.ndarray:
    """Pixels (r1 − r0, c1 − c0, C) float32 of rows ``[r0, r1)`` and columns ``[c0, c1)`` of a ``width × height``
    render of ``window``, evaluated ``max_points`` at a time (whole rows of the region per call). The values do not
    depend on how a render is cut into regions of whole rows of the same width.

    model : callable (N, 2) float64 tensor [, t] -> (N, C) tensor, e.g. ``FieldModel``
    edge_spp : when > ``spp``, pixels a discontinuity crosses average this many points (module notes)
    mixed : the ``EdgeMask`` of this ``width × height`` render of ``window`` (built when None and needed; pass one
        to reuse it across the regions of a render)
    pixel_filter : a ``dfc.pixel_filter.PixelFilter`` (or its spec string) in output pixels, instead of
        ``edge_spp``: the pixels a discontinuity changes under it (``PixelFilter.filtered``) are filtered by
        quadrature (``filter_nodes``), the others take the value at their centre (``spp`` points)
    """
    if width < 1 or height < 1:
        raise ValueError(f"output size must be at least 1×1, got {width}×{height}")
    window = check_window(window, model.field.mesh.domain)
    (r0, r1), (c0, c1) = rows, cols
    step = max(1, min(r1 - r0, max_points // ((c1 - c0) * spp)))
    device = model.field.bank.device
    nodes = None
    if pixel_filter is not None:
        from .pixel_filter import parse

        pixel_filter = parse(pixel_filter) if isinstance(pixel_filter, str) else pixel_filter
        nodes = filter_nodes(pixel_filter) if pixel_filter.mixes else None
        edge_spp = 0
    if (edge_spp > spp or nodes is not None) and mixed is None:
        from .geometry.pixels import EdgeMask

        mixed = EdgeMask(model.field.mesh, height, width, window)
    out = []
    with torch.no_grad():
        for a in range(r0, r1, step):
            b = min(r1, a + step)
            xy = torch.from_numpy(window_points(window, width, height, spp, rows=(a, b), cols=(c0, c1))).to(device)
            vals = model(xy, t) if t is not None else model(xy)
            block = vals.float().reshape(b - a, c1 - c0, spp, -1).mean(dim=2).cpu().numpy()
            if edge_spp > spp:
                mask = mixed.rows(a, b, cols=(c0, c1))
                if mask.any():
                    block[mask] = _pixel_means(model, window, width, height, edge_spp, t, (a, c0), mask, max_points)
            elif nodes is not None:
                mask = _filtered_rows(mixed, pixel_filter, (a, b), (c0, c1))
                if mask.any():
                    block[mask] = _pixel_means(model, window, width, height, len(nodes[1]), t, (a, c0), mask,
                                               max_points, nodes)
            out.append(block)
    return np.concatenate(out)


def filter_nodes(pixel_filter) -> tuple[np.ndarray, np.ndarray]:
    """A decode's quadrature of ``pixel_filter`` (``PixelFilter.nodes``): offsets (K, 2) in pixels from the pixel's
    corner and weights (K,). The continuous box takes the ``EDGE_SPP`` points a render without a filter averages,
    other kernels ``dfc.pixel_filter.DECODE_POINTS``."""
    from .pixel_filter import DECODE_POINTS

    continuous_box = pixel_filter.name == "box" and pixel_filter.param is None
    off, weight = pixel_filter.nodes(EDGE_SPP if continuous_box else DECODE_POINTS)
    return off + 0.5, weight


def _filtered_rows(mixed, pixel_filter, rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
    """(r1 − r0, c1 − c0) bool: the pixels of the region that ``pixel_filter`` blends across a discontinuity (its
    crossed pixels ``mixed`` grown by the filter's reach, read with that margin so regions agree)."""
    m = pixel_filter.reach
    (r0, r1), (c0, c1) = rows, cols
    grown = pixel_filter.filtered(mixed.rows(r0 - m, r1 + m, cols=(c0 - m, c1 + m)))
    return grown[m:m + r1 - r0, m:m + c1 - c0]


def _pixel_means(model, window, width, height, spp, t, corner, mask, max_points, nodes=None) -> np.ndarray:
    """(M, C) float32 means of ``spp`` points in each of the M pixels ``mask`` (h, w) marks; its first pixel is
    ``corner`` (row, column) of the ``width × height`` render of ``window``. ``nodes``: (offsets (spp, 2) from the
    pixel's corner, weights (spp,)) of a filter's quadrature instead of ``pixel_offsets(spp)`` averaged."""
    rows, cols = np.nonzero(mask)
    x0, y0, x1, y1 = window
    off = pixel_offsets(spp) if nodes is None else nodes[0]
    px = x0 + (corner[1] + cols[:, None] + off[None, :, 0]) * ((x1 - x0) / width)
    py = y0 + (corner[0] + rows[:, None] + off[None, :, 1]) * ((y1 - y0) / height)
    xy = np.stack([px.ravel(), py.ravel()], axis=1)
    device = model.field.bank.device
    step = max(spp, max_points // spp * spp)
    out = []
    for i in range(0, len(xy), step):
        pts = torch.from_numpy(xy[i:i + step]).to(device)
        out.append((model(pts, t) if t is not None else model(pts)).float().cpu().numpy())
    values = np.concatenate(out).reshape(len(rows), spp, -1)
    if nodes is None:
        return values.mean(axis=1)
    return np.einsum("mkc,k->mc", values, nodes[1].astype(np.float32))


def values_at(model, xy: np.ndarray, *, device: str = "cpu", block: int = MAX_POINTS) -> np.ndarray:
    """Model values (N, C) float64 at scattered points xy (N, 2) float64 in domain units, ``block`` points per call
    on ``device`` (memory stays bounded)."""
    with torch.no_grad():
        out = [model(torch.from_numpy(xy[i:i + block]).to(device)).double().cpu().numpy()
               for i in range(0, len(xy), block)]
    return np.concatenate(out)


def render(model, width: int, height: int, window=None, *, spp: int = 1, t=None, edge_spp: int = 0,
           pixel_filter=None) -> np.ndarray:
    """Render into memory: (height, width, C) float32. For huge outputs use ``dfc.render_file.write_render``."""
    return render_region(model, width, height, window, rows=(0, height), cols=(0, width), spp=spp, t=t,
                         edge_spp=edge_spp, pixel_filter=pixel_filter)


DEFAULT_SIDE = (256, 4096)
"""Clamp of the default render size's long side, in pixels."""


def default_size(window: tuple[float, float, float, float], domain) -> tuple[int, int]:
    """Render size for ``window`` when none is given: the long side as for the whole domain (its long side in
    domain units, clamped into ``DEFAULT_SIDE``), the short side by the window's aspect ratio."""
    long_side = min(max(round(max(domain[2] - domain[0], domain[3] - domain[1])), DEFAULT_SIDE[0]), DEFAULT_SIDE[1])
    w, h = window[2] - window[0], window[3] - window[1]
    scale = long_side / max(w, h)
    return max(1, round(w * scale)), max(1, round(h * scale))
