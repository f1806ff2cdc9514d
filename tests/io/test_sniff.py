"""Inputs recognised by content (magic bytes), the extension as fallback; a valid file under the wrong name reads."""

import shutil

import meshio
import numpy as np
import pytest

from dfc.cli.encode import input_kind
from dfc.io.fem import read_fem
from dfc.io.image import read_image, write_exr, write_png
from dfc.io.samples import SampleSet, write_samples
from dfc.io.sniff import file_kind, sniff, sniff_bytes

from ..conftest import SAMPLES


@pytest.mark.parametrize("head,kind", [
    (b"\x76\x2f\x31\x01\x02\x00\x00\x00", "exr"),
    (b"\x89PNG\r\n\x1a\n\x00\x00", "png"),
    (b"\xff\xd8\xff\xe0\x00\x10JFIF", "jpeg"),
    (b"PK\x03\x04\x14\x00", "npz"),
    (b"# vtk DataFile Version 5.1\nvtk output\nASCII", "vtk"),
    (b'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0">', "vtu"),
    (b'<?xml version="1.0" ?>\n<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n<Xdmf Version="3.0">', "xdmf"),
    (b"$MeshFormat\n4.1 0 8\n", "gmsh"),
    (b"\x89HDF\r\n\x1a\n", "hdf5"),
    (b'<?xml version="1.0"?>\n<VTKFile type="PolyData">', None),
    (b"hello", None),
    (b"", None),
])
def test_magic_bytes(head, kind):
    assert sniff_bytes(head) == kind


def test_content_wins_over_the_extension_and_the_extension_is_the_fallback(tmp_path):
    exr = tmp_path / "render.bin"
    write_exr(tmp_path / "r.exr", np.full((4, 5, 3), 2.5, np.float32), ["R", "G", "B"])
    shutil.copy(tmp_path / "r.exr", exr)
    assert sniff(exr) == "exr" and file_kind(exr) == "exr"
    image = read_image(exr)
    assert image.hdr and image.pixels.shape == (4, 5, 3) and image.pixels.max() == 2.5
    png_named_exr = tmp_path / "photo.exr"
    write_png(tmp_path / "p.png", np.full((3, 2, 3), 0.5, np.float32))
    shutil.copy(tmp_path / "p.png", png_named_exr)
    assert file_kind(png_named_exr) == "png" and not read_image(png_named_exr).hdr
    truncated = tmp_path / "cut.exr"
    truncated.write_bytes(b"\x00" * 8)  # the magic bytes are gone: the extension decides, the EXR reader refuses
    assert sniff(truncated) is None and file_kind(truncated) == "exr"
    assert file_kind(tmp_path / "missing.npz") == "npz" and file_kind(tmp_path / "x.unknown") is None


def test_encode_input_kind_by_content(tmp_path):
    """The issue's case: a valid EXR without its extension was reported as "not a mesh meshio can read"."""
    shutil.copy(SAMPLES / "sample.exr", tmp_path / "sample")
    assert input_kind((str(tmp_path / "sample"),), None) == "image"
    rng = np.random.default_rng(0)
    write_samples(tmp_path / "s.npz", SampleSet(rng.random((10, 2)), rng.random((10, 1)).astype(np.float32)))
    shutil.copy(tmp_path / "s.npz", tmp_path / "walks.dat")
    assert input_kind((str(tmp_path / "walks.dat"),), None) == "samples"
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))],
                                                 point_data={"u": np.array([0.0, 1.0, 2.0])}))
    shutil.copy(tmp_path / "m.vtu", tmp_path / "solution.dat")
    assert input_kind((str(tmp_path / "solution.dat"),), None) == "fem"
    assert read_fem(tmp_path / "solution.dat").channels == ["u"]  # meshio is told the format found by content
    assert input_kind((str(tmp_path / "sample"), str(SAMPLES / "sample.exr")), [0.0, 1.0]) == "frames"


@pytest.mark.parametrize("head,kind", [
    (b'{"format": "dfc-curves/1"}', "json"),
    (b'\xef\xbb\xbf  {"a": 1}', "json"),
    (b'<?xml version="1.0"?>\n<!-- made by hand -->\n<!DOCTYPE svg>\n<svg xmlns="http://www.w3.org/2000/svg">', "svg"),
    (b"<svg:svg xmlns:svg='http://www.w3.org/2000/svg'>", "svg"),
    (b'<curve_set image_width="4" image_height="4">', "dcxml"),
    (b'<scene image_width="512" image_height="512">', "dcxml"),
    (b'<?xml version="1.0"?>\n<scene version="3.0.0">\n<shape type="sphere"/>', "mitsuba"),
    (b"<html><body/></html>", None),
    (b"[1, 2, 3]", None),
])
def test_curves_and_scenes_by_content(head, kind):
    assert sniff_bytes(head) == kind


def test_one_sniffer_for_curves_scenes_and_images(tmp_path):
    """Content decides for curves files and for ``dfc curves``' inputs too; the extension only when the content
    says nothing."""
    from dfc.cli.curves import _is_image, _is_scene
    from dfc.errors import CurveError
    from dfc.geometry.sources import read_curves

    json_named_svg = tmp_path / "curves.svg"
    shutil.copy(SAMPLES / "sample.json", json_named_svg)
    assert file_kind(json_named_svg) == "json"
    assert read_curves(json_named_svg).n_curves == read_curves(SAMPLES / "sample.json").n_curves
    scene = tmp_path / "scene.txt"
    scene.write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    with pytest.raises(CurveError, match="Mitsuba 3 scene"):
        read_curves(scene)
    assert _is_scene(scene) and not _is_image(scene)
    png_named_dat = tmp_path / "photo.dat"
    write_png(png_named_dat, np.full((3, 2, 3), 0.5, np.float32))
    assert _is_image(png_named_dat) and not _is_scene(png_named_dat)
    image_named_xml = tmp_path / "photo.xml"
    shutil.copy(png_named_dat, image_named_xml)
    assert _is_image(image_named_xml) and not _is_scene(image_named_xml)
    damaged = tmp_path / "damaged.xml"
    damaged.write_bytes(b"\x00" * 16)  # nothing to recognise: the extension decides
    assert file_kind(damaged) == "xml" and _is_scene(damaged)
