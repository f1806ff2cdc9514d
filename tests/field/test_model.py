import json

import numpy as np
import pytest
import torch

from dfc.errors import FormatError
from dfc.field.feature_field import FeatureField
from dfc.field.mlp import MLP, OneBlob, _ReluMLP
from dfc.field.model import FieldModel
from dfc.field.quantize import dequantize_weights, fake_quantize_weights, quantize_weights
from dfc.geometry.curves import Curves, elevate
from dfc.geometry.triangulate import triangulate


@pytest.fixture(scope="module")
def mesh():
    cp = np.stack([elevate(np.array([[(2.0, 0.0), (6.0, 8.0)]]), 1)[0], np.array([(0, 5), (3, 2), (5, 9), (8, 6.0)])])
    curves = Curves((0.0, 0.0, 8.0, 8.0), cp, [1, 3], [0, 1], [(0, 1)] * 2, names=["a", "b"], sides=[None] * 2)
    return triangulate(curves, max_triangles=200)


def _xy(n=50, seed=1):
    return torch.rand(n, 2, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 8


# -- MLP and OneBlob ----------------------------------------------------------------------------
@pytest.mark.parametrize("layers,activation", [(0, "relu"), (2, "relu"), (3, "tanh")])
def test_mlp_shapes(layers, activation):
    m = MLP(7, 3, hidden=16, layers=layers, activation=activation)
    assert m(torch.zeros(5, 7)).shape == (5, m.get_out_dim()) == (5, 3)
    assert len(m.linears()) == layers + 1
    act = torch.nn.Tanh if activation == "tanh" else torch.nn.ReLU
    assert sum(isinstance(mod, act) for mod in m.net) == layers


@pytest.mark.parametrize("activation,n", [("relu", 10), ("relu", 5000), ("tanh", 50)])
def test_mlp_values_and_gradients_are_those_of_the_plain_layers(activation, n):
    """The decoder (for ReLU its own forward and backward, whose narrow products run transposed) gives the values
    and gradients of the layers applied one after another, to float32 rounding."""
    m = MLP(5, 3, hidden=16, layers=2, activation=activation)
    act = torch.relu if activation == "relu" else torch.tanh
    x = torch.randn(n, 5, requires_grad=True)
    x_ref = x.detach().clone().requires_grad_(True)
    lin = m.linears()
    y_ref = lin[2](act(lin[1](act(lin[0](x_ref)))))
    grads_ref = torch.autograd.grad(y_ref.square().sum(), [x_ref, *m.parameters()])
    y = m(x)
    grads = torch.autograd.grad(y.square().sum(), [x, *m.parameters()])
    torch.testing.assert_close(y, y_ref, rtol=1e-5, atol=1e-6)
    for a, b in zip(grads, grads_ref):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5 * float(b.abs().max()))


def test_relu_mlp_gradient_is_the_derivative():
    """The ReLU decoder's own backward against finite differences (float64, inputs away from the kinks: rows with a
    hidden pre-activation within 1e-3 of zero are left out, where a finite difference would straddle the kink)."""
    with torch.random.fork_rng():
        torch.manual_seed(0)
        m = MLP(5, 3, hidden=8, layers=2).double()
        x = torch.randn(80, 5, dtype=torch.float64)
    clear, h = torch.ones(len(x), dtype=torch.bool), x
    for lin in m.linears()[:-1]:
        z = lin(h).detach()
        clear &= (z.abs() > 1e-3).all(dim=1)
        h = torch.relu(z)
    x = x[clear][:40].clone().requires_grad_(True)
    assert len(x) >= 20
    params = [p.detach().clone().requires_grad_(True) for p in (*(lin.weight for lin in m.linears()),
                                                                *(lin.bias for lin in m.linears()))]
    assert torch.autograd.gradcheck(lambda x, *p: _ReluMLP.apply(x, *p), (x, *params))


def test_mlp_rejects_bad_arguments():
    with pytest.raises(ValueError, match="activation"):
        MLP(2, 3, activation="gelu")
    with pytest.raises(ValueError, match="in_dim"):
        MLP(0, 3)
    with pytest.raises(ValueError, match=r"expected input \(\.\.\., 4\)"):
        MLP(4, 1)(torch.zeros(2, 3))


