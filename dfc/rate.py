"""Rate control: how large a mesh an encode builds.

Every function returns the mesh as the decoder will see it (``build_mesh``: Draco-quantised vertices in the decoder's
order), which is the geometry the fit runs on. ``settings`` is a ``dfc.codec.EncodeSettings`` (any dataclass with its
mesh-size fields: ``max_triangles``, ``max_area``, ``edge_length``, ``target_bytes``, ``mesh_bits``, and for byte
targets ``dim``, ``feature_bits`` (an int: the encoders resolve the default, ``dfc.codec.EncodeSettings``), ``seed``).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import torch

from .errors import TargetBytesError, TriangleBudgetError
from .geometry.curves import Curves
from .geometry.mesh import Mesh
from .geometry.triangulate import DEFAULT_TRIANGLES, halving_points, triangulate

__all__ = ["COARSE_FEATURE_BITS", "COARSE_LOSS_DB", "DECODER_HIDDEN", "DECODER_SHARE", "FEATURE_BITS_FALLBACK",
           "FILL", "FILL_CARRY_POINTS", "FILL_RETRIES", "HALVING_COST", "NOISY_SAMPLES_PER_TRIANGLE",
           "PIXELS_PER_TRIANGLE", "RASTER_MARGIN_DB", "RASTER_STEPS", "RASTER_TRIANGLES", "REFINE_SHARE",
           "RESIDUAL_FIELD_BPP", "RESIDUAL_MIN_BYTES", "RESIDUAL_NOISE", "RESIDUAL_SHARE", "SHORT_FIT_HIDDEN",
           "TARGET_BYTES_PROBES", "build_mesh", "decoder_hidden", "features_at", "field_bytes", "fill_points",
           "forced_mesh", "image_mesh_size", "is_clean", "mesh_bytes", "mesh_for_bytes", "mesh_size_set",
           "refinement_points", "residual_choices", "sample_mesh_size", "size_at", "sized_mesh", "smallest_bytes"]

TARGET_BYTES_PROBES = 12
"""Triangulations tried at most when sizing the mesh to a byte target."""
HALVING_COST = 3.0
"""Weight of halving a curved piece against a centroid split when ``refinement_points`` ranks triangles by error per
cost. In file bytes a halving costs 5–9 splits (a curve vertex with a feature vector per side, two more control
points, new tangent-triangle apexes: 42–76 bytes against 8–9), but it also sharpens the jump, which the 1× error does
not see: at 6 the zoom windows' edges lost up to 1 dB, at 3 they did not (CHANGELOG.md, "Refinement ranked by error
per byte")."""
REFINE_SHARE = 0.5
"""A refinement round splits the triangles holding this share of the fit's squared error (at most a set number)."""
NOISY_SAMPLES_PER_TRIANGLE = 500
"""Sample sets without a mesh-size option get the triangles their curves force plus about one per this many
samples (at most ``DEFAULT_TRIANGLES``) spent away from the curves: a finer mesh fits the noise of Monte Carlo
samples, and a mesh of the forced triangles alone has no interior vertices (long slivers between the curves;
CHANGELOG.md, "Sample sets sized to their samples")."""
PIXELS_PER_TRIANGLE = 16
"""Images without a mesh-size option get at most one triangle per this many pixels (and at most
``DEFAULT_TRIANGLES``, which a 256 × 256 image already reaches): a 64 × 64 image gets 256, a 1 × 1 image the two
triangles of its square, plus what the curves force."""
FILL = 0.97
"""Refinement under a byte target aims at this share of the target (``fill_points``): the refit changes the
features' bytes by a few per cent."""
FILL_RETRIES = 3
"""Under a byte target, refits redone when the refitted file still outgrows the target (``dfc.codec._fill_within``:
with fewer fill points, the last time, or once no cut can fit, at one feature bit fewer when the encoder chose the
bits): the refit's features can cost more bytes than the carried-over ones ``fill_points`` priced."""
FILL_CARRY_POINTS = 1 << 14
"""``fill_points`` prices a candidate mesh with a carry-over fitted at about this many of the caller's points."""
RESIDUAL_SHARE = 0.5
"""``--residual-bytes auto`` under a byte target: the share of the target a residual raster gets (``rESD``), the field
the rest (CHANGELOG.md, "A residual raster under a byte target")."""
RESIDUAL_FIELD_BPP = 0.5
"""``--residual-bytes auto`` under a byte target gives the field at most this many bits per pixel of the image (and
at most ``1 − RESIDUAL_SHARE`` of the target), the residual the rest: past it a byte buys more dB in the residual
(CHANGELOG.md, "The residual's share capped, its AVIF planes coded as they are and its bytes filled")."""
RESIDUAL_NOISE = 1e-4
"""``--residual-bytes auto`` stores a residual only for images whose ``dfc.metrics.noise_sigma`` is below this: on a
noisy image (a render's Monte Carlo noise, 0.9–2.6e-3 at 256 spp; σ 0.02) a residual codes the noise, which the field
alone leaves out, and loses against the clean truth; clean images (solves, vector art, test charts) read 6e-6 or
less."""
RASTER_TRIANGLES = 2
"""The raster mode's field (``dfc.codec._raster_mode``): the domain's two triangles, no curves, every feature row one
vector (``dfc.train.flat.constant_rows``), so the residual raster holds the whole image."""
RASTER_STEPS = 100
"""Fit steps of the raster mode's field: enough to bring its one value near the image's (the residual takes the
rest)."""
RASTER_MARGIN_DB = 2.0
"""The raster mode's file is kept only when its PSNR is at least this much above the field's file: a field keeps its
curves' jumps sharp at every zoom, which 1× does not measure (on the clean diffusion-curve solves the raster mode is
0.2–1.3 dB above the field at 0.25–0.5 bits per pixel; on the EXR test charts 2.4–20 dB)."""
RESIDUAL_MIN_BYTES = 512
"""``--residual-bytes auto`` stores no residual of fewer bytes (a 256² AVIF's smallest streams take 300–500)."""
FEATURE_BITS_FALLBACK = (8, 6)
"""Feature bits an encode with the default bits (``dfc.codec.EncodeSettings.feature_bits`` None) tries, in order,
when its byte target is too small for the smallest mesh with ``dfc.field.quantize.DEFAULT_FEATURE_BITS`` (with a
note; CHANGELOG.md, "Small byte targets keep working")."""
COARSE_FEATURE_BITS = 8
"""Feature bits a byte target's fill switches to when the encoder chose the bits and its first fit, stored with
them, loses less than ``COARSE_LOSS_DB`` (``dfc.codec._refine``): where the fit's own error dwarfs the features'
rounding, the bytes two bits fewer save buy triangles (CHANGELOG.md, "Coarser features where they cost nothing")."""
COARSE_LOSS_DB = 0.5
"""Largest loss (dB of the squared error at the refinement's points) of the first fit at ``COARSE_FEATURE_BITS``
for which a fill switches to them."""
DECODER_HIDDEN = (8, 32)
"""Narrowest and widest hidden layers ``decoder_hidden`` gives an image. 32, not the paper's 64: at the default 3,000
steps a 32-wide decoder gives smaller files at about the same PSNR on real content, and fits faster (CHANGELOG.md,
"Image decoders 32 wide")."""
SHORT_FIT_HIDDEN = 64
"""The widest decoder of an image fit of fewer than ``dfc.train.fit.DECODER_LR_MIN_STEPS`` steps, where a 32-wide one
converges too slowly (the README sample, 100 steps: 42.6 dB at width 64, 28.0 at 32)."""
DECODER_SHARE = 0.15
"""Under a byte target the decoder's weights take at most this share of it (``decoder_hidden``); the rest buys
triangles (CHANGELOG.md, "The decoder's share of a byte target"; docs/results.md, "Rate and quality levers")."""


