"""Rate control: mesh sizes by sample count and by byte target."""

import pytest

from dfc.bench.scenes import sample_scene
from dfc.codec import EncodeSettings
from dfc.errors import InputError, MeshError


@pytest.fixture(scope="module")
def scene():
    return sample_scene()


def test_sample_sets_size_their_mesh_by_the_sample_count_on_top_of_the_curves(scene):
    from dfc.errors import TriangleBudgetError
    from dfc.geometry.triangulate import triangulate
    from dfc.rate import NOISY_SAMPLES_PER_TRIANGLE, sample_mesh_size

    curves = scene.curves
    with pytest.raises(TriangleBudgetError) as refused:
        triangulate(curves, max_triangles=2)
    forced = refused.value.needed  # what the curves' vertices alone need
    few, few_mesh = sample_mesh_size(curves, EncodeSettings(), 10)
    assert few.max_triangles >= forced + 2
    assert few_mesh.n_triangles <= few.max_triangles  # the mesh the fit runs on, built once
    n = 300 * NOISY_SAMPLES_PER_TRIANGLE
    middle, middle_mesh = sample_mesh_size(curves, EncodeSettings(), n)
    assert middle.max_triangles >= forced + 300
    many, _ = sample_mesh_size(curves, EncodeSettings(), 10**9)
    assert many.max_triangles - middle.max_triangles == 2000 - 300  # the samples' share is capped at the default
    # the samples' triangles are spent away from the curves: interior vertices, not the curves' slivers alone
    assert middle_mesh.n_vertices > few_mesh.n_vertices + 100
    given = EncodeSettings(max_area=5.0)
    kept, no_mesh = sample_mesh_size(curves, given, 10)
    assert kept is given and no_mesh is None  # an explicit mesh size wins


def test_sample_sets_fit_for_a_number_of_passes_over_their_samples():
    from dfc.codec import SAMPLE_PASSES, sample_steps
    from dfc.train.fit import DEFAULT_STEPS

    assert sample_steps(10, 16384) == DEFAULT_STEPS  # small sets: the default
    assert sample_steps(10**7, 16384) == -(-SAMPLE_PASSES * 10**7 // 16384)
    assert sample_steps(10**7, 16384) * 16384 >= SAMPLE_PASSES * 10**7 > (sample_steps(10**7, 16384) - 1) * 16384


def test_each_input_kind_has_its_default_step_count(scene):
    from dfc.codec import default_steps, encode_image, loads, sample_steps
    from dfc.train.fit import DEFAULT_STEPS, IMAGE_STEPS

    assert IMAGE_STEPS > DEFAULT_STEPS
    assert default_steps("image") == IMAGE_STEPS
    assert default_steps("samples", 10**7, 4096) == sample_steps(10**7, 4096) > DEFAULT_STEPS
    assert default_steps("fem") == default_steps("frames") == DEFAULT_STEPS
    # the library resolves them as the CLI does: an image encode without steps runs IMAGE_STEPS and records them
    image = scene.render(16, 16, spp=1)
    steps = []
    blob, _ = encode_image(image, scene.curves, EncodeSettings(batch_size=64),
                           fit_curves=True, callback=lambda step, *_: steps.append(step))
    assert len(steps) == IMAGE_STEPS
    assert loads(blob).header["encoder"]["steps"] == IMAGE_STEPS


def test_sample_sets_cut_curved_pieces_shorter_the_more_samples_they_have():
    from dfc.codec import sample_piece_length

    domain = (0.0, 0.0, 2.0, 1.0)
    lengths = [sample_piece_length(domain, n) for n in (0, 10**3, 10**5, 10**7)]
    assert all(a > b for a, b in zip(lengths[1:], lengths[2:]))
    assert lengths[2] / lengths[3] == pytest.approx(100 ** 0.25)
    assert lengths[0] == pytest.approx(sample_piece_length((0.0, 0.0, 1.0, 2.0), 1))  # the longer side counts


@pytest.mark.slow
def test_byte_targets_size_the_file_and_report_real_mesh_errors(scene, monkeypatch):
    from dfc import rate

    mesh = rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=12_000, feature_bits=10), ["R", "G", "B"])
    larger = rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=24_000, feature_bits=10), ["R", "G", "B"])
    assert mesh.n_triangles < larger.n_triangles
    with pytest.raises(InputError, match="too small.*fewer --feature-bits than 10"):
        rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=500, feature_bits=10), ["R", "G", "B"])
    with pytest.raises(InputError, match="too small") as refused:
        rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=500, feature_bits=6), ["R", "G", "B"])
    assert "--feature-bits" not in str(refused.value)  # no hint at the coarsest bits the encoders fall back to

    def broken(*args, **kwargs):
        raise MeshError("triangulate: pieces 3 and 4 cannot be separated")

    monkeypatch.setattr(rate, "triangulate", broken)
    with pytest.raises(MeshError, match="cannot be separated"):  # not reported as a byte target too small
        rate.mesh_for_bytes(scene.curves, EncodeSettings(target_bytes=12_000, feature_bits=10), ["R", "G", "B"])


