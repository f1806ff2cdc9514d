"""Diffusion-curve XML (Orzan et al. 2008, and the ``SceneXML`` variant built on it) -> ``Curves``.

Two dialects, told apart by the root element (see ``spec/curves.md`` for the evidence):

- ``<curve_set image_width image_height>`` (``<!DOCTYPE CurveSetXML>``, Orzan's own tool): the
  attribute called ``x`` is the vertical coordinate and ``y`` the horizontal one, and ``R``/``B`` are
  swapped; after the transpose the file's left side is dfc's left side.
- ``<scene image_width image_height>`` with a ``<curve_set>`` child (``<!DOCTYPE SceneXML>``):
  coordinates and colours as written, but the file's ``left`` is dfc's *right* side.

Every ``<curve>`` holds ``3k + 1`` control points, a chain of ``k`` cubics. Colour stops sit at
``globalID``, an index into a sampling of 10 points per cubic segment, so ``s = globalID / 10``.
Colours become floats ``value / 255`` (display sRGB values, not linearised). Blur points, Poisson
curves and gradient meshes are ignored.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...errors import CurveError
from ..curves import Curves, SideValues
from ._common import LinedElement, assemble, parse_xml, read_bytes

__all__ = ["read_dcxml", "SAMPLES_PER_SEGMENT"]

SAMPLES_PER_SEGMENT = 10
"""``globalID`` steps per cubic segment in Orzan's curve sampling: ``s = globalID / 10``."""

_DIALECTS = {"curve_set": "orzan", "scene": "scene"}


def read_dcxml(path: str | Path, *, convention: str | None = None) -> Curves:
    """Read a diffusion-curve XML file.

    Parameters
    ----------
    path : the ``.xml`` file
    convention : {None, 'orzan', 'scene'}
        How to map coordinates, colours and sides. None picks it from the root element
        (``<curve_set>`` -> 'orzan', ``<scene>`` -> 'scene'); pass it to override a mislabelled file.

    Returns
    -------
    Curves with domain ``(0, 0, image_width, image_height)``, all pieces cubic, and one
    ``SideValues`` (3 channels R, G, B in [0, 1]) per curve.

    Raises
    ------
    CurveError naming the file, the line and the problem.
    """
    path = Path(path)
    if convention not in (None, "orzan", "scene"):
        raise ValueError(f"convention must be None, 'orzan' or 'scene', got {convention!r}")
    root = parse_xml(path, read_bytes(path))
    if root.tag not in _DIALECTS:
        raise CurveError(f"{path}: line {root.line}: root element <{root.tag}> is neither <scene> nor <curve_set>")
    orzan = (convention or _DIALECTS[root.tag]) == "orzan"
    width, height = (_number(path, root, name, positive=True) for name in ("image_width", "image_height"))
    domain = (0.0, 0.0, width, height)
    curve_set = root if root.tag == "curve_set" else root.find("curve_set")
    elements = [] if curve_set is None else curve_set.findall("curve")
    if curve_set is not None and curve_set.get("nb_curves") is not None:
        _check_count(path, curve_set, "nb_curves", len(elements), "<curve> elements")
    chains, names, sides = [], [], []
    for i, el in enumerate(elements):
        control_points = _control_points(path, el, i, orzan)
        k = (len(control_points) - 1) // 3
        segments = np.lib.stride_tricks.sliding_window_view(control_points, 4, axis=0)[::3]  # (k, 2, 4)
        chains.append((np.full(k, 3, dtype=np.int8), segments.transpose(0, 2, 1).copy()))
        names.append(f"curve {i}")
        left_s, left = _colours(path, el, i, "left", orzan, k)
        right_s, right = _colours(path, el, i, "right", orzan, k)
        if not orzan:  # SceneXML's left is dfc's right
            left_s, left, right_s, right = right_s, right, left_s, left
        sides.append(SideValues(left_s, left, right_s, right))
    return assemble(path, domain, chains, names, sides)


