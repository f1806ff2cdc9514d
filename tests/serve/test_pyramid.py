"""Static pyramids (``dfc tiles``, ``dfc.pyramid``): the IIIF level 0 and Deep Zoom layouts, tiles equal to the
server's answers to the same requests."""

import io
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from PIL import Image

from dfc.codec import load
from dfc.pyramid import count_tiles, write_pyramid
from dfc.serve.server import App
from dfc.serve.sources import FieldSource
from dfc.tiles import tile_grid

from ..cli.test_cli import assert_one_line_error, run
from ..conftest import SAMPLES

pytestmark = pytest.mark.usefixtures("one_thread")
SAMPLE = SAMPLES / "sample.dfield"


@pytest.fixture(scope="module")
def model():
    return load(SAMPLE)


def test_iiif_level0_pyramid_holds_the_servers_tiles(model, tmp_path):
    grid = tile_grid(model, 1)  # 512 x 512: two grid pixels per input pixel
    assert (grid.width, grid.height, grid.scale) == (512, 512, 2)
    assert write_pyramid(model, tmp_path, grid, name="sample") == count_tiles(grid, "iiif") == 5
    doc = json.loads((tmp_path / "info.json").read_text())
    assert doc["profile"] == "level0" and doc["id"] == "sample" and (doc["width"], doc["height"]) == (512, 512)
    assert doc["tiles"] == [{"width": 256, "height": 256, "scaleFactors": [1, 2]}]
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*.png"))
    assert written == ["0,0,256,256/256,256/0/default.png", "0,256,256,256/256,256/0/default.png",
                       "256,0,256,256/256,256/0/default.png", "256,256,256,256/256,256/0/default.png",
                       "full/256,256/0/default.png"]  # the URLs OpenSeadragon asks a level 0 IIIF 3 service for
    app = App([(FieldSource("sample", SAMPLE, levels_beyond=1), None)])
    for name in written:
        assert app.respond(f"/iiif/sample/{name}").body == (tmp_path / name).read_bytes(), name


def test_deep_zoom_pyramid(model, tmp_path):
    grid = tile_grid(model, 1)
    n = write_pyramid(model, tmp_path, grid, fmt="dzi", name="sample", tile_format="jpg")
    image = ET.parse(tmp_path / "sample.dzi").getroot()
    ns = "{http://schemas.microsoft.com/deepzoom/2008}"
    assert image.tag == f"{ns}Image" and image.get("Format") == "jpg" and image.get("TileSize") == "256"
    assert image.find(f"{ns}Size").attrib == {"Width": "512", "Height": "512"}
    levels = sorted(int(p.name) for p in (tmp_path / "sample_files").iterdir())
    assert levels == list(range(10))  # 1 x 1 .. 512 x 512
    assert n == 9 + 4
    assert Image.open(tmp_path / "sample_files/0/0_0.jpg").size == (1, 1)
    assert Image.open(tmp_path / "sample_files/8/0_0.jpg").size == (256, 256)
    top = [np.asarray(Image.open(tmp_path / f"sample_files/9/{i}_{j}.jpg")) for j in (0, 1) for i in (0, 1)]
    assert all(t.shape == (256, 256, 3) for t in top)
    whole = np.asarray(Image.open(io.BytesIO(App([(FieldSource("s", SAMPLE, levels_beyond=1), None)]).respond(
        "/iiif/s/256,256,256,256/256,256/0/default.png").body))).astype(int)
    assert np.abs(top[3].astype(int) - whole).mean() < 3  # the same pixels, up to JPEG's loss


def test_tiles_command(tmp_path, capsys):
    out = tmp_path / "pyr"
    code, stdout, err = run(["tiles", SAMPLE, "-o", out, "--format", "dzi", "--levels-beyond", "0", "-q", "--json",
                             tmp_path / "t.json"], capsys)
    assert code == 0, err
    assert "wrote 9 tiles" in stdout and (out / "sample.dzi").exists()
    figures = json.loads((tmp_path / "t.json").read_text())
    assert figures["tiles"] == 9 and figures["index"] == "sample.dzi" and figures["width"] == 256
    code, _, err = run(["tiles", SAMPLE, "-o", tmp_path / "big", "--levels-beyond", "3", "--max-tiles", "10"], capsys)
    assert_one_line_error(code, err, "--max-tiles")
    assert not (tmp_path / "big").exists()
