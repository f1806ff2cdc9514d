"""Out-of-core rasters: EXR files read in bands (scanline and tiled, several compressions, data windows) give the
pixels a whole read gives; damaged, truncated and NaN inputs are one clear error."""

import numpy as np
import OpenEXR
import pytest

from dfc.errors import InputError
from dfc.io.bands import ArrayBands, ExrBands, band_ranges, open_bands
from dfc.io.image import read_image, write_exr

RNG = np.random.default_rng(0)
PIXELS = (RNG.random((67, 45, 3)) * 4).astype(np.float16)


def _write(path, pixels, compression, tiles=None, data_window=None):
    header = {"compression": compression, "type": OpenEXR.tiledimage if tiles else OpenEXR.scanlineimage}
    if tiles:
        td = OpenEXR.TileDescription()
        td.xSize, td.ySize, td.mode = tiles, tiles, OpenEXR.ONE_LEVEL
        header["tiles"] = td
    h, w = pixels.shape[:2]
    if data_window is not None:
        header["dataWindow"] = data_window
        header["displayWindow"] = ((0, 0), (w + 9, h + 6))
    channels = {c: np.ascontiguousarray(pixels[..., k]) for k, c in enumerate("RGB")}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


@pytest.mark.parametrize("compression,tiles", [
    (OpenEXR.NO_COMPRESSION, None), (OpenEXR.ZIP_COMPRESSION, None), (OpenEXR.PIZ_COMPRESSION, None),
    (OpenEXR.DWAA_COMPRESSION, None), (OpenEXR.ZIP_COMPRESSION, 16), (OpenEXR.PIZ_COMPRESSION, 32),
    (OpenEXR.B44_COMPRESSION, 8),
])
def test_bands_give_the_pixels_of_a_whole_read(tmp_path, compression, tiles):
    path = tmp_path / "in.exr"
    _write(path, PIXELS, compression, tiles)
    whole = read_image(path).pixels
    bands = ExrBands(path)
    assert (bands.width, bands.height, bands.channels, bands.tiled) == (45, 67, ["R", "G", "B"], tiles is not None)
    assert bands.chunk_rows == (tiles or {OpenEXR.NO_COMPRESSION: 1, OpenEXR.ZIP_COMPRESSION: 16}.get(compression, 32))
    for rows in (1, 7, 32, 67):
        got = np.concatenate([bands.rows(y0, y1) for y0, y1 in band_ranges(67, rows)])
        np.testing.assert_array_equal(got, whole)


def test_band_rows_follow_the_file_chunks(tmp_path):
    path = tmp_path / "in.exr"
    _write(path, PIXELS, OpenEXR.PIZ_COMPRESSION)
    bands = ExrBands(path)
    assert bands.band_rows(1) == 32  # never less than one chunk
    assert bands.band_rows(45 * 3 * 4 * 100) == 96  # whole chunks


def test_data_window_inside_a_larger_display_window(tmp_path):
    path = tmp_path / "in.exr"
    _write(path, PIXELS, OpenEXR.ZIP_COMPRESSION, data_window=((4, 3), (48, 69)))
    bands = ExrBands(path)
    got = np.concatenate([bands.rows(y0, y1) for y0, y1 in band_ranges(bands.height, 10)])
    np.testing.assert_array_equal(got, read_image(path).pixels)
    np.testing.assert_array_equal(got[3:70, 4:49], PIXELS.astype(np.float32))
    assert not got[:3].any() and not got[:, :4].any()


def test_channels_chosen_and_missing(tmp_path):
    path = tmp_path / "in.exr"
    _write(path, PIXELS, OpenEXR.ZIP_COMPRESSION)
    np.testing.assert_array_equal(ExrBands(path, ["G"]).rows(0, 5)[..., 0], PIXELS[:5, :, 1].astype(np.float32))
    with pytest.raises(InputError, match="not in the file"):
        ExrBands(path, ["Z"])


def test_truncated_file_is_refused_at_open(tmp_path, capfd):
    path = tmp_path / "in.exr"
    write_exr(path, (RNG.random((400, 300, 3))).astype(np.float32), ["R", "G", "B"])
    data = path.read_bytes()
    cut = tmp_path / "cut.exr"
    cut.write_bytes(data[: len(data) // 2])  # a band in the middle of the file is cut
    with pytest.raises(InputError, match="truncated"):
        ExrBands(cut)
    assert capfd.readouterr().err == ""


def test_damaged_chunk_is_one_error_naming_its_rows(tmp_path, capfd):
    path = tmp_path / "in.exr"
    write_exr(path, (RNG.random((400, 300, 3))).astype(np.float32), ["R", "G", "B"])
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = bytes(4000)  # zeroed chunk data, the offset table intact
    path.write_bytes(bytes(data))
    bands = ExrBands(path)
    with pytest.raises(InputError, match="damaged OpenEXR data in rows"):
        for y0, y1 in band_ranges(bands.height, 16):
            bands.rows(y0, y1)
    assert capfd.readouterr().err == ""  # OpenEXR's own messages are in the error, not on stderr


def test_nan_pixels_are_named(tmp_path):
    pixels = RNG.random((40, 30, 3)).astype(np.float32)
    pixels[33, 7, 2] = np.nan
    path = tmp_path / "nan.exr"
    write_exr(path, pixels, ["R", "G", "B"], half=False)
    bands = ExrBands(path)
    bands.rows(0, 32)
    with pytest.raises(InputError, match="row 33, column 7, channel 'B'"):
        bands.rows(32, 40)


def test_not_an_exr_and_missing_file(tmp_path):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"not an exr file at all")
    with pytest.raises(InputError, match="not a readable OpenEXR file"):
        ExrBands(bad)
    with pytest.raises(InputError, match="no such image file"):
        ExrBands(tmp_path / "none.exr")


def test_open_bands_serves_png_from_memory(tmp_path):
    from dfc.io.image import write_png

    pixels = RNG.random((20, 10, 3)).astype(np.float32)
    write_png(tmp_path / "a.png", pixels)
    bands = open_bands(tmp_path / "a.png")
    assert isinstance(bands, ArrayBands) and bands.channels == ["R", "G", "B"]
    np.testing.assert_array_equal(bands.rows(3, 9), read_image(tmp_path / "a.png").pixels[3:9])