def _number(path: Path, el: LinedElement, name: str, *, positive: bool = False) -> float:
    """A finite float attribute of ``el`` (required)."""
    text = el.get(name)
    if text is None:
        raise CurveError(f"{path}: line {el.line}: <{el.tag}> lacks the attribute {name}")
    try:
        value = float(text)
    except ValueError:
        raise CurveError(f"{path}: line {el.line}: <{el.tag}> {name}={text!r} is not a number") from None
    if not math.isfinite(value) or (positive and value <= 0):
        kind = "a positive finite number" if positive else "finite"
        raise CurveError(f"{path}: line {el.line}: <{el.tag}> {name}={text!r} is not {kind}")
    return value


def _check_count(path: Path, el: LinedElement, attribute: str, actual: int, what: str) -> None:
    declared = el.get(attribute)
    if declared.strip() != str(actual):
        raise CurveError(f"{path}: line {el.line}: {attribute}={declared!r} but the file holds {actual} {what}")


def _control_points(path: Path, el: LinedElement, i: int, orzan: bool) -> np.ndarray:
    """(3k + 1, 2) float64 control points of ``<curve>`` number ``i``, in dfc's (x, y)."""
    point_set = el.find("control_points_set")
    if point_set is None:
        raise CurveError(f"{path}: line {el.line}: curve {i}: no <control_points_set>")
    points = point_set.findall("control_point")
    if el.get("nb_control_points") is not None:
        _check_count(path, el, "nb_control_points", len(points), "control points")
    n = len(points)
    if n < 4 or (n - 1) % 3:
        raise CurveError(
            f"{path}: line {el.line}: curve {i}: {n} control points; a chain of k cubics needs 3k + 1 (4, 7, 10, ...)"
        )
    xy = np.array([[_number(path, p, "x"), _number(path, p, "y")] for p in points], dtype=np.float64)
    return xy[:, ::-1].copy() if orzan else xy


def _colours(
    path: Path, el: LinedElement, i: int, side: str, orzan: bool, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The file's ``side`` stops of curve ``i`` (a chain of ``k`` cubics): positions s (m,) float64 in [0, k],
    sorted, and (R, G, B) values (m, 3) float64 in [0, 1] (R and B already swapped back for Orzan files)."""
    stop_set = el.find(f"{side}_colors_set")
    stops = [] if stop_set is None else stop_set.findall(f"{side}_color")
    if not stops:
        raise CurveError(f"{path}: line {el.line}: curve {i}: no <{side}_color> stops")
    if el.get(f"nb_{side}_colors") is not None:
        _check_count(path, el, f"nb_{side}_colors", len(stops), f"{side} colours")
    gid = np.array([_number(path, c, "globalID") for c in stops])
    rgb = np.array([[_channel(path, c, ch) for ch in "rgb"] for c in stops])
    if orzan:
        rgb = rgb[:, ::-1].copy()
    if (gid < 0).any():
        bad = stops[int(np.argmax(gid < 0))]
        raise CurveError(f"{path}: line {bad.line}: globalID {bad.get('globalID')} is negative")
    top = SAMPLES_PER_SEGMENT * k
    # Orzan's files never pass 10 k; some exporters write 0..N with any N: scale this side onto [0, k]
    s = gid / SAMPLES_PER_SEGMENT if gid.max() <= top else gid * (k / gid.max())
    order = np.argsort(s, kind="stable")
    return s[order], rgb[order]


def _channel(path: Path, el: LinedElement, channel: str) -> float:
    """One colour channel in [0, 1]: ``R``/``G``/``B`` in 0..255, or ``r``/``g``/``b`` already in [0, 1]."""
    if el.get(channel.upper()) is not None:
        value, scale = _number(path, el, channel.upper()), 255.0
    else:
        value, scale = _number(path, el, channel), 1.0
    if not 0.0 <= value <= scale:
        raise CurveError(f"{path}: line {el.line}: colour channel {channel.upper()}={value:g} outside [0, {scale:g}]")
    return value / scale
