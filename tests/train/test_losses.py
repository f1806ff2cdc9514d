"""The data loss: MSE and the relative MSE with its detached denominator."""

import pytest
import torch

from dfc.train.losses import loss_value


def test_loss_values_and_relmse_gradient():
    f = torch.tensor([[0.5, 2.0]], requires_grad=True)
    g = torch.tensor([[0.3, 1.0]])
    assert loss_value("mse", f, g).item() == pytest.approx((0.04 + 1.0) / 2)
    rel = loss_value("relmse", f, g)
    assert rel.item() == pytest.approx((0.04 / 0.51**2 + 1.0 / 2.01**2) / 2)
    rel.backward()  # the denominator is detached: d/df = (f - g) / (f + 0.01)² (mean over 2)
    torch.testing.assert_close(f.grad, torch.tensor([[0.2 / 0.51**2, 1.0 / 2.01**2]]))
    with pytest.raises(ValueError, match="loss"):
        loss_value("l1", f, g)
