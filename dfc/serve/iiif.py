"""The IIIF Image API 3.0 (https://iiif.io/api/image/3.0/): parsing an image request's path segments and writing an
image's ``info.json``. Pure functions of strings and sizes; the HTTP server (``dfc.serve.server``) uses them.

Supported: regions ``full``, ``square``, ``x,y,w,h``, ``pct:x,y,w,h``; sizes ``max``, ``w,``, ``,h``, ``w,h``,
``!w,h``, ``pct:n``, each also with ``^`` (upscaling); rotation ``0``; quality ``default``; formats png, jpg and exr
(float32: the decoded values). That is compliance level 1 plus the level-2 region and size features, PNG and EXR
(``info.json`` lists them).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ..errors import InputError

__all__ = ["IIIFError", "ImageRequest", "Limits", "info", "parse_image_request"]

CONTEXT = "http://iiif.io/api/image/3/context.json"
PROFILE = "level1"
FORMATS = ("png", "jpg", "exr")
EXTRA_FEATURES = ["baseUriRedirect", "cors", "jsonldMediaType", "regionByPct", "regionByPx", "regionSquare",
                  "sizeByConfinedWh", "sizeByH", "sizeByPct", "sizeByW", "sizeByWh", "sizeUpscaling"]

_INT = r"(0|[1-9][0-9]{0,15})"
_NUM = r"([0-9]{1,16}(?:\.[0-9]{1,16})?)"
_REGION_PX = re.compile(rf"{_INT},{_INT},{_INT},{_INT}")
_REGION_PCT = re.compile(rf"pct:{_NUM},{_NUM},{_NUM},{_NUM}")
_SIZE_WH = re.compile(rf"(!?){_INT}?,{_INT}?")
_SIZE_PCT = re.compile(rf"pct:{_NUM}")


class IIIFError(InputError):
    """A request the server refuses: ``status`` 400 (malformed or unsupported) or 413 (larger than the limits)."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class Limits:
    """The largest output a request may ask for (``info.json``'s ``maxWidth``, ``maxHeight``, ``maxArea``)."""

    max_width: int = 4096
    max_height: int = 4096
    max_area: int = 2048 * 2048


@dataclass(frozen=True)
class ImageRequest:
    """A parsed image request: ``region`` (x, y, w, h) integer pixels of the full image, clipped to it; ``size``
    (w, h) of the output; ``fmt`` "png" or "jpg"."""

    region: tuple[int, int, int, int]
    size: tuple[int, int]
    fmt: str


def parse_image_request(region: str, size: str, rotation: str, quality_format: str, width: int, height: int,
                        limits: Limits = Limits()) -> ImageRequest:
    """The ``ImageRequest`` of the four path segments after an image's identifier, for a ``width × height`` full
    image. Raises ``IIIFError`` (400: malformed, unsupported, a region outside the image, an upscale without ``^``;
    413: an output beyond ``limits``)."""
    quality, dot, fmt = quality_format.partition(".")
    if not dot:
        raise IIIFError(f"quality and format {quality_format!r} must read quality.format, e.g. default.png")
    if quality != "default":
        raise IIIFError(f"quality {quality!r} is not supported: use default")
    if fmt not in FORMATS:
        raise IIIFError(f"format {fmt!r} is not supported: use {', '.join(FORMATS)}")
    if rotation != "0":
        raise IIIFError(f"rotation {rotation!r} is not supported: use 0")
    box = _region(region, width, height)
    return ImageRequest(box, _size(size, box[2], box[3], limits), fmt)


