"""Benchmark reports, written the same way by every comparison: ``results.json`` (the record), ``results.md`` (a
markdown table), ``contact.png`` (a grid of labelled tiles), the dfc file and any plots, each atomically into one
directory."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np

__all__ = ["LABEL_WIDTH", "TILE", "contact_sheet", "display", "markdown_table", "write_report"]

TILE = 192
"""Side of a contact-sheet tile, pixels."""
LABEL_WIDTH = 110
"""Width of the contact sheet's row-label column, pixels."""
HEADER = 20
"""Height of the contact sheet's column-label row, pixels."""


def display(tile: np.ndarray, hdr: bool) -> np.ndarray:
    """(h, w, C) linear values -> (h, w, 3) uint8 sRGB (tone-mapped with ``x / (1 + x)`` first for HDR; one channel
    as grey)."""
    from ..io.image import display8

    v = tile[..., :3] if tile.shape[2] >= 3 else np.repeat(tile[..., :1], 3, axis=2)
    return display8(v, hdr)


def contact_sheet(columns: list[str], rows: list[tuple[str, list[np.ndarray | None], list[str | None]]]) -> bytes:
    """PNG bytes of a grid: a label row on top (``columns``), then one row of ``TILE``-sized tiles per entry of
    ``rows`` = (row label, tiles (h, w, 3) uint8 or None per column, caption or None per column), each tile scaled
    to ``TILE`` with nearest-neighbour sampling (pixels stay visible)."""
    from PIL import Image as PILImage
    from PIL import ImageDraw

    sheet = PILImage.new("RGB", (LABEL_WIDTH + len(columns) * TILE, len(rows) * TILE + HEADER), (40, 40, 40))
    draw = ImageDraw.Draw(sheet)
    for c, label in enumerate(columns):
        draw.text((LABEL_WIDTH + c * TILE + 4, 4), label, fill=(255, 255, 255))
    for r, (label, tiles, captions) in enumerate(rows):
        top = HEADER + r * TILE
        draw.text((4, top + 4), label, fill=(255, 255, 255))
        for c, (tile, caption) in enumerate(zip(tiles, captions)):
            if tile is None:
                continue
            sheet.paste(PILImage.fromarray(tile).resize((TILE, TILE), PILImage.NEAREST), (LABEL_WIDTH + c * TILE, top))
            if caption:
                draw.text((LABEL_WIDTH + c * TILE + 4, top + TILE - 14), caption, fill=(255, 255, 0))
    buf = io.BytesIO()
    sheet.save(buf, format="PNG")
    return buf.getvalue()


def markdown_table(title: str, notes: str, header: list[str], rows: list[list[str]], footer: str = "") -> str:
    """``results.md``: a title, a paragraph of notes, a table (first column left-aligned, the others right-aligned)
    and an optional closing paragraph."""
    lines = [f"# {title}", "", notes, "", "| " + " | ".join(header) + " |",
             "|---|" + "---:|" * (len(header) - 1)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    if footer:
        lines += ["", footer]
    return "\n".join(lines) + "\n"


def finite(obj):
    """``obj`` with every non-finite float (an infinite PSNR of identical rasters) replaced by None."""
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_report(directory: str | Path, record: dict, markdown: str, sheet: bytes | None, blob: bytes | None,
                 extra: dict[str, bytes] | None = None) -> list[Path]:
    """Write ``results.json`` (``record`` as a result file, ``dfc.bench.results.publish_record``; non-finite numbers
    as null), ``results.md`` and, when given, ``contact.png``, ``dfc.dfield`` and the ``extra`` files {name: bytes}
    (plots) into ``directory`` (created if missing), each atomically. Returns the paths written."""
    from ..io.atomic import write_bytes_atomic
    from .results import publish_record

    record = publish_record(record, markdown)

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    files = {"results.json": (json.dumps(finite(record), indent=2, allow_nan=False) + "\n").encode(),
             "results.md": markdown.encode()}
    if sheet is not None:
        files["contact.png"] = sheet
    if blob is not None:
        files["dfc.dfield"] = blob
    files.update(extra or {})
    for name, data in files.items():
        write_bytes_atomic(out / name, data)
    return [out / name for name in files]
