"""Real HTTP requests against ``dfc serve``'s server on a free local port (``conftest.server``)."""

import io
import json
import threading

import numpy as np
import pytest
from PIL import Image

from dfc.cli import main

from ..conftest import SAMPLES
from .conftest import LIMITS, get, get_json

SCALE = 1024  # tile grid pixels per input pixel (10 levels beyond the 256 x 256 input)
SIDE = 256 * SCALE


def image(body: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(body)))


def test_info_json(server):
    status, headers, doc = get_json(server, "/iiif/sample/info.json")
    assert status == 200 and headers["content-type"] == "application/json"
    assert headers["access-control-allow-origin"] == "*"
    assert doc["@context"] == "http://iiif.io/api/image/3/context.json" and doc["type"] == "ImageService3"
    host, port, app = server
    assert doc["id"] == f"http://{host}:{port}/iiif/sample" and doc["profile"] == "level1"  # absolute, on Host
    assert app.respond("/iiif/sample/info.json", host="a b/c").body.startswith(b'{"@context"')
    assert json.loads(app.respond("/iiif/sample/info.json", host="a b/c").body)["id"] == "/iiif/sample"
    assert (doc["width"], doc["height"]) == (SIDE, SIDE)  # 1024x deeper than the input's pixels
    assert doc["tiles"][0]["scaleFactors"] == [2 ** k for k in range(11)]  # down to the input's 256 px: one tile
    assert (doc["maxWidth"], doc["maxHeight"], doc["maxArea"]) == (1024, 1024, 512 * 512)
    _, headers, _ = get(server, "/iiif/sample/info.json", {"Accept": "application/ld+json"})
    assert headers["content-type"].startswith("application/ld+json;profile=")
    status, headers, _ = get(server, "/iiif/sample")
    assert status == 303 and headers["location"] == "/iiif/sample/info.json"


@pytest.mark.parametrize("path, mode, size", [
    ("/iiif/sample/full/256,/0/default.png", "RGB", (256, 256)),
    ("/iiif/sample/square/,64/0/default.jpg", "RGB", (64, 64)),
    ("/iiif/sample/194560,46080,2048,1024/!64,64/0/default.png", "RGB", (64, 32)),
    ("/iiif/sample/pct:50,25,10,20/pct:0.1/0/default.png", "RGB", (26, 52)),
    ("/iiif/sample/full/max/0/default.png", "RGB", (512, 512)),  # max is bounded by maxArea
    ("/iiif/sample/0,0,100,50/^200,/0/default.png", "RGB", (200, 100)),
])
def test_regions_and_sizes(server, path, mode, size):
    status, headers, body = get(server, path)
    assert status == 200, body
    assert headers["content-type"] == ("image/png" if path.endswith("png") else "image/jpeg")
    img = Image.open(io.BytesIO(body))
    assert img.mode == mode and img.size == size


@pytest.mark.parametrize("path, status", [
    ("/iiif/sample/full/max/90/default.png", 400),
    ("/iiif/sample/full/max/0/bitonal.png", 400),
    ("/iiif/sample/full/max/0/default.webp", 400),
    ("/iiif/sample/-5,0,10,10/max/0/default.png", 400),
    ("/iiif/sample/0,0,10,10/50,/0/default.png", 400),  # an upscale without ^
    (f"/iiif/sample/{SIDE},0,10,10/max/0/default.png", 400),  # outside the image
    ("/iiif/sample/full/2048,/0/default.png", 413),  # beyond maxWidth
    ("/iiif/sample/full/600,600/0/default.png", 413),  # beyond maxArea
    ("/iiif/sample/full/max/0", 400),
    ("/iiif/sample/full/max/0/default.png/extra", 400),
    ("/iiif/sample/%ff%fe/max/0/default.png", 400),
    ("/iiif/nosuch/info.json", 404),
    ("/iiif/sample/full/max/0/default.png?x=%00", 200),  # a query is ignored
])
def test_errors_are_json(server, path, status):
    got, headers, body = get(server, path)
    assert got == status, body
    if status != 200:
        assert headers["content-type"] == "application/json"
        doc = json.loads(body)
        assert doc["status"] == status and doc["error"] and "Traceback" not in doc["error"]


@pytest.mark.parametrize("path", [
    "/static/../../../../etc/passwd", "/static/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "/static//etc/passwd",
    "/static/..%2f..%2f..%2fetc%2fpasswd", "/iiif/..%2f..%2fsamples%2fsample/info.json", "/../../etc/passwd",
    "/iiif/../samples/sample.dfield", "/samples/sample.dfield", "/static/viewer.js/../../serve/server.py",
    "/api/curves/..%2fsample", "/%2e%2e/dfc/tiles.py", "*", "http://127.0.0.1/../etc/passwd",
])
def test_no_path_reaches_the_file_system(server, path):
    status, _, body = get(server, path)
    assert status in (400, 404), (path, status)
    assert b"root:" not in body and b"import" not in body


