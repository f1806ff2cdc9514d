"""Units must not matter: every input kind fits the same after an affine change of its values' units
(``dfc.field.units``), and the file returns the values in the data's own units."""

import meshio
import numpy as np
import pytest

from dfc.bench.scenes import get_scene
from dfc.codec import (
    EncodeSettings,
    check_domain,
    encode_bands,
    encode_fem,
    encode_frames,
    encode_image,
    encode_samples,
    loads,
)
from dfc.field.units import choose, describe
from dfc.geometry.sources import read_curves
from dfc.io.bands import ArrayBands
from dfc.io.fem import from_meshio
from dfc.io.frames import FrameSequence
from dfc.io.samples import SampleSet
from dfc.metrics import is_hdr, psnr
from dfc.physics.fem import node_points
from dfc.render import default_edge_spp, render, values_at

from .physics.test_fem import grid_mesh, write_curves

UNITS = [(1e-8, 3e-8), (1e-3, -2e-3), (1e4, 0.0), (1e8, -5e8)]
"""(scale, offset) pairs: the data becomes ``scale · v + offset``."""
SETTINGS = EncodeSettings(steps=60, batch_size=1024, max_triangles=120)
POINTS = EncodeSettings(steps=250, batch_size=1024, max_triangles=120)
"""Sample sets and FEM fits start slower (``dfc.train.fit.SAMPLES_LR``)."""
DB, SIZE = 0.5, 0.02


def _own_range_psnr(truth, decoded) -> float:
    truth = np.asarray(truth, np.float64)
    return psnr(truth, np.asarray(decoded, np.float64), data_range=float(truth.max() - truth.min()))


def _image(values):
    scene = get_scene("shapes")
    h, w = values.shape[:2]
    blob, _ = encode_image(values, check_domain(scene.curves, w, h, fit=True), SETTINGS)
    m = loads(blob)
    return blob, render(m, w, h, edge_spp=default_edge_spp(m, w, h))


def _bands(values):
    scene = get_scene("shapes")
    h, w = values.shape[:2]
    blob, _ = encode_bands(ArrayBands(values, ["R", "G", "B"]), check_domain(scene.curves, w, h, fit=True), SETTINGS)
    return blob, render(loads(blob), w, h)


def _frames(values):
    scene = get_scene("shapes")
    t, h, w = values.shape[:3]
    blob, _ = encode_frames(FrameSequence(values, np.arange(t, dtype=np.float64)),
                            check_domain(scene.curves, w, h, fit=True), SETTINGS)
    m = loads(blob)
    return blob, np.stack([render(m, w, h, t=float(s), edge_spp=default_edge_spp(m, w, h)) for s in range(t)])


def _wall(tmp_path):
    return read_curves(write_curves(tmp_path / "wall.json", [[[0.5, 0.1], [0.5, 0.9]]]))


def _samples_case(tmp_path):
    rng = np.random.default_rng(0)
    xy = rng.random((3000, 2))
    values = np.where(xy[:, :1] < 0.5, 0.2, 0.7) + 0.3 * np.sin(4 * xy[:, 1:])
    curves = _wall(tmp_path)

    def run(v):
        blob, _ = encode_samples(SampleSet(xy, v.astype(np.float32), curves.domain, None), curves, POINTS)
        return blob, values_at(loads(blob), xy)
    return values, run


def _fem_case(tmp_path):
    pts, tris = grid_mesh(16)
    u = np.where(pts[:, 0] < 0.5, 0.2, 0.7) + 0.3 * np.cos(3 * pts[:, 1]) * pts[:, 0]
    curves = _wall(tmp_path)
    solution = from_meshio(meshio.Mesh(pts, [("triangle", tris)], point_data={"u": u}))

    def run(v):
        s = from_meshio(meshio.Mesh(pts, [("triangle", tris)], point_data={"u": v[:, 0]}))
        blob, _ = encode_fem(s, curves, POINTS)
        return blob, values_at(loads(blob), node_points(s)[0])
    return solution.values.astype(np.float64), run


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    """kind -> (unit-scale values, run(values) -> (blob, decoded values at the truth's points))."""
    tmp = tmp_path_factory.mktemp("units")
    pixels = get_scene("shapes").render(32, 32).astype(np.float64)
    frames = np.stack([pixels, pixels[:, ::-1]])
    return {"image": (pixels, lambda v: _image(v.astype(np.float32))),
            "frames": (frames, lambda v: _frames(v.astype(np.float32))),
            "bands": (pixels, lambda v: _bands(v.astype(np.float32))),
            "samples": _samples_case(tmp), "fem": _fem_case(tmp)}


