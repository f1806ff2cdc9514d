"""Tiled EXR output written tile by tile: OpenEXR and the band reader read back what was written."""

import numpy as np
import OpenEXR
import pytest

from dfc.io.bands import ExrBands
from dfc.io.tiled import ExrTileWriter, tile_chunk


@pytest.mark.parametrize("half", [True, False])
@pytest.mark.parametrize("size,tile", [((70, 45), 16), ((64, 64), 64), ((5, 130), 32)])
def test_tiles_read_back(tmp_path, half, size, tile):
    width, height = size
    pixels = (np.random.default_rng(1).random((height, width, 4)) * 5).astype(np.float32)
    pixels[..., 1] = 0.25  # a constant channel compresses; the others are stored raw
    names = ["R", "G", "B", "depth.Z"]
    path = tmp_path / "t.exr"
    with ExrTileWriter(path, width, height, names, half=half, tile=tile) as w:
        for tx, ty, x0, y0, x1, y1 in w.tiles():
            w.write_tile(tx, ty, tile_chunk(pixels[y0:y1, x0:x1], w.order, w.half))
    expect = pixels.astype(np.float16).astype(np.float32) if half else pixels
    with OpenEXR.File(str(path), separate_channels=True) as f:
        assert f.header()["type"] == OpenEXR.tiledimage
        got = np.stack([f.channels()[c].pixels.astype(np.float32) for c in names], axis=-1)
    np.testing.assert_array_equal(got, expect)
    np.testing.assert_array_equal(ExrBands(path, names).rows(0, height), expect)


def test_tiles_out_of_order_or_missing_leave_no_file(tmp_path):
    path = tmp_path / "t.exr"
    block = np.zeros((16, 16, 3), np.float32)
    with pytest.raises(ValueError, match="in order"):
        with ExrTileWriter(path, 32, 32, ["R", "G", "B"], tile=16) as w:
            w.write_tile(1, 0, tile_chunk(block, w.order, True))
    with pytest.raises(ValueError, match="only 1 of 4 tiles"):
        with ExrTileWriter(path, 32, 32, ["R", "G", "B"], tile=16) as w:
            w.write_tile(0, 0, tile_chunk(block, w.order, True))
    assert list(tmp_path.iterdir()) == []
