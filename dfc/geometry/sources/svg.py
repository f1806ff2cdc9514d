"""SVG -> ``Curves`` through ``svgelements``.

Every path command (absolute, relative, implicit repeats, smooth S/T reflections, arcs) and the
basic shapes (rect incl. rounded, circle, ellipse, line, polyline, polygon) become Bézier pieces,
with all transforms applied. Each subpath of each element is one input curve. Coordinates stay in
the root ``viewBox``'s user units: svgelements maps them to viewport pixels, and this module maps
them back, so the domain (the viewBox, or ``[0, width] × [0, height]`` without one) and the pieces
share one unit. Styles, fills, strokes, text and images are ignored; ``display: none`` and
``<defs>`` content are not drawn, ``<use>`` instances are.
"""

from __future__ import annotations

import io
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import svgelements as se

from ...errors import CurveError
from ..curves import DEGREE_CUBIC, DEGREE_LINE, DEGREE_QUADRATIC, Curves
from ..tolerances import tol
from ._common import assemble, chain, parse_xml, read_bytes

__all__ = ["read_svg", "arc_pieces"]

_ARC_ERROR_FACTOR = 4.0
"""Measured bound on svgelements' arc-to-cubic error: ≤ 3.6 × R × (4/27) sin⁶(θ/4) / cos²(θ/4) for sweep θ."""


def read_svg(path: str | Path) -> Curves:
    """Read the geometry of an SVG file.

    Returns ``Curves`` in the root viewBox's user units (``domain`` = the viewBox rectangle, or
    ``[0, width] × [0, height]`` in px when there is no viewBox), no side values. Raises
    ``CurveError`` for malformed XML or path data, a missing/empty viewport, or non-finite coordinates.
    """
    path = Path(path)
    data = read_bytes(path)
    try:
        svg = se.SVG.parse(io.BytesIO(data), on_error="raise")
    except ET.ParseError as e:
        line, column = e.position
        raise CurveError(f"{path}: line {line}, column {column + 1}: XML parse error: {e.msg.split(':')[0]}") from None
    except ValueError:
        raise CurveError(_locate_bad_data(path, data)) from None
    if not isinstance(svg, se.SVG):
        raise CurveError(f"{path}: the root element is not <svg>")
    domain, to_user = _viewport(path, svg)
    diagonal = math.hypot(domain[2] - domain[0], domain[3] - domain[1])
    chains, names = [], []
    shapes = [e for e in svg.elements() if isinstance(e, se.Shape)]
    for index, shape in enumerate(shapes):
        tag = shape.values.get("tag", "shape")
        base = f"{tag}#{shape.id}" if shape.id else f"{tag}[{index}]"
        subpaths = _subpaths(path, base, shape, to_user, diagonal)
        for j, (degrees, points) in enumerate(subpaths):
            chains.append(chain(degrees, points))
            names.append(base if len(subpaths) == 1 else f"{base} subpath {j}")
    return assemble(path, domain, chains, names, [None] * len(chains))


def _viewport(path: Path, svg: se.SVG) -> tuple[tuple[float, float, float, float], np.ndarray]:
    """Domain in user units and the (2, 3) affine map from svgelements' viewport pixels to user units."""
    vb = svg.viewbox
    if vb is not None:
        box = (vb.x, vb.y, vb.width, vb.height)
        if not all(v is not None and math.isfinite(v) for v in box) or vb.width <= 0 or vb.height <= 0:
            raise CurveError(f"{path}: viewBox {svg.values.get('viewBox')!r} is not four numbers with positive size")
        m = ~se.Matrix(svg.viewbox_transform)
        to_user = np.array([[m.a, m.c, m.e], [m.b, m.d, m.f]], dtype=np.float64)
        return (vb.x, vb.y, vb.x + vb.width, vb.y + vb.height), to_user
    raw = [svg.values.get(k) for k in ("width", "height")]
    if any(v is None or str(v).strip().endswith("%") for v in raw):
        raise CurveError(f"{path}: no viewBox and no absolute width and height: the domain is unknown")
    if not (math.isfinite(svg.width) and math.isfinite(svg.height) and svg.width > 0 and svg.height > 0):
        raise CurveError(f"{path}: width {raw[0]!r} and height {raw[1]!r} must be positive")
    return (0.0, 0.0, float(svg.width), float(svg.height)), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _subpaths(
    path: Path, name: str, shape: se.Shape, to_user: np.ndarray, diagonal: float
) -> list[tuple[list[int], list[np.ndarray]]]:
    """The subpaths of one element: per subpath the piece degrees and (degree + 1, 2) user-unit points."""
    scale = float(np.linalg.norm(to_user[:, :2], 2))
    arc_tol = tol.svg_arc_rel * diagonal
    out = []
    current: list[tuple[int, list, bool]] = []  # (degree, svgelements points, is the closing line)

    def flush():
        kept = _finish(path, name, current, to_user, diagonal)
        if kept[0]:
            out.append(kept)
        current.clear()

    for seg in se.Path(shape).segments():
        if isinstance(seg, se.Move):
            flush()
            continue
        if seg.start is None:
            raise CurveError(f"{path}: {name}: path data must begin with a moveto (M/m)")
        if isinstance(seg, se.Close):
            current.append((DEGREE_LINE, [seg.start, seg.end], True))
            flush()  # a command after Z starts a new subpath at the same point
        elif isinstance(seg, se.Line):
            current.append((DEGREE_LINE, [seg.start, seg.end], False))
        elif isinstance(seg, se.QuadraticBezier):
            current.append((DEGREE_QUADRATIC, [seg.start, seg.control, seg.end], False))
        elif isinstance(seg, se.CubicBezier):
            current.append((DEGREE_CUBIC, [seg.start, seg.control1, seg.control2, seg.end], False))
        elif isinstance(seg, se.Arc):
            current.extend((d, p, False) for d, p in _arc(seg, scale, arc_tol))
        else:
            raise CurveError(f"{path}: {name}: unsupported path segment {type(seg).__name__}")
    flush()
    return out


