"""Rate control: mesh sizes by sample count and by byte target."""

import pytest

from dfc.bench.scenes import sample_scene
from dfc.codec import EncodeSettings
from dfc.errors import InputError, MeshError


@pytest.fixture(scope="module")
def scene():
    return sample_scene()


def test_sample_sets_size_their_mesh_by_the_sample_count(scene):
    from dfc.geometry.triangulate import triangulate
    from dfc.rate import NOISY_SAMPLES_PER_TRIANGLE, sample_mesh_size

    curves = scene.curves
    floor = triangulate(curves, max_triangles=None).n_triangles  # at least what the curves force
    many, _ = sample_mesh_size(curves, EncodeSettings(), 10**9)
    assert many.max_triangles == 2000  # capped at the default mesh
    few, few_mesh = sample_mesh_size(curves, EncodeSettings(), 10)
    assert 2 < few.max_triangles <= floor
    assert triangulate(curves, max_triangles=few.max_triangles).n_triangles <= few.max_triangles
    assert few_mesh.n_triangles <= few.max_triangles  # the mesh the fit runs on, built once
    n = 300 * NOISY_SAMPLES_PER_TRIANGLE
    middle, _ = sample_mesh_size(curves, EncodeSettings(), n)
    assert middle.max_triangles == max(300, few.max_triangles)
    given = EncodeSettings(max_area=5.0)
    kept, no_mesh = sample_mesh_size(curves, given, 10)
    assert kept is given and no_mesh is None  # an explicit mesh size wins


def test_byte_targets_size_the_file_and_report_real_mesh_errors(scene, monkeypatch):
    from dfc import rate

    mesh = rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=12_000), ["R", "G", "B"])
    larger = rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=24_000), ["R", "G", "B"])
    assert mesh.n_triangles < larger.n_triangles
    with pytest.raises(InputError, match="too small"):
        rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=500), ["R", "G", "B"])

    def broken(*args, **kwargs):
        raise MeshError("triangulate: pieces 3 and 4 cannot be separated")

    monkeypatch.setattr(rate, "triangulate", broken)
    with pytest.raises(MeshError, match="cannot be separated"):  # not reported as a byte target too small
        rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=12_000), ["R", "G", "B"])
