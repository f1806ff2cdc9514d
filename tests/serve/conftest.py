"""A tile server on a free local port, serving the shipped sample (and its input raster to compare), in a thread."""

import http.client
import json
import threading

import pytest
import torch

from dfc.serve.iiif import Limits
from dfc.serve.server import App, make_server
from dfc.serve.sources import FieldSource, RasterSource

from ..conftest import SAMPLES

LIMITS = Limits(max_width=1024, max_height=1024, max_area=512 * 512)


@pytest.fixture(scope="module")
def server():
    """(host, port, app) of a running server; stopped after the module."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    source = FieldSource("sample", SAMPLES / "sample.dfield")
    app = App([(source, RasterSource("sample-compare", SAMPLES / "sample.exr", source))], limits=LIMITS,
              cache_bytes=4 << 20, threads=2)
    srv = make_server(app, "127.0.0.1", 0, quiet=True)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield srv.server_address[0], srv.server_address[1], app
    srv.shutdown()
    srv.server_close()
    thread.join(10)
    torch.set_num_threads(threads)


def get(server, path: str, headers=None):
    """(status, headers dict, body bytes) of a GET of the raw ``path`` (sent as is: no client-side normalising)."""
    host, port, _ = server
    conn = http.client.HTTPConnection(host, port, timeout=60)
    try:
        conn.request("GET", path, headers=headers or {})
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def get_json(server, path: str):
    status, headers, body = get(server, path)
    return status, headers, json.loads(body)
