"""Equal-size baselines: sizing to a byte budget, storage rules, the hash function, and fitting a tiny image."""

import numpy as np
import pytest
import torch

from dfc.bench.baselines import BASELINES, HashGrid, Raster, ReluField, TanhField, fit_baseline
from dfc.bench.baselines.base import fp16_bytes
from dfc.bench.baselines.hashgrid import PRIMES, level_layout
from dfc.bench.baselines.raster import area_resize, exr_bytes
from dfc.bench.scenes import shapes_scene
from dfc.metrics import psnr
from dfc.train.samplers import image_sampler

pytestmark = pytest.mark.usefixtures("one_thread")

DOMAIN = (0.0, 0.0, 256.0, 256.0)
RGB = ["R", "G", "B"]


@pytest.fixture(scope="module")
def image():
    return shapes_scene().render(32, 32, spp=2)


def _centres(n: int, domain=DOMAIN) -> torch.Tensor:
    u = (np.arange(n) + 0.5) * (domain[2] - domain[0]) / n
    X, Y = np.meshgrid(u, u)
    return torch.from_numpy(np.stack([X.ravel(), Y.ravel()], 1))


@pytest.mark.parametrize("target", [6_000, 20_000, 60_000])
@pytest.mark.parametrize("cls", [HashGrid, ReluField])
def test_parametric_baselines_meet_the_budget(cls, target):
    model = cls.for_budget(target, DOMAIN, RGB)
    assert 0.97 * target <= model.stored_bytes() <= target
    for _ in model.stages(10)[1:]:  # the ReLU field counts its final grid from the start
        model.next_stage()
    assert model.stored_bytes() == fp16_bytes(model) == 2 * sum(p.numel() for p in model.parameters())


def test_relu_field_keeps_the_aspect_ratio():
    model = ReluField.for_budget(30_000, (0.0, 0.0, 300.0, 100.0), ["Y"])
    ny, nx = model.shape
    assert abs((nx - 1) / (ny - 1) - 3.0) < 0.1
    assert 0.97 * 30_000 <= model.stored_bytes() <= 30_000


@pytest.fixture(scope="module")
def large_image():
    return shapes_scene().render(96, 96, spp=1)


@pytest.mark.parametrize("target", [3_000, 5_000])
def test_raster_meets_the_budget_with_its_exr_size(large_image, target):
    model = Raster.for_budget(target, DOMAIN, RGB, image=large_image)
    assert 0.95 * target <= model.stored_bytes() <= target
    w, h = model.size
    assert 1 <= w < 96 and abs(h - w) <= 1  # the aspect ratio within a pixel
    stored = model.image[0].permute(1, 2, 0).numpy()
    assert model.stored_bytes() == exr_bytes(stored, RGB)


def test_budgets_too_small_are_refused(image):
    with pytest.raises(ValueError, match="budget"):
        HashGrid.for_budget(100, DOMAIN, RGB)
    with pytest.raises(ValueError, match="budget"):
        ReluField.for_budget(20, DOMAIN, RGB)
    with pytest.raises(ValueError, match="budget"):
        Raster.for_budget(10, DOMAIN, RGB, image=image)


def test_raster_at_full_size_reproduces_pixel_centres(image):
    model = Raster.for_budget(10**7, DOMAIN, RGB, image=image)
    assert model.size == (32, 32)
    with torch.no_grad():
        out = model(_centres(32)).numpy().reshape(32, 32, 3)
    np.testing.assert_allclose(out, image.astype(np.float16).astype(np.float32), atol=1e-6)


def test_area_resize_is_a_box_filter():
    rng = np.random.default_rng(0)
    img = rng.random((12, 18, 2)).astype(np.float32)
    half = area_resize(img, 9, 6)
    np.testing.assert_allclose(half, img.reshape(6, 2, 9, 2, 2).mean(axis=(1, 3)), rtol=1e-6)
    odd = area_resize(img, 7, 5)
    np.testing.assert_allclose(odd.mean(axis=(0, 1)), img.mean(axis=(0, 1)), rtol=1e-5)