def test_oneblob_values_and_gradient():
    enc = OneBlob(bins=4, domain=(0.0, 0.0, 8.0, 4.0))
    assert enc.get_out_dim() == 8
    # x = 3 → u = 0.375, the centre of bin 1; y = 0.5 → v = 0.125, the centre of bin 0
    out = enc(torch.tensor([[3.0, 0.5]], dtype=torch.float64))[0]
    assert out[1] == pytest.approx(1.0) and out[4] == pytest.approx(1.0)
    assert out[0] == pytest.approx(np.exp(-0.5)) and out[7] == pytest.approx(np.exp(-0.5 * 9))
    xy = torch.tensor([[1.3, 2.2]], dtype=torch.float64, requires_grad=True)
    enc(xy).sum().backward()
    eps = 1e-4
    fd = (enc(xy.detach() + torch.tensor([[eps, 0.0]], dtype=torch.float64)).sum() - enc(xy.detach()).sum()) / eps
    assert xy.grad[0, 0].item() == pytest.approx(fd.item(), rel=1e-2)
    with pytest.raises(ValueError, match="bins"):
        OneBlob(bins=0)


# -- FieldModel ---------------------------------------------------------------------------------
def test_forward_shapes_and_features(mesh):
    model = FieldModel(FeatureField(mesh, dim=4), ["R", "G"], hidden=8, oneblob_bins=3)
    xy = _xy()
    assert model(xy).shape == (50, 2) and model(xy).dtype == torch.float32
    torch.testing.assert_close(model.features(xy), model.field.features(xy))
    assert model.decoder.in_dim == 4 + 6


def test_log_transform(mesh):
    model = FieldModel(FeatureField(mesh), ["Y"], transform="log")
    xy = _xy()
    y = model.decoder(model.features(xy))
    torch.testing.assert_close(model(xy), torch.expm1(y))


def test_precomputed_query_matches(mesh):
    model = FieldModel(FeatureField(mesh), ["R", "G", "B"])
    with torch.no_grad():
        model.field.bank.uniform_(-1, 1)
    xy = _xy()
    torch.testing.assert_close(model(xy, query=model.field.query(xy)), model(xy))


def test_config_round_trip(mesh):
    model = FieldModel(FeatureField(mesh, dim=3), ["R", "G", "B"], hidden=16, layers=1, activation="tanh",
                       oneblob_bins=4, transform="log")
    config = json.loads(json.dumps(model.config()))
    assert config["channels"] == ["R", "G", "B"] and config["dim"] == 3 and config["n_slices"] == 1
    again = FieldModel.from_config(mesh, config)
    again.load_state_dict(model.state_dict())
    xy = _xy()
    torch.testing.assert_close(again(xy), model(xy))
    assert again.config() == config
    with pytest.raises(FormatError, match="keys"):
        FieldModel.from_config(mesh, {**config, "extra": 1})
    with pytest.raises(FormatError, match="activation"):
        FieldModel.from_config(mesh, {**config, "activation": "swish"})


def test_decoder_init_is_seeded(mesh):
    a = FieldModel(FeatureField(mesh), ["Y"], seed=3)
    b = FieldModel(FeatureField(mesh), ["Y"], seed=3)
    c = FieldModel(FeatureField(mesh), ["Y"], seed=4)
    torch.testing.assert_close(a.decoder.net[0].weight, b.decoder.net[0].weight, rtol=0, atol=0)
    assert not torch.equal(a.decoder.net[0].weight, c.decoder.net[0].weight)


def test_quantized_mode(mesh):
    model = FieldModel(FeatureField(mesh), ["R", "G"], hidden=8)
    with torch.no_grad():
        model.field.bank.uniform_(-1, 1)
    raw_bank = model.field.bank.detach().clone()
    raw_w = model.decoder.net[0].weight.detach().clone()
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    model.quantization = {"feature_bits": 4}
    bank = model.field.bank.detach()
    for k in range(bank.shape[-1]):
        assert len(torch.unique(bank[..., k])) <= 16
    w = model.decoder.net[0].weight.detach()
    torch.testing.assert_close(w, w.half().float(), rtol=0, atol=0)
    assert not torch.equal(w, raw_w)
    # gradients reach the raw parameters the optimiser holds (straight-through)
    model(_xy()).sum().backward()
    optimizer.step()
    model.quantization = None
    assert not torch.equal(model.field.bank.detach(), raw_bank)
    assert list(dict(model.named_parameters())) == ["field.bank"] + [
        f"decoder.net.{i}.{n}" for i in (0, 2, 4) for n in ("weight", "bias")
    ]
    with pytest.raises(ValueError, match="feature_bits"):
        model.quantization = {"feature_bits": 0}
    with pytest.raises(ValueError, match="feature_bits"):
        model.quantization = {"bits": 8}