def _region(text: str, width: int, height: int) -> tuple[int, int, int, int]:
    if text == "full":
        return 0, 0, width, height
    if text == "square":
        side = min(width, height)
        return (width - side) // 2, (height - side) // 2, side, side
    m = _REGION_PX.fullmatch(text)
    if m:
        x, y, w, h = (int(v) for v in m.groups())
    else:
        m = _REGION_PCT.fullmatch(text)
        if not m:
            raise IIIFError(f"region {text!r} must be full, square, x,y,w,h or pct:x,y,w,h")
        px, py, pw, ph = (float(v) for v in m.groups())
        x, y = round(px / 100 * width), round(py / 100 * height)
        w, h = round(pw / 100 * width), round(ph / 100 * height)
    if w <= 0 or h <= 0:
        raise IIIFError(f"region {text!r} is empty")
    if x >= width or y >= height:
        raise IIIFError(f"region {text!r} lies outside the {width}x{height} image")
    return x, y, min(w, width - x), min(h, height - y)


def _size(text: str, rw: int, rh: int, limits: Limits) -> tuple[int, int]:
    upscale = text.startswith("^")
    body = text[1:] if upscale else text
    if body == "max":
        k = min(limits.max_width / rw, limits.max_height / rh, math.sqrt(limits.max_area / (rw * rh)))
        k = k if upscale else min(1.0, k)  # ^max: as large as the limits allow
        return max(1, math.floor(rw * k)), max(1, math.floor(rh * k))
    m = _SIZE_PCT.fullmatch(body)
    if m:
        n = float(m.group(1))
        w, h = round(rw * n / 100), round(rh * n / 100)
    else:
        m = _SIZE_WH.fullmatch(body)
        if not m or (m.group(2) is None and m.group(3) is None):
            raise IIIFError(f"size {text!r} must be max, w,, ,h, w,h, !w,h or pct:n (^ before any to upscale)")
        confined, w, h = m.group(1) == "!", m.group(2), m.group(3)
        if confined and (w is None or h is None):
            raise IIIFError(f"size {text!r}: !w,h needs both a width and a height")
        w, h = (int(w) if w is not None else None), (int(h) if h is not None else None)
        if w == 0 or h == 0:
            raise IIIFError(f"size {text!r} is empty")
        if confined:
            k = min(w / rw, h / rh)
            w, h = round(rw * k), round(rh * k)
        elif w is None:
            w = round(rw * h / rh)
        elif h is None:
            h = round(rh * w / rw)
    if not (w > 0 and h > 0) and m.re is _SIZE_PCT:
        raise IIIFError(f"size {text!r} is empty")
    w, h = max(w, 1), max(h, 1)  # a side computed from the aspect ratio rounds to at least one pixel
    if not upscale and (w > rw or h > rh):
        raise IIIFError(f"size {text!r} ({w}x{h}) is larger than the {rw}x{rh} region: use ^ to upscale")
    if w > limits.max_width or h > limits.max_height or w * h > limits.max_area:
        raise IIIFError(f"size {w}x{h} exceeds this server's limits (maxWidth {limits.max_width}, maxHeight "
                        f"{limits.max_height}, maxArea {limits.max_area})", status=413)
    return w, h


def info(identifier: str, width: int, height: int, scale_factors: list[int], tile: int,
         limits: Limits = Limits(), *, level0: bool = False) -> dict:
    """The ``info.json`` document of a ``width × height`` image served at ``identifier`` (its base URI), tiled
    ``tile × tile`` at ``scale_factors``; ``level0``: a static pyramid of those tiles only."""
    doc = {
        "@context": CONTEXT,
        "id": identifier,
        "type": "ImageService3",
        "protocol": "http://iiif.io/api/image",
        "profile": "level0" if level0 else PROFILE,
        "width": width,
        "height": height,
        "tiles": [{"width": tile, "height": tile, "scaleFactors": list(scale_factors)}],
        "sizes": [{"width": math.ceil(width / s), "height": math.ceil(height / s)} for s in reversed(scale_factors)
                  if math.ceil(width / s) <= tile and math.ceil(height / s) <= tile],
    }
    if level0:
        doc["preferredFormats"] = ["png"]
        doc["extraFormats"] = ["png"]
    else:
        doc.update(maxWidth=limits.max_width, maxHeight=limits.max_height, maxArea=limits.max_area,
                   preferredFormats=["png"], extraFormats=["png", "exr"], extraFeatures=EXTRA_FEATURES)
    return doc