@pytest.fixture(scope="module")
def unit_results(cases):
    out = {}
    for kind, (values, run) in cases.items():
        blob, decoded = run(values)
        out[kind] = (len(blob), _own_range_psnr(values.astype(np.float32), decoded))
    return out


@pytest.mark.parametrize("kind", ["image", "frames", "samples", "fem", "bands"])
@pytest.mark.parametrize("scale,offset", UNITS)
def test_quality_and_size_do_not_depend_on_units(cases, unit_results, kind, scale, offset, one_thread):
    values, run = cases[kind]
    scaled = values * scale + offset
    truth = scaled.astype(np.float64 if kind == "fem" else np.float32)
    blob, decoded = run(scaled)
    size, db = unit_results[kind]
    got = _own_range_psnr(truth, decoded)
    assert db > 20  # the unit-scale fit fits
    assert abs(got - db) <= DB, (kind, scale, offset, got, db)
    assert abs(len(blob) - size) <= SIZE * size, (kind, scale, offset, len(blob), size)


def test_fem_keeps_a_huge_offset(cases, unit_results, one_thread):
    """1e6 ± 1e-3 (FEM values are read as float64): decoded in binary64, it fits as the unit-scale data does."""
    values, run = cases["fem"]
    scaled = 1e6 + 1e-3 * values
    blob, decoded = run(scaled)
    assert loads(blob).header["value_offset"][0] == pytest.approx(1e6, rel=1e-9)
    assert abs(_own_range_psnr(scaled, decoded) - unit_results["fem"][1]) <= DB


def test_choose_normalises_to_the_unit_interval():
    lo, hi = np.array([3.0, -2.5e-7]), np.array([7.0, 4.0e-7])
    m = choose(lo, hi)
    assert np.all(m.scale == m.scale[0]) and m.unit >= 7.0 + 2.5e-7
    v = m.normalise(np.stack([lo, hi]))
    assert v.min() >= 0.0 and v.max() <= 1.0 and m.unit == pytest.approx(7.0, rel=1e-5)
    const = choose(np.array([1e6 + 0.25]), np.array([1e6 + 0.25]))
    assert const.offset[0] == 1e6 + 0.25 and const.offset[0] + const.scale[0] * 0.99 == const.offset[0]
    assert "constant data" in describe(5.0, 5.0, const)
    # a huge offset on a small variation read as float32 has lost its digits; the summary says so
    line = describe(1e6 - 1e-3, 1e6 + 1e-3, choose([1e6 - 1e-3], [1e6 + 1e-3]))
    assert "a large offset" in line and "float32 input resolves only about 0 levels" in line
    assert "[999999.999, 1000000.001]" in line  # the range is printed with the digits that tell its ends apart
    assert "levels" not in describe(0.0, 1.0, choose([0.0], [1.0]))


def test_constant_data_decodes_exactly(tmp_path, one_thread):
    pts, tris = grid_mesh(8)
    solution = from_meshio(meshio.Mesh(pts, [("triangle", tris)], point_data={"u": np.full(len(pts), 3.25)}))
    blob, report = encode_fem(solution, _wall(tmp_path), EncodeSettings(steps=20, batch_size=256, max_triangles=40))
    assert np.all(values_at(loads(blob), node_points(solution)[0]) == 3.25) and report.psnr == float("inf")
    assert "constant data" in report.units


def test_hdr_is_a_peak_not_a_unit():
    """An LDR image in any unit is fitted as values; HDR light (a peak far above its mean) in log space."""
    ldr = get_scene("shapes").render(32, 32)
    assert not is_hdr(ldr) and not is_hdr(ldr * 1e4) and not is_hdr(ldr + 1e6)
    hdr = get_scene("hdr").render(32, 32)
    assert is_hdr(hdr)
    blob, report = encode_image(hdr, check_domain(get_scene("hdr").curves, 32, 32, fit=True), SETTINGS)
    header = loads(blob).header
    assert report.tonemapped and header["value_transform"] == "log" and "value_offset" not in header
    assert "log space" in report.units


def test_hdr_summary_says_when_values_below_minus_one_keep_the_fit_out_of_log_space():
    """log(1 + v) needs v > -1: HDR light with such values (a wide-gamut EXR's negative channels) is fitted on its
    values, and the summary says so rather than claiming log space."""
    assert "log space as HDR" in describe(-0.5, 18.0, None)
    line = describe(-1.3, 18.0, None)
    assert "no log space" in line and "fitted in log space" not in line
