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

__all__ = ["read_any", "read_curves", "read_svg", "read_json", "read_dcxml", "write_json", "READERS"]

READERS = {"svg": read_svg, "json": read_json, "dcxml": read_dcxml, "xml": read_dcxml}
"""Reader by file kind (``dfc.io.sniff.file_kind``); XML whose root names no known format goes to the diffusion-curve
reader, whose error names the root element."""


def read_curves(path: str | Path) -> Curves:
    """Read a curves file: SVG, dfc's JSON curves or diffusion-curve XML, chosen by content, by extension only when
    the content says nothing specific (``dfc.io.sniff.file_kind``), so that curves piped through standard input
    read too.

    Raises ``CurveError`` naming the file for unrecognised content, a Mitsuba scene, a missing file or a malformed
    one.
    """
    from ...io.sniff import file_kind

    path = Path(path)
    if not path.is_file():
        raise CurveError(f"{path}: no such file")
    kind = file_kind(path)
    if kind == "mitsuba":
        raise CurveError(f"{path}: a Mitsuba 3 scene, not a curves file; find its curves with dfc curves")
    if kind not in READERS:
        raise CurveError(f"{path}: unknown curves file extension {path.suffix!r} and content that is neither JSON "
                         f"nor XML; accepted: .svg, .json, .xml")
    return READERS[kind](path)


read_any = read_curves
"""The name the readers' tests and benchmarks use for ``read_curves``."""
