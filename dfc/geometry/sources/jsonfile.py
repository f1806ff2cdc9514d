"""dfc's own JSON curves format (``"format": "dfc-curves/1"``, schema in ``spec/curves.md``).

A piece is written in its true degree (2, 3 or 4 points) and elevated to a cubic on reading.
``write_json`` writes what ``read_json`` reads back: lines and cubics bit-exactly, quadratics to
within a few units in the last place (their middle control point is recovered from the cubic form).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...errors import CurveError
from ...io.atomic import write_bytes_atomic
from ..curves import DEGREE_CUBIC, DEGREE_LINE, DEGREE_QUADRATIC, Curves, SideValues
from ._common import assemble, chain, read_bytes

__all__ = ["FORMAT", "read_json", "write_json"]

FORMAT = "dfc-curves/1"
_DEGREE = {"line": DEGREE_LINE, "quadratic": DEGREE_QUADRATIC, "cubic": DEGREE_CUBIC}
_TYPE = {d: t for t, d in _DEGREE.items()}
_TOP_KEYS = {"format", "domain", "curves", "pieces"}
_CURVE_KEYS = {"name", "pieces", "left", "right"}
_PIECE_KEYS = {"type", "points", "t"}


class _Bad(Exception):
    """A schema violation at a location inside the document (turned into ``CurveError``)."""

    def __init__(self, where: str, problem: str):
        super().__init__(f"{where}: {problem}" if where else problem)


def read_json(path: str | Path) -> Curves:
    """Read a JSON curves file.

    Returns ``Curves`` with one input curve per entry of ``curves`` (in order), then one per
    entry of the top-level ``pieces``. Raises ``CurveError`` naming the file, the JSON location
    (``curves[2].pieces[0]``) and the problem.
    """
    path = Path(path)
    data = read_bytes(path)
    try:
        doc = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise CurveError(f"{path}: not UTF-8 text (byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise CurveError(f"{path}: line {e.lineno}, column {e.colno}: invalid JSON: {e.msg}") from None
    try:
        return _document(path, doc)
    except _Bad as e:
        raise CurveError(f"{path}: {e}") from None


def _document(path: Path, doc) -> Curves:
    _object(doc, "", _TOP_KEYS, required={"domain"})
    if "format" in doc and doc["format"] != FORMAT:
        raise _Bad("format", f"unsupported format {doc['format']!r}; this reader knows {FORMAT!r}")
    domain = _numbers(doc["domain"], "domain", 4)
    if not (domain[2] > domain[0] and domain[3] > domain[1]):
        raise _Bad("domain", f"{domain.tolist()} is not a rectangle [x0, y0, x1, y1] with x1 > x0 and y1 > y0")
    chains, names, sides = [], [], []
    for i, entry in enumerate(_list(doc.get("curves", []), "curves")):
        where = f"curves[{i}]"
        _object(entry, where, _CURVE_KEYS, required={"pieces"})
        name = entry.get("name", where)
        if not isinstance(name, str):
            raise _Bad(f"{where}.name", "must be a string")
        pieces = _list(entry["pieces"], f"{where}.pieces")
        chains.append(_chain([(p, f"{where}.pieces[{k}]") for k, p in enumerate(pieces)]))
        names.append(name)
        sides.append(_sides(entry, where, chains[-1][2]))
    for i, piece in enumerate(_list(doc.get("pieces", []), "pieces")):
        chains.append(_chain([(piece, f"pieces[{i}]")]))
        names.append(f"pieces[{i}]")
        sides.append(None)
    channels = {s.left.shape[1] for s in sides if s is not None}
    if len(channels) > 1:
        raise _Bad("curves", f"side values have different lengths across curves: {sorted(channels)}")
    t_range = np.concatenate([t for _, _, t in chains]) if chains else np.zeros((0, 2))
    return assemble(path, tuple(domain.tolist()), [(d, cp) for d, cp, _ in chains], names, sides, t_range)


def _object(value, where: str, allowed: set[str], *, required: set[str]) -> None:
    if not isinstance(value, dict):
        raise _Bad(where, f"expected an object, got {_kind(value)}")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise _Bad(where, f"unknown key {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})")
    missing = sorted(required - set(value))
    if missing:
        raise _Bad(where, f"missing key {missing[0]!r}")


def _list(value, where: str) -> list:
    if not isinstance(value, list):
        raise _Bad(where, f"expected a list, got {_kind(value)}")
    return value


def _kind(value) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null"}.get(
        type(value), "a number"
    )


def _numbers(value, where: str, n: int | None = None) -> np.ndarray:
    """A list of finite JSON numbers (length ``n`` when given) -> (n,) float64."""
    if not isinstance(value, list) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    ):
        raise _Bad(where, "expected a list of numbers")
    if n is not None and len(value) != n:
        raise _Bad(where, f"expected {n} numbers, got {len(value)}")
    a = np.array(value, dtype=np.float64)
    if not np.isfinite(a).all():
        raise _Bad(where, "NaN or infinite number")
    return a


def _points(pts: list, where: str) -> np.ndarray:
    """A list of [x, y] pairs of finite numbers -> (n, 2) float64 (fast path; the slow one names the bad point)."""
    if all(type(p) is list and len(p) == 2 and type(p[0]) in (int, float) and type(p[1]) in (int, float) for p in pts):
        a = np.array(pts, dtype=np.float64)
        if np.isfinite(a).all():
            return a
    return np.stack([_numbers(p, f"{where}[{j}]", 2) for j, p in enumerate(pts)])


def _chain(pieces: list[tuple[object, str]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse the pieces of one input curve -> degree (n,) int8, control points (n, 4, 2), t_range (n, 2)."""
    degrees, points, t_range = [], [], []
    for k, (piece, where) in enumerate(pieces):
        _object(piece, where, _PIECE_KEYS, required={"type", "points"})
        degree = _DEGREE.get(piece["type"]) if isinstance(piece["type"], str) else None
        if degree is None:
            raise _Bad(f"{where}.type", f"{piece['type']!r} is not one of 'line', 'quadratic', 'cubic'")
        pts = _list(piece["points"], f"{where}.points")
        if len(pts) != degree + 1:
            raise _Bad(where, f"{piece['type']} needs {degree + 1} points, got {len(pts)}")
        points.append(_points(pts, f"{where}.points"))
        degrees.append(degree)
        t = _numbers(piece["t"], f"{where}.t", 2) if "t" in piece else np.array([k, k + 1.0])
        if not t[1] > t[0]:
            raise _Bad(f"{where}.t", f"{t.tolist()} must be increasing")
        t_range.append(t)
    degree, cp = chain(degrees, points)
    return degree, cp, np.array(t_range, dtype=np.float64).reshape(-1, 2)


