"""Curve file readers: SVG, dfc's JSON curves format and diffusion-curve XML (``spec/curves.md``).

Each reader returns the raw pieces of the file as a ``dfc.geometry.curves.Curves`` (no intersection
splitting): piece ``k`` of input curve ``c`` has ``curve = c`` and ``t_range = [k, k + 1]``.
Every unreadable file raises one ``CurveError`` naming the file and the problem.
"""

from __future__ import annotations

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
    """Read a curves file, choosing the reader by its extension (``.svg``, ``.json``, ``.xml``).

    Raises ``CurveError`` naming the file for an unknown extension, a missing file or a malformed one.
    """
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    if reader is None:
        accepted = ", ".join(READERS)
        raise CurveError(f"{path}: unknown curves file extension {path.suffix!r}; accepted: {accepted}")
    if not path.is_file():
        raise CurveError(f"{path}: no such file")
    return reader(path)
