"""The training loop, through ``fit``: determinism, progress, argument checks."""

import numpy as np
import pytest
import torch

from dfc.field.feature_field import FeatureField
from dfc.field.model import FieldModel
from dfc.train.fit import fit
from dfc.train.samplers import image_sampler

from ._scene import scene_image


def test_fit_is_deterministic(scene_mesh):
    image = scene_image(spp=1)

    def run():
        model = FieldModel(FeatureField(scene_mesh, seed=1), ["R", "G", "B"], hidden=16, seed=1)
        sampler = image_sampler(image, scene_mesh.domain, 512)
        history = fit(model, sampler, steps=12, seed=5, qat_steps=3)
        return model, history

    (a, ha), (b, hb) = run(), run()
    assert ha == hb and len(ha["loss"]) == 12
    for (na, pa), (nb, pb) in zip(a.state_dict().items(), b.state_dict().items()):
        assert na == nb and torch.equal(pa, pb), na


def test_fused_adam_equals_the_per_tensor_and_foreach_updates(scene_mesh, monkeypatch):
    """The CPU's fused Adam (``FUSED_DEVICES``) gives the per-tensor update's values to float rounding, and the
    per-tensor update the foreach update's (``FOREACH_DEVICES``) to the bit."""
    import dfc.train.loop as loop

    image = scene_image(spp=1)

    def run():
        model = FieldModel(FeatureField(scene_mesh, seed=1), ["R", "G", "B"], hidden=16, seed=1)
        fit(model, image_sampler(image, scene_mesh.domain, 256), steps=20, seed=2, qat_steps=5, decoder_lr=0.2,
            final_lr=1e-3)
        return model.state_dict()

    fused = run()
    monkeypatch.setattr(loop, "FUSED_DEVICES", ())
    per_tensor = run()
    monkeypatch.setattr(loop, "FOREACH_DEVICES", ("cpu", "cuda"))
    foreach = run()
    for name, a in fused.items():
        b = per_tensor[name]
        if b.is_floating_point():
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4 * float(b.abs().max()))
        else:
            assert torch.equal(a, b), name
        assert torch.equal(b, foreach[name]), name


@pytest.mark.parametrize("kind", ["fused", "foreach", "per-tensor"])
def test_loop_adam_is_torch_adam(kind, monkeypatch):
    """The loop's Adam makes ``torch.optim.Adam``'s updates to the bit: two groups, learning rates changed between
    steps, a parameter without a gradient in some steps."""
    import dfc.train.loop as loop

    monkeypatch.setattr(loop, "FUSED_DEVICES", ("cpu",) if kind == "fused" else ())
    monkeypatch.setattr(loop, "FOREACH_DEVICES", ("cpu",) if kind == "foreach" else ())
    gen = torch.Generator().manual_seed(0)
    start = [torch.randn(7, 3, generator=gen), torch.randn(5, generator=gen), torch.randn(2, 2, generator=gen)]
    grads = [[torch.randn_like(p) for p in start] for _ in range(6)]
    ours = [p.clone().requires_grad_(True) for p in start]
    theirs = [p.clone().requires_grad_(True) for p in start]
    mine = loop._Adam([{"params": ours[:2], "lr": 0.0}, {"params": ours[2:], "lr": 0.0}], (0.9, 0.99),
                      torch.device("cpu"))
    ref = torch.optim.Adam([{"params": theirs[:2]}, {"params": theirs[2:]}], lr=0.0, betas=(0.9, 0.99),
                           fused=kind == "fused", foreach=kind == "foreach")
    for k, step_grads in enumerate(grads):
        for a, b, lr in zip(mine.groups, ref.param_groups, (1e-2 * 0.9 ** k, 2e-3)):
            a["lr"] = b["lr"] = lr
        mine.zero_grad()
        ref.zero_grad(set_to_none=True)
        for i, g in enumerate(step_grads):
            if not (i == 1 and k % 2):  # parameter 1 has no gradient in odd steps
                ours[i].grad, theirs[i].grad = g.clone(), g.clone()
        mine.step()
        ref.step()
        for a, b in zip(ours, theirs):
            assert torch.equal(a, b)
    assert not torch.equal(ours[0], start[0])


def test_fit_reduces_loss_and_reports(scene_mesh):
    seen = []
    model = FieldModel(FeatureField(scene_mesh), ["R", "G", "B"])
    history = fit(model, image_sampler(scene_image(spp=1), scene_mesh.domain, 2048), steps=40,
                  callback=lambda step, loss, p: seen.append((step, loss, p)))
    assert [s for s, _, _ in seen] == list(range(40))
    assert history["loss"][-1] < 0.2 * history["loss"][0]
    assert history["psnr"][-1] == pytest.approx(10 * np.log10(1 / history["loss"][-1]), rel=0.05)


@pytest.mark.parametrize("decoder_lr", [1.0, 0.2])
def test_the_decoder_learns_at_its_factor_of_the_features_rate(scene_mesh, decoder_lr):
    model = FieldModel(FeatureField(scene_mesh, seed=1), ["R", "G", "B"], hidden=16, seed=1)
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    fit(model, image_sampler(scene_image(spp=1), scene_mesh.domain, 4096), steps=1, lr=1e-2, decoder_lr=decoder_lr)
    moved = {name: (p.detach() - before[name]).abs().max().item() for name, p in model.named_parameters()}
    features = [v for name, v in moved.items() if name.startswith("field.")]
    decoder = [v for name, v in moved.items() if not name.startswith("field.")]
    assert features and decoder
    # Adam's first step moves every parameter with a gradient by its group's learning rate
    assert max(features) == pytest.approx(1e-2, rel=1e-3)
    assert max(decoder) == pytest.approx(decoder_lr * 1e-2, rel=1e-3)


