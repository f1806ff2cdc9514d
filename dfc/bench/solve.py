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

import io
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError

__all__ = ["LEARNING_RATES", "SOLVE_METHODS", "SolveBenchSettings", "contact_sheet", "markdown_table",
           "run_solve_bench", "write_outputs"]

SOLVE_METHODS = ("dfc", "tanh_field", "siren", "tanh_mlp")
LEARNING_RATES = {"dfc": 1e-2, "tanh_field": 1e-2, "siren": 1e-4, "tanh_mlp": 1e-3}
"""Adam's starting learning rate per method (each decays by ``dfc.physics.solve.FINAL_LR_FACTOR``): dfc's is DESIGN §6's,
the grid's the ReLU field's; SIREN's is the SIREN paper's and the MLP's the usual PINN value."""
LABELS = {"reference": "reference", "dfc": "dfc", "tanh_field": "TanH field", "siren": "SIREN", "tanh_mlp": "MLP"}
TILE = 256
"""Side of a contact-sheet tile, pixels."""
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
    from ..codec import loads
    from ..io.samples import default_channels
    from ..metrics import psnr
    from ..physics.reference import solve_reference
    from ..physics.solve import BOUNDARY_WEIGHT, SolveSettings, prepare, solve, solve_scene
    from ..physics.wos import grid_size
    from ..render import values_at
    from .baselines import BASELINES
    from .compare import window_points

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
    data_range = problem.data_range
    channels = default_channels(problem.n_channels)
    renders = {"reference": reference.astype(np.float32)}
    record: dict[str, dict] = {}
    blob = None

    def every(label):
        step_every = max(1, settings.steps // 10)

        def callback(step, energy, boundary):
            if (step + 1) % step_every == 0 or step + 1 == settings.steps:
                progress(f"{label}: step {step + 1}/{settings.steps}, energy {energy:.4g}, boundary {boundary:.3g}")

        return callback

    for method in [m for m in SOLVE_METHODS if m in settings.methods]:  # dfc first: it sets the budget
        progress(f"{method}: solving")
        clock = time.perf_counter()
        if method == "dfc":
            blob, report = solve_scene(curves, solve_settings, problem=problem, callback=every(method))
            model, size = loads(blob, device=settings.device), len(blob)
            details = {"triangles": report.n_triangles, "vertices": report.n_vertices, "energy": report.energy,
                       "boundary": report.boundary}
        else:
            model = BASELINES[method].for_budget(len(blob), problem.domain, channels, seed=settings.seed,
                                                 device=settings.device)
            model.init_mean(torch.from_numpy(problem.boundary_values.mean(axis=0)))
            history = solve(model, problem, steps=settings.steps, batch_size=settings.batch_size,
                            lr=LEARNING_RATES[method], boundary_weight=weight, seed=settings.seed,
                            callback=every(method))
            model.round_to_storage()
            size = model.stored_bytes()
            details = {**model.describe(), "energy": history["energy"][-1], "boundary": history["boundary"][-1]}
        seconds = time.perf_counter() - clock
        out = values_at(model, xy, device=settings.device, block=EVAL_BLOCK).reshape(height, width, -1).astype(np.float32)
        renders[method] = out
        record[method] = {"bytes": int(size), "psnr": psnr(reference, out, data_range=data_range),
                          "solve_s": seconds, "lr": LEARNING_RATES[method], **details}
    baselines = [r["psnr"] for m, r in record.items() if m != "dfc"]
    return {
        "input": name or curves.source,
        "reference": f"Shortley-Weller finite differences, {width} x {height} pixel centres",
        "reference_s": reference_s,
        "data_range": data_range,
        "budget_bytes": record["dfc"]["bytes"],
        "margin_db": record["dfc"]["psnr"] - max(baselines) if baselines else None,
        "settings": {**{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(settings).items()},
                     "boundary_weight": weight},
        "methods": record,
        "renders": renders,
        "blob": blob,
    }


def markdown_table(results: dict) -> str:
    """``results.md``: one row per method — bytes, PSNR against the reference, solve time."""
    s = results["settings"]
    lines = [f"# dfc bench --solve: {results['input']}", "",
             f"Reference: {results['reference']}. PSNR in dB (data range {results['data_range']:.4g}); "
             f"{s['steps']} steps, batch {s['batch_size']}, boundary weight {s['boundary_weight']:g}.", "",
             "| method | bytes | PSNR | solve s |", "|---|---:|---:|---:|"]
    for m, r in results["methods"].items():
        lines.append(f"| {LABELS[m]} | {r['bytes']} | {r['psnr']:.2f} | {r['solve_s']:.0f} |")
    if results["margin_db"] is not None:
        lines += ["", f"dfc over the best baseline: {results['margin_db']:+.2f} dB."]
    return "\n".join(lines) + "\n"


def contact_sheet(results: dict) -> bytes:
    """PNG bytes like the paper's Fig. 12: the reference and every method on top, their error maps below."""
    from PIL import Image as PILImage
    from PIL import ImageDraw

    from .compare import _display

    renders = results["renders"]
    keys = list(renders)
    sheet = PILImage.new("RGB", (len(keys) * TILE, 2 * TILE + 20), (40, 40, 40))
    draw = ImageDraw.Draw(sheet)
    ref = renders["reference"]
    for c, key in enumerate(keys):
        label = LABELS[key] + ("" if key == "reference" else f"  {results['methods'][key]['psnr']:.1f} dB")
        draw.text((c * TILE + 4, 4), label, fill=(255, 255, 255))
        sheet.paste(PILImage.fromarray(_display(renders[key], False)).resize((TILE, TILE), PILImage.NEAREST),
                    (c * TILE, 20))
        if key != "reference":
            err = np.clip(ERROR_GAIN * np.abs(renders[key] - ref).mean(axis=2), 0.0, 1.0)
            grey = PILImage.fromarray(np.round(255 * err).astype(np.uint8)).resize((TILE, TILE), PILImage.NEAREST)
            sheet.paste(grey.convert("RGB"), (c * TILE, 20 + TILE))
    draw.text((4, 24 + TILE), f"|error| x {ERROR_GAIN:g}", fill=(255, 255, 255))
    buf = io.BytesIO()
    sheet.save(buf, format="PNG")
    return buf.getvalue()


def write_outputs(results: dict, directory: str | Path) -> list[Path]:
    """Write ``results.json``, ``results.md``, ``contact.png`` and ``dfc.dfield`` into ``directory`` (created
    if missing), each atomically. Returns the paths written."""
    from ..io.atomic import write_bytes_atomic

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    record = {k: v for k, v in results.items() if k not in ("renders", "blob")}
    files = {"results.json": (json.dumps(record, indent=2) + "\n").encode(),
             "results.md": markdown_table(results).encode(), "contact.png": contact_sheet(results),
             "dfc.dfield": results["blob"]}
    for name, data in files.items():
        write_bytes_atomic(out / name, data)
    return [out / name for name in files]
