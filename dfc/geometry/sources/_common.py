"""What every curves reader shares: reading the file's bytes, a line-numbered XML tree, and
assembling chains of pieces into one ``Curves``.

A *chain* is one input curve: ``degree`` (n,) int and ``control_points`` (n, 4, 2) float64
(already elevated to cubics). Piece ``k`` of a chain covers ``s`` in ``[k, k + 1]``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

import numpy as np

from ...errors import CurveError
from ..curves import Curves, SideValues, elevate


def read_bytes(path: Path) -> bytes:
    """The file's bytes; ``CurveError`` if it cannot be read or holds nothing but whitespace."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise CurveError(f"{path}: cannot read: {e.strerror or e}") from None
    if not data.strip():
        raise CurveError(f"{path}: empty file")
    return data


class LinedElement(ET.Element):
    """An ``ElementTree`` element that remembers the source ``line`` its start tag is on."""

    line: int = 0


def parse_xml(path: Path, data: bytes) -> LinedElement:
    """Parse XML ``data`` into a tree of ``LinedElement`` (expat, no external entities).

    Raises ``CurveError`` naming the file, line and column of the first syntax error.
    """
    builder = ET.TreeBuilder(element_factory=LinedElement)
    parser = expat.ParserCreate()

    def start(tag, attrs):
        builder.start(tag, attrs).line = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    parser.ordered_attributes = False
    try:
        parser.Parse(data, True)
    except expat.ExpatError as e:
        raise CurveError(
            f"{path}: line {e.lineno}, column {e.offset + 1}: XML parse error: {expat.ErrorString(e.code)}"
        ) from None
    return builder.close()


def chain(degrees: list[int] | np.ndarray, points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Elevate a list of pieces of mixed degree to one chain.

    degrees : (n,) int, 1 line / 2 quadratic / 3 cubic
    points : n arrays of shape (degree + 1, 2), float
    returns degree (n,) int8 and control_points (n, 4, 2) float64
    """
    deg = np.asarray(degrees, dtype=np.int8).reshape(-1)
    cp = np.empty((len(deg), 4, 2), dtype=np.float64)
    for d in (1, 2, 3):
        (idx,) = np.nonzero(deg == d)
        if len(idx):
            cp[idx] = elevate(np.stack([points[i] for i in idx]), d)
    return deg, cp


def assemble(
    path: Path,
    domain: tuple[float, float, float, float],
    chains: list[tuple[np.ndarray, np.ndarray]],
    names: list[str],
    sides: list[SideValues | None],
    t_range: np.ndarray | None = None,
) -> Curves:
    """One ``Curves`` from per-input-curve chains: piece ``k`` of chain ``c`` gets ``curve = c`` and, unless
    ``t_range`` ((P, 2) float64, all pieces in order) is given, ``t_range = [k, k + 1]``."""
    counts = np.array([len(d) for d, _ in chains], dtype=np.int64)
    n = int(counts.sum())
    degree = np.concatenate([d for d, _ in chains]) if n else np.zeros(0, np.int8)
    control_points = np.concatenate([cp for _, cp in chains]) if n else np.zeros((0, 4, 2))
    curve = np.repeat(np.arange(len(chains), dtype=np.int64), counts)
    if t_range is None:
        k = np.arange(n, dtype=np.float64) - np.repeat(np.cumsum(counts) - counts, counts)
        t_range = np.stack([k, k + 1.0], axis=1)
    return Curves(domain, control_points, degree, curve, t_range, names, sides, str(path))
