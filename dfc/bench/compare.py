"""Equal-size comparison of dfc against the baselines at increasing zoom (paper Figs. 1, 2, 9).

``run_bench`` fits dfc (``dfc.codec.encode_image``, decoded again with ``dfc.codec.loads``) to a raster,
then sizes every baseline (``dfc.bench.baselines``) to the ``.dfield``'s byte count and trains it on the same
raster with the same number of steps and batch size (``dfc.train.samplers.image_sampler``; the baselines do not know
the curves, so they see every pixel). Each probe point gets one window per zoom ``z``: the domain's size
divided by ``z``, centred on the probe and shifted to lie inside the domain (so zoom 1 is the domain
itself). A window is rendered at ``render × render·aspect`` pixels, each the mean of ``spp`` points
(``dfc.render.pixel_offsets``), for every method and — for an analytic scene — for the exact value at the
same points, the reference its PSNR is measured against. For a user image only zoom 1 has a reference:
the method rendered at the image's own resolution against the image; larger zooms get PSNR ``None``.

PSNR uses ``dfc.metrics.data_range`` of the input (as ``dfc.codec`` does). Decode throughput is points per second of one batched forward pass, best of
``THROUGHPUT_REPEATS``. The library never prints: progress goes through ``progress(message)``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import InputError
from ..metrics import data_range as signal_range
from ..render import values_at, window_points, window_shape, zoom_window
from .report import contact_sheet as contact_sheet_grid
from .report import display, write_report
from .report import markdown_table as table
from .timing import best_seconds

__all__ = ["METHODS", "ZOOMS", "BenchResult", "BenchSettings", "contact_sheet", "markdown_table", "run_bench",
           "run_scene", "throughput", "write_outputs"]

ZOOMS = (1, 10, 33, 100)
METHODS = ("dfc", "hashgrid", "relu", "raster")
EVAL_BLOCK = 1 << 16
"""Points per forward pass when rendering windows."""
THROUGHPUT_POINTS = 1 << 16
THROUGHPUT_REPEATS = 3


@dataclass
class BenchSettings:
    """Knobs of a benchmark run (stored in ``results.json``).

    steps, batch_size : optimiser steps and samples per step, the same for every method
    size : longer side of the raster fitted for an analytic scene (default: the domain's longer side in its
        units); ignored for a user image
    render, spp : window resolution (longer side) and points averaged per pixel
    zooms : zoom factors ≥ 1
    methods : subset of ``METHODS``
    target_bytes : the byte budget when "dfc" is not benchmarked; with dfc, its ``.dfield`` is sized to it
    max_triangles : dfc mesh size cap (default: ``dfc.geometry.triangulate``'s)
    """

    steps: int = 1000
    batch_size: int = 1 << 14
    size: int | None = None
    render: int = 256
    spp: int = 4
    zooms: tuple[float, ...] = ZOOMS
    methods: tuple[str, ...] = METHODS
    target_bytes: int | None = None
    max_triangles: int | None = None
    seed: int = 0
    device: str = "cpu"

    def check(self) -> None:
        """Raise InputError on inconsistent settings."""
        unknown = [m for m in self.methods if m not in METHODS]
        if not self.methods or unknown:
            raise InputError(f"methods must be a non-empty subset of {', '.join(METHODS)}, got {list(self.methods)}")
        if "dfc" not in self.methods and self.target_bytes is None:
            raise InputError("without dfc among the methods, give the byte budget (target_bytes / --bytes)")
        if not self.zooms or any(not (math.isfinite(z) and z >= 1) for z in self.zooms):
            raise InputError(f"zooms must be finite numbers ≥ 1, got {list(self.zooms)}")
        for key in ("steps", "batch_size", "render", "spp"):
            if getattr(self, key) < 1:
                raise InputError(f"{key} must be ≥ 1, got {getattr(self, key)}")


# ----------------------------------------------------------------------------------------------- windows
def _pixel_mean(values: np.ndarray, width: int, height: int, spp: int) -> np.ndarray:
    return values.reshape(height, width, spp, -1).mean(axis=2).astype(np.float32)


def throughput(model: nn.Module, domain, device: str, seed: int = 0) -> float:
    """Decode throughput in points per second: best of ``THROUGHPUT_REPEATS`` forward passes of
    ``THROUGHPUT_POINTS`` uniformly random points (after one warm-up pass)."""
    x0, y0, x1, y1 = domain
    rng = np.random.default_rng(seed)
    xy = torch.from_numpy(rng.random((THROUGHPUT_POINTS, 2)) * [x1 - x0, y1 - y0] + [x0, y0]).to(device)
    with torch.no_grad():
        return THROUGHPUT_POINTS / best_seconds(lambda: model(xy), THROUGHPUT_REPEATS, device)


class _Remap(nn.Module):
    """``model`` living on ``inner`` domain, queried in ``outer`` domain units (an affine map per axis)."""

    def __init__(self, model: nn.Module, outer, inner):
        super().__init__()
        self.model = model
        self.scale = [(inner[2] - inner[0]) / (outer[2] - outer[0]), (inner[3] - inner[1]) / (outer[3] - outer[1])]
        self.outer, self.inner = outer, inner

    def forward(self, xy):
        s = torch.tensor(self.scale, dtype=xy.dtype, device=xy.device)
        o = torch.tensor(self.outer[:2], dtype=xy.dtype, device=xy.device)
        i = torch.tensor(self.inner[:2], dtype=xy.dtype, device=xy.device)
        return self.model((xy - o) * s + i)


# ----------------------------------------------------------------------------------------------- fitting
def _fit_dfc(pixels, curves, channels, settings: BenchSettings, progress) -> tuple[nn.Module, int, dict]:
    from ..codec import EncodeSettings, encode_image, loads
    from ..io.image import Image

    h, w = pixels.shape[:2]
    enc = EncodeSettings(max_triangles=settings.max_triangles, target_bytes=settings.target_bytes,
                         steps=settings.steps, batch_size=settings.batch_size, seed=settings.seed,
                         device=settings.device)
    image = Image(pixels, list(channels), hdr=float(pixels.max()) > 1.0)
    blob, report = encode_image(image, curves, enc, fit_curves=True, callback=_step_progress("dfc", settings, progress))
    model = loads(blob, device=settings.device)
    details = {"triangles": report.n_triangles, "vertices": report.n_vertices, "chunk_bytes": report.chunk_bytes,
               "psnr_at_pixels": report.psnr}
    return _Remap(model, curves.domain, (0.0, 0.0, float(w), float(h))), len(blob), {"blob": blob, **details}


def _step_progress(name: str, settings: BenchSettings, progress):
    every = max(1, settings.steps // 10)

    def callback(step, loss, psnr):
        if (step + 1) % every == 0 or step + 1 == settings.steps:
            progress(f"{name}: step {step + 1}/{settings.steps}, batch PSNR {psnr:.2f} dB")

    return callback


def _fit_baseline(name: str, pixels, domain, channels, n_bytes: int, settings: BenchSettings, loss: str,
                  data_range: float, progress) -> tuple[nn.Module, dict]:
    from ..train.samplers import image_sampler
    from .baselines import BASELINES, fit_baseline

    model = BASELINES[name].for_budget(n_bytes, domain, channels, image=pixels, seed=settings.seed,
                                       device=settings.device)
    model.init_mean(torch.from_numpy(pixels.reshape(-1, pixels.shape[2]).mean(axis=0)))
    sampler = image_sampler(pixels, domain, settings.batch_size, device=settings.device, seed=settings.seed)
    fit_baseline(model, sampler, settings.steps, loss=loss, seed=settings.seed, data_range=data_range,
                 callback=_step_progress(name, settings, progress))
    details = model.describe()
    if list(model.parameters()):  # what zstd would save on the fp16 parameters
        import zstandard

        raw = b"".join(p.detach().cpu().numpy().astype("<f2").tobytes() for p in model.parameters())
        details["zstd_bytes"] = len(zstandard.ZstdCompressor(level=19).compress(raw))
    return model, details


# ----------------------------------------------------------------------------------------------- benchmark
@dataclass
class BenchResult:
    """``results``: the JSON-able record (see ``run_bench``); ``tiles[method][probe][zoom]``: (h, w, C)
    float32 renders, with the key ``"reference"`` for the exact (scene) or input (zoom 1) raster;
    ``blob``: the dfc file's bytes (or None)."""

    results: dict
    tiles: dict[str, list[list[np.ndarray | None]]]
    blob: bytes | None = None


def run_bench(pixels: np.ndarray, curves, channels: list[str], *, probes, settings: BenchSettings,
              reference: Callable[[np.ndarray], np.ndarray] | None = None, name: str = "",
              progress: Callable[[str], None] | None = None) -> BenchResult:
    """Fit every method to ``pixels`` at equal bytes and measure it at every probe and zoom.

    Parameters
    ----------
    pixels : (H, W, C) float32 raster covering ``curves.domain`` (what every method is fitted to)
    curves : dfc.geometry.curves.Curves, the discontinuities (used by dfc only)
    channels : C channel names
    probes : (P, 2) float points in domain units, the zoom centres
    settings : BenchSettings
    reference : exact value ``(N, 2) -> (N, C)`` (an analytic scene's ``value``); None for a user image
    name : label of the input, stored in the results

    Returns
    -------
    BenchResult; ``results["methods"][m]`` has ``bytes`` (int), ``psnr`` ({str(zoom): [dB or None per
    probe]}), ``points_per_s``, ``fit_s`` and method details.
    """
    settings.check()
    progress = progress or (lambda message: None)
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    if pixels.ndim != 3 or pixels.shape[2] != len(channels):
        raise InputError(f"expected a raster (H, W, {len(channels)}) for channels {list(channels)}, got {pixels.shape}")
    probes = np.asarray(probes, dtype=np.float64).reshape(-1, 2)
    domain = curves.domain
    x0, y0, x1, y1 = domain
    if len(probes) == 0 or not np.all((probes >= [x0, y0]) & (probes <= [x1, y1])):
        raise InputError(f"probes must be points inside the domain {domain}, got {probes.tolist()}")
    data_range = signal_range(pixels)
    models, record, blob = _fit_all(pixels, curves, channels, settings, data_range, progress)
    windows = [[zoom_window(domain, p, z) for z in settings.zooms] for p in probes]
    tiles, psnr = _measure_all(models, windows, pixels, domain, reference, settings, data_range, progress)
    for m in models:
        record[m]["psnr"] = psnr[m]
    results = {
        "input": name,
        "reference": "analytic" if reference is not None else "input image (zoom 1 only; larger zooms unmeasured)",
        "data_range": data_range,
        "hdr": float(pixels.max()) > 1.0,
        "budget_bytes": int(record["dfc"]["bytes"] if "dfc" in record else settings.target_bytes),
        "zooms": [float(z) for z in settings.zooms],
        "probes": probes.tolist(),
        "windows": [[list(w) for w in row] for row in windows],
        "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(settings).items()},
        "methods": record,
    }
    return BenchResult(results, tiles, blob)


def _fit_all(pixels, curves, channels, settings: BenchSettings, data_range: float, progress):
    """Every method fitted: (models {method: module}, record {method: bytes, fit_s, points_per_s, details},
    dfc's file or None). dfc runs first: its file's size is the others' budget."""
    loss = "relmse" if float(pixels.max()) > 1.0 else "mse"
    models: dict[str, nn.Module] = {}
    record: dict[str, dict] = {}
    blob = None
    n_bytes = settings.target_bytes
    for method in [m for m in METHODS if m in settings.methods]:
        progress(f"{method}: fitting" + (f" at {n_bytes} bytes" if method != "dfc" else ""))
        clock = time.perf_counter()
        if method == "dfc":
            model, size, details = _fit_dfc(pixels, curves, channels, settings, progress)
            blob = details.pop("blob")
            n_bytes = size
        else:
            model, details = _fit_baseline(method, pixels, curves.domain, channels, n_bytes, settings, loss,
                                           data_range, progress)
            size = model.stored_bytes()
        model.eval()
        models[method] = model
        record[method] = {"bytes": int(size), "fit_s": time.perf_counter() - clock,
                          "points_per_s": throughput(model, curves.domain, settings.device, settings.seed), **details}
    return models, record, blob


def _measure_all(models, windows, pixels, domain, reference, settings: BenchSettings, data_range: float, progress):
    """(tiles {key: [probe][zoom] render or None}, psnr {method: {zoom key: [dB or None per probe]}}) of every
    window (``windows[probe][zoom]``); a window shared by several probes (zoom 1) is rendered once."""
    tiles: dict[str, list[list[np.ndarray | None]]] = {k: [] for k in ["reference", *models]}
    psnr: dict[str, dict[str, list]] = {m: {_zkey(z): [] for z in settings.zooms} for m in models}
    cache: dict[tuple, tuple[dict, dict]] = {}
    for k, row in enumerate(windows):
        for key in tiles:
            tiles[key].append([])
        for z, window in zip(settings.zooms, row):
            progress(f"probe {k + 1}/{len(windows)}, zoom {_zkey(z)}: rendering")
            if window not in cache:
                cache[window] = _measure(models, window, domain, pixels, reference, settings, data_range)
            renders, scores = cache[window]
            for key in tiles:
                tiles[key][-1].append(renders.get(key))
            for m in models:
                psnr[m][_zkey(z)].append(scores[m])
    return tiles, psnr


def run_scene(scene, settings: BenchSettings, *, probes=None,
              progress: Callable[[str], None] | None = None) -> BenchResult:
    """``run_bench`` on an analytic scene (``dfc.bench.scenes.AnalyticScene``): fitted to its box-filtered raster
    (longer side ``settings.size``, default the domain's longer side in its units; 4 × 4 points per pixel),
    measured against its exact value; ``probes`` default to ``dfc.bench.scenes.default_probes``."""
    from .scenes import default_probes

    settings.check()
    x0, y0, x1, y1 = scene.domain
    longer = settings.size or max(8, round(max(x1 - x0, y1 - y0)))
    scale = longer / max(x1 - x0, y1 - y0)
    w, h = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
    if progress is not None:
        progress(f"scene {scene.name}: rendering the {w}x{h} raster to fit")
    pixels = scene.render(w, h)
    points = default_probes(scene) if probes is None or len(probes) == 0 else probes
    return run_bench(pixels, scene.curves, scene.channels, probes=points, settings=settings, reference=scene.value,
                     name=f"scene {scene.name}", progress=progress)


def _zkey(z: float) -> str:
    return str(int(z)) if float(z).is_integer() else str(z)


def _measure(models, window, domain, pixels, reference, settings: BenchSettings, data_range: float):
    """Renders {key: (h, w, C)} and PSNR {method: dB or None} of one window."""
    from ..metrics import psnr

    H, W = pixels.shape[:2]
    whole = bool(np.allclose(window, domain))
    if reference is None and whole:  # a user image is a reference at zoom 1 only, pixel for pixel
        width, height = W, H
    else:
        width, height = window_shape(window, settings.render)
    xy = window_points(window, width, height, settings.spp)
    renders = {m: _pixel_mean(values_at(model, xy, device=settings.device, block=EVAL_BLOCK), width, height,
                              settings.spp)
               for m, model in models.items()}
    if reference is not None:
        renders["reference"] = _pixel_mean(np.asarray(reference(xy), dtype=np.float64), width, height, settings.spp)
    elif whole:
        renders["reference"] = pixels
    ref = renders.get("reference")
    scores = {m: None if ref is None else psnr(ref, renders[m], data_range=data_range) for m in models}
    return renders, scores


# ----------------------------------------------------------------------------------------------- outputs
def markdown_table(results: dict) -> str:
    """``results.md``: one row per method — bytes, mean PSNR over the probes per zoom, decode throughput."""
    zooms = [_zkey(z) for z in results["zooms"]]
    rows = []
    for m, r in results["methods"].items():
        cells = []
        for z in zooms:
            vals = [v for v in r["psnr"][z] if v is not None]
            cells.append(f"{np.mean(vals):.2f}" if vals else "–")
        rows.append([m, str(r["bytes"]), *cells, f"{r['points_per_s']:.3g}"])
    notes = (f"Reference: {results['reference']}. PSNR in dB (data range {results['data_range']:.4g}), "
             f"mean over {len(results['probes'])} probe(s); budget {results['budget_bytes']} bytes.")
    return table(f"dfc bench: {results['input']}", notes, ["method", "bytes", *(f"{z}×" for z in zooms), "points/s"],
                 rows)


def contact_sheet(result: BenchResult) -> bytes:
    """PNG bytes: for each probe, a block of rows (reference, then each method) by columns (zooms)."""
    res = result.results
    rows = []
    for p in range(len(res["probes"])):
        for key in ["reference", *res["methods"]]:
            tiles = [None if t is None else display(t, res["hdr"]) for t in result.tiles[key][p]]
            captions = [None] * len(tiles)
            if key != "reference":
                captions = [None if v is None else f"{v:.1f} dB"
                            for v in (res["methods"][key]["psnr"][_zkey(z)][p] for z in res["zooms"])]
            rows.append((f"probe {p + 1}\n{key}", tiles, captions))
    return contact_sheet_grid([f"{_zkey(z)}x" for z in res["zooms"]], rows)


def write_outputs(result: BenchResult, directory: str | Path) -> list[Path]:
    """Write ``results.json``, ``results.md``, ``contact.png`` (and ``dfc.dfield`` when dfc ran) into
    ``directory`` (``dfc.bench.report.write_report``). Returns the paths written."""
    return write_report(directory, result.results, markdown_table(result.results), contact_sheet(result),
                        result.blob)
