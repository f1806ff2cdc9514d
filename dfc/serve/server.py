"""The tile server behind ``dfc serve`` and ``dfc view``: IIIF Image API 3.0 images of the named files (and of the
rasters to compare them with), the viewer page and its two small JSON endpoints, on the standard library's threading
HTTP server.

URLs (``ID``: a file's identifier, ``dfc.serve.sources.identifiers``; a compare raster's is ``ID-compare``):

- ``/`` the viewer (``?file=ID`` picks a file, ``&compare=1`` opens the side-by-side view); ``/static/NAME`` its
  files, read from the package once at start;
- ``/iiif/ID`` (303 to ``info.json``), ``/iiif/ID/info.json``, ``/iiif/ID/REGION/SIZE/ROTATION/QUALITY.FORMAT``;
- ``/api/files``: the files, their grids and IIIF URLs; ``/api/value/ID?x=X&y=Y``: the decoded value at a domain
  point; ``/api/curves/ID``: the file's curves.

Safety: no request path reaches the file system (sources and static files are looked up in dictionaries built at
start); a malformed or unsupported request is a 400 with a JSON body ``{"error": …}``, an output beyond the limits
a 413, an unknown path a 404, anything unexpected a 500 with one line in the log, never a traceback to the client.
Tiles render (and encode) in a pool of ``threads`` threads: at most that many at once, their working memory held by
those threads whatever the number of connections. Encoded tiles are kept in an LRU cache bounded in bytes.
"""

from __future__ import annotations

import json
import math
import mimetypes
import re
import sys
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, unquote, urlsplit

from ..tiles import TILE_SIDE, encode_tile, scale_factors
from .iiif import IIIFError, Limits, info, parse_image_request

__all__ = ["App", "Response", "TileCache", "make_server"]

JSON = "application/json"
JSONLD = 'application/ld+json;profile="http://iiif.io/api/image/3/context.json"'
_HOST = re.compile(r"[A-Za-z0-9.-]{1,253}(:[0-9]{1,5})?|\[[0-9A-Fa-f:.]{2,45}\](:[0-9]{1,5})?")
TILE_TYPES = {"png": "image/png", "jpg": "image/jpeg", "exr": "image/x-exr"}


@dataclass
class Response:
    status: int
    content_type: str
    body: bytes
    headers: dict = field(default_factory=dict)


class TileCache:
    """Encoded tiles, least recently used dropped first, at most ``max_bytes`` of tile bytes in all (0: none kept)."""

    def __init__(self, max_bytes: int):
        self.max_bytes, self.bytes = max_bytes, 0
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self.hits = self.misses = 0

    def get(self, key):
        with self._lock:
            data = self._items.get(key)
            if data is None:
                self.misses += 1
                return None
            self._items.move_to_end(key)
            self.hits += 1
            return data

    def put(self, key, data: bytes) -> None:
        if len(data) > self.max_bytes:
            return
        with self._lock:
            old = self._items.pop(key, None)
            self.bytes += len(data) - (len(old) if old is not None else 0)
            self._items[key] = data
            while self.bytes > self.max_bytes:
                _, dropped = self._items.popitem(last=False)
                self.bytes -= len(dropped)


def _error(status: int, message: str) -> Response:
    return Response(status, JSON, json.dumps({"error": message, "status": status}).encode() + b"\n")


def _json(data, content_type: str = JSON) -> Response:
    return Response(200, content_type, json.dumps(data).encode() + b"\n")


def _static_files() -> dict[str, tuple[bytes, str]]:
    """name (``a/b.png``) → (bytes, content type) of every file under the package's ``static`` folder."""
    out = {}

    def walk(node, prefix):
        for child in node.iterdir():
            name = prefix + child.name
            if child.is_dir():
                walk(child, name + "/")
            else:
                kind = mimetypes.guess_type(child.name)[0] or "application/octet-stream"
                out[name] = (child.read_bytes(), kind + ("; charset=utf-8" if kind.startswith("text/") or
                                                         kind.endswith("javascript") else ""))

    walk(resources.files("dfc.serve") / "static", "")
    return out


