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
