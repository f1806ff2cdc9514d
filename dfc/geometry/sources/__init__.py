"""Curve file readers: SVG, dfc's JSON curves format and diffusion-curve XML (``spec/curves.md``).

Each reader returns the raw pieces of the file as a ``dfc.geometry.curves.Curves`` (no intersection
splitting): piece ``k`` of input curve ``c`` has ``curve = c`` and ``t_range = [k, k + 1]``.
Every unreadable file raises one ``CurveError`` naming the file and the problem.
"""

from __future__ import annotations

import re
from pathlib import Path

from ...errors import CurveError
from ..curves import Curves
from .dcxml import read_dcxml
from .jsonfile import read_json, write_json
from .svg import read_svg

__all__ = ["read_any", "read_svg", "read_json", "read_dcxml", "write_json", "READERS"]

READERS = {".svg": read_svg, ".json": read_json, ".xml": read_dcxml}
"""Reader by lower-case file extension."""


def read_any(path: str | Path) -> Curves:
    """Read a curves file, choosing the reader by its extension (``.svg``, ``.json``, ``.xml``), or by its content
    when the extension is none of these (a JSON object; an ``<svg>`` document; other XML: diffusion curves), so that
    curves piped through standard input read too.

    Raises ``CurveError`` naming the file for unrecognised content, a missing file or a malformed one.
    """
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    if reader is None and path.is_file():
        reader = _reader_by_content(path)
    if reader is None and path.exists():
        accepted = ", ".join(READERS)
        raise CurveError(f"{path}: unknown curves file extension {path.suffix!r} and content that is neither JSON "
                         f"nor XML; accepted: {accepted}")
    if reader is None or not path.is_file():
        raise CurveError(f"{path}: no such file")
    return reader(path)


def _reader_by_content(path: Path):
    """``read_json`` for a JSON object, ``read_svg`` for an ``<svg>`` document, ``read_dcxml`` for other XML."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return None
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith(b"{"):
        return read_json
    if text.startswith(b"<"):
        return read_svg if re.search(rb"<svg[\s>]", head) else read_dcxml
    return None