def test_the_mesh_search_interpolates_file_sizes(monkeypatch):
    """Files grow nearly linearly with the triangle cap: the search reaches the largest cap within its tolerance
    that fits in about half the probes of a plain bisection (nine here)."""
    from dfc import rate

    probes = []

    def linear(curves, settings, channels, n, size_of):  # a file of 500 bytes plus 4 per triangle
        probes.append(n)
        return 500 + 4 * n, f"mesh of {n}"

    monkeypatch.setattr(rate, "_file_bytes", linear)
    mesh, cap = rate._mesh_and_cap(None, EncodeSettings(target_bytes=4096), ["R"], None)
    assert mesh == f"mesh of {cap}" and 500 + 4 * cap <= 4096
    assert cap >= 899 - max(8, 899 // 50)  # 899: the largest cap that fits
    assert len(probes) <= 5


def test_the_decoder_narrows_to_its_share_of_a_byte_target():
    from dfc.rate import DECODER_HIDDEN, decoder_hidden

    lo, hi = DECODER_HIDDEN
    assert decoder_hidden(10**7) == hi and decoder_hidden(10) == lo
    weights = {w: 5 * w + w * w + 3 * w for w in (8, 16, 32, 64)}  # 5 features, two hidden layers, RGB
    for budget in (100, 500, 2_000, 5_000, 10**6):
        width = decoder_hidden(10**7, budget)
        fits = [w for w in weights if weights[w] <= budget and w <= hi] or [lo]
        assert width == max(fits)  # the widest whose 8-bit weights fit (the narrowest when none does)
    assert decoder_hidden(10**7, 1_500) == 32 and decoder_hidden(10**7, 1_500, weight_bits=None) == 16  # float16
    assert decoder_hidden(64 * 64 * 3, 10**6) == decoder_hidden(64 * 64 * 3)  # never wider than the input allows
    assert decoder_hidden(10**7, widest=64) == 64 and decoder_hidden(10**7, 2_000, widest=64) == 32


def test_image_decoders_are_32_wide_and_short_fits_64(one_thread):
    """The width rule of an image encode: 32 at the default steps and from DECODER_LR_MIN_STEPS up, 64 below (a
    32-wide decoder converges too slowly there); an explicit ``hidden`` still caps it."""
    from dfc.codec import image_decoder
    from dfc.rate import DECODER_HIDDEN, SHORT_FIT_HIDDEN
    from dfc.train.fit import DECODER_LR_MIN_STEPS

    n = 256 * 256 * 3
    assert DECODER_HIDDEN[1] == 32 < SHORT_FIT_HIDDEN == 64
    assert image_decoder(EncodeSettings(), n, 3).hidden == 32
    assert image_decoder(EncodeSettings(steps=DECODER_LR_MIN_STEPS), n, 3).hidden == 32
    assert image_decoder(EncodeSettings(steps=DECODER_LR_MIN_STEPS - 1), n, 3).hidden == 64
    assert image_decoder(EncodeSettings(steps=100, hidden=16), n, 3).hidden == 16
    assert image_decoder(EncodeSettings(steps=100, target_bytes=4_000), n, 3).hidden == 16  # its share of a target


@pytest.mark.slow
def test_fill_points_spend_what_the_target_leaves(scene):
    """The refinement that fills a byte target: more vertices for a larger target, none when the file is already at
    it, and the file carried onto the refined mesh within ``FILL`` of the target."""
    import numpy as np

    from dfc.codec import check_domain
    from dfc.field.model import FieldModel
    from dfc.field.transfer import carry_over
    from dfc.io.container import encode_dfield
    from dfc.io.dfield import to_contents
    from dfc.rate import FILL, build_mesh, fill_points
    from dfc.render import window_points
    from dfc.train.fit import fit_image

    image = scene.render(48, 48, spp=1)
    curves = check_domain(scene.curves, 48, 48, fit=True)
    settings = EncodeSettings(max_triangles=200)
    model = fit_image(image, build_mesh(curves, settings), steps=20, batch_size=512, hidden=16)
    xy = window_points(curves.domain, 48, 48)
    err = np.abs(np.sin(xy[:, 0] * 0.3)) + 0.1  # any error map: where the splits go does not matter here

    def size_of(m):
        return len(encode_dfield(to_contents(m), mesh_validated=True)[0])

    now = size_of(model)
    none = fill_points(model, curves, settings, np.zeros((0, 2)), xy, err, size_of, int(now / FILL))
    assert len(none) == 0
    # a vertex costs little in the derived mesh encoding: every candidate grows the file by about a quarter
    small, large = (fill_points(model, curves, settings, np.zeros((0, 2)), xy, err, size_of, int(f * now))
                    for f in (1.1, 1.3))
    assert 0 < len(small) < len(large)
    refined = build_mesh(curves, settings, extra_points=large)
    carried = FieldModel.from_config(refined, model.config())
    carry_over(model, carried, xy)
    assert size_of(carried) <= FILL * 1.3 * now


def test_refinement_along_a_curve_halves_its_piece(scene):
    """Error in a curved triangle alone: the refinement's point halves that triangle's piece when the mesh is
    rebuilt (one more curved piece, the curve drawn as before), instead of the curve staying as it is."""
    import numpy as np
    import torch

    from dfc.codec import check_domain
    from dfc.field.layout import build_layout
    from dfc.field.locate import PointLocator
    from dfc.geometry import bezier
    from dfc.rate import build_mesh, refinement_points
    from dfc.render import window_points

    curves = check_domain(scene.curves, 64, 64, fit=True)
    settings = EncodeSettings(max_triangles=300)
    mesh = build_mesh(curves, settings)
    xy = window_points(curves.domain, 256, 256)
    locator = PointLocator(mesh.vertices, mesh.triangles, mesh.domain)
    tri = locator(locator.clamp(torch.from_numpy(xy)))[0].numpy()
    piece = build_layout(mesh).triangle_curve
    area = np.bincount(tri, minlength=mesh.n_triangles)
    target = int(np.argmax(np.where(piece >= 0, area, -1)))  # the curved triangle holding the most points
    err = (tri == target).astype(np.float64)
    points = refinement_points(mesh, xy, err, most=1)
    assert len(points) == 1
    cp = mesh.curve_control_points[piece[target]]
    apex = bezier.tangent_apex(cp[None])[0]
    np.testing.assert_allclose(points[0], (cp[0] + cp[3] + apex) / 3.0)
    refined = build_mesh(curves, settings, extra_points=points)
    refined.validate()
    assert len(refined.curve_control_points) == len(mesh.curve_control_points) + 1
    ends = refined.curve_control_points[:, [0, 3]].reshape(-1, 2)
    middle = bezier.evaluate(cp[None], np.array([0.5]))[0]
    assert np.hypot(*(ends - middle).T).min() < 1e-3  # the new endpoint is the piece's middle (mesh-quantised)


def test_refinement_ranks_by_error_per_byte(scene):
    """A curved triangle's halving costs ``HALVING_COST`` centroid splits: with less than that factor more error than
    a plain triangle it comes second, with more it comes first."""
    import numpy as np
    import torch

    from dfc.codec import check_domain
    from dfc.field.layout import build_layout
    from dfc.field.locate import PointLocator
    from dfc.rate import HALVING_COST, build_mesh, refinement_points
    from dfc.render import window_points

    curves = check_domain(scene.curves, 64, 64, fit=True)
    mesh = build_mesh(curves, EncodeSettings(max_triangles=300))
    xy = window_points(curves.domain, 256, 256)
    locator = PointLocator(mesh.vertices, mesh.triangles, mesh.domain)
    tri = locator(locator.clamp(torch.from_numpy(xy)))[0].numpy()
    piece = build_layout(mesh).triangle_curve
    count = np.bincount(tri, minlength=mesh.n_triangles)
    curved = int(np.argmax(np.where(piece >= 0, count, -1)))
    plain = int(np.argmax(np.where(piece < 0, count, -1)))
    centroid = mesh.vertices[mesh.triangles[plain]].mean(axis=0)
    for factor, plain_first in [(0.8 * HALVING_COST, True), (1.25 * HALVING_COST, False)]:
        err = np.where(tri == curved, factor / count[curved], 0.0) + np.where(tri == plain, 1.0 / count[plain], 0.0)
        first = refinement_points(mesh, xy, err, share=1.0, most=1)[0]
        assert np.allclose(first, centroid) == plain_first


@pytest.mark.slow
def test_a_byte_target_too_small_for_the_default_feature_bits_falls_back_to_fewer(scene, tmp_path):
    import re

    from dfc.codec import encode_image
    from dfc.errors import TargetBytesError
    from dfc.field.quantize import DEFAULT_FEATURE_BITS
    from dfc.io.container import read_dfield_info

    image = scene.render(64, 64)

    def smallest(bits: int) -> int:
        with pytest.raises(TargetBytesError) as refused:
            encode_image(image, scene.curves, EncodeSettings(target_bytes=300, feature_bits=bits, steps=1),
                         fit_curves=True)
        return int(re.search(r"smallest file tried takes (\d+) bytes", str(refused.value)).group(1))

    at10, at8 = smallest(DEFAULT_FEATURE_BITS), smallest(8)
    assert at8 < at10
    target = (at8 + at10) // 2
    settings = EncodeSettings(target_bytes=target, steps=5, batch_size=1024, refine=0)
    blob, report = encode_image(image, scene.curves, settings, fit_curves=True, raster_mode=False)  # the field's
    assert report.feature_bits == 8 and report.fallback_from == DEFAULT_FEATURE_BITS and len(blob) <= target
    path = tmp_path / "small.dfield"
    path.write_bytes(blob)
    assert read_dfield_info(path)["features"]["bits"] == 8  # the file stores what the report says
    with pytest.raises(TargetBytesError, match="fewer --feature-bits than 10"):  # bits the caller chose are kept
        encode_image(image, scene.curves, EncodeSettings(target_bytes=target, feature_bits=10, steps=5),
                     fit_curves=True, raster_mode=False)
    _, default = encode_image(image, scene.curves, EncodeSettings(max_triangles=200, steps=5, batch_size=1024),
                              fit_curves=True)
    assert default.feature_bits == DEFAULT_FEATURE_BITS  # no byte target: the default bits



def test_a_fill_priced_at_fewer_feature_bits_buys_more_triangles(scene):
    """``fill_points(bits=B)`` prices every candidate file with B-bit features (the bits the refit will store):
    the same target buys more vertices at 8 bits than at 10."""
    import numpy as np

    from dfc.codec import check_domain
    from dfc.io.container import encode_dfield
    from dfc.io.dfield import to_contents
    from dfc.rate import build_mesh, fill_points
    from dfc.render import window_points
    from dfc.train.fit import fit_image

    image = scene.render(48, 48, spp=1)
    curves = check_domain(scene.curves, 48, 48, fit=True)
    settings = EncodeSettings(max_triangles=200)
    xy = window_points(curves.domain, 48, 48)
    err = np.abs(np.sin(xy[:, 0] * 0.3)) + 0.1
    priced = []

    def size_of(m):
        bits = (m.quantization or {}).get("feature_bits", 10)
        priced.append(bits)
        return len(encode_dfield(to_contents(m), mesh_validated=True, feature_bits=bits)[0])

    counts = {}
    for bits in (10, 8):
        model = fit_image(image, build_mesh(curves, settings), steps=20, batch_size=512, hidden=16, feature_bits=10)
        target = int(1.2 * size_of(model))  # the same target for both: 20 % over the 10-bit file
        priced.clear()
        counts[bits] = len(fill_points(model, curves, settings, np.zeros((0, 2)), xy, err, size_of, target, bits=bits))
        assert set(priced) == {bits}
    assert 0 < counts[10] < counts[8]


def test_a_fill_switches_to_coarse_features_only_when_they_cost_the_fit_little():
    from types import SimpleNamespace

    import numpy as np

    from dfc.codec import _coarse_costs_little
    from dfc.rate import COARSE_FEATURE_BITS, COARSE_LOSS_DB

    err = np.full(100, 1e-3)

    def residual_losing(db):  # squared error db decibels higher at the coarse bits
        def residual(m):
            assert m.quantization["weight_bits"] == 8  # measured with the weights as they are stored
            coarse = m.quantization["feature_bits"] == COARSE_FEATURE_BITS
            return None, err * 10 ** (db / 10) if coarse else err
        return residual

    model = SimpleNamespace(quantization={"feature_bits": 10, "weight_bits": 8})
    assert _coarse_costs_little(model, residual_losing(0.9 * COARSE_LOSS_DB), err, 10)
    assert model.quantization == {"feature_bits": 10, "weight_bits": 8}  # the model is left as it was
    assert not _coarse_costs_little(model, residual_losing(1.1 * COARSE_LOSS_DB), err, 10)
    assert not _coarse_costs_little(model, residual_losing(0.0), err, COARSE_FEATURE_BITS)  # no coarser than that


@pytest.mark.slow
def test_a_noisy_image_under_a_byte_target_stores_coarse_features(scene, tmp_path, monkeypatch):
    """Noise dominates the fit's error: the fill stores ``COARSE_FEATURE_BITS`` and spends the bytes they save,
    within the target, refitting first on a mesh sized for them (more triangles than the first); bits the caller
    gives are kept."""
    import numpy as np

    import dfc.codec
    from dfc.codec import encode_image
    from dfc.io.container import read_dfield_info
    from dfc.rate import COARSE_FEATURE_BITS, sized_mesh

    sized = []  # triangles of each mesh a byte target sized

    def recorded(*args, **kwargs):
        mesh_settings, mesh = sized_mesh(*args, **kwargs)
        sized.append(mesh.n_triangles)
        return mesh_settings, mesh

    monkeypatch.setattr(dfc.codec, "sized_mesh", recorded)
    rng = np.random.default_rng(0)
    image = (scene.render(64, 64) + rng.normal(0.0, 0.05, (64, 64, 3))).astype(np.float32)
    settings = EncodeSettings(target_bytes=1500, steps=100, batch_size=1024, refine=1)
    blob, report = encode_image(image, scene.curves, settings, fit_curves=True)
    assert report.feature_bits == COARSE_FEATURE_BITS and len(blob) <= 1500
    assert report.fallback_from is None  # stored coarse by choice, not because the target was too small
    assert len(sized) == 2 and sized[1] > sized[0]  # the first mesh, then one sized for the coarse features
    assert report.n_triangles >= sized[1]  # the fill refines that one
    path = tmp_path / "noisy.dfield"
    path.write_bytes(blob)
    assert read_dfield_info(path)["features"]["bits"] == COARSE_FEATURE_BITS
    kept, given = encode_image(image, scene.curves, EncodeSettings(target_bytes=1500, steps=100, batch_size=1024,
                                                                   refine=1, feature_bits=10), fit_curves=True)
    assert given.feature_bits == 10 and len(kept) <= 1500
    assert len(sized) == 3  # no switch, no second sizing
