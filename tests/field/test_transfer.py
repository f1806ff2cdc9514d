"""Carrying a fitted field onto another mesh of the same curves (dfc.field.transfer)."""

import numpy as np
import pytest
import torch

from dfc.field.feature_field import FeatureField
from dfc.field.model import FieldModel
from dfc.field.transfer import carry_over, support_points
from dfc.geometry.curves import Curves, elevate
from dfc.geometry.triangulate import triangulate


@pytest.fixture(scope="module")
def curves():
    cp = np.stack([elevate(np.array([[(2.0, 0.0), (6.0, 8.0)]]), 1)[0], np.array([(0, 5), (3, 2), (5, 9), (8, 6.0)])])
    return Curves((0.0, 0.0, 8.0, 8.0), cp, [1, 3], [0, 1], [(0, 1)] * 2, names=["a", "b"], sides=[None] * 2)


def _smooth_model(mesh, seed=0):
    """A model whose features are a smooth function of position on each side of the straight curve, so another mesh
    of the same curves can represent them closely."""
    model = FieldModel(FeatureField(mesh, dim=3, seed=seed), ["R", "G"], hidden=8, seed=seed)
    xy = support_points(mesh)
    with torch.no_grad():
        idx, w = model.field.query(torch.from_numpy(xy))
    # a bank fitted by least squares to sin/cos of the position, plus a jump across the straight curve x = 2 + y / 2
    side = (xy[:, 0] > 2 + xy[:, 1] / 2).astype(np.float64)
    target = np.stack([np.sin(xy[:, 0] / 3) + side, np.cos(xy[:, 1] / 2), xy[:, 0] * xy[:, 1] / 64], axis=1)
    import scipy.sparse as sp
    from scipy.sparse.linalg import lsqr

    A = sp.csr_matrix((w.numpy().ravel(), (np.repeat(np.arange(len(xy)), idx.shape[1]), idx.numpy().ravel())),
                      shape=(len(xy), model.field.n_features))
    bank = np.stack([lsqr(A, target[:, k])[0] for k in range(3)], axis=1)
    with torch.no_grad():
        model.field.bank.copy_(torch.from_numpy(bank)[None].to(model.field.bank))
    return model


def _features(model, xy):
    with torch.no_grad():
        return model.features(torch.from_numpy(xy)).numpy()


def test_support_points_touch_every_row(curves):
    mesh = triangulate(curves, max_triangles=120)
    field = FeatureField(mesh, dim=2)
    with torch.no_grad():
        idx, w = field.query(torch.from_numpy(support_points(mesh)))
    used = np.unique(idx.numpy()[w.numpy() > 1e-6])
    assert np.array_equal(used, np.arange(field.n_features))


def test_carry_over_on_the_same_mesh_reproduces_the_field(curves):
    mesh = triangulate(curves, max_triangles=120)
    old = _smooth_model(mesh, seed=0)
    raw = old.field.bank.detach().clone()
    old.quantization = {"feature_bits": 8}
    new = FieldModel(FeatureField(mesh, dim=3, seed=5), ["R", "G"], hidden=8, seed=5)
    xy = np.random.default_rng(0).uniform(0, 8, (2000, 2))
    carry_over(old, new, xy)
    assert old.quantization == {"feature_bits": 8}  # left as it was: an encoder still stores it with those bits
    assert not torch.allclose(old.field.bank, raw, rtol=0, atol=1e-3)  # (8-bit steps are coarser than the tolerance)
    torch.testing.assert_close(new.field.bank, raw, rtol=1e-3, atol=1e-3)  # the raw values are carried
    old.quantization = None
    for a, b in zip(new.decoder.state_dict().values(), old.decoder.state_dict().values()):
        assert torch.equal(a, b)
    with torch.no_grad():
        torch.testing.assert_close(new(torch.from_numpy(xy)), old(torch.from_numpy(xy)), rtol=0, atol=1e-3)


