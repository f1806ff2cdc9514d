"""Pictures of a mesh for eyes: thin grey edges, discontinuous edges in red, curved pieces in blue over
tinted curved triangles. PNG (Pillow) or SVG (text), chosen by the file's suffix, written atomically.
Image rows run along +y (y down), as in ``spec/conventions.md``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from ..io.atomic import atomic_path, write_bytes_atomic
from . import bezier
from .curves import Curves
from .mesh import Mesh

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


def draw_curves(curves: Curves, path: str | Path, background: np.ndarray | None = None, *, scale: int = 1) -> None:
    """Draw ``curves`` in red over ``background`` ((H, W, 3) uint8 sRGB covering the curves' domain, or white) to a
    PNG at ``scale`` × the background's size (the domain's size in its units when there is none), atomically."""
    x0, y0, x1, y1 = curves.domain
    if background is None:
        background = np.full((max(1, round(y1 - y0)), max(1, round(x1 - x0)), 3), 255, np.uint8)
    height, width = background.shape[:2]
    image = Image.fromarray(np.ascontiguousarray(background, dtype=np.uint8), "RGB")
    if scale != 1:
        image = image.resize((width * scale, height * scale), Image.NEAREST)
    draw = ImageDraw.Draw(image)
    factor = np.array([width * scale / (x1 - x0), height * scale / (y1 - y0)])
    for line in (bezier.flatten(curves.control_points, _CURVE_SAMPLES) - (x0, y0)) * factor:
        draw.line([tuple(p) for p in line], fill=_DISC, width=max(1, scale // 2))
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")
