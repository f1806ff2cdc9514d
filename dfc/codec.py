"""The codec pipeline: image + curves -> mesh -> fit -> ``.dfield``, and ``.dfield`` -> model.

This is the glue the CLI and the Python API share; each step lives in its own module. The fit runs on
the mesh exactly as the decoder will see it (``build_mesh``), the last steps run quantisation-aware, and
the reported PSNR is measured on the written bytes decoded again, so the file decodes to what it reports.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch

from . import __version__
from .errors import InputError, MeshError, TriangleBudgetError
from .geometry.curves import Curves, split_pieces
from .geometry.mesh import Mesh
from .geometry.triangulate import DEFAULT_TRIANGLES, triangulate
from .render import values_at

if TYPE_CHECKING:
    from .io.container import DfieldContents

__all__ = ["EncodeSettings", "EncodeReport", "build_mesh", "check_domain", "encode_fem", "encode_frames",
           "encode_image", "encode_samples", "fit_curves_to_domain", "from_contents", "load", "loads", "to_contents"]

TARGET_BYTES_PROBES = 12
"""Triangulations tried at most when sizing the mesh to a byte target."""
QUERY_BLOCK = 1 << 18
"""Points evaluated per call when measuring a decoded file at scattered positions."""
SAMPLE_PIECE_REL = 1.0 / 64.0
"""Sample sets: curved pieces are cut to at most this fraction of the domain's longer side before meshing
(``dfc.geometry.curves.split_pieces``). A curved piece's sliver carries one curve feature, so long pieces leave a
wide band along the curve with little freedom; cutting them halves the walk-on-spheres fit's error near the
curves (``dfc benchmark wos``)."""
NOISY_SAMPLES_PER_TRIANGLE = 1000
"""Sample sets without a mesh-size option get about one triangle per this many samples (at most
``DEFAULT_TRIANGLES``, at least what the curves force): a finer mesh fits the noise of Monte Carlo samples
(on the pepper at 500² and 11 spp, 2.75M samples on 1,746 triangles denoise 30×)."""


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


# ----------------------------------------------------------------------------------------------- mesh
def build_mesh(curves: Curves, settings: EncodeSettings, *, stats: dict | None = None) -> Mesh:
    """Triangulate ``curves`` with the settings' size knobs and return the mesh as the decoder will see it
    (Draco-quantised with ``settings.mesh_bits``, decoder vertex order): the geometry the fit runs on."""
    from .io.meshcodec import roundtrip_mesh
    mesh = triangulate(curves, max_area=settings.max_area, edge_length=settings.edge_length,
                       max_triangles=settings.max_triangles, stats=stats)
    return roundtrip_mesh(mesh, settings.mesh_bits)


# ----------------------------------------------------------------------------------------------- model <-> file
_ARCH_KEYS = ("dim", "hidden", "layers", "activation", "oneblob_bins")


def to_contents(model, encoder: dict | None = None) -> DfieldContents:
    """The ``.dfield`` contents of a fitted ``FieldModel`` (quantised values when its quantised mode is on).

    encoder : free-form provenance stored in the header's ``encoder`` object (never needed to decode)
    """
    from .io.container import DfieldContents

    config = model.config()
    header = {
        "domain": [float(v) for v in model.field.mesh.domain],
        "channels": list(config["channels"]),
        "value_transform": config["transform"],
        "times": config["times"],
        "model": {k: config[k] for k in _ARCH_KEYS},
        "encoder": dict(encoder or {}),
    }
    with torch.no_grad():
        features = model.field.bank.detach().cpu().numpy().astype(np.float32)
        mlp = {}
        for i, lin in enumerate(model.decoder.linears()):
            mlp[f"layers.{i}.weight"] = lin.weight.detach().cpu().numpy().astype(np.float32)
            mlp[f"layers.{i}.bias"] = lin.bias.detach().cpu().numpy().astype(np.float32)
    return DfieldContents(header=header, mesh=model.field.mesh, features=features, mlp=mlp)


def from_contents(contents: DfieldContents, *, device: str = "cpu"):
    """Rebuild the ``FieldModel`` a file describes. Raises ``FormatError`` when the header's model does
    not match the stored features or weights."""
    from .errors import FormatError
    from .field.model import FieldModel

    h = contents.header
    arch = h["model"]
    missing = [k for k in _ARCH_KEYS if k not in arch]
    if missing:
        raise FormatError(f"HEAD: model lacks {missing}")
    config = {**{k: arch[k] for k in _ARCH_KEYS}, "transform": h["value_transform"], "channels": h["channels"],
              "n_slices": int(contents.features.shape[0]), "times": h["times"]}
    model = FieldModel.from_config(contents.mesh, config, device=device)
    with torch.no_grad():
        bank = torch.from_numpy(np.ascontiguousarray(contents.features))
        if tuple(bank.shape) != tuple(model.field.bank.shape):
            raise FormatError(f"FEAT: bank shape {tuple(bank.shape)}, the model needs {tuple(model.field.bank.shape)}")
        model.field.bank.copy_(bank)
        linears = model.decoder.linears()
        expected = {f"layers.{i}.{p}" for i in range(len(linears)) for p in ("weight", "bias")}
        if set(contents.mlp) != expected:
            raise FormatError(f"MLPW: tensors {sorted(contents.mlp)}, the model needs {sorted(expected)}")
        for i, lin in enumerate(linears):
            for p in ("weight", "bias"):
                w = torch.from_numpy(contents.mlp[f"layers.{i}.{p}"])
                target = getattr(lin, p)
                if tuple(w.shape) != tuple(target.shape):
                    raise FormatError(f"MLPW: layers.{i}.{p} has shape {tuple(w.shape)}, expected {tuple(target.shape)}")
                target.copy_(w)
    model.header = h
    model.eval()
    return model


def loads(blob: bytes, *, device: str = "cpu"):
    """``FieldModel`` from the bytes of a ``.dfield`` file (fully checked; ``FormatError`` if damaged)."""
    from .io.container import decode_dfield

    return from_contents(decode_dfield(blob), device=device)


def load(path: str | Path, *, device: str = "cpu"):
    """``FieldModel`` from a ``.dfield`` file: ``model(xy)``, ``model.features(xy)``, ``model.render(w, h)``."""
    from .io.container import read_dfield

    return from_contents(read_dfield(path), device=device)


# ----------------------------------------------------------------------------------------------- encode
def _size_mesh(curves: Curves, settings: EncodeSettings, channels: list[str]) -> Mesh:
    """The decoder-view mesh, sized to ``settings.target_bytes`` when given (else the explicit knobs)."""
    if settings.target_bytes is None:
        return build_mesh(curves, settings)
    from .field.feature_field import FeatureField
    from .field.model import FieldModel
    from .io.container import encode_dfield

    def file_bytes(n_triangles: int) -> tuple[int, Mesh]:
        s = replace(settings, max_triangles=n_triangles, max_area=None, edge_length=None)
        mesh = build_mesh(curves, s)
        # a fitted bank is about as incompressible as a random one at the same bit depth
        model = FieldModel(FeatureField(mesh, dim=settings.dim, seed=settings.seed), channels)
        with torch.no_grad():
            model.field.bank.uniform_(-1.0, 1.0, generator=torch.Generator().manual_seed(settings.seed))
        blob, _ = encode_dfield(to_contents(model), feature_bits=settings.feature_bits)
        return len(blob), mesh

    # Bisection on the triangle cap: ``fits`` is the largest cap known to fit the target, ``over`` the smallest
    # known not to (too many bytes, or fewer triangles than the curves force).
    fits, over, best, size = 0, None, None, None
    n = DEFAULT_TRIANGLES
    for _ in range(TARGET_BYTES_PROBES):
        try:
            size, mesh = file_bytes(n)
        except MeshError:  # below the triangles the curves force: only larger caps can work
            fits, size = max(fits, n), None
        if size is not None and size <= settings.target_bytes:
            fits, best = n, mesh
        elif size is not None:
            over = n
        if over is not None and over - fits <= max(8, fits // 50):
            break
        n = 2 * n if over is None else (fits + over) // 2
    if best is None:
        raise InputError(f"target of {settings.target_bytes} bytes is too small for these curves"
                         + (f": the smallest mesh tried needs {size} bytes" if size is not None else ""))
    return best


def _encoder_info(settings: EncodeSettings, source: str, extra: dict) -> dict:
    return {"software": f"dfc {__version__}", "source": source, **asdict(settings), **extra}


def _mesh_and_fit(fit_fn, signal, curves: Curves, settings: EncodeSettings, channels: list[str], callback,
                  mesh: Mesh | None = None, **fit_kw):
    """Build the decoder-view mesh (unless ``mesh`` is that mesh already), then fit ``fit_fn`` (``fit_image``,
    ``fit_samples`` or ``fit_frames``) to ``signal`` on it; ``fit_kw`` go to ``fit_fn``. Returns (model, seconds
    per stage)."""
    clock = time.perf_counter()
    mesh = mesh if mesh is not None else _size_mesh(curves, settings, channels)
    seconds = {"mesh_s": time.perf_counter() - clock}
    clock = time.perf_counter()
    model = fit_fn(signal, mesh, steps=settings.steps, batch_size=settings.batch_size, dim=settings.dim,
                   seed=settings.seed, loss=settings.loss, device=settings.device, qat_steps=settings.qat_steps,
                   feature_bits=settings.feature_bits, callback=callback, channels=channels, **fit_kw)
    seconds["fit_s"] = time.perf_counter() - clock
    return model, seconds


def _finish(model, settings: EncodeSettings, info: dict, seconds: dict, n_pixels: int,
            truth: Callable[[object], tuple[np.ndarray, np.ndarray]], data_range: float):
    """Write the model to bytes, decode them, measure PSNR of the decoded model against ``truth``."""
    from .io.container import encode_dfield
    from .metrics import psnr

    clock = time.perf_counter()
    blob, sizes = encode_dfield(to_contents(model, info), feature_bits=settings.feature_bits)
    decoded = loads(blob, device=settings.device)
    seconds["write_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    reference, test = truth(decoded)
    seconds["verify_s"] = time.perf_counter() - clock
    mesh = decoded.field.mesh
    report = EncodeReport(
        chunk_bytes=sizes, total_bytes=len(blob), bits_per_pixel=8.0 * len(blob) / n_pixels,
        psnr=psnr(reference, test, data_range=data_range), data_range=data_range,
        n_vertices=mesh.n_vertices, n_triangles=mesh.n_triangles, n_features=decoded.field.n_features,
        seconds=seconds,
    )
    return blob, report


def encode_image(image, curves: Curves, settings: EncodeSettings | None = None, *,
                 fit_curves: bool = False, callback: Callable[[int, float, float], None] | None = None):
    """Encode a raster with its discontinuity curves.

    Parameters
    ----------
    image : ``dfc.io.image.Image`` or (H, W, C) float array of linear values covering [0, W] × [0, H]
    curves : Curves over the same domain (or any domain with ``fit_curves=True``, scaled onto the image)
    settings : EncodeSettings (defaults when None)
    callback : ``callback(step, loss, batch_psnr)`` after each optimiser step

    Returns
    -------
    (blob, report): the ``.dfield`` bytes and an ``EncodeReport`` whose ``psnr`` is of ``blob`` decoded and
    rendered at the input's pixel centres, against the input (data range 1 for LDR, the input's span for HDR).
    """
    from .io.samples import default_channels
    from .render import render
    from .train.fit import _check_pixels, fit_image

    settings = settings or EncodeSettings()
    pixels = _check_pixels(image)
    h, w, c = pixels.shape
    channels = getattr(image, "channels", None) or default_channels(c)
    curves = check_domain(curves, w, h, fit_curves)
    model, seconds = _mesh_and_fit(fit_image, image, curves, settings, channels, callback)
    hdr = float(pixels.max()) > 1.0
    data_range = float(pixels.max() - pixels.min()) if hdr else 1.0
    info = _encoder_info(settings, curves.source, {"input": f"image {w}x{h}", "pixels": w * h, "hdr": hdr})
    return _finish(model, settings, info, seconds, w * h, lambda m: (pixels, render(m, w, h)), max(data_range, 1e-12))


def _sample_mesh_size(curves: Curves, settings: EncodeSettings, n_samples: int) -> tuple[EncodeSettings, Mesh | None]:
    """``settings`` with ``max_triangles`` following the sample count (``NOISY_SAMPLES_PER_TRIANGLE``) and the
    decoder-view mesh built with them, when no mesh-size option is set; else ``settings`` unchanged and None."""
    if any(v is not None for v in (settings.max_triangles, settings.max_area, settings.edge_length,
                                   settings.target_bytes)):
        return settings, None
    cap = min(DEFAULT_TRIANGLES, max(2, n_samples // NOISY_SAMPLES_PER_TRIANGLE))
    while True:  # the first refusal counts vertices only; the curves' apexes may need a few more triangles
        sized = replace(settings, max_triangles=cap)
        try:
            return sized, build_mesh(curves, sized)
        except TriangleBudgetError as e:
            cap = max(e.needed, cap + 1)


def encode_samples(samples, curves: Curves, settings: EncodeSettings | None = None, *,
                   callback: Callable[[int, float, float], None] | None = None):
    """Encode a scattered sample set (``dfc.io.samples.SampleSet``) with its discontinuity curves.

    The samples' domain (when given) must equal the curves'. Curved pieces are cut to ``SAMPLE_PIECE_REL`` of
    the longer side, and without a mesh-size setting the mesh follows the sample count
    (``NOISY_SAMPLES_PER_TRIANGLE``). ``report.psnr`` is of the decoded file at
    the sample positions against the sample values (data range: the values' span), and
    ``bits_per_pixel`` counts bits per sample.
    """
    from .io.samples import default_channels
    from .train.fit import fit_samples

    settings = settings or EncodeSettings()
    domain = getattr(samples, "domain", None)
    if domain is not None and not np.allclose(domain, curves.domain, rtol=1e-9, atol=0):
        raise InputError(f"the samples' domain {tuple(domain)} differs from the curves' {tuple(curves.domain)}")
    values = np.asarray(samples.values, dtype=np.float32)
    channels = samples.channels or default_channels(values.shape[1])
    x0, y0, x1, y1 = curves.domain
    curves = split_pieces(curves, SAMPLE_PIECE_REL * max(x1 - x0, y1 - y0))
    clock = time.perf_counter()
    settings, mesh = _sample_mesh_size(curves, settings, len(values))
    sizing_s = time.perf_counter() - clock
    model, seconds = _mesh_and_fit(fit_samples, samples, curves, settings, channels, callback, mesh=mesh)
    seconds["mesh_s"] += sizing_s
    xy = np.asarray(samples.xy, dtype=np.float64)

    def truth(m):
        return values, values_at(m, xy, device=settings.device, block=QUERY_BLOCK)

    data_range = max(float(values.max() - values.min()), 1e-12)
    info = _encoder_info(settings, curves.source, {"input": f"samples {len(xy)}", "samples": len(xy)})
    return _finish(model, settings, info, seconds, len(xy), truth, data_range)


def _physical(settings: EncodeSettings) -> tuple[EncodeSettings, dict]:
    """Settings and fit options for simulation data: values above 1 are physical quantities, not HDR light, so
    ``loss="auto"`` means the MSE and the values are decoded without the log transform."""
    if settings.loss == "auto":
        settings = replace(settings, loss="mse")
    return settings, {"transform": "identity"}


def encode_fem(solution, curves: Curves, settings: EncodeSettings | None = None, *, sampling: str = "linear",
               callback: Callable[[int, float, float], None] | None = None):
    """Encode a FEM solution (``dfc.io.fem.FemSolution``) with its barrier curves.

    The domain is the curves' when it contains the mesh, else the mesh's bounding box (``dfc.io.fem.fem_curves``).
    The fit sees the nodes and ``dfc.io.fem.SAMPLES_PER_TRIANGLE`` points per element valued by ``sampling`` ("linear" or
    "nearest", ``dfc.io.fem.interpolate``: never across a barrier). ``report.psnr`` is of the decoded file at the
    nodes (each read just inside its first element, ``dfc.io.fem.node_points``) against the nodal values, data range
    the values' span over all channels; ``bits_per_pixel`` counts bits per node.
    """
    from .io.fem import fem_curves, node_points, sample_fem
    from .io.samples import SampleSet
    from .train.fit import fit_samples

    settings, fit_kw = _physical(settings or EncodeSettings())
    curves = fem_curves(solution, curves)
    xy, values = sample_fem(solution, curves, mode=sampling, seed=settings.seed)
    samples = SampleSet(xy, values, curves.domain, list(solution.channels))
    model, seconds = _mesh_and_fit(fit_samples, samples, curves, settings, list(solution.channels), callback,
                                   **fit_kw)
    node_xy = node_points(solution)[0]
    nodal = solution.values[np.unique(solution.triangles)]
    data_range = max(float(nodal.max() - nodal.min()), 1e-12)
    info = _encoder_info(settings, curves.source, {"input": f"FEM {solution.source or 'mesh'}: {len(nodal)} nodes, "
                                                            f"{len(solution.triangles)} triangles",
                                                   "nodes": len(nodal), "fem_sampling": sampling})
    return _finish(model, settings, info, seconds, len(nodal),
                   lambda m: (nodal, values_at(m, node_xy, device=settings.device, block=QUERY_BLOCK)),
                   data_range)


def encode_frames(sequence, curves: Curves, settings: EncodeSettings | None = None, *, fit_curves: bool = False,
                  callback: Callable[[int, float, float], None] | None = None):
    """Encode a frame sequence (``dfc.io.frames.FrameSequence``, T frames of W × H covering [0, W] × [0, H]) with its
    discontinuity curves into a time-sliced file: one feature slice per frame time, linear blending between them.

    ``report.psnr`` is of the decoded file rendered at every frame's pixel centres and time against the frames,
    data range 1 when every value lies in [0, 1], else the values' span; ``bits_per_pixel`` counts T · W · H pixels.
    """
    from .io.frames import check_frames
    from .io.samples import default_channels
    from .render import render
    from .train.fit import fit_frames

    settings = settings or EncodeSettings()
    sequence = check_frames(sequence)
    frames = sequence.frames
    t, h, w, c = frames.shape
    channels = sequence.channels or default_channels(c)
    curves = check_domain(curves, w, h, fit_curves)
    settings, fit_kw = _physical(settings)
    model, seconds = _mesh_and_fit(fit_frames, sequence, curves, settings, channels, callback, **fit_kw)
    lo, hi = float(frames.min()), float(frames.max())
    data_range = 1.0 if lo >= 0.0 and hi <= 1.0 else max(hi - lo, 1e-12)
    info = _encoder_info(settings, curves.source, {"input": f"frames {t}x{w}x{h}", "pixels": t * w * h,
                                                   "hdr": hi > 1.0})

    def truth(m):
        return frames, np.stack([render(m, w, h, t=float(s)) for s in sequence.times])

    return _finish(model, settings, info, seconds, t * w * h, truth, data_range)
