"""Parsing IIIF Image API 3.0 requests and writing info.json (no server)."""

import pytest

from dfc.serve.iiif import IIIFError, Limits, info, parse_image_request

W, H = 1000, 600
LIMITS = Limits(max_width=800, max_height=800, max_area=400 * 400)


def parse(region, size="max", rotation="0", qf="default.png"):
    return parse_image_request(region, size, rotation, qf, W, H, LIMITS)


@pytest.mark.parametrize("region, box", [
    ("full", (0, 0, W, H)),
    ("square", (200, 0, 600, 600)),
    ("10,20,30,40", (10, 20, 30, 40)),
    ("990,590,100,100", (990, 590, 10, 10)),  # clipped to the image
    ("pct:10,50,20,50", (100, 300, 200, 300)),
    ("pct:0.5,0,1.5,100", (5, 0, 15, 600)),
])
def test_regions(region, box):
    assert parse(region, "^max").region == box


@pytest.mark.parametrize("region, size, out", [
    ("0,0,400,200", "200,", (200, 100)),
    ("0,0,400,200", ",50", (100, 50)),
    ("0,0,400,200", "100,30", (100, 30)),  # w,h may distort
    ("0,0,400,200", "!100,100", (100, 50)),
    ("0,0,400,200", "pct:25", (100, 50)),
    ("0,0,400,200", "max", (400, 200)),
    ("full", "max", (516, 309)),  # max stays within maxArea: 159,444 pixels
    ("0,0,10,10", "^200,", (200, 200)),
    ("0,0,10,10", "^max", (400, 400)),
    ("0,0,10,1", "5,", (5, 1)),  # a side from the aspect ratio is at least one pixel
])
def test_sizes(region, size, out):
    assert parse(region, size).size == out


@pytest.mark.parametrize("region, size, rotation, qf, status, words", [
    ("full", "max", "90", "default.png", 400, "rotation"),
    ("full", "max", "!0", "default.png", 400, "rotation"),
    ("full", "max", "0", "gray.png", 400, "quality"),
    ("full", "max", "0", "default.gif", 400, "format"),
    ("full", "max", "0", "default", 400, "quality.format"),
    ("1000,0,10,10", "max", "0", "default.png", 400, "outside"),
    ("0,0,0,10", "max", "0", "default.png", 400, "empty"),
    ("-1,0,10,10", "max", "0", "default.png", 400, "region"),
    ("1e3,0,10,10", "max", "0", "default.png", 400, "region"),
    ("0,0,10", "max", "0", "default.png", 400, "region"),
    ("pct:50,50,-1,1", "max", "0", "default.png", 400, "region"),
    ("fulll", "max", "0", "default.png", 400, "region"),
    ("0,0,10,10", "20,", "0", "default.png", 400, "^"),  # upscaling needs ^
    ("0,0,10,10", ",", "0", "default.png", 400, "size"),
    ("0,0,10,10", "0,5", "0", "default.png", 400, "empty"),
    ("0,0,10,10", "!5,", "0", "default.png", 400, "both"),
    ("0,0,10,10", "pct:0", "0", "default.png", 400, "empty"),
    ("0,0,10,10", "big", "0", "default.png", 400, "size"),
    ("full", "900,", "0", "default.png", 413, "limits"),
    ("full", "500,400", "0", "default.png", 413, "limits"),  # 200,000 pixels > maxArea
])
def test_errors(region, size, rotation, qf, status, words):
    with pytest.raises(IIIFError) as e:
        parse(region, size, rotation, qf)
    assert e.value.status == status and words in str(e.value)


def test_info_document():
    doc = info("/iiif/x", 262144, 131072, [1, 2, 4], 256, LIMITS)
    assert doc["@context"] == "http://iiif.io/api/image/3/context.json"
    assert doc["type"] == "ImageService3" and doc["protocol"] == "http://iiif.io/api/image"
    assert doc["profile"] == "level1" and doc["id"] == "/iiif/x"
    assert (doc["width"], doc["height"]) == (262144, 131072)
    assert doc["tiles"] == [{"width": 256, "height": 256, "scaleFactors": [1, 2, 4]}]
    assert (doc["maxWidth"], doc["maxHeight"], doc["maxArea"]) == (800, 800, 160000)
    assert "png" in doc["extraFormats"] and "regionByPct" in doc["extraFeatures"]
    static = info("tiles", 512, 256, [1, 2], 256, level0=True)
    assert static["profile"] == "level0" and "maxWidth" not in static
    assert static["sizes"] == [{"width": 256, "height": 128}]
