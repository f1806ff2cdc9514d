"""The decoder side of a field: a small MLP and the one-blob encoding of positions.

Both are ``torch.nn.Module`` with ``in_dim`` and ``get_out_dim()`` so they compose without
hard-coded widths (the nerfstudio field-component habit).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["ACTIVATIONS", "MLP", "OneBlob"]

ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh}


class MLP(nn.Module):
    """Fully connected network ``in_dim → hidden → … → hidden → out_dim``.

    ``layers`` is the number of hidden layers (the paper's "two-layer perceptron with 64 neurons"
    is ``hidden=64, layers=2``: three Linear maps). The output layer is linear (no activation).
    Input (N, in_dim) float32 → output (N, out_dim) float32.

    Mixed precision (``mixed_precision``): on CUDA the hidden layers run in bfloat16 under ``torch.autocast`` and the
    output layer in float32. bfloat16 keeps float32's range, so gradients need no loss scaling (and no per-step
    overflow check, which would sync with the host). CPU tensors always run in float32. ``FieldModel`` turns it on
    for the identity value transform only: log-transformed (HDR) fits lose PSNR in bfloat16 (CHANGELOG.md,
    "bfloat16 hidden layers on CUDA").
    """

    mixed_precision = False

    def __init__(self, in_dim: int, out_dim: int, hidden: int = 64, layers: int = 2, activation: str = "relu"):
        super().__init__()
        for name, v, lo in (("in_dim", in_dim, 1), ("out_dim", out_dim, 1), ("hidden", hidden, 1), ("layers", layers, 0)):
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{name} must be an integer ≥ {lo}, got {v!r}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        self.in_dim, self.out_dim, self.hidden, self.layers, self.activation = in_dim, out_dim, hidden, layers, activation
        widths = [in_dim] + [hidden] * layers + [out_dim]
        mods: list[nn.Module] = []
        for i in range(len(widths) - 1):
            mods.append(nn.Linear(widths[i], widths[i + 1]))
            if i < len(widths) - 2:  # ReLU in place: the same values and gradients, one tensor fewer per layer
                mods.append(nn.ReLU(inplace=True) if activation == "relu" else ACTIVATIONS[activation]())
        self.net = nn.Sequential(*mods)

    def get_out_dim(self) -> int:
        return self.out_dim

    def linears(self) -> list[nn.Linear]:
        """The Linear layers in order (what a file stores: weight (out, in) and bias (out,) each)."""
        return [m for m in self.net if isinstance(m, nn.Linear)]

    def forward(self, x: Tensor) -> Tensor:
        if x.shape[-1] != self.in_dim:
            raise ValueError(f"expected input (..., {self.in_dim}), got {tuple(x.shape)}")
        if self.mixed_precision and x.is_cuda:
            with torch.autocast("cuda", dtype=torch.bfloat16):
                hidden = self.net[:-1](x)
            return self.net[-1](hidden.float())
        if self.activation == "relu" and x.dim() == 2 and torch.is_grad_enabled():  # training: the faster backward
            linears = self.linears()
            return _ReluMLP.apply(x, *(m.weight for m in linears), *(m.bias for m in linears))
        return self.net(x)


def _mm(a: Tensor, b: Tensor) -> Tensor:
    """``a @ b`` (m, k) @ (k, n); a product with few columns (n < 16 < m) is computed as ``(bᵀ aᵀ)ᵀ``: the same
    product to float rounding, and on the CPU several times faster for the gradients of the decoder's narrow first
    and last layers (BLAS is slow on tall outputs of a few columns)."""
    if b.shape[1] < 16 < a.shape[0]:
        return b.t().mm(a.t()).t()
    return a.mm(b)


class _ReluMLP(torch.autograd.Function):
    """The ReLU MLP ``x → relu(x W₁ᵀ + b₁) → … → h Wₗᵀ + bₗ`` whose backward takes its products through ``_mm``.
    The forward is ``nn.Linear``'s, so a point's value does not depend on the other points of its call (a render
    cut into regions gives the pixels of the whole). Inputs: x (N, in), the L weights (out, in), the L biases
    (out,)."""

    @staticmethod
    def forward(ctx, x, *params):
        n = len(params) // 2
        weights, biases = params[:n], params[n:]
        inputs = [x]
        for i, (w, b) in enumerate(zip(weights, biases)):
            y = torch.addmm(b, inputs[-1], w.t())
            if i < n - 1:
                y.relu_()
            inputs.append(y)
        ctx.save_for_backward(*inputs[:-1], *weights)
        return inputs[-1]

    @staticmethod
    def backward(ctx, grad):
        saved = ctx.saved_tensors
        n = len(saved) // 2
        inputs, weights = saved[:n], saved[n:]
        grad_w, grad_b = [None] * n, [None] * n
        g = grad
        for i in reversed(range(n)):
            grad_w[i] = _mm(g.t(), inputs[i])
            grad_b[i] = g.sum(0)
            if i > 0 or ctx.needs_input_grad[0]:
                g = _mm(g, weights[i])
                if i > 0:
                    g = torch.ops.aten.threshold_backward(g, inputs[i], 0)
        return (g.contiguous() if ctx.needs_input_grad[0] else None), *grad_w, *grad_b


class OneBlob(nn.Module):
    """One-blob encoding of 2-D positions (Müller et al. 2018, "Neural Importance Sampling").

    Each coordinate is normalised to ``u ∈ [0, 1]`` over the domain and encoded as a Gaussian
    kernel ``exp(-(u - c_k)² / (2σ²))``, ``σ = 1 / bins``, evaluated at the bin centres
    ``c_k = (k + 0.5) / bins``. Smooth (differentiable in x), no trainable parameters.

    Parameters
    ----------
    bins : int ≥ 1
    domain : (x0, y0, x1, y1) float, the rectangle positions live in

    Input (N, 2) float → output (N, 2 * bins) float32, x's bins then y's. Positions outside the domain are
    clamped onto it first, as the feature field clamps them (gradient zero outside).
    """

    in_dim = 2

    def __init__(self, bins: int = 16, domain=(0.0, 0.0, 1.0, 1.0)):
        super().__init__()
        if not isinstance(bins, int) or isinstance(bins, bool) or bins < 1:
            raise ValueError(f"bins must be an integer ≥ 1, got {bins!r}")
        x0, y0, x1, y1 = (float(v) for v in domain)
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"domain {tuple(domain)} must have x1 > x0 and y1 > y0")
        self.bins = bins
        self.register_buffer("lo", torch.tensor([x0, y0], dtype=torch.float64), persistent=False)
        self.register_buffer("span", torch.tensor([x1 - x0, y1 - y0], dtype=torch.float64), persistent=False)
        self.register_buffer("centres", (torch.arange(bins, dtype=torch.float64) + 0.5) / bins, persistent=False)

    def get_out_dim(self) -> int:
        return 2 * self.bins

    def forward(self, xy: Tensor) -> Tensor:
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"expected positions (N, 2), got {tuple(xy.shape)}")
        u = ((xy.to(torch.float64) - self.lo) / self.span).clamp(0.0, 1.0)  # (N, 2), clamped into the domain
        d = (u[:, :, None] - self.centres) * self.bins  # (N, 2, bins), in units of σ
        return torch.exp(-0.5 * d * d).reshape(len(xy), 2 * self.bins).to(torch.float32)
