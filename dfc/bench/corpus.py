"""The real-content corpus of ``dfc bench --corpus``: rate–distortion curves of dfc's default encode against the
classical codecs on content its own analytic scenes do not cover, summarised as BD-rates.

Every case (``CASES``) has a name, an input raster, the curves dfc is fitted with (the scene's own, or ``auto``:
found in the raster by ``dfc curves``' extractor), a 1× truth and, where one exists, a reference for the zoom
windows (Mitsuba rendering each window, or an analytic scene's exact value); a case without one is measured at 1×
only (``CorpusCase.zoom_truth``). No case downloads anything: Mitsuba scenes come from the repository's
``samples/scene/`` or are written here (``SHAPES_SCENE``), the third-party EXRs and diffusion-curve scenes from
a ``shared/data`` directory next to the repository (cases needing it are skipped when it is absent).

``run_corpus`` runs ``dfc.bench.rd.run_rd`` on each case at ``CORPUS_BPP`` bits per pixel, dfc encoded as a user's
default encode is (``BenchSettings.default_encode``) against ``CORPUS_METHODS``, and ``corpus_record`` turns the
curves into the BD-rate table (``bd_rate``), the 1× PSNR per budget, the zoom margins over the best codec and the
acceptance checks of each case.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from .codecs import CODECS, SDR_ONLY

__all__ = ["CASES", "CORPUS_BPP", "CORPUS_METHODS", "NOISE_SIGMA", "CorpusCase", "bd_rate", "corpus_document", "corpus_markdown",
           "corpus_record", "corpus_series", "default_shared", "found_curves", "run_case", "run_corpus", "select_cases"]

CORPUS_BPP = (0.25, 0.5, 1.0, 2.0)
"""Budgets in bits per input pixel."""
CORPUS_METHODS = ("dfc", *CODECS)
"""dfc and the classical codecs (WebP for SDR input only); no neural baselines."""
NOISE_SIGMA = 0.02
"""Standard deviation of the Gaussian noise of the noisy diffusion-curve cases (then quantised to 8 bits)."""
BD_TARGET = -10.0
"""Issue 29's acceptance: BD-rate (%) of dfc against the better of JPEG XL and AVIF at most this."""
EDGE_TARGET_DB = 10.0
"""Issue 29's acceptance: median margin (dB) of dfc over the best codec at the edge probes of the zoom windows."""
REPO = Path(__file__).resolve().parents[2]
SAMPLE_SCENE = REPO / "samples" / "scene" / "scene.xml"
GLASS_SCENE = REPO / "samples" / "scene" / "glass.xml"
"""A glass sphere, a gold sphere and a rough aluminium cube on a floor, lit by a small area light: hard shadows,
reflections, refraction and caustics (HDR)."""
TEXTURE_SCENE = REPO / "samples" / "scene" / "texture.xml"
"""A diffuse sphere and cube with checkerboard textures on a floor (SDR)."""
EXRS = ("RgbRampsDiagonal", "SquaresSwirls", "WideColorGamut")
DIFFUSION = {"poivron": "poivron_orzan", "sunset": "sunset_illustration", "test-curve": "test_curve"}
NOISY = ("poivron", "sunset")
"""Diffusion-curve scenes that also get a noisy case (test_curve is a single curve: clean only)."""

SHAPES_SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 2.5, 6" target="0, 0.5, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.2"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><translate x="1" y="4" z="1"/></transform>
        <emitter type="area"><rgb name="radiance" value="8"/></emitter>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="4"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.45"/></bsdf>
    </shape>
    <shape type="sphere"><point name="center" x="-1" y="0.6" z="0"/><float name="radius" value="0.6"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.25, 0.2"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="0.9" y="1.4" z="-0.8"/><float name="radius" value="0.25"/>
        <emitter type="area"><rgb name="radiance" value="30, 24, 12"/></emitter></shape>
    <shape type="cylinder"><point name="p0" x="0.5" y="0.35" z="0.8"/><point name="p1" x="1.6" y="0.35" z="0.1"/>
        <float name="radius" value="0.35"/>
        <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.8"/></bsdf></bsdf></shape>
    <shape type="disk">
        <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="-90"/><translate x="-0.2" y="0.01" z="1.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.85, 0.2"/></bsdf></shape>