def test_integer_weight_mode_freezes_the_weight_matrices(mesh):
    model = FieldModel(FeatureField(mesh), ["R", "G"], hidden=8)
    raw = [lin.weight.detach().clone() for lin in model.decoder.linears()]
    bias = model.decoder.linears()[0].bias.detach().clone()
    optimizer = torch.optim.Adam(model.parameters(), lr=0.1)
    model.quantization = {"feature_bits": 8, "weight_bits": 3}
    assert model.quantization == {"feature_bits": 8, "weight_bits": 3}
    for lin, w in zip(model.decoder.linears(), raw):
        q, scale = quantize_weights(w, 3)
        assert q.abs().max() <= 3 and torch.equal(lin.weight, dequantize_weights(q, scale))
    model(_xy()).square().sum().backward()
    optimizer.step()
    model.quantization = None  # the weight matrices kept their raw values; features and biases trained
    assert all(torch.equal(lin.weight, w) and lin.weight.requires_grad for lin, w in zip(model.decoder.linears(), raw))
    assert not torch.equal(model.decoder.linears()[0].bias, bias)
    with pytest.raises(ValueError, match="weight bits"):
        model.quantization = {"feature_bits": 8, "weight_bits": 1}


def test_weight_quantisation_is_per_row_and_symmetric():
    W = torch.tensor([[0.5, -1.0, 0.25], [0.0, 0.0, 0.0], [3.0, 1.5, -0.75]])
    q, scale = quantize_weights(W, 4)
    assert torch.allclose(scale, torch.tensor([1 / 7, 1.0, 3 / 7]), rtol=1e-3)
    assert q.abs().max() == 7 and q[0, 1] == -7 and q[2, 0] == 7 and not q[1].any()
    assert torch.equal(scale, scale.half().float())  # the file stores float16 scales
    W.requires_grad_(True)
    fake_quantize_weights(W, 4).sum().backward()
    assert torch.equal(W.grad, torch.ones_like(W))  # straight through


@pytest.mark.parametrize("bits", [8, 12, 14, 15, 16])
def test_many_weight_bits_keep_small_weights(bits):
    """At 15 and 16 bits the scale of a row of weights below 1 or 2 is below float16's smallest normal: it is that
    normal, not 1 (which rounded every weight of the README sample's decoder to 0 or ±1: 61.2 → 28.8 dB)."""
    gen = torch.Generator().manual_seed(0)
    W = (torch.rand(32, 32, generator=gen) - 0.5) * torch.logspace(-4, 0, 32)[:, None]  # rows' largest 1e-4 … 0.5
    q, scale = quantize_weights(W, bits)
    top = 2 ** (bits - 1) - 1
    assert q.abs().max() <= top and torch.equal(scale, scale.half().float()) and bool((scale > 0).all())
    assert torch.all((dequantize_weights(q, scale) - W).abs() <= 0.5 * scale[:, None] * (1 + 1e-6))
    assert float((dequantize_weights(q, scale) - W).abs().max()) < 0.5 * 2.0 / top + 1e-7


def test_rejects_bad_options(mesh):
    field = FeatureField(mesh)
    with pytest.raises(ValueError, match="transform"):
        FieldModel(field, ["R"], transform="gamma")
    with pytest.raises(ValueError, match="unique"):
        FieldModel(field, ["R", "R"])
    with pytest.raises(ValueError, match="single time slice"):
        FieldModel(FeatureField(mesh, n_slices=2, times=[0.0, 1.0]), ["R"])(_xy(), 0.5, query=field.query(_xy()))


def test_queries_outside_the_domain_take_the_nearest_domain_value(mesh):
    """spec/conventions.md: the one-blob encoding clamps exactly as the feature field does."""
    model = FieldModel(FeatureField(mesh, dim=4, seed=3), ["R"], hidden=8, oneblob_bins=4, seed=3)
    x0, y0, x1, y1 = mesh.domain
    mid = 0.5 * (y0 + y1)
    outside = torch.tensor([[x0 - 5.0 * (x1 - x0), mid], [x1 + 1.0, y1 + 1.0]], dtype=torch.float64)
    border = torch.tensor([[x0, mid], [x1, y1]], dtype=torch.float64)
    with torch.no_grad():
        torch.testing.assert_close(model(outside), model(border), rtol=0, atol=0)
        assert not torch.equal(model(border[:1]), model(border[1:]))
