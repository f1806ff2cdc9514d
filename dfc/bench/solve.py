"""``dfc bench --solve``: dfc against the physics-informed baselines on a diffusion-curve scene (paper Fig. 12).

Every method is trained by ``dfc.physics.solve.solve`` on the same loss, the same interior and boundary points (one
``SolveProblem``, stratified over dfc's mesh) and the same number of steps and batch size; only the learning
rate is each method's own (``LEARNING_RATES``). dfc's result is its written ``.dfield`` decoded again; the
baselines are rounded to their stored float16 values. The TanH field is sized to the ``.dfield``'s bytes; SIREN
and the MLP keep the paper's fixed architectures, and the table gives their true (larger) sizes.

Each is rendered at the pixel centres of the reference grid (``settings.size`` pixels on the long side) and
compared with ``dfc.physics.reference.solve_reference`` on that grid (PSNR over every pixel, data range 1 for colours in
[0, 1], else the span of the prescribed values). The library never prints: progress goes through
``progress(message)``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from .report import contact_sheet as contact_sheet_grid
from .report import display, write_report
from .report import markdown_table as table

__all__ = ["LEARNING_RATES", "SOLVE_METHODS", "SolveBenchSettings", "contact_sheet", "markdown_table",
           "run_solve_bench", "write_outputs"]

SOLVE_METHODS = ("dfc", "tanh_field", "siren", "tanh_mlp")
LEARNING_RATES = {"dfc": 1e-2, "tanh_field": 1e-2, "siren": 1e-4, "tanh_mlp": 1e-3}
"""Adam's starting learning rate per method (each decays by ``dfc.physics.solve.FINAL_LR_FACTOR``): dfc's is
docs/design.md §6's, the grid's the ReLU field's; SIREN's is the SIREN paper's and the MLP's the usual PINN value."""
LABELS = {"reference": "reference", "dfc": "dfc", "tanh_field": "TanH field", "siren": "SIREN", "tanh_mlp": "MLP"}
ERROR_GAIN = 4.0
"""Error maps show ``ERROR_GAIN × |f − reference|`` (mean over channels) as grey."""
EVAL_BLOCK = 1 << 16


@dataclass
class SolveBenchSettings:
    """Knobs of a solve benchmark (stored in ``results.json``).

    steps, batch_size : of every method; size : the reference grid's long side, pixels
    methods : subset of ``SOLVE_METHODS`` with dfc; max_triangles : dfc's mesh size
    boundary_weight : of the loss (None: ``dfc.physics.solve.BOUNDARY_WEIGHT``)
    """

    steps: int = 1000
    batch_size: int = 1 << 12
    size: int = 256
    methods: tuple[str, ...] = SOLVE_METHODS
    max_triangles: int | None = None
    boundary_weight: float | None = None
    seed: int = 0
    device: str = "cpu"

    def check(self) -> None:
        """Raise InputError on inconsistent settings."""
        unknown = [m for m in self.methods if m not in SOLVE_METHODS]
        if not self.methods or unknown or "dfc" not in self.methods:
            raise InputError(f"solve methods must include dfc and be a subset of {', '.join(SOLVE_METHODS)}, "
                             f"got {list(self.methods)}")
        for key in ("steps", "batch_size"):
            if getattr(self, key) < 1:
                raise InputError(f"{key} must be ≥ 1, got {getattr(self, key)}")
        if self.size < 8:
            raise InputError(f"the reference grid needs at least 8 pixels on its long side, got {self.size}")


def run_solve_bench(curves, settings: SolveBenchSettings, *, name: str = "",
                    progress: Callable[[str], None] | None = None) -> dict:
    """Solve ``curves`` (with side values) with every method; return the JSON-able ``results`` plus
    ``"renders"`` ({method or "reference": (H, W, C) float32}, not JSON) and ``"blob"`` (dfc's file)."""
    from ..metrics import psnr
    from ..physics.reference import solve_reference
    from ..physics.solve import BOUNDARY_WEIGHT, SolveSettings, prepare
    from ..physics.wos import grid_size
    from ..render import values_at, window_points

    settings.check()
    progress = progress or (lambda message: None)
    weight = BOUNDARY_WEIGHT if settings.boundary_weight is None else settings.boundary_weight
    solve_settings = SolveSettings(max_triangles=settings.max_triangles, steps=settings.steps,
                                   batch_size=settings.batch_size, boundary_weight=weight,
                                   lr=LEARNING_RATES["dfc"], seed=settings.seed, device=settings.device)
    progress("building the mesh and the sample sets")
    problem = prepare(curves, solve_settings)
    width, height = grid_size(problem.domain, settings.size)
    progress(f"reference: finite-difference solve on {width} x {height}")
    clock = time.perf_counter()
    reference = solve_reference(problem.scene, max(2, width), max(2, height)).values
    reference_s = time.perf_counter() - clock
    xy = window_points(problem.domain, width, height, 1)  # the reference's pixel centres
    renders = {"reference": reference.astype(np.float32)}
    record: dict[str, dict] = {}
    blob = None
    for method in [m for m in SOLVE_METHODS if m in settings.methods]:  # dfc first: it sets the budget
        progress(f"{method}: solving")
        clock = time.perf_counter()
        model, size, details, file = _solve_one(method, curves, problem, solve_settings, blob, settings,
                                                _every(method, settings.steps, progress))
        blob = blob or file
        seconds = time.perf_counter() - clock
        out = values_at(model, xy, device=settings.device, block=EVAL_BLOCK).reshape(height, width, -1)
        renders[method] = out.astype(np.float32)
        record[method] = {"bytes": int(size), "psnr": psnr(reference, renders[method], data_range=problem.data_range),
                          "solve_s": seconds, "lr": LEARNING_RATES[method], **details}
    baselines = [r["psnr"] for m, r in record.items() if m != "dfc"]
    return {
        "input": name or curves.source,
        "reference": f"Shortley-Weller finite differences, {width} x {height} pixel centres",
        "reference_s": reference_s,
        "data_range": problem.data_range,
        "budget_bytes": record["dfc"]["bytes"],
        "margin_db": record["dfc"]["psnr"] - max(baselines) if baselines else None,
        "settings": {**{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(settings).items()},
                     "boundary_weight": weight},
        "methods": record,
        "renders": renders,
        "blob": blob,
    }


def _every(label: str, steps: int, progress):
    """A solve callback reporting to ``progress`` ten times over the run."""
    step_every = max(1, steps // 10)

    def callback(step, energy, boundary):
        if (step + 1) % step_every == 0 or step + 1 == steps:
            progress(f"{label}: step {step + 1}/{steps}, energy {energy:.4g}, boundary {boundary:.3g}")

    return callback


def _solve_one(method: str, curves, problem, solve_settings, budget_blob, settings: SolveBenchSettings, callback):
    """(model, stored bytes, details, dfc's file or None) of one method solved on ``problem``; the baselines are
    sized to ``budget_blob``, dfc's file."""
    from ..codec import loads
    from ..io.samples import default_channels
    from ..physics.solve import solve, solve_scene
    from .baselines import BASELINES

    if method == "dfc":
        blob, report = solve_scene(curves, solve_settings, problem=problem, callback=callback)
        details = {"triangles": report.n_triangles, "vertices": report.n_vertices, "energy": report.energy,
                   "boundary": report.boundary}
        return loads(blob, device=settings.device), len(blob), details, blob
    model = BASELINES[method].for_budget(len(budget_blob), problem.domain, default_channels(problem.n_channels),
                                         seed=settings.seed, device=settings.device)
    model.init_mean(torch.from_numpy(problem.boundary_values.mean(axis=0)))
    history = solve(model, problem, steps=settings.steps, batch_size=settings.batch_size,
                    lr=LEARNING_RATES[method], boundary_weight=solve_settings.boundary_weight, seed=settings.seed,
                    callback=callback)
    model.round_to_storage()
    details = {**model.describe(), "energy": history["energy"][-1], "boundary": history["boundary"][-1]}
    return model, model.stored_bytes(), details, None


def markdown_table(results: dict) -> str:
    """``results.md``: one row per method — bytes, PSNR against the reference, solve time."""
    s = results["settings"]
    notes = (f"Reference: {results['reference']}. PSNR in dB (data range {results['data_range']:.4g}); "
             f"{s['steps']} steps, batch {s['batch_size']}, boundary weight {s['boundary_weight']:g}.")
    rows = [[LABELS[m], str(r["bytes"]), f"{r['psnr']:.2f}", f"{r['solve_s']:.0f}"]
            for m, r in results["methods"].items()]
    footer = "" if results["margin_db"] is None else f"dfc over the best baseline: {results['margin_db']:+.2f} dB."
    return table(f"dfc bench --solve: {results['input']}", notes, ["method", "bytes", "PSNR", "solve s"], rows,
                 footer)


def contact_sheet(results: dict) -> bytes:
    """PNG bytes like the paper's Fig. 12: the reference and every method on top, their error maps below."""
    renders = results["renders"]
    ref = renders["reference"]
    methods = [k for k in renders if k != "reference"]
    labels = [LABELS[k] + ("" if k == "reference" else f"  {results['methods'][k]['psnr']:.1f} dB") for k in renders]
    errors = [None] + [np.clip(ERROR_GAIN * np.abs(renders[k] - ref).mean(axis=2, keepdims=True), 0.0, 1.0)
                       for k in methods]
    rows = [("solution", [display(v, False) for v in renders.values()], [None] * len(renders)),
            (f"|error| x {ERROR_GAIN:g}", [None if e is None else _grey(e) for e in errors], [None] * len(renders))]
    return contact_sheet_grid(labels, rows)


def _grey(error: np.ndarray) -> np.ndarray:
    """(h, w, 1) values in [0, 1] -> (h, w, 3) uint8 grey, linearly (no transfer curve: an error map)."""
    return np.repeat(np.round(255 * error).astype(np.uint8), 3, axis=2)


def write_outputs(results: dict, directory: str | Path) -> list[Path]:
    """Write ``results.json``, ``results.md``, ``contact.png`` and ``dfc.dfield`` into ``directory``
    (``dfc.bench.report.write_report``). Returns the paths written."""
    record = {k: v for k, v in results.items() if k not in ("renders", "blob")}
    return write_report(directory, record, markdown_table(results), contact_sheet(results), results["blob"])