def test_carry_over_onto_a_refined_mesh_keeps_the_features_and_the_jumps(curves):
    coarse = triangulate(curves, max_triangles=120)
    rng = np.random.default_rng(1)
    fine = triangulate(curves, max_triangles=120, extra_points=rng.uniform(0.5, 7.5, (150, 2)))
    assert fine.n_triangles > coarse.n_triangles + 100
    old = _smooth_model(coarse)
    new = FieldModel(FeatureField(fine, dim=3, seed=3), ["R", "G"], hidden=8, seed=3)
    xy = rng.uniform(0, 8, (4000, 2))
    carry_over(old, new, xy)
    a, b = _features(old, xy), _features(new, xy)
    assert np.sqrt(np.mean((a - b) ** 2)) < 0.05 * a.std()
    # across the straight curve x = 2 + y / 2, both sides keep their own values
    y = rng.uniform(1, 7, 200)
    left, right = np.stack([2 + y / 2 - 1e-3, y], 1), np.stack([2 + y / 2 + 1e-3, y], 1)
    jump_old = _features(old, right) - _features(old, left)
    jump_new = _features(new, right) - _features(new, left)
    assert np.abs(jump_old).mean() > 0.05
    assert np.abs(jump_new - jump_old).mean() < 0.2 * np.abs(jump_old).mean()


def test_carry_over_keeps_every_row_within_the_old_range(curves):
    """A row that the points barely constrain (few points, a curve's thin sliver) would take any value the least
    squares allow; carried rows stay within the old bank's range per channel, which sets the file's quantisation."""
    coarse = triangulate(curves, max_triangles=120)
    rng = np.random.default_rng(2)
    fine = triangulate(curves, max_triangles=120, extra_points=rng.uniform(0.5, 7.5, (150, 2)))
    old = FieldModel(FeatureField(coarse, dim=3, seed=4), ["R", "G"], hidden=8, seed=4)
    with torch.no_grad():
        old.field.bank.copy_(torch.from_numpy(rng.normal(0.0, 1.0, tuple(old.field.bank.shape))))  # a rough bank
    new = FieldModel(FeatureField(fine, dim=3, seed=3), ["R", "G"], hidden=8, seed=3)
    carry_over(old, new, rng.uniform(0, 8, (40, 2)))
    lo, hi = old.field.bank.detach().amin(dim=(0, 1)), old.field.bank.detach().amax(dim=(0, 1))
    bank = new.field.bank.detach()
    assert bool(((bank >= lo - 1e-6) & (bank <= hi + 1e-6)).all())
    assert bool(((bank - lo).abs() < 1e-6).any() | ((bank - hi).abs() < 1e-6).any())  # the range is reached: clipped


def test_carry_over_solves_the_damped_least_squares_exactly(curves):
    """The carried bank is the minimiser of |A b − t|² + damp² |b|² (then clipped to the old range), for every
    channel: the same as a dense solve of the stacked system."""
    from dfc.field import transfer

    coarse = triangulate(curves, max_triangles=120)
    rng = np.random.default_rng(5)
    fine = triangulate(curves, max_triangles=120, extra_points=rng.uniform(0.5, 7.5, (60, 2)))
    old = _smooth_model(coarse)
    new = FieldModel(FeatureField(fine, dim=3, seed=3), ["R", "G"], hidden=8, seed=3)
    xy = rng.uniform(0, 8, (500, 2))
    carry_over(old, new, xy)
    points = np.concatenate([xy, support_points(fine)])
    with torch.no_grad():
        idx, w = new.field.query(torch.from_numpy(points))
    A = np.zeros((len(points), new.field.n_features))
    np.add.at(A, (np.repeat(np.arange(len(points)), idx.shape[1]), idx.numpy().ravel()), w.numpy().ravel())
    stacked = np.concatenate([A, transfer._DAMP * np.eye(A.shape[1])])
    target = np.concatenate([_features(old, points), np.zeros((A.shape[1], 3))]).astype(np.float64)
    want = np.linalg.lstsq(stacked, target, rcond=None)[0]
    bank = old.field.bank.detach().double().numpy()[0]
    want = np.clip(want, bank.min(axis=0), bank.max(axis=0))
    np.testing.assert_allclose(new.field.bank.detach().double().numpy()[0], want, rtol=0, atol=1e-5)
