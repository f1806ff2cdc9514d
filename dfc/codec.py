"""The codec pipeline: image + curves -> mesh -> fit -> ``.dfield``, and ``.dfield`` -> model.

This is the glue the CLI and the Python API share; each step lives in its own module.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .curves import Curves
from .errors import InputError


@dataclass
class EncodeSettings:
    """Every knob of an encode; stored in the file's header (``encoder``) so a decode never depends on defaults."""

    max_triangles: int | None = None
    max_area: float | None = None
    edge_length: float | None = None
    target_bytes: int | None = None
    steps: int = 2000
    batch_size: int = 1 << 14
    dim: int = 5
    feature_bits: int = 8
    mesh_bits: int = 20
    qat_steps: int | None = None
    loss: str = "auto"
    seed: int = 0
    device: str = "cpu"


@dataclass
class EncodeReport:
    """What an encode measured. ``psnr`` is of the written file decoded at the input's pixel centres."""

    chunk_bytes: dict[str, int]
    total_bytes: int
    bits_per_pixel: float
    psnr: float
    data_range: float
    n_vertices: int
    n_triangles: int
    n_features: int
    seconds: dict[str, float] = field(default_factory=dict)


def fit_curves_to_domain(curves: Curves, domain: tuple[float, float, float, float]) -> Curves:
    """Scale and translate curves so their domain maps onto ``domain`` (independently in x and y)."""
    sx0, sy0, sx1, sy1 = curves.domain
    dx0, dy0, dx1, dy1 = domain
    scale = np.array([(dx1 - dx0) / (sx1 - sx0), (dy1 - dy0) / (sy1 - sy0)])
    cp = (curves.control_points - [sx0, sy0]) * scale + [dx0, dy0]
    return Curves(domain, cp, curves.degree, curves.curve, curves.t_range, curves.names, curves.sides, curves.source)


def check_domain(curves: Curves, width: int, height: int, fit: bool) -> Curves:
    """The image covers [0, W] × [0, H]; curves must share that domain (or be scaled onto it with ``fit``)."""
    image_domain = (0.0, 0.0, float(width), float(height))
    if np.allclose(curves.domain, image_domain, rtol=0, atol=1e-9 * max(width, height)):
        return curves
    if fit:
        return fit_curves_to_domain(curves, image_domain)
    raise InputError(
        f"the curves' domain {tuple(round(v, 6) for v in curves.domain)} does not match the image's "
        f"[0, {width}] × [0, {height}]; pass --fit-curves-to-image to scale the curves onto the image"
    )