def _arc(seg: se.Arc, scale: float, arc_tol: float) -> list[tuple[int, list]]:
    """An SVG arc as pieces: cubics within ``arc_tol`` user units, a line when a radius is zero, nothing when empty."""
    if seg.sweep == 0 or seg.rx == 0 or seg.ry == 0:
        return [] if seg.start == seg.end else [(DEGREE_LINE, [seg.start, seg.end])]
    n = arc_pieces(abs(seg.sweep), max(seg.rx, seg.ry) * scale, arc_tol)
    return [(DEGREE_CUBIC, [c.start, c.control1, c.control2, c.end]) for c in seg.as_cubic_curves(n)]


def arc_pieces(sweep: float, radius: float, max_error: float) -> int:
    """Number of cubics for an elliptical arc of ``sweep`` radians and largest radius ``radius``
    so that each deviates at most ``max_error`` (same unit as ``radius``); at least one per 90°."""
    n = np.arange(max(1, math.ceil(sweep / (math.pi / 2))), 4097)
    q = sweep / n / 4.0
    error = _ARC_ERROR_FACTOR * radius * (4.0 / 27.0) * np.sin(q) ** 6 / np.cos(q) ** 2
    ok = np.nonzero(error <= max_error)[0]
    return int(n[ok[0]] if len(ok) else n[-1])


def _finish(
    path: Path, name: str, pieces: list[tuple[int, list, bool]], to_user: np.ndarray, diagonal: float
) -> tuple[list[int], list[np.ndarray]]:
    """Map one subpath's pieces (degree, svgelements points in viewport px, is-closing) to user units,
    check them, and drop a closing line shorter than ``tol.zero_length_rel`` × diagonal."""
    if not pieces:
        return [], []
    flat = np.array([(p[0], p[1]) for _, points, _ in pieces for p in points], dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite input is reported just below
        flat = flat @ to_user[:, :2].T + to_user[:, 2]
    if not np.isfinite(flat).all():
        raise CurveError(f"{path}: {name}: NaN or infinite coordinate")
    user = np.split(flat, np.cumsum([d + 1 for d, _, _ in pieces])[:-1])
    keep = [
        i for i, (_, _, closing) in enumerate(pieces)
        if not (closing and np.hypot(*(user[i][1] - user[i][0])) <= tol.zero_length_rel * diagonal)
    ]
    return [pieces[i][0] for i in keep], [user[i] for i in keep]


def _locate_bad_data(path: Path, data: bytes) -> str:
    """Message for geometry svgelements rejected: the first ``<path>`` whose ``d`` does not parse."""
    for el in parse_xml(path, data).iter():
        if el.tag.rsplit("}", 1)[-1] == "path" and el.get("d") is not None:
            try:
                se.Path(el.get("d"))
            except ValueError:
                ident = f" id={el.get('id')!r}" if el.get("id") else ""
                return f"{path}: line {el.line}: <path{ident}>: malformed path data"
    return f"{path}: malformed SVG geometry (svgelements rejected an attribute)"