def build_mesh(curves: Curves, settings, *, extra_points=None, stats: dict | None = None) -> Mesh:
    """Triangulate ``curves`` with the settings' size knobs (and the refinement vertices ``extra_points`` (M, 2),
    see ``dfc.geometry.triangulate``) and return the mesh as the decoder will see it (Draco-quantised with
    ``settings.mesh_bits``, decoder vertex order): the geometry the fit runs on. With ``settings.mesh_coding``
    "derived" the free vertices are snapped to the coarse lattice that encoding stores them on."""
    from .io.meshcodec import roundtrip_mesh

    lattice = settings.mesh_bits if settings.mesh_coding == "derived" and settings.mesh_bits >= 2 else None
    mesh = triangulate(curves, max_area=settings.max_area, edge_length=settings.edge_length,
                       max_triangles=settings.max_triangles, extra_points=extra_points, lattice_bits=lattice,
                       stats=stats)
    return roundtrip_mesh(mesh, settings.mesh_bits)


def refinement_points(mesh: Mesh, xy: np.ndarray, error: np.ndarray, *, share: float = REFINE_SHARE,
                      most: int, min_area: float = 0.0) -> np.ndarray:
    """Points (P, 2) float64 that split the triangles to split next (``dfc.geometry.triangulate``'s
    ``extra_points``): ``error`` (M,) ≥ 0 at points ``xy`` (M, 2) is summed per triangle; the triangles in
    decreasing order of that sum per unit of cost (1, ``HALVING_COST`` for a curved triangle), until they hold
    ``share`` of the total, at most ``most``, leaving out triangles below ``min_area``. A triangle's point is its
    centroid; a curved triangle's is its piece's ``halving_points``, which halves the piece (the curve's geometry
    unchanged)."""
    from .field.layout import build_layout
    from .field.locate import PointLocator
    from .geometry.plane import triangle_areas

    locator = PointLocator(mesh.vertices, mesh.triangles, mesh.domain)
    with torch.no_grad():
        tri, _ = locator(locator.clamp(torch.from_numpy(np.asarray(xy, np.float64))))
    total = np.bincount(tri.cpu().numpy(), weights=np.asarray(error, np.float64), minlength=mesh.n_triangles)
    total[triangle_areas(mesh.vertices[mesh.triangles]) < min_area] = 0.0
    if most < 1 or total.sum() <= 0:
        return np.zeros((0, 2))
    piece = build_layout(mesh).triangle_curve
    order = np.argsort(-total / np.where(piece >= 0, HALVING_COST, 1.0), kind="stable")
    reach = np.searchsorted(np.cumsum(total[order]), share * total.sum()) + 1
    chosen = order[:min(most, reach)]
    chosen = chosen[total[chosen] > 0]
    piece = piece[chosen]
    points = mesh.vertices[mesh.triangles[chosen]].mean(axis=1)
    points[piece >= 0] = halving_points(mesh.curve_control_points[piece[piece >= 0]])
    return points


