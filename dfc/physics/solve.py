"""Physics-informed solve of a diffusion-curve scene (paper §6.3): a field trained on Laplace's equation alone.

The problem is the one ``dfc.physics.wos`` samples and ``dfc.physics.reference`` solves: ``Δf = 0`` in the domain, the left and
right ``SideValues`` on the two sides of every curve, zero flux through the canvas border.

**Loss** ``L = E + w · B`` (``solve``), with positions measured in units ``u = (x − (x0, y0)) / S`` of the
domain's longer side ``S``, so that the domain has area ``A = (x1 − x0)(y1 − y0) / S² ≤ 1`` and a scene drawn
on a 512-pixel canvas or on a unit square gives the same loss (values are colours, of order 1, as they are):

- ``E = ½ ∫ |∇_u f|² du`` summed over channels, the Dirichlet energy (the weak form of Laplace's equation),
  estimated as ``½ A · mean Σ_c |∇_u f_c|²`` over interior points; gradients by autograd through the model
  (for dfc through the MLP and the interpolation weights, whose barycentric coordinates are differentiable in
  the position). On dfc's mesh every curve is a mesh edge (or lies in one triangle) and the features on its two
  sides are independent; the energy is a sum over points, never a difference across a curve, so nothing couples
  the two sides except the loss's own minimum.
- ``B = mean Σ_c (f_c − b_c)²`` over boundary points: every curve point gives two, offset by ``OFFSET_REL · S``
  along the normal to each side, whose target ``b`` is that side's prescribed value at the point's curve
  parameter.
- Nothing on the canvas border: the zero-flux condition ``∂f/∂n = 0`` is the weak form's natural boundary
  condition, so minimising ``E`` over fields free on the border imposes it.

**Samples** (``SolveProblem``). Interior points are stratified over the triangles of dfc's mesh: each step draws
``batch_size`` points by systematic sampling of the triangles' area distribution (every triangle gets its
expected share of the batch, rounded up or down at random) and a uniform point in each triangle. Boundary points
come from a pool of ``POOL_CURVE_POINTS`` jittered points evenly spaced in arc length over all curves, drawn
``batch_size`` at a time; offset points whose closest curve is another input curve or whose side differs (next
to junctions and crossings) are dropped from the pool. Every method — dfc and the baselines — gets the same
points for the same seed.

**Optimiser.** ``dfc.train.loop.train``: Adam with betas (0.9, 0.99) and the learning rate decaying geometrically
from ``lr`` to
``lr · FINAL_LR_FACTOR``; the last ``QAT_SHARE`` of the steps run with the model's quantised mode on (stored
feature bits and fp16 weights, ``FieldModel.quantization`` / ``Baseline.quantization``), so the written file and
the stored baseline evaluate as trained. The library never prints: progress goes to ``callback``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor, nn

from ..errors import InputError
from ..field.quantize import DEFAULT_FEATURE_BITS
from ..geometry import bezier
from ..geometry.mesh import Mesh
from ..geometry.plane import triangle_areas
from ..metrics import data_range
from .wos import Scene

__all__ = ["BOUNDARY_WEIGHT", "DFC_LR", "OFFSET_REL", "SolveProblem", "SolveReport", "SolveSettings", "dfc_model",
           "losses", "prepare", "solve", "solve_scene"]

OFFSET_REL = 1e-3
"""Offset of the boundary points from their curve, × the domain's longer side (the paper's 0.001)."""
BOUNDARY_WEIGHT = 1e3
"""Weight ``w`` of the boundary term. A penalty leaves the field off its prescribed values by about the normal
flux over ``w``, so ``w`` must be large against the energy (of order 1 to 10 in these units for the shipped
scenes), but a stiffer penalty slows Adam down (1e4 against 1e3: docs/results.md, "Physics-informed solve")."""
DFC_LR = 1e-2
"""Adam's starting learning rate for dfc's features and MLP (docs/design.md §6's, as for fitting images)."""
FINAL_LR_FACTOR = 0.1
"""The learning rate decays geometrically to this fraction of its start."""
QAT_SHARE = 0.1
"""Share of the steps run quantisation-aware at the end."""
POOL_CURVE_POINTS = 1 << 14
"""Curve points in the boundary pool (each gives one point per side)."""
DEFAULT_STEPS = 1000
DEFAULT_BATCH = 1 << 12
"""Interior points (and boundary points) per step of ``dfc solve``; smaller batches make dfc's energy estimate
noisier (1024 against 4096: docs/results.md, "Physics-informed solve")."""


def _normals(cp: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points B(t) (N, 2) and unit left normals (N, 2) of pieces cp (N, 4, 2) at t (N,).

    The left of a piece is where ``cross(tangent, p − B(t)) < 0`` (``dfc.physics.wos.Scene.closest``): ``(t_y, −t_x)``."""
    p = bezier.evaluate(cp, t)
    d = bezier.derivative(cp, t)
    flat = np.linalg.norm(d, axis=1) < 1e-12
    d[flat] = (cp[flat, 3] - cp[flat, 0])  # degenerate end tangent: the chord
    n = np.stack([d[:, 1], -d[:, 0]], axis=1)
    return p, n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


class SolveProblem:
    """The sample sets of one scene on one mesh.

    scene : ``dfc.physics.wos.Scene`` (curves with side values on every input curve)
    mesh : the triangulation whose triangles stratify the interior samples (dfc's decoder-view mesh)
    seed : seeds the boundary pool

    Attributes: ``scene``, ``mesh``, ``domain``, ``scale`` (S, the longer side), ``area`` (A, normalised),
    ``n_channels``, ``boundary_xy`` (M, 2) float64 and ``boundary_values`` (M, C) float32, the pool.
    """

    def __init__(self, scene: Scene, mesh: Mesh, *, seed: int = 0):
        self.scene = scene
        self.mesh = mesh
        self.domain = tuple(float(v) for v in scene.domain)
        x0, y0, x1, y1 = self.domain
        self.scale = max(x1 - x0, y1 - y0)
        self.area = (x1 - x0) * (y1 - y0) / self.scale**2
        self.n_channels = scene.n_channels
        tri = mesh.vertices[mesh.triangles]  # (T, 3, 2)
        self.corners = torch.from_numpy(np.ascontiguousarray(tri))
        area = triangle_areas(tri)
        self.cdf = torch.from_numpy(np.cumsum(area) / area.sum())
        self.boundary_xy, self.boundary_values = self._pool(np.random.default_rng(seed))
        if not len(self.boundary_xy):
            raise InputError(f"{scene.curves.source or 'scene'}: no boundary point could be placed beside a curve")
        self.pool = (torch.from_numpy(self.boundary_xy), torch.from_numpy(self.boundary_values))

    def to(self, device) -> SolveProblem:
        """Move the sampling tables (triangles, area distribution, boundary pool) to ``device``; returns self."""
        self.corners, self.cdf = self.corners.to(device), self.cdf.to(device)
        self.pool = tuple(t.to(device) for t in self.pool)
        return self

    @property
    def data_range(self) -> float:
        """PSNR data range of this scene: ``dfc.metrics.data_range`` of the prescribed values."""
        return data_range(self.boundary_values)

    def _pool(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        lines = self.scene.lines
        seg = np.flatnonzero(~lines.last)
        length = np.linalg.norm(lines.vertices[seg + 1] - lines.vertices[seg], axis=1)
        cum = np.cumsum(length)
        at = (np.arange(POOL_CURVE_POINTS) + rng.random(POOL_CURVE_POINTS)) * (cum[-1] / POOL_CURVE_POINTS)
        k = np.minimum(np.searchsorted(cum, at), len(seg) - 1)
        lam = np.clip(1.0 - (cum[k] - at) / np.maximum(length[k], 1e-300), 0.0, 1.0)
        s = seg[k]
        piece = lines.piece[s]
        t = lines.t[s] + lam * (lines.t[s + 1] - lines.t[s])
        p, n = _normals(self.scene.curves.control_points[piece], t)
        delta = OFFSET_REL * self.scale
        xy = np.concatenate([p + delta * n, p - delta * n])
        piece2, t2 = np.concatenate([piece, piece]), np.concatenate([t, t])
        left = np.concatenate([np.ones(len(p), bool), np.zeros(len(p), bool)])
        x0, y0, x1, y1 = self.domain
        inside = np.all((xy >= [x0, y0]) & (xy <= [x1, y1]), axis=1)
        near_piece, _, near_left = self.scene.closest(np.clip(xy, [x0, y0], [x1, y1]))
        curve = self.scene.curves.curve
        keep = inside & (curve[near_piece] == curve[piece2]) & (near_left == left)
        values = self.scene.side_values(piece2[keep], t2[keep], left[keep])
        return xy[keep], values.astype(np.float32)

    def interior(self, n: int, generator: torch.Generator) -> Tensor:
        """(n, 2) float64 points stratified over the triangles (module docstring), domain units, drawn on the
        generator's device (where ``to`` put the tables)."""
        device = generator.device
        u = (torch.arange(n, dtype=torch.float64, device=device)
             + torch.rand(n, generator=generator, dtype=torch.float64, device=device)) / n
        tri = torch.searchsorted(self.cdf, u).clamp_max(len(self.cdf) - 1)
        r = torch.rand(n, 2, generator=generator, dtype=torch.float64, device=device)
        flip = r.sum(dim=1) > 1
        r[flip] = 1 - r[flip]
        a = self.corners[tri]
        return a[:, 0] + r[:, :1] * (a[:, 1] - a[:, 0]) + r[:, 1:] * (a[:, 2] - a[:, 0])

    def boundary(self, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """(n, 2) float64 boundary points and their (n, C) float32 targets, drawn from the pool."""
        rows = torch.randint(len(self.boundary_xy), (n,), generator=generator, device=generator.device)
        return self.pool[0][rows], self.pool[1][rows]


class TwiceDifferentiable(nn.Module):
    """A single-slice ``FieldModel`` evaluated with the feature gather written as an indexed sum.

    ``FieldModel`` gathers features with ``embedding_bag``, whose gradient has no derivative of its own; the
    energy's gradient with respect to the features needs one (it differentiates ``∇_x f``, which depends on the
    features through the interpolation weights' derivatives). Same values as ``model(xy)`` for models without
    one-blob encoding and with the identity transform (what ``dfc_model`` builds).
    """

    def __init__(self, model):
        super().__init__()
        if model.encoding is not None or model.transform != "identity" or model.field.n_slices != 1:
            raise ValueError("TwiceDifferentiable needs a single-slice FieldModel without one-blob and transform")
        self.model = model

    def forward(self, xy: Tensor) -> Tensor:
        idx, w = self.model.field.query(xy)
        features = (self.model.field.bank[0][idx] * w[..., None]).sum(dim=1)
        return self.model.decoder(features)


def _evaluator(model: nn.Module) -> nn.Module:
    from ..field.model import FieldModel

    return TwiceDifferentiable(model) if isinstance(model, FieldModel) else model


def losses(model: nn.Module, problem: SolveProblem, xy: Tensor, bxy: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """The energy ``E`` and boundary term ``B`` (scalars, module docstring) at interior points xy (N, 2) and
    boundary points bxy (M, 2) with targets (M, C), all on the model's device, domain units."""
    evaluate = _evaluator(model)
    xy = xy.clone().requires_grad_(True)
    f = evaluate(xy)
    grad2 = xy.new_zeros(len(xy))
    for c in range(f.shape[1]):
        (g,) = torch.autograd.grad(f[:, c].sum(), xy, create_graph=True)
        grad2 = grad2 + (g * g).sum(dim=1)
    energy = 0.5 * problem.area * problem.scale**2 * grad2.mean()
    boundary = ((evaluate(bxy) - target) ** 2).sum(dim=1).mean()
    return energy.to(torch.float32), boundary


class PoissonLoss:
    """``loss`` of ``dfc.train.loop.train`` for a solve: ``E + weight · B`` on a ``physics_sampler`` batch; metrics
    ``energy`` and ``boundary``."""

    def __init__(self, problem: SolveProblem, weight: float):
        self.problem, self.weight = problem, weight

    def __call__(self, model: nn.Module, batch: tuple) -> tuple[Tensor, dict[str, Tensor]]:
        energy, boundary = losses(model, self.problem, *batch)
        return energy + self.weight * boundary, {"energy": energy.detach(), "boundary": boundary.detach()}


def solve(model: nn.Module, problem: SolveProblem, *, steps: int, batch_size: int, lr: float,
          boundary_weight: float = BOUNDARY_WEIGHT, feature_bits: int = DEFAULT_FEATURE_BITS, seed: int = 0,
          callback: Callable[[int, Tensor, Tensor], None] | None = None) -> dict:
    """Train ``model`` in place on the loss ``E + boundary_weight · B`` (module docstring).

    model : any module ``xy (N, 2) domain units -> (N, C)`` with a ``quantization`` property (``FieldModel`` or a
        ``dfc.bench.baselines.Baseline``); its device is that of its first parameter
    steps, batch_size : optimiser steps; interior points and boundary points per step (each)
    lr : Adam's starting learning rate (decays to ``lr · FINAL_LR_FACTOR``)
    feature_bits : the quantised mode of the last ``QAT_SHARE`` of the steps (left on at return)
    seed : seeds the samples (the same for every model)
    callback : ``callback(step, energy, boundary)`` after every step (0-dim tensors)

    A model with ``stages`` / ``next_stage`` (a coarse-to-fine baseline) grows between its stages, each stage with
    a fresh Adam; the learning rate decays straight through the stages. Returns ``{"energy": [...], "boundary":
    [...]}``, one float per step.
    """
    from ..train.loop import Schedule, train
    from ..train.samplers import physics_sampler

    if not isinstance(steps, int) or steps < 1 or not isinstance(batch_size, int) or batch_size < 1:
        raise InputError(f"steps and batch size must be positive integers, got {steps!r} and {batch_size!r}")
    if not (math.isfinite(boundary_weight) and boundary_weight > 0) or not (math.isfinite(lr) and lr > 0):
        raise InputError(f"boundary weight and learning rate must be positive, got {boundary_weight} and {lr}")
    device = next(model.parameters()).device
    schedule = Schedule(steps, lr=lr, final_lr=lr * FINAL_LR_FACTOR, qat_steps=max(1, round(QAT_SHARE * steps)),
                        feature_bits=feature_bits)
    return train(model, PoissonLoss(problem, boundary_weight), physics_sampler(problem, batch_size, device=device),
                 schedule, seed=seed, callback=callback)


def dfc_model(mesh: Mesh, channels: list[str], mean: np.ndarray, *, dim: int = 5, seed: int = 0,
              device: str = "cpu"):
    """dfc's model for a solve: a ``FieldModel`` with the paper's tanh MLP (2 × 64; smooth, where ReLU's zero
    second derivative leaves the field's gradient piecewise constant), its output bias at ``mean`` (C,), the mean
    prescribed value."""
    from ..field.feature_field import FeatureField
    from ..field.model import FieldModel

    model = FieldModel(FeatureField(mesh, dim=dim, seed=seed, device=device), channels, activation="tanh", seed=seed)
    model.decoder.mixed_precision = False  # the energy differentiates the MLP twice: keep float32 there
    with torch.no_grad():
        model.decoder.linears()[-1].bias.copy_(torch.as_tensor(mean, dtype=torch.float32))
    return model


@dataclass
class SolveSettings:
    """Every knob of ``dfc solve``; stored in the file's header (``encoder``).

    max_triangles : dfc's mesh size (default: ``dfc.geometry.triangulate``'s, about 2,000 plus those the curves force)
    steps, batch_size, boundary_weight, lr, seed : of ``solve``; dim : feature channels per vertex
    feature_bits, mesh_bits : storage (as ``dfc.codec.EncodeSettings``); device : torch device of the solve
    """

    max_triangles: int | None = None
    steps: int = DEFAULT_STEPS
    batch_size: int = DEFAULT_BATCH
    boundary_weight: float = BOUNDARY_WEIGHT
    lr: float = DFC_LR
    dim: int = 5
    feature_bits: int = DEFAULT_FEATURE_BITS
    mesh_bits: int = 20
    seed: int = 0
    device: str = "cpu"


@dataclass
class SolveReport:
    """What a solve measured: the file's bytes (total and per chunk), the mesh, the last step's loss terms, and
    seconds per stage (``mesh_s`` only when ``solve_scene`` built the problem itself)."""

    total_bytes: int
    chunk_bytes: dict[str, int]
    n_vertices: int
    n_triangles: int
    n_features: int
    energy: float
    boundary: float
    seconds: dict[str, float] = field(default_factory=dict)


def prepare(curves, settings: SolveSettings) -> SolveProblem:
    """The scene (``InputError`` without side values), dfc's decoder-view mesh and their sample sets."""
    from ..settings import EncodeSettings
    from ..rate import build_mesh

    scene = Scene(curves)
    mesh = build_mesh(curves, EncodeSettings(max_triangles=settings.max_triangles, mesh_bits=settings.mesh_bits))
    return SolveProblem(scene, mesh, seed=settings.seed)


def solve_scene(curves, settings: SolveSettings | None = None, *, problem: SolveProblem | None = None,
                callback: Callable[[int, float, float], None] | None = None) -> tuple[bytes, SolveReport]:
    """Solve a diffusion-curve scene with dfc and return the ``.dfield`` bytes and a ``SolveReport``.

    curves : Curves with side values on every input curve; problem : ``prepare(curves, settings)`` when already
    built; callback : as ``solve``'s. The file stores the model as trained (quantised mode on at the end).
    """
    import time

    from ..io.container import encode_dfield
    from ..io.dfield import encoder_info, to_contents
    from ..io.samples import default_channels

    settings = settings or SolveSettings()
    seconds = {}
    if problem is None:
        clock = time.perf_counter()
        problem = prepare(curves, settings)
        seconds["mesh_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    mesh = problem.mesh
    model = dfc_model(mesh, default_channels(problem.n_channels), problem.boundary_values.mean(axis=0),
                      dim=settings.dim, seed=settings.seed, device=settings.device)
    history = solve(model, problem, steps=settings.steps, batch_size=settings.batch_size, lr=settings.lr,
                    boundary_weight=settings.boundary_weight, feature_bits=settings.feature_bits, seed=settings.seed,
                    callback=callback)
    seconds["solve_s"] = time.perf_counter() - clock
    info = encoder_info(settings, curves.source, {"input": "physics-informed solve"})
    blob, sizes = encode_dfield(to_contents(model, info), feature_bits=settings.feature_bits, mesh_validated=True)
    report = SolveReport(total_bytes=len(blob), chunk_bytes=sizes, n_vertices=mesh.n_vertices,
                         n_triangles=mesh.n_triangles, n_features=model.field.n_features,
                         energy=history["energy"][-1], boundary=history["boundary"][-1], seconds=seconds)
    return blob, report
