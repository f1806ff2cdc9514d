"""Rendering a file into an image file region by region: the same pixels tiled or scanline, in one process or in
two, anti-aliased or not, huge sizes written tiled, PNG refused above its limit, a worker that dies stopping the
decode."""

import json
import sys

import numpy as np
import OpenEXR
import pytest

from dfc.codec import load
from dfc.errors import InputError
from dfc.io.bands import ExrBands
from dfc.io.image import read_image
from dfc.render import render, render_region
from dfc.render_file import write_render

from .cli.test_cli import assert_one_line_error, run
from .conftest import SAMPLES
from .train.test_distributed import kill_a_child

DFIELD = SAMPLES / "sample.dfield"


@pytest.fixture(scope="module")
def model():
    return load(DFIELD)


def test_tiled_and_scanline_hold_the_render(model, tmp_path):
    window = (100.0, 40.0, 160.0, 90.0)
    direct = render(model, 300, 250, window)
    for tiled in (True, False):
        out = tmp_path / f"{tiled}.exr"
        layout = write_render(model, out, (300, 250), window, half=False, tiled=tiled)
        assert layout == ("tiled" if tiled else "scanline")
        with OpenEXR.File(str(out), header_only=True) as f:
            assert (f.header()["type"] == OpenEXR.tiledimage) == tiled
        np.testing.assert_array_equal(read_image(out).pixels, direct)


def test_two_workers_write_the_same_tiles_as_one(model, tmp_path):
    one, two = tmp_path / "one.exr", tmp_path / "two.exr"
    done = []
    write_render(model, one, (600, 520), (0, 0, 256, 256), tiled=True)
    write_render(model, two, (600, 520), (0, 0, 256, 256), tiled=True, workers=2, source=DFIELD,
                 callback=lambda k, n: done.append((k, n)))
    assert one.read_bytes() == two.read_bytes()
    assert done[-1][0] == done[-1][1] == len(done) > 1


def test_anti_aliased_pixels_do_not_depend_on_how_the_render_is_cut(model, tmp_path):
    """``edge_spp`` on the region renderer: any cut into regions, tiles or scanline blocks, one process or two, gives
    the pixels of the whole anti-aliased render, which differ from the plain one only where a curve crosses."""
    from dfc.geometry.pixels import edge_pixels

    size, window = (600, 520), (0.0, 0.0, 256.0, 256.0)
    direct = render(model, *size, window, edge_spp=16)
    plain = render(model, *size, window)
    mixed = edge_pixels(model.field.mesh, size[1], size[0], window)
    changed = np.any(direct != plain, axis=2)
    assert changed.any() and not (changed & ~mixed).any()
    rows, cols = (0, 13, 200, 520), (0, 77, 600)
    pieces = [[render_region(model, *size, window, rows=(r0, r1), cols=(c0, c1), edge_spp=16, max_points=5000)
               for c0, c1 in zip(cols, cols[1:])] for r0, r1 in zip(rows, rows[1:])]
    np.testing.assert_array_equal(np.concatenate([np.concatenate(row, axis=1) for row in pieces]), direct)
    outputs = {}
    for tiled, workers in ((True, 1), (False, 1), (True, 2)):
        out = outputs[tiled, workers] = tmp_path / f"{tiled}{workers}.exr"
        write_render(model, out, size, window, half=False, tiled=tiled, edge_spp=16, workers=workers, source=DFIELD)
        np.testing.assert_array_equal(read_image(out).pixels, direct)
    assert outputs[True, 1].read_bytes() == outputs[True, 2].read_bytes()


@pytest.mark.parametrize("size", ["300x200", "200x150"])  # 200x150: below the input's resolution, anti-aliased
def test_cli_decode_workers_write_the_same_rows(tmp_path, capsys, size):
    one, two = tmp_path / "one.png", tmp_path / "two.png"
    for out, workers in ((one, 1), (two, 2)):
        code, stdout, err = run(["decode", DFIELD, "-o", out, "--size", size, "--workers", workers, "-q", "--json",
                                 tmp_path / f"{workers}.json"], capsys)
        assert code == 0, err
        record = json.loads((tmp_path / f"{workers}.json").read_text())
        assert record["pixel_filter"] == ("box" if size == "200x150" else "point") and record["edge_spp"] == 0
    np.testing.assert_array_equal(read_image(one).pixels, read_image(two).pixels)
    code, _, err = run(["decode", DFIELD, "-o", one, "--workers", "0"], capsys)
    assert code == 2 and "--workers" in err


def test_wider_than_a_scanline_file_is_tiled_and_png_refused(model, tmp_path, capsys):
    out = tmp_path / "wide.exr"
    code, stdout, err = run(["decode", DFIELD, "-o", out, "--size", "70000x2", "-q"], capsys)
    assert code == 0, err
    assert "(tiled EXR)" in stdout
    bands = ExrBands(out)
    assert (bands.width, bands.height, bands.tiled) == (70000, 2, True)
    row = bands.rows(0, 2)
    np.testing.assert_allclose(row[:, ::1000], render(model, 70000, 2)[:, ::1000], atol=2e-3)  # half floats
    code, _, err = run(["decode", DFIELD, "-o", tmp_path / "wide.png", "--size", "70000x2"], capsys)
    assert code == 2 and "PNG output stops there" in err
    with pytest.raises(InputError, match="PNG output is limited"):
        write_render(model, tmp_path / "w.png", (70000, 2), (0, 0, 256, 256))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wide.exr"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the workers through /proc")
def test_a_render_worker_that_dies_stops_the_decode_with_one_line_and_no_output(tmp_path):
    out = tmp_path / "big.exr"
    proc, _, stdout, stderr = kill_a_child(["decode", DFIELD, "-o", out, "--size", "20000x20000", "--workers", "2",
                                            "-q"], 0, 2.0)  # 2 s: the workers render
    assert_one_line_error(proc.returncode, stderr, "a render worker died")
    assert stdout == "" and list(tmp_path.iterdir()) == []  # no output, no temporary file
