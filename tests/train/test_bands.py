"""Out-of-core sampling: held-out pixels, the scan of the bands, and stratified epochs drawn band by band (every
rank its own bands), checked against the raster held in memory."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from dfc.errors import InputError
from dfc.geometry.pixels import EdgeMask, edge_pixels
from dfc.io.bands import ArrayBands
from dfc.train.bands import HeldOut, band_sampler, default_epoch_pixels, scan
from dfc.train.fit import fit_bands

from ._scene import scene_image


class _Small(ArrayBands):
    """A band source with bands of a few rows, so that the tests cross many band borders."""

    def band_rows(self, target_bytes=0):
        return 5


def _source(height=37, width=23, channels=2, seed=0):
    pixels = np.random.default_rng(seed).random((height, width, channels)).astype(np.float32)
    return _Small(pixels, [f"c{k}" for k in range(channels)])


@settings(max_examples=30, deadline=None)
@given(st.integers(8, 120), st.integers(8, 120), st.integers(1, 400), st.integers(0, 99))
def test_held_out_is_one_pixel_per_cell_in_any_band(width, height, count, seed):
    held = HeldOut(width, height, count, seed)
    every = held.pixels(0, height)
    cells = every // held.cell
    assert len(np.unique(cells[:, 0] * held.ny + cells[:, 1])) == len(every) == held.nx * held.ny
    assert (every >= 0).all() and (every[:, 0] < width).all() and (every[:, 1] < height).all()
    assert len(every) <= max(1, width * height // 64) * 4  # at most one pixel in 64, give or take the border cells
    rows = np.concatenate([held.mask(y0, min(height, y0 + 7)) for y0 in range(0, height, 7)])
    expect = np.zeros((height, width), bool)
    expect[every[:, 1], every[:, 0]] = True
    np.testing.assert_array_equal(rows, expect)


@pytest.mark.parametrize("world", [1, 3])
def test_scan_over_the_ranks_sums_to_the_whole_image(world):
    source = _source()
    held = HeldOut(23, 37, 20)
    parts = [scan(source, held_out=held, rank=r, world=world) for r in range(world)]
    pixels = source.pixels.reshape(-1, 2)
    np.testing.assert_array_equal(np.min([p.lo for p in parts], axis=0), pixels.min(axis=0))
    np.testing.assert_array_equal(np.max([p.hi for p in parts], axis=0), pixels.max(axis=0))
    np.testing.assert_allclose(np.sum([p.total for p in parts], axis=0), pixels.sum(axis=0, dtype=np.float64))
    assert sum(p.count for p in parts) == 23 * 37
    xy = np.concatenate([p.held_xy for p in parts])
    assert sorted(map(tuple, xy)) == sorted(map(tuple, held.pixels(0, 37)))
    np.testing.assert_array_equal(np.concatenate([p.held_values for p in parts]),
                                  source.pixels[xy[:, 1], xy[:, 0]])


def _epoch(sampler, generator):
    """A new epoch of a band sampler: (xy (n, 2), target (n, C))."""
    sampler._draw(generator)
    return sampler.xy.numpy(), sampler.target.numpy()


def test_batches_visit_each_epoch_once_across_epoch_borders():
    source = _source()
    sampler = band_sampler(source, (0, 0, 23, 37), 100, epoch_pixels=10**6)
    generator = torch.Generator().manual_seed(0)
    xy = torch.cat([sampler(k, generator)[0] for k in range(26)]).numpy()  # 2600 samples: 3 epochs and a bit
    assert sampler.epoch == 4
    pixel = np.floor(xy[:, 1]) * 23 + np.floor(xy[:, 0])
    for e in range(3):
        np.testing.assert_array_equal(np.sort(pixel[e * 851 : (e + 1) * 851]), np.arange(851))


def test_full_epochs_visit_every_kept_pixel_once_and_ranks_share_them():
    source = _source()
    held = HeldOut(23, 37, 10)
    domain = (10.0, -5.0, 33.0, 69.0)  # pixels of 1 × 2 domain units
    seen = []
    for rank in range(2):
        sampler = band_sampler(source, domain, 64, epoch_pixels=10**6, held_out=held, rank=rank, world=2)
        assert sampler.cells == 23 * sum(b1 - b0 for b0, b1 in sampler.bands)
        xy, target = _epoch(sampler, torch.Generator().manual_seed(rank))
        ij = np.floor((xy - [10.0, -5.0]) / [1.0, 2.0]).astype(int)
        np.testing.assert_array_equal(target, source.pixels[ij[:, 1], ij[:, 0]])  # the pixel under the point
        seen.append(ij[:, 1] * 23 + ij[:, 0])
    assert len(np.intersect1d(seen[0], seen[1])) == 0  # each rank samples its own bands
    every = np.sort(np.concatenate(seen))
    expect = np.setdiff1d(np.arange(23 * 37), held.pixels(0, 37) @ [1, 23])
    np.testing.assert_array_equal(every, expect)  # every pixel but the held-out ones, once


def test_smaller_epochs_are_stratified_and_leave_mixed_pixels_out():
    from dfc.geometry.triangulate import triangulate

    from ._scene import scene_curves

    mesh = triangulate(scene_curves(), max_triangles=200)
    pixels = scene_image()
    source = _Small(pixels, ["R", "G", "B"])
    mixed = EdgeMask(mesh, 64, 64)
    sampler = band_sampler(source, mesh.domain, 50, epoch_pixels=256, mixed=mixed)
    assert (sampler.gx, sampler.gy) == (16, 16)
    generator = torch.Generator().manual_seed(3)
    counts = []
    for _ in range(3):
        xy, target = _epoch(sampler, generator)
        assert len(xy) <= sampler.cells == 256
        ij = np.floor(xy).astype(int)
        assert not edge_pixels(mesh, 64, 64)[ij[:, 1], ij[:, 0]].any()
        np.testing.assert_array_equal(target, pixels[ij[:, 1], ij[:, 0]])
        cell = (ij[:, 1] // 4) * 16 + ij[:, 0] // 4
        assert len(np.unique(cell)) == len(cell)  # at most one sample per 4 × 4 cell
        counts.append(len(cell))
    assert sampler.epoch == 3 and min(counts) > 200  # cells lose their sample only on a mixed pixel


def test_default_epoch_is_sized_to_memory():
    assert default_epoch_pixels(100, 3) == 100
    assert default_epoch_pixels(1 << 40, 3, budget=36 * 1000) == 1000


def test_rank_without_rows_and_all_pixels_left_out_are_clear_errors():
    with pytest.raises(InputError, match="too few rows"):
        band_sampler(_source(height=1, width=4), (0, 0, 4, 1), 2, rank=1, world=2)
    class Everywhere:
        def rows(self, y0, y1):
            return np.ones((y1 - y0, 8), bool)

    sampler = band_sampler(_source(height=8, width=8), (0, 0, 8, 8), 4, mixed=Everywhere())
    with pytest.raises(InputError, match="every pixel"):
        sampler(0, torch.Generator())


def test_fit_bands_fits_the_scene_out_of_core():
    from dfc.geometry.triangulate import triangulate
    from dfc.metrics import psnr

    from ._scene import scene_curves

    mesh = triangulate(scene_curves(), max_triangles=300)
    pixels = scene_image()
    source = _Small(pixels, ["R", "G", "B"])
    held = HeldOut(64, 64, 64)
    stats = scan(source, held_out=held)
    model = fit_bands(source, mesh, stats, steps=200, batch_size=2048, epoch_pixels=1024, mixed=EdgeMask(mesh, 64, 64),
                      held_out=held)
    centres = torch.from_numpy(stats.held_xy + 0.5)
    with torch.no_grad():
        assert psnr(stats.held_values, model(centres).numpy(), data_range=1.0) > 30.0


def test_located_epochs_give_the_queries_of_their_points():
    from dfc.field.feature_field import FeatureField
    from dfc.geometry.triangulate import triangulate

    from ._scene import scene_curves

    field = FeatureField(triangulate(scene_curves(), max_triangles=200))
    sampler = band_sampler(_Small(scene_image(), ["R", "G", "B"]), field.mesh.domain, 700, epoch_pixels=1000,
                           query=field.query)
    generator = torch.Generator().manual_seed(1)
    for step in range(4):  # crosses an epoch border
        xy, target, (idx, w) = sampler(step, generator)
        ref_idx, ref_w = field.query(xy)
        assert torch.equal(idx, ref_idx) and torch.equal(w, ref_w)