def _brute_force_rows(model: HashGrid, x: float, y: float) -> list[list[int]]:
    """Corner rows per level with Python integers (independent of the vectorised code)."""
    lay = level_layout(model.levels, model.base_resolution, model.finest_resolution, model.extent, model.table_size,
                       model.dense_levels)
    side = max(model.domain[2] - model.domain[0], model.domain[3] - model.domain[1])
    u, v = (x - model.domain[0]) / side, (y - model.domain[1]) / side
    out = []
    for level in range(model.levels):
        r, nx, ny = int(lay["res"][level]), int(lay["nx"][level]), int(lay["ny"][level])
        i0, j0 = min(int(np.floor(u * r)), nx - 2), min(int(np.floor(v * r)), ny - 2)
        rows = []
        for dj in (0, 1):
            for di in (0, 1):
                i, j = i0 + di, j0 + dj
                if nx * ny > model.table_size and level >= model.dense_levels:
                    row = ((i * PRIMES[0]) ^ ((j * PRIMES[1]) % 2**32)) % model.table_size
                else:
                    row = i + j * nx
                rows.append(int(lay["offset"][level]) + row)
        out.append(rows)
    return out


def test_hash_rows_match_a_brute_force_reference():
    model = HashGrid(DOMAIN, RGB, levels=8, table_size=997, base_resolution=4, finest_resolution=300)
    assert 0 < model.first_hashed < model.levels  # both dense and hashed levels are exercised
    pts = np.array([[0.0, 0.0], [256.0, 256.0], [13.37, 200.1], [128.0, 64.5], [255.9, 0.2], [77.7, 31.3]])
    rows, w = model.corners(torch.from_numpy(pts))
    for k, (x, y) in enumerate(pts):
        assert rows[k].tolist() == _brute_force_rows(model, x, y)
    torch.testing.assert_close(w.sum(-1), torch.ones(len(pts), model.levels))
    assert int(rows.max()) < model.table.shape[0]


def test_dense_coarse_levels_are_not_hashed():
    model = HashGrid(DOMAIN, RGB, levels=6, table_size=60, base_resolution=8, finest_resolution=64, dense_levels=3)
    lay = level_layout(6, 8, 64, model.extent, 60, 3)
    assert model.first_hashed == 3 and not lay["hashed"][:3].any() and lay["hashed"][3:].all()
    assert np.array_equal(lay["rows"][:3], lay["nx"][:3] * lay["ny"][:3]) and (lay["rows"][:3] > 60).all()
    pts = np.array([[0.0, 0.0], [256.0, 256.0], [13.37, 200.1], [77.7, 31.3]])
    rows, _ = model.corners(torch.from_numpy(pts))
    for k, (x, y) in enumerate(pts):
        assert rows[k].tolist() == _brute_force_rows(model, x, y)
    sized = HashGrid.for_budget(20_000, DOMAIN, RGB, levels=16, hidden=16, dense_levels=4)
    assert 0.97 * 20_000 <= sized.stored_bytes() <= 20_000 and sized.first_hashed >= 4
    with pytest.raises(ValueError, match="dense levels"):
        HashGrid.for_budget(3_000, DOMAIN, RGB, levels=8, hidden=16, dense_levels=8)


@pytest.mark.parametrize("features", [1, 2, 3, 6])
def test_relu_field_channels_trade_for_resolution(features):
    model = ReluField.for_budget(12_000, DOMAIN, RGB, features=features)
    assert 0.97 * 12_000 <= model.stored_bytes() <= 12_000
    assert (model.head is None) == (features == 3) and model.describe()["features"] == features
    model.init_mean(torch.tensor([0.2, 0.5, 0.9]))
    torch.testing.assert_close(model(_centres(4)), torch.tensor([[0.2, 0.5, 0.9]]).expand(16, 3))
    nodes = model.shape[0] * model.shape[1]
    assert nodes == pytest.approx((12_000 - (0 if features == 3 else 2 * (features + 1) * 3)) / (2 * features), rel=0.03)
    for _ in model.stages(10)[1:]:
        model.next_stage()
    assert model.stored_bytes() == fp16_bytes(model)