def fill_points(model, curves: Curves, mesh_settings, extra: np.ndarray, xy: np.ndarray, error: np.ndarray,
                size_of, target: int, *, min_area: float = 0.0, bits: int | None = None) -> np.ndarray:
    """Refinement points (P, 2) float64 that fill a byte target: those of the triangles to split
    (``refinement_points``, every triangle allowed), in their order (error per byte), as many as keep the file
    within ``FILL`` × ``target`` bytes.

    A candidate count is priced by the file of ``model`` carried onto the refined mesh (``build_mesh`` with
    ``mesh_settings``, ``extra`` (E, 2) and the candidates; ``dfc.field.transfer.carry_over`` at up to
    ``FILL_CARRY_POINTS`` of ``xy``): ``size_of(model) -> bytes`` writes it as the encoder will (with ``bits`` per
    feature when given: the bits the refit will store, ``FieldModel.quantization``). Fitted features are
    smoother than random ones, so this is what the sizing probe of ``mesh_for_bytes`` (a random bank) cannot know.
    The count is found by regula falsi on the file size, nearly linear in it: at most ``TARGET_BYTES_PROBES`` files,
    stopping within 2 % of the count. No vertex when the file is already at the target.
    """
    from .field.model import FieldModel
    from .field.transfer import carry_over

    mesh = model.field.mesh
    candidates = refinement_points(mesh, xy, error, share=1.0, most=mesh.n_triangles, min_area=min_area)
    budget, n = FILL * target, len(candidates)
    config, device = model.config(), model.field.bank.device
    xy = xy[::max(1, len(xy) // FILL_CARRY_POINTS)]
    known = {0: size_at(size_of, model, bits)}  # candidate count -> bytes of the file

    def price(k: int) -> int:
        refined = build_mesh(curves, mesh_settings, extra_points=np.concatenate([extra, candidates[:k]]))
        carried = FieldModel.from_config(refined, config, device=device)
        carry_over(model, carried, xy)
        known[k] = size_at(size_of, carried, bits)
        return known[k]

    lo, hi = 0, n + 1  # the largest count known to fit, the smallest known not to (n + 1: none)
    slope = known[0] / mesh.n_vertices  # first guess: every vertex costs what one costs now (MLP included: low)
    for _ in range(TARGET_BYTES_PROBES):
        k = min(hi - 1, n, lo + max(1, int((budget - known[lo]) / max(slope, 1e-9))))
        if k <= lo or budget <= known[lo]:
            break
        lo, hi = (k, hi) if price(k) <= budget else (lo, k)
        if lo == n or hi - lo <= max(1, lo // 50):
            break
        a, b = (lo, hi) if hi <= n else (min(known), lo)  # regula falsi within the bracket, else extrapolate
        slope = (known[b] - known[a]) / (b - a) if b > a else slope
    return candidates[:lo]


@contextmanager
def features_at(model, bits: int):
    """Within the block, ``model`` (a ``FieldModel``, or anything with its ``quantization``) reads and stores its
    features with ``bits`` (``quantization["feature_bits"] = bits``, its weights' quantisation kept); afterwards its
    mode is what it was."""
    saved = model.quantization
    model.quantization = {**(saved or {}), "feature_bits": bits}
    try:
        yield model
    finally:
        model.quantization = saved


def size_at(size_of, model, bits: int | None) -> int:
    """``size_of(model)`` (bytes of its file) with the features stored with ``bits`` (``features_at``; None: as
    ``model`` stores them)."""
    if bits is None:
        return size_of(model)
    with features_at(model, bits):
        return size_of(model)


def sized_mesh(curves: Curves, settings, channels: list[str], size_of=None) -> tuple[object, Mesh]:
    """(mesh settings, mesh): the decoder-view mesh, sized to ``settings.target_bytes`` when given
    (``mesh_for_bytes``), else by the explicit knobs; and the settings that rebuild it with ``build_mesh`` (the
    byte target resolved into the triangle cap it found)."""
    if settings.target_bytes is None:
        return settings, build_mesh(curves, settings)
    mesh, cap = _mesh_and_cap(curves, settings, channels, size_of)
    return replace(settings, target_bytes=None, max_triangles=cap, max_area=None, edge_length=None), mesh


def _file_bytes(curves: Curves, settings, channels: list[str], n_triangles: int, size_of) -> tuple[int, Mesh]:
    """Bytes of a file on a mesh of at most ``n_triangles`` (``mesh_bytes``) and that mesh."""
    mesh = build_mesh(curves, replace(settings, max_triangles=n_triangles, max_area=None, edge_length=None))
    return mesh_bytes(mesh, settings, channels, size_of), mesh


def mesh_bytes(mesh: Mesh, settings, channels: list[str], size_of=None) -> int:
    """Bytes of a file on ``mesh`` with incompressible features: a bank uniform in ±1 stored with
    ``settings.feature_bits`` (a fitted bank is at most about as incompressible as a random one at the same bit
    depth) and a decoder of ``settings.hidden`` × ``settings.layers``. ``size_of(model) -> bytes`` writes the file
    (None: with an empty header ``encoder`` record)."""
    from .field.feature_field import FeatureField
    from .field.model import FieldModel

    model = FieldModel(FeatureField(mesh, dim=settings.dim, seed=settings.seed), channels, hidden=settings.hidden,
                       layers=settings.layers)
    with torch.no_grad():
        model.field.bank.uniform_(-1.0, 1.0, generator=torch.Generator().manual_seed(settings.seed))
    if size_of is None:
        from .io.dfield import encode_model

        return len(encode_model(model, settings)[0])
    return size_of(model)


def forced_mesh(curves: Curves, settings) -> Mesh:
    """The decoder-view mesh with the fewest triangles ``curves`` allow (what they force); ``settings`` must set no
    mesh size."""
    return _counted_mesh(curves, settings, 2)[1]


def smallest_bytes(forced: Mesh, settings, channels: list[str]) -> int:
    """Bytes of the smallest file a byte target could get on the mesh the curves force (``forced_mesh``, as
    ``mesh_for_bytes`` with every feature depth of ``FEATURE_BITS_FALLBACK`` would): its incompressible features
    (``mesh_bytes``) at ``FEATURE_BITS_FALLBACK[-1]`` bits, with the decoder of ``settings``."""
    return mesh_bytes(forced, replace(settings, feature_bits=FEATURE_BITS_FALLBACK[-1]), channels)


def mesh_for_bytes(curves: Curves, settings, channels: list[str], size_of=None) -> Mesh:
    """The largest decoder-view mesh whose file stays within ``settings.target_bytes``, by a search on the triangle
    cap that halves or interpolates its bracket (``_between``; at most ``TARGET_BYTES_PROBES`` triangulations; files
    priced by ``size_of(model) -> bytes``, by default with an empty header ``encoder`` record). ``TargetBytesError``
    when even the mesh the curves force is too large."""
    return _mesh_and_cap(curves, settings, channels, size_of)[0]


def _mesh_and_cap(curves: Curves, settings, channels: list[str], size_of) -> tuple[Mesh, int]:
    """``mesh_for_bytes``'s mesh and the triangle cap it was built with."""
    # ``fits`` is the largest cap known to fit the target, ``over`` the smallest known not to (too many bytes, or
    # fewer triangles than the curves force).
    fits, over, best, smallest = 0, None, None, math.inf
    known = {}  # cap -> bytes of its file
    n = DEFAULT_TRIANGLES
    for _ in range(TARGET_BYTES_PROBES):
        try:
            size, mesh = _file_bytes(curves, settings, channels, n, size_of)
            smallest, known[n] = min(smallest, size), size
        except TriangleBudgetError:  # below the triangles the curves force: only larger caps can work
            fits, size = max(fits, n), None
        if size is not None and size <= settings.target_bytes:
            fits, best = n, (mesh, n)
        elif size is not None:
            over = n
        if over is not None and over - fits <= max(8, fits // 50):
            break
        n = 2 * n if over is None else _between(fits, over, known, settings.target_bytes)
    if best is None:
        raise TargetBytesError(f"target of {settings.target_bytes} bytes is too small for these curves"
                               + (f": the smallest file tried takes {smallest} bytes" if smallest < math.inf else "")
                               + (f" (fewer --feature-bits than {settings.feature_bits} make smaller files)"
                                  if settings.feature_bits > FEATURE_BITS_FALLBACK[-1] else ""))
    return best


def _between(fits: int, over: int, known: dict[int, int], target: int) -> int:
    """The next triangle cap to try inside the bracket (``fits``, ``over``): where the line through the two files'
    bytes (``known``: cap -> bytes, nearly linear in the cap) meets ``target``, at least an eighth of the bracket from
    either end; the middle when ``fits`` has no file (none tried yet, or below the triangles the curves force)."""
    if fits not in known:
        return (fits + over) // 2
    margin = max(1, (over - fits) // 8)
    slope = (known[over] - known[fits]) / (over - fits)
    guess = fits + (target - known[fits]) / slope if slope > 0 else (fits + over) / 2
    return int(min(max(guess, fits + margin), over - margin))


def sample_mesh_size(curves: Curves, settings, n_samples: int):
    """(settings, mesh) for a sample set: ``settings`` with ``max_triangles`` = the triangles the curves force plus
    one per ``NOISY_SAMPLES_PER_TRIANGLE`` samples (at most ``DEFAULT_TRIANGLES``), and the decoder-view mesh built
    with them, when no mesh-size option is set; else ``settings`` unchanged and None."""
    return _counted_mesh(curves, settings, n_samples // NOISY_SAMPLES_PER_TRIANGLE, on_top=True)


def image_mesh_size(curves: Curves, settings, n_pixels: int):
    """(settings, mesh) for an image of ``n_pixels``, as ``sample_mesh_size`` with ``PIXELS_PER_TRIANGLE``: a
    small image gets a mesh sized to it; from ``DEFAULT_TRIANGLES × PIXELS_PER_TRIANGLE`` pixels up, (settings, None)
    (the triangulation's default size)."""
    if n_pixels // PIXELS_PER_TRIANGLE >= DEFAULT_TRIANGLES:
        return settings, None
    return _counted_mesh(curves, settings, n_pixels // PIXELS_PER_TRIANGLE)


def decoder_hidden(n_values: int, budget: float | None = None, *, inputs: int = 5, outputs: int = 3,
                   layers: int = 2, weight_bits: int | None = 8, widest: int | None = None) -> int:
    """Width of the decoder's hidden layers for an input of ``n_values`` numbers (pixels × channels): the power of
    two nearest below √n / 2, within ``DECODER_HIDDEN`` — 32 from about 37 × 37 RGB pixels up, 16 for 20 × 20,
    8 for a handful of pixels, whose file would otherwise be mostly decoder weights (1.3 KB at width 32). With a
    ``budget`` in bytes, halved (not below the narrowest) until the weight matrices (``inputs`` features,
    ``layers`` hidden layers, ``outputs`` channels; ``weight_bits`` each, None: float16) fit in it. ``widest``
    replaces the widest of ``DECODER_HIDDEN``."""
    lo, hi = DECODER_HIDDEN[0], widest or DECODER_HIDDEN[1]
    width = min(hi, max(lo, 1 << max(0, int(math.floor(math.log2(max(1.0, math.sqrt(n_values) / 2)))))))
    bits = weight_bits or 16
    while budget is not None and width > lo and \
            (inputs * width + (layers - 1) * width * width + width * outputs) * bits / 8 > budget:
        width //= 2
    return width


def mesh_size_set(settings) -> bool:
    """Whether ``settings`` size the mesh themselves: ``max_triangles``, ``max_area``, ``edge_length`` or
    ``target_bytes``."""
    return any(v is not None for v in (settings.max_triangles, settings.max_area, settings.edge_length,
                                       settings.target_bytes))


def _counted_mesh(curves: Curves, settings, cap: int, on_top: bool = False):
    """(settings with ``max_triangles = cap`` clamped to 2 .. ``DEFAULT_TRIANGLES``, and the decoder-view mesh), raising
    the cap to what the curves force (``on_top``: adding the cap to it); (settings, None) when a mesh-size option
    is set."""
    if mesh_size_set(settings):
        return settings, None
    cap = min(DEFAULT_TRIANGLES, max(2, cap))
    if on_top:
        cap += _forced_triangles(curves, settings)
    while True:  # the first refusal counts vertices only; the curves' apexes may need a few more triangles
        sized = replace(settings, max_triangles=cap)
        try:
            return sized, build_mesh(curves, sized)
        except TriangleBudgetError as e:
            cap = max(e.needed, cap + 1)


def _forced_triangles(curves: Curves, settings) -> int:
    """Triangles the curves' vertices alone need (their apexes may add a few), 0 for a domain without curves."""
    try:
        build_mesh(curves, replace(settings, max_triangles=2))
    except TriangleBudgetError as e:
        return e.needed
    return 0


def residual_choices(pixels: np.ndarray, target_bytes: int | None, clean: bool | None = None) -> list[int]:
    """The residual bytes ``--residual-bytes auto`` tries for an image ``pixels`` (H, W, C) under ``target_bytes``,
    in order, while the field does not fit what they leave (``dfc.codec._residual_auto``): for a clean image
    (``dfc.metrics.noise_sigma`` below ``RESIDUAL_NOISE``) the bytes that leave the field ``RESIDUAL_FIELD_BPP``
    bits per pixel, when that is more than ``RESIDUAL_SHARE`` of the target, then that share; none under
    ``RESIDUAL_MIN_BYTES``. Empty for a noisy image (``is_clean``, unless ``clean`` says it already) and without a
    target."""
    if target_bytes is None:
        return []
    share = round(RESIDUAL_SHARE * target_bytes)
    capped = target_bytes - round(RESIDUAL_FIELD_BPP * pixels.shape[0] * pixels.shape[1] / 8)
    choices = [n for n in dict.fromkeys((max(share, capped), share)) if n >= RESIDUAL_MIN_BYTES]
    return choices if choices and (is_clean(pixels) if clean is None else clean) else []


def is_clean(pixels: np.ndarray) -> bool:
    """Whether an image ``pixels`` (H, W, C) is clean enough for a residual raster: its ``dfc.metrics.noise_sigma``
    is below ``RESIDUAL_NOISE``."""
    from .metrics import noise_sigma

    return noise_sigma(pixels) < RESIDUAL_NOISE


def field_bytes(pixels: np.ndarray, target_bytes: int | None, residual_bytes: int | str) -> int | None:
    """What a byte target leaves the field of an image ``pixels`` (H, W, C) when ``residual_bytes`` (an integer or
    "auto": the first of ``residual_choices``) go to a residual raster; None without a target."""
    if target_bytes is None:
        return None
    n = (residual_choices(pixels, target_bytes) or [0])[0] if residual_bytes == "auto" else residual_bytes
    return target_bytes - n
