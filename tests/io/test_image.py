import struct
import zlib

import numpy as np
import OpenEXR
import pytest
from PIL import Image as PILImage

from dfc.errors import InputError
from dfc.io.image import (
    ExrBlockWriter,
    PngBlockWriter,
    linear_to_srgb,
    read_image,
    srgb_to_linear,
    tonemap,
    write_exr,
    write_png,
)


def _ramp(h=19, w=23, c=3, scale=1.0):
    y, x = np.mgrid[0:h, 0:w]
    planes = [(x + 2 * y + 7 * k) / (w + 2 * h + 7 * c) * scale for k in range(c)]
    return np.stack(planes, -1).astype(np.float32)


@pytest.mark.parametrize("half", [True, False])
def test_exr_round_trip(tmp_path, half):
    px = _ramp(scale=37.0)
    write_exr(tmp_path / "a.exr", px, ["R", "G", "B"], half=half)
    im = read_image(tmp_path / "a.exr")
    assert im.channels == ["R", "G", "B"] and im.hdr
    expect = px.astype(np.float16).astype(np.float32) if half else px
    np.testing.assert_array_equal(im.pixels, expect)
    assert im.pixels.dtype == np.float32 and im.pixels.flags.c_contiguous


def test_exr_named_channels(tmp_path):
    px = _ramp(c=4)
    write_exr(tmp_path / "a.exr", px, ["depth", "R", "G", "B"], half=False)
    assert read_image(tmp_path / "a.exr").channels == ["R", "G", "B"]  # default: RGB when present
    im = read_image(tmp_path / "a.exr", channels=["depth", "G"])
    np.testing.assert_array_equal(im.pixels, px[..., [0, 2]])
    write_exr(tmp_path / "b.exr", px[..., :2], ["u", "v"], half=False)
    assert read_image(tmp_path / "b.exr").channels == ["u", "v"]  # no RGB: every channel
    with pytest.raises(InputError, match=r"\['Z'\] not in the file"):
        read_image(tmp_path / "a.exr", channels=["Z"])


def test_exr_alpha_kept_by_default(tmp_path):
    write_exr(tmp_path / "a.exr", _ramp(c=4), ["R", "G", "B", "A"])
    assert read_image(tmp_path / "a.exr").channels == ["R", "G", "B", "A"]


@pytest.mark.parametrize("data", [((2, 3), (5, 7)), ((-2, 6), (3, 12))])
def test_exr_data_window_placed_in_display_window(tmp_path, data):
    (x0, y0), (x1, y1) = data
    vals = np.arange((y1 - y0 + 1) * (x1 - x0 + 1), dtype=np.float32).reshape(y1 - y0 + 1, x1 - x0 + 1) + 1
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "dataWindow": data,
        "displayWindow": ((0, 0), (9, 8)),
    }
    with OpenEXR.File(header, {"Y": vals}) as f:
        f.write(str(tmp_path / "w.exr"))
    im = read_image(tmp_path / "w.exr")
    assert im.pixels.shape == (9, 10, 1)
    expect = np.zeros((9, 10), np.float32)
    full = np.zeros((40, 40), np.float32)  # paint the data window on a big canvas offset by 20
    full[20 + y0 : 21 + y1, 20 + x0 : 21 + x1] = vals
    expect[:] = full[20:29, 20:30]
    np.testing.assert_array_equal(im.pixels[..., 0], expect)


def test_nan_pixels_rejected_with_location(tmp_path):
    px = _ramp()
    px[4, 7, 1] = np.nan
    px[10, 2, 0] = np.inf
    write_exr(tmp_path / "n.exr", px, ["R", "G", "B"], half=False)
    with pytest.raises(InputError, match=r"2 NaN/Inf sample\(s\); the first at row 4, column 7, channel 'G'"):
        read_image(tmp_path / "n.exr")


@pytest.mark.shared
def test_damaged_exr_files_raise_input_error(shared_data, tmp_path):
    files = sorted(p for p in (shared_data / "exr" / "damaged").iterdir() if p.is_file())
    assert len(files) > 100
    for p in files:
        link = tmp_path / f"{p.name}.exr"
        link.symlink_to(p)
        with pytest.raises(InputError):
            read_image(link)


@pytest.mark.shared
def test_reference_exr(shared_data):
    im = read_image(shared_data / "exr" / "RgbRampsDiagonal.exr")
    assert im.pixels.shape == (800, 800, 3) and im.channels == ["R", "G", "B"]
    assert im.pixels.max() == pytest.approx(18.0)


def test_absurd_exr_size_refused_before_reading(tmp_path):
    write_exr(tmp_path / "a.exr", _ramp(), ["R", "G", "B"])
    data = bytearray((tmp_path / "a.exr").read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at : at + 16] = struct.pack("<iiii", 0, 0, 70_000, 18)  # same chunk count, too wide
    (tmp_path / "big.exr").write_bytes(bytes(data))
    with pytest.raises(InputError, match="outside the supported range"):
        read_image(tmp_path / "big.exr")


def test_srgb_transfer_function():
    # IEC 61966-2-1 reference points
    np.testing.assert_allclose(srgb_to_linear(np.array([0.0, 0.04045, 0.5, 1.0])), [0, 0.04045 / 12.92, 0.21404114, 1], rtol=1e-6)
    s = np.linspace(0, 1, 101)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(s)), s, atol=1e-6)
    np.testing.assert_allclose(tonemap(np.array([0.0, 1.0, 3.0, -1.0])), [0, 0.5, 0.75, 0])