</scene>
"""
"""A Mitsuba 3 scene of analytic shapes only (spheres, a cylinder, a disk, rectangles), 256 × 256, with a small
emitting sphere in view: its renders are HDR."""


def default_shared() -> Path:
    """``shared/data`` beside the repository (``../shared/data`` from its root), where the third-party inputs live."""
    return REPO.parent / "shared" / "data"


# ----------------------------------------------------------------------------------------------- BD-rate
def _rd_points(rates, psnrs) -> tuple[np.ndarray, np.ndarray]:
    r, p = np.asarray(rates, dtype=np.float64), np.asarray(psnrs, dtype=np.float64)
    ok = np.isfinite(r) & np.isfinite(p) & (r > 0)
    r, p = r[ok], p[ok]
    order = np.argsort(p, kind="stable")
    p, log_r = p[order], np.log(r[order])
    keep = np.concatenate([[True], np.diff(p) > 0]) if len(p) else np.zeros(0, dtype=bool)
    return p[keep], log_r[keep]


def bd_rate(rate_test, psnr_test, rate_anchor, psnr_anchor) -> float | None:
    """Bjøntegaard delta rate (%) of the test curve against the anchor: the mean difference of log rate over the
    PSNR range both curves cover, each curve's log rate interpolated as a function of PSNR by a piecewise-cubic
    Hermite (PCHIP) interpolant, as ``exp(mean difference) − 1`` in percent. Negative: the test needs fewer bytes
    for the same quality. Points with a non-finite rate or PSNR are left out, as is a repeated PSNR. None when
    either curve has fewer than two points or the PSNR ranges do not overlap.

    rate_* : (N,) positive rates (bytes); psnr_* : (N,) PSNR in dB, one per rate
    """
    from scipy.interpolate import PchipInterpolator

    pt, lt = _rd_points(rate_test, psnr_test)
    pa, la = _rd_points(rate_anchor, psnr_anchor)
    if len(pt) < 2 or len(pa) < 2:
        return None
    lo, hi = max(pt[0], pa[0]), min(pt[-1], pa[-1])
    if not hi > lo:
        return None
    diff = PchipInterpolator(pt, lt).integrate(lo, hi) - PchipInterpolator(pa, la).integrate(lo, hi)
    return float(np.expm1(diff / (hi - lo)) * 100.0)


# ----------------------------------------------------------------------------------------------- cases
@dataclass(frozen=True)
class CorpusCase:
    """One corpus case: ``build(size, progress)`` returns ``run_bench``'s keyword arguments (``pixels``, ``curves``,
    ``channels``, ``probes``, ``probe_kinds``, ``reference``, ``truth``, ``truth_label``, ``name``, and
    ``other_truths`` for a noisy input) for an input whose longer side is at most ``size``; ``auto``: dfc is fitted
    with the curves found in the raster (the probes stay the scene's); ``zoom_truth``: whether the windows above 1×
    have a reference; ``needs``: ``"shared"`` (the third-party data) or ``"samples"`` (the repository's sample
    scene) or None; ``pixel_grid``: points per pixel and axis of the 1× renders (1: the pixel centre, for a
    point-sampled raster); ``smooth``: a piecewise-smooth case (the BD-rate target applies)."""

    name: str
    summary: str
    build: Callable
    auto: bool = False
    zoom_truth: bool = False
    needs: str | None = None
    pixel_grid: int = 4
    smooth: bool = True


def _mitsuba(path_of: Callable[[], Path], pixel_filter: str, spp: int):
    def build(size, settings, progress):
        from .rendered import mitsuba_inputs

        return mitsuba_inputs(path_of(), replace(settings, size=size), spp=spp, pixel_filter=pixel_filter,
                              progress=progress)

    return build


def _shapes_path() -> Path:
    directory = Path(tempfile.mkdtemp(prefix="dfc-corpus-"))
    (directory / "shapes.xml").write_text(SHAPES_SCENE)
    return directory / "shapes.xml"


def _block_mean(pixels: np.ndarray, size: int) -> np.ndarray:
    """``pixels`` (H, W, C) area-averaged by the smallest integer factor that makes its longer side ≤ ``size``
    (rows and columns that do not fill a block dropped)."""
    h, w, c = pixels.shape
    f = max(1, -(-max(h, w) // size))
    h2, w2 = h // f, w // f
    return pixels[: h2 * f, : w2 * f].reshape(h2, f, w2, f, c).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)


def _exr(stem: str):
    def build(size, settings, progress, shared: Path):
        from ..io.image import read_image

        image = read_image(shared / "exr" / f"{stem}.exr")
        pixels = _block_mean(image.pixels, size)
        h, w = pixels.shape[:2]
        progress(f"{stem}.exr: {image.width}x{image.height} area-averaged to {w}x{h}")
        return {"pixels": pixels, "domain": (0.0, 0.0, float(w), float(h)), "channels": list(image.channels),
                "probes": [[w / 2, h / 2]],
                "probe_kinds": ["smooth"], "truth_label": "the input (a third-party EXR, area-averaged)",
                "name": f"{stem}.exr ({w}x{h})"}

    return build


def _diffusion(stem: str, noisy: bool):
    def build(size, settings, progress, shared: Path):
        from ..geometry.sources import read_curves
        from ..physics.reference import reference_solution
        from .probes import labelled_probes

        curves = read_curves(shared / "diffusion-curves" / f"{stem}.xml")
        x0, y0, x1, y1 = curves.domain
        scale = size / max(x1 - x0, y1 - y0)
        w, h = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
        progress(f"{stem}.xml: solving the diffusion curves on a {2 * w}x{2 * h} grid (box-filtered to {w}x{h})")
        fine = reference_solution(curves, 2 * w, 2 * h)
        clean = fine.reshape(h, 2, w, 2, -1).mean(axis=(1, 3)).astype(np.float32)
        c = clean.shape[2]
        channels = ["R", "G", "B"] if c == 3 else [f"C{k}" for k in range(c)]
        points, kinds = labelled_probes(curves)
        inputs = {"curves": curves, "channels": channels, "probes": points, "probe_kinds": kinds}
        label = "finite-difference solve on a 2x finer grid, 2x2 box-filtered"
        if not noisy:
            return {**inputs, "pixels": clean, "truth_label": f"the input ({label})", "name": f"{stem}.xml ({w}x{h})"}
        rng = np.random.default_rng(0)
        pixels = np.clip(np.round((clean + rng.normal(0.0, NOISE_SIGMA, clean.shape)) * 255.0), 0, 255) / 255.0
        return {**inputs, "pixels": pixels.astype(np.float32),
                "truth_label": f"the noisy input (σ {NOISE_SIGMA}, 8-bit); also against the clean solve ({label})",
                "other_truths": {"clean": clean}, "name": f"{stem}.xml ({w}x{h}) + noise σ {NOISE_SIGMA}, 8-bit"}

    return build


def _point_shapes(size, settings, progress):
    from .compare import AnalyticReference
    from .pixel_filters import filtered_raster
    from .probes import labelled_probes
    from .scenes import shapes_scene

    scene = shapes_scene()
    pixels = filtered_raster(scene, size, size, "point")
    points, kinds = labelled_probes(scene.curves)
    return {"pixels": pixels, "curves": scene.curves, "channels": scene.channels, "probes": points,
            "probe_kinds": kinds, "reference": AnalyticReference(scene.value), "truth": pixels,
            "truth_label": "the exact value at each pixel centre (the input itself; every method rendered at the "
                           "pixel centres)", "name": f"scene shapes, point-sampled ({size}x{size})"}


def _cases() -> dict[str, CorpusCase]:
    spp = 256
    cases = [
        CorpusCase("mitsuba-box", "samples/scene/scene.xml (meshes, analytic shapes), box filter, 256 spp, HDR, "
                   "the scene's curves", _mitsuba(lambda: SAMPLE_SCENE, "box", spp), zoom_truth=True,
                   needs="samples"),
        CorpusCase("mitsuba-gaussian-auto", "samples/scene/scene.xml, Gaussian filter, 256 spp, HDR, --curves auto",
                   _mitsuba(lambda: SAMPLE_SCENE, "gaussian", spp), auto=True, zoom_truth=True, needs="samples"),
        CorpusCase("mitsuba-shapes-hdr", "analytic shapes, an emitter in view (SHAPES_SCENE), box filter, "
                   "256 spp, HDR, the scene's curves", _mitsuba(_shapes_path, "box", spp), zoom_truth=True),
        CorpusCase("mitsuba-shapes-auto", "the same shapes, Gaussian filter, 256 spp, HDR, --curves auto",
                   _mitsuba(_shapes_path, "gaussian", spp), auto=True, zoom_truth=True),
        CorpusCase("mitsuba-glass-auto", "glass.xml: glass, gold, rough aluminium; Gaussian filter, 256 spp, HDR, "
                   "--curves auto", _mitsuba(lambda: GLASS_SCENE, "gaussian", spp), auto=True, zoom_truth=True,
                   needs="samples"),
        CorpusCase("mitsuba-texture-auto", "texture.xml: checkerboard-textured diffuse objects; Gaussian filter, "
                   "256 spp, --curves auto", _mitsuba(lambda: TEXTURE_SCENE, "gaussian", spp), auto=True,
                   zoom_truth=True, needs="samples"),
    ]
    cases += [CorpusCase(f"exr-{stem}", f"third-party EXR {stem}.exr, HDR, area-averaged, --curves auto, 1x only",
                         _exr(stem), auto=True, needs="shared", smooth=False) for stem in EXRS]
    for name, stem in DIFFUSION.items():
        cases.append(CorpusCase(f"dc-{name}", f"diffusion curves {stem}.xml solved, the scene's curves, 1x only",
                                _diffusion(stem, False), needs="shared"))
        if name in NOISY:
                cases.append(CorpusCase(f"dc-{name}-noisy", f"{stem}.xml solved + noise σ {NOISE_SIGMA}, 8-bit; "
                                    "PSNR vs the input and the clean solve, 1x",
                                    _diffusion(stem, True), needs="shared"))
    cases.append(CorpusCase("point-shapes", "analytic scene shapes point-sampled (point filter), the scene's curves, "
                            "windows vs its exact value", _point_shapes, zoom_truth=True, pixel_grid=1))
    return {c.name: c for c in cases}


CASES = _cases()
"""Every corpus case by name, in run order."""


def select_cases(names: list[str] | None, shared: Path | None) -> tuple[list[CorpusCase], dict[str, str]]:
    """The cases named (default: all, in ``CASES`` order) that can run, and {name: why} of those skipped: a case
    needing ``shared`` when that directory (``shared/data``) is absent, one needing the sample scene outside a
    source checkout. InputError naming an unknown case."""
    names = list(CASES) if not names else list(dict.fromkeys(names))
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise InputError(f"unknown corpus case(s) {', '.join(unknown)}; known: {', '.join(CASES)}")
    run, skipped = [], {}
    for n in names:
        case = CASES[n]
        if case.needs == "shared" and (shared is None or not Path(shared).is_dir()):
            skipped[n] = f"third-party data directory {shared} not found"
        elif case.needs == "samples" and not SAMPLE_SCENE.parent.is_dir():
            skipped[n] = "samples/scene/ not found (a source checkout has it)"
        else:
            run.append(case)
    return run, skipped


def _inputs(case: CorpusCase, size: int, settings, shared: Path | None, progress) -> dict:
    if case.needs == "shared":
        inputs = case.build(size, settings, progress, Path(shared))
    else:
        inputs = case.build(size, settings, progress)
    if case.auto:
        domain = inputs.pop("domain", None) or inputs["curves"].domain
        inputs["curves"], inputs["pixel_filter"] = found_curves(inputs["pixels"], domain, progress)
    return inputs


def found_curves(pixels: np.ndarray, domain, progress: Callable[[str], None] | None = None):
    """``--curves auto``: (curves, filter spec) ``dfc encode --curves auto`` finds in ``pixels`` (H, W, C)
    (``dfc.geometry.sources.auto.find_curves``, the pixel filter detected), the curves scaled from pixels onto
    ``domain`` (x0, y0, x1, y1); they are pruned and refined for each budget with dfc's encode, which fits that
    filter (``BenchSettings.pixel_filter``). ExtraError without scikit-image."""
    from ..errors import ExtraError
    from ..geometry.curves import fit_curves_to_domain

    if progress:
        progress("finding the curves in the raster (dfc encode --curves auto)")
    try:
        from ..geometry.sources.auto import find_curves

        found, used = find_curves(pixels)[:2]
    except ImportError:
        raise ExtraError("--curves auto finds curves with scikit-image: pip install 'dfc[curves]'") from None
    return fit_curves_to_domain(found, tuple(map(float, domain))), str(used)


# ----------------------------------------------------------------------------------------------- run
def run_corpus(cases: list[CorpusCase], settings, *, size: int = 256, bpp=CORPUS_BPP, shared: Path | None = None,
               progress: Callable[[str], None] | None = None, default_encode: bool = True, own_rate: bool = False,
               jobs: int = 1) -> dict:
    """``run_case`` on every case (``own_rate`` as it says), in ``jobs`` worker processes (each on one torch and BLAS
    thread, ``dfc.command.set_threads``) when more than one (``progress`` must then be picklable: a module-level
    function). Returns {case name: record} in the cases' order; a case that fails to build or run ends the run (its
    error raised)."""
    progress = progress or _silent
    if jobs <= 1 or len(cases) <= 1:
        return {c.name: run_case(c, settings, size=size, bpp=bpp, shared=shared, progress=progress,
                                 default_encode=default_encode, own_rate=own_rate, number=f"{k + 1}/{len(cases)}")
                for k, c in enumerate(cases)}
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(_worker, c.name, settings, size, tuple(bpp), shared, progress, default_encode,
                               own_rate, f"{k + 1}/{len(cases)}") for k, c in enumerate(cases)]
        return {c.name: f.result() for c, f in zip(cases, futures)}


def _silent(message: str) -> None:
    return None


def _worker(name, settings, size, bpp, shared, progress, default_encode, own_rate, number) -> dict:
    from ..command import set_threads

    set_threads(1)
    return run_case(CASES[name], settings, size=size, bpp=bpp, shared=shared, progress=progress,
                    default_encode=default_encode, own_rate=own_rate, number=number)


def run_case(case: CorpusCase, settings, *, size: int = 256, bpp=CORPUS_BPP, shared: Path | None = None,
             progress: Callable[[str], None] | None = None, default_encode: bool = True, own_rate: bool = False,
             number: str = "") -> dict:
    """``run_rd`` on ``case`` at ``bpp`` bits per pixel of its input (settings: ``BenchSettings``; its methods
    default to ``CORPUS_METHODS``, WebP left out for HDR input; zooms above 1 only with a reference; dfc as a
    default encode unless ``default_encode`` is False: then with ``settings.steps`` and ``batch_size``). Returns the
    RD record without its per-budget ``runs``, with ``bpp``, ``case`` and the zoom margins ``zoom_margins``; with
    ``own_rate`` also ``own_rate``: dfc encoded without a byte target and every codec at that file's size, at 1×
    (``_own_rate``)."""
    from ..metrics import is_hdr
    from .compare import run_bench
    from .rd import run_rd

    progress = progress or _silent
    progress(f"case {number + ': ' if number else ''}{case.name} ({case.summary})")
    inputs = _inputs(case, size, settings, shared, lambda m: progress(f"{case.name}: {m}"))
    h, w = inputs["pixels"].shape[:2]
    methods = tuple(m for m in (settings.methods or CORPUS_METHODS) if not (is_hdr(inputs["pixels"]) and m in SDR_ONLY))
    zooms = settings.zooms if case.zoom_truth else (1,)
    run_settings = replace(settings, methods=methods, zooms=zooms, pixel_grid=case.pixel_grid,
                           default_encode=default_encode, pixel_filter=inputs.pop("pixel_filter", settings.pixel_filter))
    budgets = sorted({max(1, round(b * w * h / 8)) for b in bpp})
    result = run_rd(inputs, budgets, run_settings, lambda m: progress(f"{case.name}: {m}"))
    record = {k: v for k, v in result.results.items() if k != "runs"}
    record["bpp"] = [round(8 * b / (w * h), 4) for b in budgets]
    record["case"] = {"name": case.name, "summary": case.summary, "auto": case.auto, "zoom_truth": case.zoom_truth,
                      "smooth": case.smooth}
    record["zoom_margins"] = _zoom_margins([r.results for r in result.runs])
    if own_rate:
        own = run_bench(**inputs, settings=replace(run_settings, target_bytes=None, zooms=(1,), super_resolution=0),
                        progress=lambda m: progress(f"{case.name}: at dfc's own size: {m}"))
        record["own_rate"] = _own_rate(own.results, w * h)
    return record


def _own_rate(results: dict, pixels: int) -> dict:
    """{"bytes", "bpp", "psnr": dfc's file at 1× (all pixels), "codecs": {codec: {"bytes", "psnr"}}} of a
    ``run_bench`` result without a byte target (the codecs at dfc's size); {"failed": why} when dfc made no file."""
    methods = results["methods"]
    if "dfc" not in methods:
        return {"failed": results["failed"].get("dfc", "not run")}
    dfc = methods["dfc"]
    return {"bytes": dfc["bytes"], "bpp": round(8 * dfc["bytes"] / pixels, 4), "psnr": dfc["image_psnr"]["all"],
            "codecs": {m: {"bytes": r["bytes"], "psnr": r["image_psnr"]["all"]} for m, r in methods.items()
                       if m in CODECS}}


def _zoom_margins(runs: list[dict]) -> dict:
    """Per zoom above 1 with a reference: dfc's PSNR minus the best codec's in every window of every budget:
    {zoom: {"min", "min_at", "edge_median", "median"}} (dB)."""
    out: dict[str, dict] = {}
    for res in runs:
        if not res["zoom_truth"] or "dfc" not in res["methods"]:
            continue
        codecs = [m for m in res["methods"] if m in CODECS]
        for z, dfc in res["methods"]["dfc"]["psnr"].items():
            if float(z) <= 1:
                continue
            entry = out.setdefault(z, {"margins": [], "where": [], "kinds": []})
            for p, (v, kind) in enumerate(zip(dfc, res["probe_kinds"])):
                best = [res["methods"][m]["psnr"][z][p] for m in codecs]
                best = [b for b in best if b is not None]
                if v is None or not best:
                    continue
                entry["margins"].append(v - max(best))
                entry["where"].append(f"{kind} {p + 1} at {res['budget_bytes']} B")
                entry["kinds"].append(kind)
    summary = {}
    for z, e in out.items():
        if not e["margins"]:
            continue
        m = np.asarray(e["margins"])
        edges = [x for x, k in zip(e["margins"], e["kinds"]) if k == "edge"]
        summary[z] = {"min": float(m.min()), "min_at": e["where"][int(np.argmin(m))], "median": float(np.median(m)),
                      "edge_median": float(np.median(edges)) if edges else None}
    return summary


# ----------------------------------------------------------------------------------------------- report
def _curve(record: dict, method: str, key=lambda p: p["image_psnr"]["all"]) -> tuple[list, list]:
    pts = [(p["bytes"], key(p)) for p in record["curves"].get(method, []) if "bytes" in p and key(p) is not None]
    return [b for b, _ in pts], [v for _, v in pts]


def _fmt(v, spec=".1f", suffix="") -> str:
    return "–" if v is None else f"{v:{spec}}{suffix}"


def corpus_record(results: dict, skipped: dict[str, str], bpp=CORPUS_BPP) -> dict:
    """The corpus record: per case, the BD-rate of dfc against each codec (1× PSNR on all pixels; and against the
    clean truth for a noisy case), the acceptance checks (``checks``) and the RD record; ``skipped``."""
    cases = {}
    for name, rec in results.items():
        bd = {}
        dfc = _curve(rec, "dfc")
        for m in CODECS:
            if m in rec["curves"]:
                bd[m] = bd_rate(*dfc, *_curve(rec, m))
        clean_key = "clean" if any("image_psnr_vs" in p for p in rec["curves"].get("dfc", [])) else None
        bd_clean = {}
        if clean_key:
            def key(p):
                return p.get("image_psnr_vs", {}).get(clean_key, {}).get("all")

            for m in CODECS:
                if m in rec["curves"]:
                    bd_clean[m] = bd_rate(*_curve(rec, "dfc", key), *_curve(rec, m, key))
        better = [bd[m] for m in ("jpegxl", "avif") if bd.get(m) is not None]
        checks = {"bd_better_jxl_avif": max(better) if better else None}
        above = []
        for i, budget in enumerate(rec["budgets"]):
            points = {m: pts[i] for m, pts in rec["curves"].items()}
            d = points.get("dfc", {})
            codec_psnr = [p["image_psnr"]["all"] for m, p in points.items() if m in CODECS and "bytes" in p]
            if "bytes" not in d or not codec_psnr:
                above.append(None if not codec_psnr else False)
                continue
            above.append(d["image_psnr"]["all"] - max(codec_psnr))
        checks["margins_1x"] = above
        checks["above_1x"] = all(a is not None and a is not False and a >= 0 for a in above)
        checks["bd_met"] = checks["bd_better_jxl_avif"] is not None and checks["bd_better_jxl_avif"] <= BD_TARGET
        zm = rec["zoom_margins"]
        checks["zoom_min"] = min((v["min"] for v in zm.values()), default=None)
        edges = [v["edge_median"] for v in zm.values() if v["edge_median"] is not None]
        checks["zoom_edge_median_min"] = min(edges) if edges else None
        if "super_resolution" in rec:
            checks["super_margins"] = _super_margins(rec)
            checks["super_above"] = all(m is not None and m["vs_input"] >= 0 and (m["vs_codecs"] or 0) >= 0
                                        for m in checks["super_margins"])
        own = rec.get("own_rate")
        if own is not None:
            best = [c["psnr"] for c in own.get("codecs", {}).values()]
            checks["own_rate_margin"] = own["psnr"] - max(best) if "psnr" in own and best else None
        cases[name] = {"bd_rate": bd, "bd_rate_clean": bd_clean or None, "checks": checks, **rec}
    return {"corpus": True, "cases": cases, "skipped": skipped, "bpp": [float(b) for b in bpp]}


def _super_margins(rec: dict) -> list[dict | None]:
    """Per budget, dfc's super-resolution PSNR minus the input's upsampled (better kernel) and minus the best codec's
    (``vs_input``, ``vs_codecs``: dB, the latter None without a codec); None where dfc made no file."""
    sr = rec["super_resolution"]
    input_db = max(sr["input"].values())
    out = []
    for i, point in enumerate(rec["curves"].get("dfc", [{}] * len(rec["budgets"]))):
        codecs = [pts[i].get("super_psnr") for m, pts in rec["curves"].items() if m in CODECS]
        codecs = [c for c in codecs if c is not None]
        v = point.get("super_psnr")
        out.append(None if v is None else {"vs_input": v - input_db, "vs_codecs": v - max(codecs) if codecs else None})
    return out


def _smallest(point: dict) -> int | None:
    """dfc's smallest file (bytes) at a budget it could not meet, from its failure message, else None."""
    import re

    found = re.search(r"smallest file tried takes (\d+) bytes", point.get("failed", ""))
    return int(found.group(1)) if found else None


def corpus_markdown(record: dict) -> str:
    """The tables of a corpus run: BD-rates and acceptance per case, 1× PSNR per budget, zoom margins; the cases
    skipped."""
    from .compare import LABELS
    from .report import markdown_table as table

    cases = record["cases"]
    header = ["case", "dfc points", *(f"vs {LABELS[m]}" for m in CODECS), "vs better of JXL/AVIF",
              "1× ≥ best codec, all budgets",
              "zoom: worst probe − best codec", "zoom: edges median − best codec"]
    rows = []
    for name, c in cases.items():
        ch = c["checks"]
        pts = c["curves"].get("dfc", [])
        smallest = [_smallest(p) for p in pts if "failed" in p]
        points = f"{sum('bytes' in p for p in pts)}/{len(pts)}" + (
            f" (smallest file {max(smallest)} B)" if smallest and all(smallest) else "")
        rows.append([name, points,
                     *(_fmt(c["bd_rate"].get(m), "+.1f", " %") if m in c["bd_rate"] else "n/a" for m in CODECS),
                     _fmt(ch["bd_better_jxl_avif"], "+.1f", " %") + (" ✓" if ch["bd_met"] else " ✗"),
                     "✓" if ch["above_1x"] else "✗ (" + ", ".join(
                         "no dfc file" if a is None or a is False else f"{a:+.1f} dB" for a in ch["margins_1x"]) + ")",
                     "1× only (no reference)" if not c["case"]["zoom_truth"] else _fmt(ch["zoom_min"], "+.1f", " dB"),
                     "1× only" if not c["case"]["zoom_truth"] else _fmt(ch["zoom_edge_median_min"], "+.1f", " dB")])
    notes = ("dfc points: the budgets at which dfc made a file (its smallest file when it could not: a BD-rate "
             "needs two points). BD-rate (%) of dfc against each codec: Bjøntegaard delta rate, PCHIP of log bytes against 1× PSNR (all "
             "pixels) over the PSNR range both curves cover; negative: dfc needs fewer bytes. The acceptance of issue "
             f"29: BD-rate against the better of JPEG XL and AVIF ≤ {BD_TARGET:g} % (✓/✗), dfc's 1× PSNR at or above "
             "the best codec at every budget (margins at each budget when not), no zoom probe below the best codec, "
             f"edge probes' median margin ≥ +{EDGE_TARGET_DB:g} dB (the worst zoom's median). n/a: the codec does not "
             "apply (WebP: SDR only); –: curves that do not overlap.")
    text = table("dfc bench --corpus: BD-rate of dfc against each codec", notes, header, rows)
    noisy = {n: c for n, c in cases.items() if c.get("bd_rate_clean")}
    if noisy:
        rows = [[n, *(_fmt(c["bd_rate_clean"].get(m), "+.1f", " %") if m in c["bd_rate_clean"] else "n/a"
                      for m in CODECS)] for n, c in noisy.items()]
        text += "\n" + table("BD-rate against the clean truth (noisy inputs)", "The same, every method's 1× PSNR "
                             "measured against the clean solve instead of the noisy input it was fitted to.",
                             ["case", *(f"vs {LABELS[m]}" for m in CODECS)], rows)
    own = {n: c["own_rate"] for n, c in cases.items() if "own_rate" in c}
    if own:
        rows = []
        for n, o in own.items():
            if "psnr" not in o:
                rows.append([n, "–", "–", f"no file ({o['failed']})", "–", "–"])
                continue
            best = max(o["codecs"], key=lambda m: o["codecs"][m]["psnr"], default=None)
            rows.append([n, str(o["bytes"]), f"{o['bpp']:.3f}", f"{o['psnr']:.2f}",
                         "–" if best is None else f"{LABELS[best]} {o['codecs'][best]['psnr']:.2f} "
                                                  f"({o['codecs'][best]['bytes']})",
                         _fmt(cases[n]["checks"].get("own_rate_margin"), "+.2f", " dB")])
        text += "\n" + table("The default encode at its own size", "dfc encoded without a byte target (as `dfc encode` "
                             "does by default), every codec at most that file's size; 1× PSNR in dB on all pixels "
                             "(bytes). Issue 29 asks the default encode to land on or above the codecs' curve at its "
                             "own rate: margin ≥ 0.", ["case", "dfc bytes", "bpp", "dfc 1×", "best codec (bytes)",
                                                       "margin"], rows)
    bpp = record["bpp"]
    rows = []
    for name, c in cases.items():
        for m, pts in c["curves"].items():
            cells = [f"{p['image_psnr']['all']:.2f} ({p['bytes']})" if "bytes" in p
                     else f"– (smallest {_smallest(p)} B)" if _smallest(p) else "–" for p in pts]
            rows.append([name, LABELS[m], *cells])
            if any("image_psnr_vs" in p for p in pts):
                rows.append([name, f"{LABELS[m]} vs clean", *(
                    "–" if "bytes" not in p else f"{p['image_psnr_vs']['clean']['all']:.2f}" for p in pts)])
    text += "\n" + table("1× PSNR per budget", "PSNR in dB on all pixels (bytes used) at each budget in bits per "
                         "pixel of the case's input; HDR cases tone-mapped x / (1 + x). –: the method cannot meet the "
                         "budget (dfc: its smallest file is larger).", ["case", "method", *(f"{b:g} bpp" for b in bpp)],
                         rows)
    srows = []
    for name, c in cases.items():
        sr = c.get("super_resolution")
        if not sr:
            continue
        best_input = max(sr["input"], key=sr["input"].get)
        srows.append([name, f"the input, {best_input}", *([f"{sr['input'][best_input]:.2f}"] * len(c["budgets"]))])
        for m, pts in c["curves"].items():
            srows.append([name, LABELS[m], *("–" if p.get("super_psnr") is None else f"{p['super_psnr']:.2f}"
                                             for p in pts)])
        margins = c["checks"]["super_margins"]
        srows.append([name, "dfc − the input / − best codec", *(
            "–" if g is None else f"{g['vs_input']:+.2f} / " + _fmt(g["vs_codecs"], "+.2f") for g in margins)])
    if srows:
        factor = next(c["super_resolution"]["factor"] for c in cases.values() if c.get("super_resolution"))
        text += "\n" + table(f"{factor}× super-resolution", f"Every method rendered over the whole image at {factor}× "
                             "the input's pixels per axis against the reference rendered there (cases with a "
                             "reference); the codecs' decodes and the input itself upsampled by the better of bicubic "
                             "and Lanczos. Issue 31 asks dfc to be above the input upsampled and above the codecs' "
                             "decodes upsampled.", ["case", "method", *(f"{b:g} bpp" for b in bpp)], srows)
    zrows = []
    for name, c in cases.items():
        for z, v in c["zoom_margins"].items():
            zrows.append([name, f"{z}×", _fmt(v["min"], "+.1f"), v["min_at"], _fmt(v["median"], "+.1f"),
                          _fmt(v["edge_median"], "+.1f")])
    if zrows:
        text += "\n" + table("Zoom windows: dfc − best codec (dB)", "Over every probe and budget of the case; the "
                             "codecs upsampled by the better of bicubic and Lanczos, window by window.",
                             ["case", "zoom", "worst", "worst at", "median", "edges median"], zrows)
    if record["skipped"]:
        text += "\n" + "\n".join(f"- {n}: skipped ({why})" for n, why in record["skipped"].items()) + "\n"
    return text


def corpus_document(record: dict, markdown: str) -> dict:
    """``record`` as a result file (``dfc.bench.results.publish_record``: this run's command, date, commit and
    machine; the tables of ``markdown``) on the ``corpus`` page with its figure (``corpus_series``); non-finite
    numbers as null."""
    from .report import finite
    from .results import publish_record

    doc = publish_record(record, markdown)
    doc.update(title="dfc bench --corpus: real content at 0.25–2 bits per pixel", page="corpus",
               series=corpus_series(record))
    return finite(doc)


def corpus_series(record: dict, figure: str = "corpus_rd") -> list[dict]:
    """The lines of the corpus figure: one panel per case, 1× PSNR (all pixels) against bytes per method."""
    from .compare import LABELS

    series = []
    for name, c in record["cases"].items():
        for m in c["curves"]:
            x, y = _curve(c, m)
            series.append({"figure": figure, "figure_title": "dfc bench --corpus: 1× PSNR against bytes",
                           "panel": name, "label": LABELS[m], "x": x, "y": [round(v, 2) for v in y],
                           "x_label": "bytes", "y_label": "PSNR (dB)", "x_log2": True})
    return series