def test_image_fits_slow_the_decoder_only_when_they_are_long():
    from dfc.train.fit import DECODER_LR, DECODER_LR_MIN_STEPS, image_decoder_lr

    assert DECODER_LR < 1.0
    assert image_decoder_lr(DECODER_LR_MIN_STEPS) == image_decoder_lr(10 * DECODER_LR_MIN_STEPS) == DECODER_LR
    assert image_decoder_lr(DECODER_LR_MIN_STEPS - 1) == 1.0


@pytest.mark.parametrize("steps, lr, expected", [(500, None, "image"), (499, None, 1e-2), (500, 3e-3, 3e-3)])
def test_image_fits_start_at_the_image_rate_when_long(scene_mesh, monkeypatch, steps, lr, expected):
    import dfc.train.fit as fit_module

    assert fit_module.DECODER_LR_MIN_STEPS == 500 and fit_module.IMAGE_LR > 1e-2
    seen = {}
    monkeypatch.setattr(fit_module, "fit", lambda model, sampler, **kw: seen.update(kw))
    fit_module.fit_image(scene_image(spp=1), scene_mesh, steps=steps, lr=lr)
    assert seen["lr"] == (fit_module.IMAGE_LR if expected == "image" else expected)
    assert seen["steps"] == steps


def test_fit_rejects_bad_arguments(scene_mesh):
    model = FieldModel(FeatureField(scene_mesh), ["Y"])
    sampler = image_sampler(np.zeros((4, 4, 1), np.float32), scene_mesh.domain, 4)
    with pytest.raises(ValueError, match="steps"):
        fit(model, sampler, steps=0)
    with pytest.raises(ValueError, match="qat_steps"):
        fit(model, sampler, steps=5, qat_steps=6)
    with pytest.raises(ValueError, match="loss"):
        fit(model, sampler, steps=5, loss="l1")
    with pytest.raises(ValueError, match="decoder_lr"):
        fit(model, sampler, steps=5, decoder_lr=0.0)


class _Staged(torch.nn.Module):
    """A one-parameter model trained in three stages, recording when it grows and when quantisation starts."""

    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(1))
        self.grown, self.quantised_at, self.step = [], None, 0  # step: the next step to run

    def stages(self, steps):
        return [2, 3, steps - 5]

    def next_stage(self):
        self.grown.append(self.step)

    @property
    def quantization(self):
        return None

    @quantization.setter
    def quantization(self, value):
        self.quantised_at = self.step


@pytest.mark.parametrize("restart", [False, True])
def test_loop_runs_stages_and_quantisation_on_the_global_step(restart):
    from dfc.train.loop import Schedule, train

    model, draws = _Staged(), []

    def sampler(step, generator):
        draws.append(float(torch.rand(1, generator=generator)))
        model.step = len(draws)  # the step about to run, when the loop grows or quantises the model
        return (torch.ones(1),)

    def loss(m, batch):
        value = ((m.w - batch[0]) ** 2).sum()
        return value, {"loss": value.detach(), "w": m.w.detach()[0].clone()}

    seen = []
    history = train(model, loss, sampler, Schedule(8, lr=0.1, final_lr=0.01, qat_steps=2, restart_stages=restart),
                    seed=3, callback=lambda step, value, w: seen.append(step))
    assert seen == list(range(8)) and len(history["loss"]) == len(history["w"]) == 8
    assert model.grown == [2, 5] and model.quantised_at == 6
    assert history["w"][0] == 0 < history["w"][-1] < 1  # recorded before each step, moving towards its target, 1
    first_of_stage = [torch.rand(1, generator=torch.Generator().manual_seed(3 + k)).item() for k in range(3)]
    if restart:  # every stage reseeds its sampling with seed + stage
        assert [draws[0], draws[2], draws[5]] == pytest.approx(first_of_stage)
    else:  # one generator straight through
        assert draws[2] != pytest.approx(first_of_stage[1])


def test_quantisation_aware_steps_are_not_spoilt_by_a_few_outlying_features(scene_mesh):
    """A feature row far outside the rest (one that almost no sample reaches drifts under Adam) is clipped to the
    bulk before the quantisation-aware steps: otherwise it takes most of the quantiser's levels and the other
    features collapse onto a handful (measured on real renders: 44 → 22 dB at the first quantised step)."""
    from dfc.render import values_at

    from ._scene import scene_value

    model = FieldModel(FeatureField(scene_mesh, seed=1), ["R", "G", "B"], hidden=16, seed=1)
    sampler = image_sampler(scene_image(spp=1), scene_mesh.domain, 4096)
    fit(model, sampler, steps=150, seed=0)
    xy = np.stack(np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5), -1).reshape(-1, 2)
    truth = scene_value(xy)

    def psnr():
        return 10 * np.log10(1 / np.mean((values_at(model, xy) - truth) ** 2))

    clean = psnr()
    idx, w = model.field.query(torch.from_numpy(xy))
    reach = torch.zeros(model.field.bank.shape[1], dtype=torch.float64).index_add_(0, idx.reshape(-1),
                                                                                 w.reshape(-1).double())
    with torch.no_grad():  # the row the pixels reach least drifts to 200 × the features' spread
        model.field.bank[0, int(reach.argmin())] += 200.0
    fit(model, sampler, steps=10, seed=1, qat_steps=10, feature_bits=6, lr=1e-3)
    assert model.quantization == {"feature_bits": 6}
    assert psnr() > clean - 1.0
    assert float(model.field.bank.detach().abs().max()) < 50.0
