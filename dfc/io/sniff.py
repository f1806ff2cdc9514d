"""What an input file holds, told by its first bytes (magic numbers), with the extension as fallback.

Readers and ``dfc encode`` choose by content first, so a valid EXR named ``render.bin`` is read as an EXR, and by
extension only when the content says nothing (a damaged file whose first bytes are gone still gets the reader, and
the error, of its extension).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["FEM_KINDS", "IMAGE_KINDS", "EXTENSIONS", "file_kind", "sniff", "sniff_bytes"]

IMAGE_KINDS = ("exr", "png", "jpeg")
FEM_KINDS = ("vtk", "vtu", "xdmf", "gmsh", "hdf5")
"""Mesh formats recognised by content; each name is also meshio's ``file_format`` (``hdf5`` excepted: by
extension)."""

EXTENSIONS = {".exr": "exr", ".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".npz": "npz", ".vtk": "vtk",
              ".vtu": "vtu", ".xdmf": "xdmf", ".xmf": "xdmf", ".msh": "gmsh"}
"""Kind by lower-case extension, the fallback when the content is not recognised."""

_MAGIC = (
    (b"\x76\x2f\x31\x01", "exr"),
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"\xff\xd8\xff", "jpeg"),
    (b"PK\x03\x04", "npz"),
    (b"PK\x05\x06", "npz"),  # an empty zip archive
    (b"# vtk DataFile", "vtk"),
    (b"$MeshFormat", "gmsh"),
    (b"\x89HDF\r\n\x1a\n", "hdf5"),
)
HEAD_BYTES = 1024
"""Bytes read to recognise a file (XML formats name their root element within them)."""


def sniff_bytes(head: bytes) -> str | None:
    """The kind of a file starting with ``head`` (its first ``HEAD_BYTES``): one of ``IMAGE_KINDS``, "npz" (any zip
    archive) or one of ``FEM_KINDS``; None when the bytes match none of them."""
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith(b"<"):
        if b"<VTKFile" in head and b"UnstructuredGrid" in head:
            return "vtu"
        if b"<Xdmf" in head:
            return "xdmf"
    return None


def sniff(path: str | os.PathLike) -> str | None:
    """``sniff_bytes`` of the file's first bytes; None when it cannot be read (the reader then says why)."""
    try:
        with open(path, "rb") as f:
            return sniff_bytes(f.read(HEAD_BYTES))
    except OSError:
        return None


def file_kind(path: str | os.PathLike) -> str | None:
    """The kind by content (``sniff``), else by extension (``EXTENSIONS``), else None."""
    return sniff(path) or EXTENSIONS.get(Path(path).suffix.lower())