def test_viewer_and_static_files(server):
    status, headers, body = get(server, "/")
    assert status == 200 and headers["content-type"].startswith("text/html") and b"openseadragon.min.js" in body
    status, _, body = get(server, "/static/openseadragon.min.js")
    assert status == 200 and b"OpenSeadragon" in body[:2000]
    status, _, body = get(server, "/static/LICENSE-openseadragon.txt")
    assert status == 200 and b"OpenSeadragon contributors" in body
    status, _, files = get_json(server, "/api/files")
    assert files[0]["id"] == "sample" and files[0]["scale"] == SCALE
    assert files[0]["compare"]["info"] == "/iiif/sample-compare/info.json"


@pytest.mark.parametrize("region, size", [
    ((194560, 46080, 2560, 2560), (64, 64)),  # 100x at the triangle's edge: point samples
    ((0, 0, SIDE, SIDE), (128, 128)),  # below the input's resolution: the crossed pixels anti-aliased
])
def test_tiles_equal_dfc_decode_window(server, tmp_path, capsys, region, size):
    x, y, w, h = region
    _, _, body = get(server, f"/iiif/sample/{x},{y},{w},{h}/{size[0]},{size[1]}/0/default.png")
    window = ",".join(repr(v / SCALE) for v in (x, y, x + w, y + h))
    out = tmp_path / "window.png"
    main(["decode", str(SAMPLES / "sample.dfield"), "--window", window, "--size", f"{size[0]}x{size[1]}", "-o",
          str(out), "-q"])
    capsys.readouterr()
    tile, decoded = image(body), np.asarray(Image.open(out))
    assert tile.shape == decoded.shape and np.array_equal(tile, decoded)
    assert len(np.unique(tile.reshape(-1, 3), axis=0)) > 1  # not a flat tile: the window holds the edge


def test_compare_raster_is_the_blurred_input(server):
    region = "194560,46080,2560,2560/64,64/0/default.png"  # 2.5 x 2.5 input pixels across the triangle's edge
    field, raster = (image(get(server, f"/iiif/{ident}/{region}")[2]).astype(float)
                     for ident in ("sample", "sample-compare"))
    c = int(np.argmax(np.ptp(field.reshape(-1, 3), axis=0)))  # the channel with the largest jump
    field, raster = field[..., c], raster[..., c]
    lo, hi = field.min(), field.max()
    between = lambda a: np.mean((a > lo + 0.1 * (hi - lo)) & (a < hi - 0.1 * (hi - lo)))
    # bicubic spreads the edge over pixels the field keeps sharp
    assert between(field) < 0.05 and between(raster) > 4 * between(field)


def test_value_endpoint(server):
    _, _, _app = server
    status, _, doc = get_json(server, "/api/value/sample?x=100.5&y=20.25")
    source = _app.sources["sample"]
    assert status == 200 and doc["inside"] and doc["channels"] == ["R", "G", "B"]
    assert doc["value"] == pytest.approx(source.value(100.5, 20.25))
    assert get_json(server, "/api/value/sample?x=300&y=20")[2]["inside"] is False
    for query in ("x=1", "x=a&y=2", "x=nan&y=1", "x=inf&y=0"):
        status, _, doc = get_json(server, f"/api/value/sample?{query}")
        assert status == 400 and "error" in doc
    assert get(server, "/api/value/sample-compare?x=1&y=1")[0] == 404


def test_curves_endpoint(server):
    status, _, doc = get_json(server, "/api/curves/sample")
    assert status == 200 and doc["domain"] == [0.0, 0.0, 256.0, 256.0]
    segments = np.array(doc["segments"])
    assert segments.shape[1] == 4 and len(doc["cubics"]) > 0
    # the triangle's edge (150, 30)-(230, 60) is made of straight discontinuous edges on its line
    on_line = lambda p: abs((p[:, 0] - 150) * 30 - (p[:, 1] - 30) * 80) / np.hypot(80, 30) < 1e-3
    assert (on_line(segments[:, :2]) & on_line(segments[:, 2:])).sum() >= 1


def test_cache_is_bounded_and_concurrent_requests_agree(server):
    _, _, app = server
    paths = [f"/iiif/sample/{x},{y},2048,2048/64,64/0/default.png" for x in range(0, 40960, 4096) for y in (0, 81920)]
    results = {}

    def fetch(p):
        results[p] = get(server, p)

    threads = [threading.Thread(target=fetch, args=(p,)) for p in paths + paths[:4]]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert all(results[p][0] == 200 for p in paths)
    assert app.cache.bytes <= app.cache.max_bytes
    again = get(server, paths[0])
    assert again[2] == results[paths[0]][2]


def test_limits_fixture_is_the_servers(server):
    assert server[2].limits == LIMITS


def test_exr_tiles_hold_the_decoded_floats(server, tmp_path):
    from dfc.io.image import read_image
    from dfc.tiles import render_tile

    status, headers, body = get(server, "/iiif/sample/194560,46080,2560,2560/32,32/0/default.exr")
    assert status == 200 and headers["content-type"] == "image/x-exr"
    (tmp_path / "t.exr").write_bytes(body)
    tile = read_image(tmp_path / "t.exr")
    source = server[2].sources["sample"]
    assert tile.channels == ["R", "G", "B"]
    assert np.array_equal(tile.pixels, render_tile(source.model, (194560, 46080, 2560, 2560), (32, 32)))
