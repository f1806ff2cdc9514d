"""Pictures for eyes. ``draw_mesh``: thin grey edges, discontinuous edges in red, curved pieces in blue over
tinted curved triangles, PNG (Pillow) or SVG (text) by the file's suffix. ``draw_curves``: curves over the
image they were found in, PNG. Written atomically. Image rows run along +y (y down), as in
``spec/conventions.md``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from ..geometry import bezier
from ..geometry.curves import Curves
from ..geometry.mesh import Mesh
from .atomic import atomic_path, write_bytes_atomic

__all__ = ["draw_mesh", "draw_curves", "FORMATS"]

FORMATS = (".png", ".svg")
_GREY, _DISC, _CURVE, _TINT = (170, 170, 170), (215, 40, 40), (30, 90, 220), (200, 220, 255)
_CURVE_SAMPLES = 24  # segments per curved piece in the PNG


def draw_mesh(mesh: Mesh, path: str | Path, *, size: int = 1024) -> None:
    """Draw ``mesh`` to ``path`` (``.png`` or ``.svg``), the domain's long side ``size`` pixels wide.

    Raises ``ValueError`` for another suffix or a size below 16, ``OSError`` when the file cannot be written.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"preview: unsupported file type {suffix!r}; use one of {', '.join(FORMATS)}")
    if size < 16:
        raise ValueError(f"preview: size must be at least 16 pixels, got {size}")
    x0, y0, x1, y1 = mesh.domain
    scale = size / max(x1 - x0, y1 - y0)
    width, height = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))

    def px(p: np.ndarray) -> np.ndarray:
        return (p - np.array([x0, y0])) * scale

    if suffix == ".svg":
        write_bytes_atomic(path, _svg(mesh, px, width, height).encode())
        return
    image = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(image)
    for tri in px(mesh.vertices[mesh.triangles[mesh.curved_triangles]]):
        draw.polygon([tuple(p) for p in tri], fill=_TINT)
    edges, _ = mesh.edges()
    for a, b in px(mesh.vertices[edges]):
        draw.line([tuple(a), tuple(b)], fill=_GREY, width=1)
    for a, b in px(mesh.vertices[mesh.disc_edges]):
        draw.line([tuple(a), tuple(b)], fill=_DISC, width=2)
    if len(mesh.curved_triangles):
        for line in px(bezier.flatten(mesh.curve_control_points, _CURVE_SAMPLES)):
            draw.line([tuple(p) for p in line], fill=_CURVE, width=2)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")


_BEFORE = (128, 128, 128)
_PALETTE = [(255, 60, 60), (40, 200, 255), (255, 210, 0), (90, 230, 90), (255, 120, 220), (255, 150, 40)]


def draw_curves(curves: Curves, path: str | Path, *, background: np.ndarray | None = None, hdr: bool = False,
                size: int = 1024, before: Curves | None = None) -> None:
    """Draw ``curves`` over ``background`` to a PNG, the domain's long side ``size`` pixels wide.

    background : (H, W, C) linear values over the whole domain (grey, grey + alpha, RGB or RGBA; other channel
        counts show their first channel), shown as sRGB (tone-mapped when ``hdr``), nearest-neighbour
        enlarged so its pixels stay visible; default a white page
    before : the same curves before a change (``dfc curves --refine``), drawn over them one pixel wide in grey
    Each input curve gets a colour of its own; piece ends are dots.
    """
    from .image import linear_to_srgb, tonemap

    if Path(path).suffix.lower() != ".png":
        raise ValueError(f"preview: curves are drawn to .png, got {Path(path).suffix!r}")
    x0, y0, x1, y1 = curves.domain
    scale = size / max(x1 - x0, y1 - y0)
    width, height = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
    if background is None:
        image = Image.new("RGB", (width, height), "white")
    else:
        bg = np.asarray(background, dtype=np.float32)
        bg = bg[..., None] if bg.ndim == 2 else bg
        colour = bg[..., :3] if bg.shape[2] >= 3 else np.repeat(bg[..., :1], 3, axis=2)
        shown = np.rint(linear_to_srgb(tonemap(colour) if hdr else colour) * 255).astype(np.uint8)
        image = Image.fromarray(shown, "RGB").resize((width, height), Image.NEAREST)
    draw = ImageDraw.Draw(image)
    line_width = max(1, round(size / 512))
    for c in range(max(curves.n_curves, int(curves.curve.max()) + 1 if len(curves) else 0)):
        cp = curves.control_points[curves.curve == c]
        if not len(cp):
            continue
        colour = _PALETTE[c % len(_PALETTE)]
        for line in (bezier.flatten(cp, _CURVE_SAMPLES) - np.array([x0, y0])) * scale:
            draw.line([tuple(p) for p in line], fill=colour, width=line_width)
        for p in (np.concatenate([cp[:, 0], cp[-1:, 3]]) - np.array([x0, y0])) * scale:
            r = line_width + 1
            draw.ellipse([p[0] - r, p[1] - r, p[0] + r, p[1] + r], fill=colour)
    if before is not None:
        for line in (bezier.flatten(before.control_points, _CURVE_SAMPLES) - np.array([x0, y0])) * scale:
            draw.line([tuple(p) for p in line], fill=_BEFORE, width=1)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")


def _svg(mesh: Mesh, px, width: int, height: int) -> str:
    def path_of(segments: np.ndarray) -> str:
        return " ".join(f"M{a[0]:.2f} {a[1]:.2f}L{b[0]:.2f} {b[1]:.2f}" for a, b in segments)

    edges, _ = mesh.edges()
    tint = " ".join(
        f"M{t[0, 0]:.2f} {t[0, 1]:.2f}L{t[1, 0]:.2f} {t[1, 1]:.2f}L{t[2, 0]:.2f} {t[2, 1]:.2f}Z"
        for t in px(mesh.vertices[mesh.triangles[mesh.curved_triangles]])
    )
    curves = " ".join(
        "M{:.2f} {:.2f}C{:.2f} {:.2f} {:.2f} {:.2f} {:.2f} {:.2f}".format(*c.ravel())
        for c in px(mesh.curve_control_points)
    )
    rgb = "rgb({},{},{})".format
    return "\n".join([
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
        f'<path d="{tint}" fill="{rgb(*_TINT)}" stroke="none"/>',
        f'<path d="{path_of(px(mesh.vertices[edges]))}" fill="none" stroke="{rgb(*_GREY)}" stroke-width="0.5"/>',
        f'<path d="{path_of(px(mesh.vertices[mesh.disc_edges]))}" fill="none" stroke="{rgb(*_DISC)}" stroke-width="1.5"/>',
        f'<path d="{curves}" fill="none" stroke="{rgb(*_CURVE)}" stroke-width="1.5"/>',
        "</svg>",
        "",
    ])