def _sides(entry: dict, where: str, t_range: np.ndarray) -> SideValues | None:
    """``left``/``right`` colour stops of one curve -> SideValues, or None when both are absent."""
    if "left" not in entry and "right" not in entry:
        return None
    if "left" not in entry or "right" not in entry:
        raise _Bad(where, "give both 'left' and 'right' side values, or neither")
    lo, hi = (float(t_range[:, 0].min()), float(t_range[:, 1].max())) if len(t_range) else (0.0, 0.0)
    stops = {}
    for side in ("left", "right"):
        items = _list(entry[side], f"{where}.{side}")
        if not items:
            raise _Bad(f"{where}.{side}", "needs at least one stop")
        s, values = [], []
        for j, stop in enumerate(items):
            at = f"{where}.{side}[{j}]"
            _object(stop, at, {"s", "value"}, required={"s", "value"})
            s.append(_numbers([stop["s"]], f"{at}.s")[0])
            values.append(_numbers(stop["value"], f"{at}.value"))
        lengths = {len(v) for v in values}
        if len(lengths) > 1 or 0 in lengths:
            raise _Bad(f"{where}.{side}", f"values must all have the same non-zero length, got {sorted(lengths)}")
        s = np.array(s)
        if (np.diff(s) < 0).any():
            raise _Bad(f"{where}.{side}", "positions s must be non-decreasing")
        if s[0] < lo or s[-1] > hi:
            raise _Bad(f"{where}.{side}", f"positions s must lie in the curve's parameter range [{lo:g}, {hi:g}]")
        stops[side] = (s, np.stack(values))
    if stops["left"][1].shape[1] != stops["right"][1].shape[1]:
        raise _Bad(where, "left and right values have different lengths")
    return SideValues(stops["left"][0], stops["left"][1], stops["right"][0], stops["right"][1])


def write_json(curves: Curves, path: str | Path) -> None:
    """Write ``curves`` as a JSON curves file (atomically), every input curve with its pieces in stored order.

    A piece's ``t`` is written only where it differs from ``[k, k + 1]`` (``k`` its index in its curve).
    """
    n_curves = max(len(curves.names), int(curves.curve.max()) + 1 if len(curves) else 0)
    entries = []
    for c in range(n_curves):
        (idx,) = np.nonzero(curves.curve == c)
        pieces = [_piece(curves, i, k) for k, i in enumerate(idx)]
        entry = {"name": curves.names[c] if c < len(curves.names) else f"curves[{c}]", "pieces": pieces}
        side = curves.sides[c] if c < len(curves.sides) else None
        if side is not None:
            entry["left"] = [{"s": float(s), "value": v.tolist()} for s, v in zip(side.left_s, side.left)]
            entry["right"] = [{"s": float(s), "value": v.tolist()} for s, v in zip(side.right_s, side.right)]
        entries.append(entry)
    doc = {"format": FORMAT, "domain": list(curves.domain), "curves": entries}
    write_bytes_atomic(path, (json.dumps(doc, indent=1, allow_nan=False) + "\n").encode("utf-8"))


def _piece(curves: Curves, i: int, k: int) -> dict:
    """Piece ``i`` (the ``k``-th of its curve) as a JSON object in its true degree."""
    p = curves.control_points[i]
    degree = int(curves.degree[i])
    if degree == DEGREE_LINE:
        points = p[[0, 3]]
    elif degree == DEGREE_QUADRATIC:  # both inner cubic points determine Q1; average the two estimates
        points = np.stack([p[0], (3.0 * (p[1] + p[2]) - p[0] - p[3]) / 4.0, p[3]])
    else:
        points = p
    piece = {"type": _TYPE[degree], "points": points.tolist()}
    t = curves.t_range[i]
    if not (t[0] == k and t[1] == k + 1):
        piece["t"] = t.tolist()
    return piece