@pytest.mark.parametrize("kernel", ["bicubic", "lanczos"])
def test_pixel_images_reproduce_their_pixels_at_the_centres(image, kernel):
    from dfc.bench.baselines.upsample import PixelImage

    model = PixelImage(image, DOMAIN, RGB, n_bytes=123, kernel=kernel)
    with torch.no_grad():
        out = model(_centres(32)).numpy().reshape(32, 32, 3)
    np.testing.assert_allclose(out, image, atol=1e-5)
    other = model.with_kernel("bicubic" if kernel == "lanczos" else "lanczos")
    assert other.stored_bytes() == 123 and other.size == (32, 32) and np.array_equal(other.pixels(), image)
    flat = PixelImage(np.full((5, 7, 1), 0.25, np.float32), DOMAIN, ["Y"], n_bytes=1, kernel=kernel)
    xy = torch.from_numpy(np.random.default_rng(0).random((100, 2)) * 256)
    torch.testing.assert_close(flat(xy), torch.full((100, 1), 0.25))  # weights sum to one everywhere


def test_lanczos_differs_from_bicubic_between_centres(image):
    from dfc.bench.baselines.upsample import PixelImage

    xy = torch.from_numpy(np.random.default_rng(1).random((200, 2)) * 256)
    a = PixelImage(image, DOMAIN, RGB, n_bytes=1, kernel="bicubic")(xy)
    b = PixelImage(image, DOMAIN, RGB, n_bytes=1, kernel="lanczos")(xy)
    assert 0 < float((a - b).abs().max()) < 0.2


def test_hash_grid_interpolates_bilinearly_within_a_cell():
    model = HashGrid(DOMAIN, ["Y"], levels=1, features=1, table_size=1 << 12, base_resolution=4, finest_resolution=4)
    xy = torch.tensor([[10.0, 20.0], [30.0, 20.0], [20.0, 20.0]], dtype=torch.float64)  # same cell; mid-point last
    e = model.encode(xy).detach()
    torch.testing.assert_close(e[2], (e[0] + e[1]) / 2)


def test_quantization_reads_parameters_as_fp16():
    model = ReluField.for_budget(2_000, DOMAIN, ["Y"], lo=-10.0, hi=10.0)
    with torch.no_grad():
        model.grid.copy_(torch.rand_like(model.grid) * 3 + 1.0001)
    xy = _centres(8)
    exact = model(xy).detach()
    model.quantization = {"feature_bits": 8}
    quantised = model(xy).detach()
    model.quantization = None
    assert not torch.equal(exact, quantised)
    torch.testing.assert_close(model(xy).detach(), exact)
    model.round_to_storage()
    assert torch.equal(model.grid, model.grid.half().float())


@pytest.mark.parametrize("name,threshold", [("hashgrid", 24.0), ("relu", 24.0)])
def test_baselines_fit_a_tiny_image(image, name, threshold):
    cls = BASELINES[name]
    model = cls.for_budget(8_000, DOMAIN, RGB, finest_resolution=32) if name == "hashgrid" else \
        cls.for_budget(8_000, DOMAIN, RGB)
    model.init_mean(torch.from_numpy(image.reshape(-1, 3).mean(0)))
    before = psnr(image, model(_centres(32)).detach().numpy().reshape(32, 32, 3), data_range=1.0)
    history = fit_baseline(model, image_sampler(image, DOMAIN, 1024), 120)
    with torch.no_grad():
        after = psnr(image, model(_centres(32)).numpy().reshape(32, 32, 3), data_range=1.0)
    assert after > threshold and after > before + 5
    assert len(history["loss"]) >= 120
    assert all(torch.equal(p, p.half().float()) for p in model.parameters())  # evaluates as stored


def test_relu_field_trains_coarse_to_fine():
    model = ReluField.for_budget(8_000, DOMAIN, RGB)
    assert model.grid.shape[2:] != model.shape
    stages = model.stages(100)
    assert len(stages) == 3 and sum(stages) == 100
    coarse = model.grid.shape
    ny, nx = coarse[2:]
    v, u = torch.meshgrid(torch.linspace(0, 1, ny), torch.linspace(0, 1, nx), indexing="ij")
    with torch.no_grad():  # a bilinear function: upsampling must reproduce it exactly
        model.grid.copy_((0.2 + 0.3 * u + 0.4 * v * u).expand_as(model.grid))
    xy = _centres(16)
    before = model(xy).detach()
    model.next_stage()
    model.next_stage()
    assert tuple(model.grid.shape[2:]) == model.shape and coarse != model.grid.shape
    torch.testing.assert_close(model(xy).detach(), before, atol=1e-5, rtol=0)


