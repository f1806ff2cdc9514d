"""A Mitsuba 3 scene as the comparison's input and its exact reference at every zoom (``dfc bench --scene SCENE.xml``).

A raster is exact only at 1×; a 3D scene can be rendered again at any zoom. ``MitsubaReference`` renders each
window the comparison measures with Mitsuba itself (``dfc.io.mitsuba.render_window``: the film scaled up with a crop
window, a box pixel filter by default, as every method's pixels are box-filtered, or ``pixel_filter``: a Gaussian,
tent or Mitchell reconstruction filter, ``dfc.io.mitsuba.rfilter_plugin``), at ``spp`` samples per pixel split into two
independent halves of different seeds: their mean is the reference, their difference estimates the reference's own
error (``dfc.bench.compare.HALVES_DB``), reported beside the methods so that a score near it reads as "limited by
the reference's noise".

``mitsuba_inputs`` gives ``run_bench`` everything for a scene: its render (made here, or a render given, e.g.
``samples/make_render.py``'s), its curves (``dfc.geometry.sources.scene.read_scene`` with ``dfc curves``' defaults, or
curves given), probes found from the curves, the reference, and a 1× truth rendered independently of the input at
the input's pixels. Domain: the film's pixels ``[0, W] × [0, H]`` (``spec/conventions.md``); the input raster may
have another resolution over it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..metrics import quality_scale

__all__ = ["REFERENCE_SPP", "MitsubaReference", "is_scene_file", "mitsuba_inputs"]

REFERENCE_SPP = 256
"""Default samples per pixel of the references (and of the input when rendered here). Each reference is two
independent halves whose difference estimates its own PSNR, the ceiling of any method measured against it
(docs/scenes.md)."""


def is_scene_file(name: str) -> bool:
    """Whether ``--scene``'s value names a Mitsuba scene file (``.xml``) rather than an analytic scene."""
    return name.lower().endswith(".xml")


class MitsubaReference:
    """Mitsuba renders of a scene's windows as a ``run_bench`` reference (protocol: ``dfc.bench.compare
    .AnalyticReference``). ``window(window, width, height, spp)`` ignores ``spp`` (the methods' points per pixel)
    and renders ``self.spp`` samples per pixel: two halves of ``spp / 2``, each with a seed of its own
    (``seed``, ``seed + 1``, … in call order). Mitsuba's pixels are square: ``run_bench`` narrows its windows to
    square pixels (``square_pixels``)."""

    square_pixels = True

    def __init__(self, scene, path: str | Path, spp: int = REFERENCE_SPP, *, sensor: int = 0, seed: int = 1,
                 pixel_filter: str = "box"):
        from ..io.mitsuba import rfilter_plugin

        if spp < 2:
            raise InputError(f"a Mitsuba reference needs at least 2 samples per pixel (two halves), got {spp}")
        self.scene, self.path, self.spp, self.sensor = scene, str(path), int(spp), int(sensor)
        self.seed = int(seed)
        self.rfilter = rfilter_plugin(pixel_filter)
        self.label = f"Mitsuba renders of each window of {Path(path).name}, {self.spp} spp, {pixel_filter} filter"

    def window(self, window, width: int, height: int, spp: int | None = None):
        from ..io.mitsuba import render_window

        halves = []
        for _ in range(2):
            halves.append(render_window(self.scene, window, width, height, self.spp // 2, sensor=self.sensor,
                                        seed=self.seed, rfilter=self.rfilter))
            self.seed += 1
        a, b = halves
        return (0.5 * (a + b)).astype(np.float32), (a, b)


def _check_scaled(w: int, h: int, W: int, H: int, path, what: str) -> None:
    """InputError unless a w × h raster has square pixels over a W × H film (w / W = h / H)."""
    if w * H != h * W:
        step = max(W, H) // np.gcd(W, H)
        raise InputError(f"{what} {w}x{h}, not the film of {path} ({W}x{H}) scaled: its pixels would not be square "
                         f"(longer sides that scale it: multiples of {step})")


def mitsuba_inputs(path: str | Path, settings, *, pixels: np.ndarray | None = None, channels=None, curves=None,
                   probes=None, spp: int = REFERENCE_SPP, sensor: int = 0,
                   progress: Callable[[str], None] | None = None, pixel_filter: str = "box") -> dict:
    """The keyword arguments ``run_bench`` gets for the Mitsuba scene ``path`` (module docstring).

    settings : ``BenchSettings`` (``size``: longer side of the input rendered here, default the film's)
    pixels, channels : a render of the scene to fit instead of rendering one (any resolution with the film's aspect
        ratio); curves : its curves over the film's domain instead of extracting them
    probes : zoom centres in film pixels (default ``dfc.bench.probes.labelled_probes`` of the curves)
    spp : samples per pixel of every Mitsuba render (the input rendered here with seed 0, the references after)
    pixel_filter : the reconstruction filter of every render made here, a dfc spec Mitsuba has (``box``,
        ``gaussian[:S]``, ``tent``, ``mitchell``; ``dfc.io.mitsuba.rfilter_plugin``), stated in the labels
    """
    from ..io.mitsuba import Camera, load_scene, perspective_sensor, render_window, rfilter_plugin
    from .compare import HALVES_DB
    from .probes import labelled_probes

    progress = progress or (lambda message: None)
    scene = load_scene(path)
    W, H = Camera.from_sensor(perspective_sensor(scene, sensor, path)).size
    domain = (0.0, 0.0, float(W), float(H))
    if curves is None:
        from ..geometry.sources.scene import read_scene

        progress(f"{Path(path).name}: extracting the visible curves (dfc curves' defaults)")
        curves = read_scene(path, sensor=sensor)
    elif not np.allclose(curves.domain, domain, rtol=0, atol=1e-9 * max(W, H)):
        raise InputError(f"the curves' domain {tuple(curves.domain)} is not the film's {domain} of {path}: extract "
                         "them from the scene (dfc curves SCENE.xml) or leave --curves out")
    if pixels is None:
        longer = settings.size or max(W, H)
        w, h = max(1, round(W * longer / max(W, H))), max(1, round(H * longer / max(W, H)))
        _check_scaled(w, h, W, H, path, f"--size {longer} makes")
        progress(f"{Path(path).name}: rendering the {w}x{h} input at {spp} spp")
        pixels = render_window(scene, domain, w, h, spp, sensor=sensor, seed=0,
                               rfilter=rfilter_plugin(pixel_filter))
        channels = ["R", "G", "B"]  # window_sensor's film: pixel_format rgb
    h, w = pixels.shape[:2]
    _check_scaled(w, h, W, H, path, "the render is")
    if channels is None or len(channels) != pixels.shape[2]:
        raise ValueError(f"expected one channel name per channel of the render's {pixels.shape[2]}, got {channels}")
    reference = MitsubaReference(scene, path, spp, sensor=sensor, pixel_filter=pixel_filter)
    progress(f"{Path(path).name}: rendering the {w}x{h} 1x truth at {spp} spp")
    truth, halves = reference.window(domain, w, h)
    if probes is None or len(probes) == 0:
        points, kinds = labelled_probes(curves)
    else:
        points, kinds = np.asarray(probes, dtype=np.float64), None
    return {"pixels": pixels, "curves": curves, "channels": list(channels), "probes": points, "probe_kinds": kinds,
            "reference": reference, "truth": truth,
            "truth_label": f"an independent Mitsuba render of {w}x{h} at {spp} spp ({pixel_filter} filter)",
            "truth_psnr": quality_scale(pixels).psnr(*halves) + HALVES_DB, "name": f"Mitsuba scene {Path(path).name}"}