def test_png_read_is_linear(tmp_path):
    grey = np.full((3, 5), 128, np.uint8)
    PILImage.fromarray(np.stack([grey, grey // 2, grey * 0], -1)).save(tmp_path / "a.png")
    im = read_image(tmp_path / "a.png")
    assert im.channels == ["R", "G", "B"] and not im.hdr
    decode = lambda s: ((s / 255 + 0.055) / 1.055) ** 2.4
    np.testing.assert_allclose(im.pixels[0, 0], [decode(128), decode(64), 0], rtol=1e-5)


def test_png_16bit_grey_and_alpha(tmp_path):
    PILImage.fromarray(np.full((2, 3), 65535, np.uint16)).save(tmp_path / "g.png")
    im = read_image(tmp_path / "g.png")
    assert im.channels == ["Y"] and im.pixels.shape == (2, 3, 1)
    np.testing.assert_allclose(im.pixels, 1.0)
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., 3] = 51
    PILImage.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    im = read_image(tmp_path / "a.png")
    assert im.channels == ["R", "G", "B", "A"]
    np.testing.assert_allclose(im.pixels[..., 3], 0.2, rtol=1e-6)  # alpha is not sRGB-decoded


def test_jpeg_read(tmp_path):
    PILImage.fromarray(np.full((8, 8), 200, np.uint8)).save(tmp_path / "a.jpg", quality=95)
    im = read_image(tmp_path / "a.jpg")
    assert im.channels == ["Y"]
    np.testing.assert_allclose(im.pixels, srgb_to_linear(np.float32(200 / 255)), atol=0.01)


def test_png_write_round_trip(tmp_path):
    px = _ramp(c=3)
    write_png(tmp_path / "a.png", px)
    back = read_image(tmp_path / "a.png").pixels
    # 8-bit sRGB steps are ≤ 1/255 in sRGB, so ≤ 0.0155 in linear near 1
    np.testing.assert_allclose(back, px, atol=0.016)
    stored = np.asarray(PILImage.open(tmp_path / "a.png"))
    np.testing.assert_array_equal(stored, np.rint(linear_to_srgb(px) * 255))


def test_png_write_hdr_tonemaps(tmp_path):
    px = np.full((2, 2, 3), 3.0, np.float32)
    write_png(tmp_path / "h.png", px, hdr=True)
    stored = np.asarray(PILImage.open(tmp_path / "h.png"))
    assert (stored == np.rint(linear_to_srgb(np.float32(0.75)) * 255)).all()


def test_unsupported_and_unreadable(tmp_path):
    (tmp_path / "a.tif").write_bytes(b"II*\0")
    with pytest.raises(InputError, match="unsupported image: the content is not EXR, PNG or JPEG"):
        read_image(tmp_path / "a.tif")
    with pytest.raises(InputError, match="no such image file"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(InputError, match="not a readable PNG"):
        read_image(tmp_path / "junk.png")
    (tmp_path / "junk.exr").write_bytes(b"v/1\x01" + bytes(40))
    with pytest.raises(InputError, match="OpenEXR"):
        read_image(tmp_path / "junk.exr")


def test_absurd_png_size_refused(tmp_path):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 0, 0, 0, 0)
    (tmp_path / "big.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    with pytest.raises(InputError, match="outside the supported range"):
        read_image(tmp_path / "big.png")


@pytest.mark.parametrize("half", [True, False])
def test_exr_block_writer_matches_openexr_reader(tmp_path, half):
    rng = np.random.default_rng(0)
    px = (rng.random((37, 29, 3)) * 50).astype(np.float32)
    px[:, :, 1] = np.linspace(0, 1, 29)  # a smooth channel: ZIP actually compresses
    with ExrBlockWriter(tmp_path / "b.exr", 29, 37, ["Z", "B", "a"], half=half) as w:
        for y in range(0, 37, 7):  # blocks not aligned with the 16-row chunks
            w.write_rows(y, px[y : y + 7])
    im = read_image(tmp_path / "b.exr", channels=["Z", "B", "a"])
    expect = px.astype(np.float16).astype(np.float32) if half else px
    np.testing.assert_array_equal(im.pixels, expect)


def test_block_writers_refuse_bad_order_and_incomplete(tmp_path):
    px = _ramp(h=8, w=4)
    with pytest.raises(ValueError, match="in order"), ExrBlockWriter(tmp_path / "a.exr", 4, 8, ["R", "G", "B"]) as w:
        w.write_rows(4, px[4:])
    with pytest.raises(ValueError, match="only 4 of 8 rows"), PngBlockWriter(tmp_path / "a.png", 4, 8, 3) as w:
        w.write_rows(0, px[:4])
    assert list(tmp_path.iterdir()) == []  # atomic: nothing left behind


@pytest.mark.parametrize("channels,hdr", [(1, False), (2, False), (3, False), (4, True)])
def test_png_block_writer_matches_write_png(tmp_path, channels, hdr):
    px = _ramp(h=21, w=17, c=channels, scale=3.0 if hdr else 1.0)
    with PngBlockWriter(tmp_path / "b.png", 17, 21, channels, hdr=hdr) as w:
        for y in range(0, 21, 5):
            w.write_rows(y, px[y : y + 5])
    write_png(tmp_path / "a.png", px, hdr=hdr)
    np.testing.assert_array_equal(np.asarray(PILImage.open(tmp_path / "b.png")), np.asarray(PILImage.open(tmp_path / "a.png")))