def test_relu_field_settles_hdr_colours_in_its_unit():
    """HDR values (≈ 0.05 … 80): the grid stores them in units of the square root of the maximum (``hdr_unit``),
    which the bench's loss settles within a few hundred steps where a unit of the maximum keeps the dark colours
    off (tone-mapped PSNR, the bench's measure); the tanh field keeps the maximum, its range."""
    from dfc.bench.scenes import hdr_scene
    from dfc.metrics import quality_scale
    from dfc.train.losses import auto_loss

    hdr = hdr_scene().render(32, 32, spp=2)
    scale = quality_scale(hdr)
    assert TanhField.for_budget(8_000, DOMAIN, RGB, image=hdr).value_scale == pytest.approx(float(hdr.max()))
    scores = {}
    for unit in ("hdr_unit", "maximum"):
        model = ReluField.for_budget(8_000, DOMAIN, RGB, image=hdr)
        assert model.value_scale == pytest.approx(float(hdr.max()) ** 0.5) and model.hi is None
        if unit == "maximum":
            model.value_scale = float(hdr.max())
        model.init_mean(torch.from_numpy(hdr.reshape(-1, 3).mean(0)))
        fit_baseline(model, image_sampler(hdr, DOMAIN, 1024), 300, loss=auto_loss(hdr))
        with torch.no_grad():
            scores[unit] = scale.psnr(hdr, model(_centres(32)).numpy().reshape(32, 32, 3))
    assert scores["hdr_unit"] > 22 and scores["hdr_unit"] > scores["maximum"] + 5, scores


# -- the physics-informed baselines (dfc solve / dfc bench --solve) ------------------------------------------
def test_siren_and_tanh_mlp_keep_the_papers_architectures():
    from dfc.bench.baselines import Siren, TanhMLP

    siren = BASELINES["siren"].for_budget(20_000, DOMAIN, RGB)
    assert isinstance(siren, Siren) and len(siren.linears) == 6  # 5 sine layers of 256, then the output
    assert sum(p.numel() for p in siren.parameters()) == (2 * 256 + 256) + 4 * (256 * 256 + 256) + (256 * 3 + 3)
    assert siren.stored_bytes() == 2 * 264_707  # fixed size, far above the budget: reported as it is
    bound = np.sqrt(6 / 256) / 30
    assert siren.linears[0].weight.abs().max() <= 0.5 and 0.9 * bound < siren.linears[2].weight.abs().max() <= bound
    mlp = BASELINES["tanh_mlp"].for_budget(20_000, DOMAIN, RGB)
    assert isinstance(mlp, TanhMLP) and mlp.decoder.hidden == 512 and mlp.decoder.layers == 4
    assert mlp.stored_bytes() == 2 * ((2 * 512 + 512) + 3 * (512 * 512 + 512) + (512 * 3 + 3))
    xy = _centres(8)
    for model in (siren, mlp):
        model.init_mean(torch.tensor([0.2, 0.5, 0.9]))
        out = model(xy)
        assert out.shape == (64, 3) and out.dtype == torch.float32


@pytest.mark.parametrize("target", [6_000, 20_000])
def test_tanh_field_meets_the_budget_and_saturates(target):
    model = BASELINES["tanh_field"].for_budget(target, DOMAIN, RGB)
    assert 0.97 * target <= model.stored_bytes() <= target
    model.init_mean(torch.tensor([0.2, 0.5, 0.9]))
    torch.testing.assert_close(model(_centres(4)), torch.tensor([[0.2, 0.5, 0.9]]).expand(16, 3))
    with torch.no_grad():
        model.grid.mul_(100.0)
    out = model(_centres(4)).detach()
    assert float(out.max()) <= 1.0 and float(out.min()) >= -1.0  # tanh bounds the output unit
    xy = _centres(4).requires_grad_(True)
    (grad,) = torch.autograd.grad(model(xy).sum(), xy, create_graph=True)
    assert grad.requires_grad  # twice differentiable, unlike the ReLU field's clamp
