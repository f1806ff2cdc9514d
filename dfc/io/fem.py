"""FEM solutions as codec input: triangle meshes with nodal values, read with ``meshio`` (``dfc.physics.fem``
samples them barrier-aware).

A solution is a 2D triangle mesh (P1 nodal values, one row per node). Its point-data arrays become channels:
a real array ``a`` of shape (V,) or (V, 1) is the channel ``a``; one of shape (V, k) the channels ``a.0`` …
``a.{k-1}``; a complex array ``p`` the two channels ``p.re`` and ``p.im`` (real arrays already named so keep their
names, so a solution written as ``p.re`` / ``p.im`` because its file format has no complex type reads the same).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["FemSolution", "from_meshio", "read_fem"]

MESHIO_FORMATS = ("vtk", "vtu", "xdmf", "gmsh")
"""Kinds of ``dfc.io.sniff`` that name a meshio reader (``file_format``)."""

@dataclass(frozen=True)
class FemSolution:
    """A P1 solution on a triangle mesh.

    points : (V, 2) float64 node positions (y down, ``spec/conventions.md``)
    triangles : (T, 3) int64 node indices, counter-clockwise (cross(b − a, c − a) > 0)
    values : (V, C) float64 nodal values (as read: a huge offset on a small variation keeps its digits); channels : C
        names
    source : the file it was read from ('' in memory)
    """

    points: np.ndarray
    triangles: np.ndarray
    values: np.ndarray
    channels: list[str]
    source: str = ""

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1): the bounding box of the nodes that elements use."""
        used = self.points[np.unique(self.triangles)]
        (x0, y0), (x1, y1) = used.min(axis=0), used.max(axis=0)
        return float(x0), float(y0), float(x1), float(y1)


def read_fem(path: str | Path, fields: list[str] | None = None) -> FemSolution:
    """Read a triangle mesh with point data from any format ``meshio`` reads (.vtu, .msh, .xdmf, …): VTK, VTU,
    XDMF and Gmsh files are recognised by content (``dfc.io.sniff``), others by extension.

    fields : point-data arrays to keep (a complex array's name selects both its channels; default: all).
    Raises ``InputError`` (message starts with the path) for unreadable files and everything ``from_meshio`` refuses.
    """
    import contextlib
    import io

    import meshio

    from .sniff import sniff

    kind = sniff(path)  # by content when it says (a .vtu named .dat), else meshio goes by the extension
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            mesh = meshio.read(str(path), file_format=kind if kind in MESHIO_FORMATS else None)
    # meshio raises many types (ReadError, KeyError, ValueError, …) for bad files, and for some formats prints
    # a message and calls sys.exit
    except (Exception, SystemExit) as e:
        reason = said.getvalue().strip().splitlines()[-1:] or [f"{type(e).__name__}: {e}"]
        raise InputError(f"{path}: not a mesh meshio can read ({reason[0]})") from None
    return from_meshio(mesh, fields, source=str(path))


def from_meshio(mesh, fields: list[str] | None = None, source: str = "") -> FemSolution:
    """``FemSolution`` of a ``meshio.Mesh``: its triangle cells, the x, y of its points, the chosen point data.

    Refuses (``InputError``): no triangle cells, points that are not planar (z ≠ 0), no point data, an unknown
    field name, non-numeric arrays, NaN/Inf values, degenerate (zero-area) triangles.
    """
    label = source or "mesh"
    blocks = [np.asarray(c.data, dtype=np.int64) for c in mesh.cells if c.type == "triangle"]
    if not blocks or sum(len(b) for b in blocks) == 0:
        kinds = sorted({c.type for c in mesh.cells}) or ["none"]
        raise InputError(f"{label}: no triangle cells (cells: {', '.join(kinds)}); dfc reads 2D triangle meshes")
    triangles = np.concatenate(blocks)
    points = np.asarray(mesh.points, dtype=np.float64)
    if points.shape[1] > 2 and np.any(points[:, 2:] != 0):
        raise InputError(f"{label}: points have non-zero z; dfc reads planar meshes")
    points = np.ascontiguousarray(points[:, :2])
    if triangles.min() < 0 or triangles.max() >= len(points):
        raise InputError(f"{label}: triangles refer to nodes outside 0..{len(points) - 1}")
    values, channels = _channels(mesh.point_data, fields, len(points), label)
    a, b, c = (points[triangles[:, k]] for k in range(3))
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    if np.any(cross == 0):
        raise InputError(f"{label}: triangle {int(np.flatnonzero(cross == 0)[0])} has zero area")
    triangles = np.where((cross < 0)[:, None], triangles[:, [0, 2, 1]], triangles)
    return FemSolution(points, triangles, values, channels, source)


def _channels(point_data: dict, fields, n_points: int, label: str) -> tuple[np.ndarray, list[str]]:
    """(V, C) float64 values and their channel names from meshio point data (see the module notes)."""
    if not point_data:
        raise InputError(f"{label}: no point data (nodal values) to encode")
    names = list(point_data) if fields is None else list(fields)
    stems = {n[:-3] for n in point_data if n.endswith((".re", ".im"))}
    missing = [n for n in names if n not in point_data and n not in stems]
    if missing:
        raise InputError(f"{label}: no point data named {', '.join(missing)} (has: {', '.join(point_data)})")
    columns, channels = [], []
    for name in names:
        parts = [name] if name in point_data else [f"{name}.re", f"{name}.im"]
        for part in (p for p in parts if p in point_data):
            a = np.asarray(point_data[part])
            if a.dtype.kind not in "iufc" or len(a) != n_points:
                raise InputError(f"{label}: point data {part!r} is not numeric with one row per node")
            a = a.reshape(n_points, -1)
            cols = [a.real, a.imag] if a.dtype.kind == "c" else [a]
            suffixes = [".re", ".im"] if a.dtype.kind == "c" else [""]
            for col, suffix in zip(cols, suffixes):
                stem = f"{part}{suffix}"
                channels += [stem] if col.shape[1] == 1 else [f"{stem}.{k}" for k in range(col.shape[1])]
                columns.append(col.astype(np.float64))
    values = np.concatenate(columns, axis=1)
    bad = ~np.isfinite(values)
    if bad.any():
        node, col = np.argwhere(bad)[0]
        raise InputError(f"{label}: {int(bad.any(axis=1).sum())} nodes have NaN/Inf values, the first is node "
                         f"{int(node)} ({channels[col]})")
    if len(set(channels)) != len(channels):
        raise InputError(f"{label}: fields give repeated channel names {channels}")
    return values, channels
