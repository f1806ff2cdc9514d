"""What an input file holds, told by its first bytes (magic numbers, a JSON object, an XML root element), with the
extension as fallback: the one sniffer every reader and command uses (images, sample sets, FEM meshes, curves files,
scenes).

Content decides, so a valid EXR named ``render.bin`` is read as an EXR and JSON curves named ``c.svg`` as JSON; the
extension decides only when the content says nothing (a damaged file whose first bytes are gone, or XML whose root
element names no known format, still gets the reader, and the error, of its extension).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["CURVE_KINDS", "FEM_KINDS", "IMAGE_KINDS", "EXTENSIONS", "XML_KINDS", "file_kind", "sniff", "sniff_bytes"]

IMAGE_KINDS = ("exr", "png", "jpeg")
CURVE_KINDS = ("svg", "json", "dcxml")
"""Curves files (spec/curves.md): SVG, dfc's JSON curves, diffusion-curve XML (root ``<curve_set>``, or ``<scene>``
with the image size)."""
XML_KINDS = ("svg", "dcxml", "mitsuba", "xml")
"""XML documents: by their root element ("mitsuba": a Mitsuba 3 scene, ``<scene version=…>``), or "xml" by the
extension alone."""
FEM_KINDS = ("vtk", "vtu", "xdmf", "gmsh", "hdf5")
"""Mesh formats recognised by content; each name is also meshio's ``file_format`` (``hdf5`` excepted: by
extension)."""

EXTENSIONS = {".exr": "exr", ".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".npz": "npz", ".vtk": "vtk",
              ".vtu": "vtu", ".xdmf": "xdmf", ".xmf": "xdmf", ".msh": "gmsh", ".svg": "svg", ".json": "json",
              ".xml": "xml"}
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
HEAD_BYTES = 4096
"""Bytes read to recognise a file (XML formats name their root element within them, after any prolog)."""
_PROLOG = re.compile(rb"<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>", re.S)
_ROOT = re.compile(rb"<([A-Za-z_][\w.:-]*)([^>]*)>?")


def sniff_bytes(head: bytes) -> str | None:
    """The kind of a file starting with ``head`` (its first ``HEAD_BYTES``): one of ``IMAGE_KINDS``, "npz" (any zip
    archive), one of ``FEM_KINDS``, "json" (a JSON object), or by the root element of an XML document "vtu",
    "xdmf", "svg", "dcxml" or "mitsuba"; None when the bytes match none of them (XML with another root element
    included)."""
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith(b"{"):
        return "json"
    if not text.startswith(b"<"):
        return None
    if b"<VTKFile" in head and b"UnstructuredGrid" in head:
        return "vtu"
    if b"<Xdmf" in head:
        return "xdmf"
    root = _ROOT.match(_PROLOG.sub(b"", text).lstrip())
    tag, attributes = (root.group(1).rpartition(b":")[2], root.group(2)) if root else (b"", b"")
    if tag == b"svg":
        return "svg"
    if tag == b"curve_set" or (tag == b"scene" and b"image_width" in attributes):
        return "dcxml"
    if tag == b"scene" and re.search(rb"\bversion\s*=", attributes):
        return "mitsuba"
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
