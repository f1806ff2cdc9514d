"""Data samplers: stratified epochs over pixels, the point-location cache and excluded pixels."""

import numpy as np
import pytest
import torch

from dfc.field.feature_field import FeatureField
from dfc.train.samplers import image_sampler

from ._scene import scene_image


def test_sampler_visits_every_pixel_once_per_epoch():
    h, w = 5, 7
    image = np.arange(h * w, dtype=np.float32).reshape(h, w, 1)
    domain = (10.0, 20.0, 24.0, 30.0)  # 2 × 2 units per pixel
    sampler = image_sampler(image, domain, batch_size=8)
    gen = torch.Generator().manual_seed(0)
    xy, target = map(torch.cat, zip(*[sampler(k, gen) for k in range(9)]))  # 72 samples: 2 epochs + 2
    assert xy.dtype == torch.float64 and target.shape == (72, 1)
    ij = np.floor((xy.numpy() - [10.0, 20.0]) / 2.0).astype(int)
    np.testing.assert_array_equal(ij[:, 1] * w + ij[:, 0], target[:, 0].numpy())  # each point in its pixel
    for epoch in (slice(0, 35), slice(35, 70)):
        assert sorted(target[epoch, 0].tolist()) == list(range(35))
    assert not torch.equal(target[:35], target[35:70])  # a fresh order each epoch


def test_sampler_query_cache_and_exclusion(scene_mesh):
    field = FeatureField(scene_mesh)
    image = scene_image(spp=1)
    exclude = np.zeros((64, 64), bool)
    exclude[:, :32] = True
    sampler = image_sampler(image, scene_mesh.domain, 1000, query=field.query, jitter_sets=2, exclude=exclude)
    xy, _, (idx, w) = sampler(0, torch.Generator().manual_seed(0))
    assert (xy[:, 0] >= 32).all()
    ref_idx, ref_w = field.query(xy)
    torch.testing.assert_close(idx, ref_idx, rtol=0, atol=0)
    torch.testing.assert_close(w, ref_w)
    with pytest.raises(ValueError, match="exclude"):
        image_sampler(image, scene_mesh.domain, 10, exclude=np.zeros((3, 3), bool))


@pytest.mark.parametrize("batch_size", [23, 100])  # batches that straddle epochs; larger than an epoch
# batches of one chunk of pixels; of several, straddling chunks and laid-out blocks of three chunks
@pytest.mark.parametrize("chunks, block", [(1, 64), (8, 3)])
def test_filtered_sampler_batches_cross_epochs(batch_size, chunks, block, monkeypatch):
    from dfc.field.feature_field import pack_query
    from dfc.pixel_filter import parse
    from dfc.train import pixel_sampler
    from dfc.train.pixel_sampler import filtered_sampler

    monkeypatch.setattr(pixel_sampler, "CHUNKS_PER_BATCH", chunks)
    monkeypatch.setattr(pixel_sampler, "BLOCK_CHUNKS", block)

    h, w, sets = 6, 7, 3
    image = np.arange(h * w, dtype=np.float32).reshape(h, w, 1)
    filtered = np.zeros((h, w), bool)
    filtered[2:4, 1:5] = True

    def query(xy):  # a stand-in for field.query: a function of the point alone, one slot of weight 0
        return (torch.cat([torch.floor(xy * 10).long(), torch.zeros(len(xy), 1, dtype=torch.long)], 1),
                torch.cat([xy.float(), torch.zeros(len(xy), 1)], 1))

    sampler = filtered_sampler(image, (0.0, 0.0, float(w), float(h)), batch_size, parse("box:4"), filtered,
                               query=query, sets=sets, seed=0)
    gen = torch.Generator().manual_seed(0)
    pixels, epoch_points = [], []
    for step in range(6):
        xy, target, pw = sampler(step, gen)
        assert target.shape == (batch_size, 1)
        for got, want in zip(pw.query, pack_query(*query(xy))):  # each point's own location, no zero slot
            torch.testing.assert_close(got, want, rtol=0, atol=0)
        assert len(pw.query.idx) == 2 * len(xy) - int((xy == 0).sum())
        pixel = target[pw.row, 0].long()  # the pixel each point belongs to (the image holds its index)
        assert torch.equal(torch.floor(xy[:, 0]).long(), pixel % w)  # each point in its pixel
        assert torch.equal(torch.floor(xy[:, 1]).long(), pixel // w)
        counts = torch.bincount(pw.row, minlength=batch_size)
        np.testing.assert_array_equal(counts, np.where(filtered.ravel()[target[:, 0].long()], 16, 1))
        np.testing.assert_allclose(torch.zeros(batch_size).index_add_(0, pw.row, pw.weight), 1.0, rtol=1e-6)
        pixels.append(target[:, 0].long())
        epoch_points.append(xy)
    pixels = torch.cat(pixels)
    n = h * w
    for e in range(len(pixels) // n):  # every pixel once per epoch, a fresh order each
        assert sorted(pixels[e * n:(e + 1) * n].tolist()) == list(range(n))
    assert not torch.equal(pixels[:n], pixels[n:2 * n])


def test_steep_pixels_get_the_dense_quadrature():
    """Beside an HDR step (0.2 to 30: 3.3 in log units) the filtered pixels get ``STEEP_POINTS`` points, the others
    ``TRAIN_POINTS``, each pixel's weights summing to one; a step within [0, 1] (an LDR image's whole range) is
    never steep."""
    from dfc.pixel_filter import STEEP_POINTS, TRAIN_POINTS, parse
    from dfc.train.fit import steep_pixels
    from dfc.train.pixel_sampler import filtered_sampler

    h, w = 8, 12
    hdr = np.full((h, w, 1), 0.2, np.float32)
    hdr[:, 6:] = 30.0
    hdr[:, :3] = 0.9
    steep = steep_pixels(hdr, "logmse", 2)
    assert steep[:, 4:8].all() and not steep[:, :4].any() and not steep[:, 8:].any()
    assert not steep_pixels(np.clip(hdr, 0.0, 1.0), "mse", 2).any()
    filtered = np.zeros((h, w), bool)
    filtered[:, 1:7] = True
    index = np.arange(h * w, dtype=np.float32).reshape(h, w, 1)  # each pixel's target is its index
    sampler = filtered_sampler(index, (0.0, 0.0, float(w), float(h)), h * w, parse("gaussian:0.5"), filtered,
                               steep=steep & filtered, seed=0)
    xy, target, pw = sampler(0, torch.Generator().manual_seed(0))
    pixel = target[:, 0].long().numpy()
    counts = np.zeros(h * w, int)
    counts[pixel] = torch.bincount(pw.row, minlength=h * w).numpy()
    want = np.where(filtered & steep, STEEP_POINTS, np.where(filtered, TRAIN_POINTS, 1))
    np.testing.assert_array_equal(counts.reshape(h, w), want)
    np.testing.assert_allclose(torch.zeros(h * w).index_add_(0, pw.row, pw.weight), 1.0, rtol=1e-5)