class App:
    """Answers a request's path with a ``Response``; no sockets (``make_server`` puts it behind HTTP).

    files : list of (FieldSource, RasterSource or None) pairs; limits : the largest output of one request;
    cache_bytes : the tile cache's bound; threads : tiles rendered at once
    """

    def __init__(self, files, *, limits: Limits | None = None, cache_bytes: int = 256 << 20, threads: int = 1):
        self.files = files
        self.sources = {}
        for source, compare in files:
            self.sources[source.ident] = source
            if compare is not None:
                self.sources[compare.ident] = compare
        self.limits = limits or Limits()
        self.cache = TileCache(cache_bytes)
        self.renders = ThreadPoolExecutor(threads, thread_name_prefix="render")
        self.static = _static_files()

    def close(self) -> None:
        """Stop the render pool: queued renders are dropped, one in progress finishes before this returns (no
        render thread is left running torch while the interpreter exits)."""
        self.renders.shutdown(wait=True, cancel_futures=True)

    def respond(self, target: str, accept: str = "", host: str = "") -> Response:
        """The response to a GET of ``target`` (path and query); ``accept`` and ``host``: the request's headers
        (``info.json``'s ``id`` is an absolute URL on ``host`` when it is a plain host[:port], else a path)."""
        parts = urlsplit(target)
        segments = [unquote(s) for s in parts.path.split("/")[1:]]
        if not segments:
            return _error(404, "no such path")
        if segments in ([""], ["index.html"]):
            body, kind = self.static["viewer.html"]
            return Response(200, kind, body)
        head, rest = segments[0], segments[1:]
        if head == "static" and rest:
            found = self.static.get("/".join(rest))
            return Response(200, found[1], found[0]) if found else _error(404, "no such file")
        if head == "iiif" and rest:
            return self._iiif(rest, accept, host)
        if head == "api" and len(rest) == 1 and rest[0] == "files":
            return _json([self._describe(s, c) for s, c in self.files])
        if head == "api" and len(rest) == 2 and rest[0] in ("value", "curves"):
            source = self.sources.get(rest[1])
            if source is None or not hasattr(source, "curves"):
                return _error(404, f"no file {rest[1]!r}")
            return self._value(source, parse_qs(parts.query)) if rest[0] == "value" else _json(source.curves())
        return _error(404, "no such path")

    def _describe(self, source, compare) -> dict:
        grid = source.grid
        return {"id": source.ident, "name": source.name, "info": f"/iiif/{source.ident}/info.json",
                "domain": list(grid.domain), "width": grid.width, "height": grid.height, "scale": grid.scale,
                "channels": source.channels,
                "compare": None if compare is None else {"id": compare.ident, "name": compare.name,
                                                          "info": f"/iiif/{compare.ident}/info.json"}}

    def _iiif(self, rest: list[str], accept: str, host: str) -> Response:
        source = self.sources.get(rest[0])
        if source is None:
            return _error(404, f"no image {rest[0]!r}")
        grid = source.grid
        if len(rest) == 1:
            return Response(303, JSON, b"", {"Location": f"/iiif/{rest[0]}/info.json"})
        if len(rest) == 2 and rest[1] == "info.json":
            base = f"http://{host}" if _HOST.fullmatch(host) else ""
            doc = info(f"{base}/iiif/{source.ident}", grid.width, grid.height, scale_factors(grid), TILE_SIDE, self.limits)
            return _json(doc, JSONLD if "application/ld+json" in accept else JSON)
        if len(rest) != 5:
            return _error(400, "an image request reads /iiif/ID/REGION/SIZE/ROTATION/QUALITY.FORMAT")
        try:
            request = parse_image_request(*rest[1:], grid.width, grid.height, self.limits)
        except IIIFError as e:
            return _error(e.status, str(e))
        key = (source.ident, request)
        data = self.cache.get(key)
        if data is None:
            data = self.renders.submit(self._render, source, request).result()
            self.cache.put(key, data)
        return Response(200, TILE_TYPES[request.fmt], data, {"Cache-Control": "public, max-age=86400"})

    @staticmethod
    def _render(source, request) -> bytes:
        return encode_tile(source.pixels(request.region, request.size), request.fmt, hdr=source.hdr,
                           channels=source.channels)

    def _value(self, source, query: dict) -> Response:
        try:
            x, y = (float(query[k][0]) for k in ("x", "y"))
        except (KeyError, ValueError):
            return _error(400, "a value request reads /api/value/ID?x=X&y=Y (domain units)")
        if not (math.isfinite(x) and math.isfinite(y)):
            return _error(400, "x and y must be finite numbers")
        d0, e0, d1, e1 = source.grid.domain
        return _json({"x": x, "y": y, "inside": bool(d0 <= x <= d1 and e0 <= y <= e1), "channels": source.channels,
                      "value": source.value(x, y)})


class _Handler(BaseHTTPRequestHandler):
    server_version = "dfc-serve"
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # headers and body leave at once (no 40 ms delayed-ACK stall per response)

    def do_GET(self):
        self._answer(send_body=True)

    def do_HEAD(self):
        self._answer(send_body=False)

    def _answer(self, send_body: bool) -> None:
        try:
            response = self.server.app.respond(self.path, self.headers.get("Accept", ""),
                                               self.headers.get("Host", ""))
        except Exception as e:  # noqa: BLE001 (any failure: a log line, a JSON 500, the server goes on)
            self.log_error("error answering %r: %s: %s", self.path, type(e).__name__, e)
            response = _error(500, "internal error")
        self.send_response(response.status)
        self.send_header("Content-Type", response.content_type)
        self.send_header("Content-Length", str(len(response.body)))
        self.send_header("Access-Control-Allow-Origin", "*")
        for name, value in response.headers.items():
            self.send_header(name, value)
        self.end_headers()
        if send_body:
            self.wfile.write(response.body)

    def log_message(self, format, *args):
        if not self.server.quiet:
            super().log_message(format, *args)

    def log_error(self, format, *args):
        super().log_message(format, *args)  # errors are logged even when quiet


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 64

    def handle_error(self, request, client_address):
        """A client that went away is no error; anything else is one line on stderr, not a traceback."""
        error = sys.exc_info()[1]
        if not isinstance(error, ConnectionError):
            sys.stderr.write(f"dfc serve: error with client {client_address[0]}: {type(error).__name__}: {error}\n")


def make_server(app: App, host: str = "127.0.0.1", port: int = 8000, *, quiet: bool = False) -> ThreadingHTTPServer:
    """A threading HTTP server bound to (host, port) answering with ``app`` (port 0: a free port, see
    ``server.server_address``). Run it with ``serve_forever()``; ``shutdown()`` from another thread stops it."""
    server = _Server((host, port), _Handler)
    server.app, server.quiet = app, quiet
    return server
