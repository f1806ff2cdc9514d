"""Curve refinement against the pixels: ``refine_curves(pixels, curves, pixel_filter) -> Refined``.

A pixel a sharp discontinuity crosses holds ``B + (A − B) S``: ``A`` and ``B`` the two sides' values there and
``S`` the share of its pixel filter (``dfc.pixel_filter``) on ``A``'s side. Where the curve is off by a fraction of
a pixel, ``S`` predicts the mixed pixels wrongly; this module moves the curves' control points until it predicts
them best (least squares), before any mesh is built. It is a refinement pass against the pixels, not a joint fit
with the field: the two sides are modelled locally, each as a plane read from the image (bilinear) at
``SIDE_NEAR + reach`` and ``SIDE_FAR + reach`` px on the normal through the pixel's foot point and ``ALONG`` px
either way along the curve (``reach``: the filter's effective radius, × √2 for the diagonal), so a smooth trend
across or along the curve cancels; the predicted pixel is the filter's mean of side A's plane over its share and
side B's over the rest.

The share is differentiable in the control points: each pixel's filter is a fixed quadrature (``QUAD_POINTS``
points of ``PixelFilter.nodes``), each point's signed distance to the curve is taken from the osculating parabola
at the pixel's foot point (parameter held fixed within a round and found again between rounds: the distance's
derivative in the parameter vanishes there), and the side test is a logistic of width ``SOFT`` px (annealed,
``SOFT_DISCRETE``, for filters of a few sub-samples: ``point`` and ``box:N``, whose pixels change in steps). An
isotropic Gaussian needs no side test: across the curve its share is the normal distribution's tail, exact, and
only the points along the curve are a quadrature (``GAUSS_HERMITE``). Only clean pixels count: the curve within the
filter's reach of the pixel follows that parabola within ``STRAIGHT`` px (no junction, corner or second curve), the
side readings are clear of every other curve and inside the image, each side's readings (a third pair midway too)
lie on one plane within ``PLANAR`` of the jump, and the jump is at least ``MIN_JUMP`` of the image's range where its
PSNR is measured (``dfc.metrics.measure_space``: tone-mapped for HDR light).

Constraints: endpoints that coincide (``JOIN`` px) are one variable (junctions, closed curves, chained pieces);
an endpoint lying on another piece's inside (a T) is that piece's point at a fixed parameter; an endpoint on the
image border slides along it; every control point stays inside the image and within ``MAX_MOVE`` px of where it
was; lines stay lines and quadratics quadratics. Pieces that cross each other where they do not share a point are
left as given, with every endpoint they share and the pieces their T ends lie on, and the others refined, with a
warning; when a refinement would make two pieces cross that did not, those two are held as given too and the rest
solved again (up to ``HOLDS`` times; then every piece is left as given), with a warning.

Coordinates follow ``spec/conventions.md``: pixel ``(r, c)`` covers ``[c, c + 1] × [r, r + 1]`` of the image's
domain ``[0, W] × [0, H]``; curves over another domain are scaled onto it and back.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...errors import InputError
from ...metrics import step_size
from .. import bezier
from ..curves import Curves

__all__ = ["Refined", "crossings", "refine_curves"]

ROUNDS = 4
"""Rounds of (foot points, clean pixels and side values from the current curves; then a least-squares solve)."""
STEPS = 30
"""L-BFGS iterations per round."""
QUAD_POINTS = 512
"""Quadrature points per pixel filter (``box:N`` uses its N × N sub-samples exactly; a Gaussian takes
``GAUSS_HERMITE``)."""
GAUSS_HERMITE = 8
"""Points along the curve of a Gaussian filter's quadrature (across the curve it is integrated exactly)."""
SOFT = 0.02
"""Width (px) of the logistic side test of a mixing filter."""
SOFT_DISCRETE = (0.1, 0.05, 0.02, 0.01)
"""Widths (px) of the side test per round for filters of a few sub-samples (``point``, ``box:N``): their pixels
change in steps as a curve moves, the annealed test finds the middle of the step the pixels allow."""
STRAIGHT = 0.1
"""A pixel counts when the curve samples within its filter's reach lie this close (px) to the foot's parabola."""
SIDE_NEAR, SIDE_FAR = 1.5, 3.0
"""Distances (px) beyond the filter's reach at which each side's value is read."""
ALONG = 1.0
"""Each side is read this far (px) along the curve either way of the foot point too: a plane per side, whose
gradient enters the prediction of a mixed pixel (its filter weighs each side's plane over that side's share)."""
PLANAR = 0.1
"""A pixel counts when each side's readings agree with one plane: the twist of its four readings and the bend of a
third pair midway (twice its offset from the near and far readings' mean) are both within this share of the jump
(a texture edge, a highlight or a limb's shading read as a side would move the curve instead)."""
MIN_JUMP = 0.05
"""Smallest jump of a pixel that counts, as a share of the image's range in ``dfc.metrics.measure_space``."""
MAX_MOVE = 1.0
"""Largest move (px) of any control point."""
JOIN = 1e-6
"""Endpoints closer than this (px) are one point; an endpoint this close to another piece's inside is a T."""
PENALTY = 1e-3
"""Weight of the squared move (px²) of each control point against the pixels' squared share misfit."""
HOLDS = 3
"""Times a refinement that makes pieces cross that did not is solved again with the pieces of those crossings held
as given (then every piece is left as given, with a warning)."""
CHUNK = 1 << 20
"""Pixel × quadrature point pairs per chunk of the loss (memory: about 100 bytes each)."""
_SPACING = 0.1  # px between curve samples for foot points and clearance tests


@dataclass(frozen=True)
class Refined:
    """The outcome of ``refine_curves``.

    curves : the refined ``Curves`` (same pieces, names and domain as the input)
    moved : (P,) float64 largest move of each piece's control points from the input (``origin`` when given), px
    pixels : clean pixels the last round fitted
    misfit_before, misfit_after : RMS misfit over those pixels, as a share of the jump, with the input (``origin``
        when given) and the refined curves (the last round's model)
    warning : one line when pieces were left as given (crossing curves), else None
    left_as_given : how many pieces were left as given because they cross or would cross
    pixel_filter : spec of the ``dfc.pixel_filter`` filter the pixels were seen through
    """

    curves: Curves
    moved: np.ndarray
    pixels: int
    misfit_before: float
    misfit_after: float
    warning: str | None = None
    left_as_given: int = 0
    pixel_filter: str = "box"

    def summary(self) -> str:
        """One line: pixels fitted, misfit before → after, the largest move (and whether some pieces were left as
        given: ``warning``)."""
        if not self.pixels or (self.warning and not self.moved.any()):
            return "left as given" + ("" if self.warning else ": no clean mixed pixels to fit")
        return (f"{self.pixels} mixed pixels, misfit {100 * self.misfit_before:.2f} % → {100 * self.misfit_after:.2f} % "
                f"of the jump, control points moved ≤ {float(self.moved.max(initial=0.0)):.3f} px"
                + ("; crossing pieces left as given" if self.warning else ""))

    def to_dict(self) -> dict:
        """The record a summary or a file's encoder info keeps (short: it goes into every file's header, so the
        warning is counted, not quoted)."""
        out = {"pixels": self.pixels, "misfit_before": round(self.misfit_before, 4),
               "misfit_after": round(self.misfit_after, 4), "max_move_px": round(float(self.moved.max(initial=0.0)), 3)}
        return {**out, "left_as_given": self.left_as_given} if self.left_as_given else out


def refine_curves(pixels: np.ndarray, curves: Curves, pixel_filter=None, *, rounds: int = ROUNDS,
                  origin: Curves | None = None) -> Refined:
    """Move the control points of ``curves`` so that the mixed pixels of ``pixels`` (H, W, C) or (H, W) linear
    values are explained by sharp steps across them seen through ``pixel_filter`` (a ``dfc.pixel_filter.PixelFilter``,
    None: the box). ``curves`` cover the image: their domain is mapped onto ``[0, W] × [0, H]``. ``origin``: the
    curves (the same pieces over the same domain) that ``Refined.moved`` and ``misfit_before`` are measured from,
    when ``curves`` are themselves the outcome of an earlier refinement (default: ``curves``).

    Raises ``InputError`` when a control point lies outside the domain or the image holds non-finite values,
    ``ValueError`` when ``origin`` has other pieces or another domain.
    """
    from ...pixel_filter import parse

    f = pixel_filter if pixel_filter is not None else parse("box")
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    H, W, _ = pixels.shape
    if not np.isfinite(pixels).all():
        raise InputError("image holds NaN or infinite values: curves cannot be refined against it")
    x0, y0, x1, y1 = curves.domain
    scale = np.array([W / (x1 - x0), H / (y1 - y0)])
    offset = np.array([x0, y0])
    start = (curves.control_points - offset) * scale
    _check_inside(start, curves, W, H)
    if origin is not None and (origin.control_points.shape != start.shape or origin.domain != curves.domain):
        raise ValueError("origin: expected the same pieces over the same domain as the curves refined")
    first = start if origin is None else (origin.control_points - offset) * scale  # (P, 4, 2) px

    def moved_from_first(cp):
        return np.linalg.norm(cp - first, axis=2).max(axis=1, initial=0.0)

    if not len(start):
        return Refined(curves, np.zeros(0), 0, 0.0, 0.0, pixel_filter=str(f))
    crossed = crossings(start)
    reach = _reach(f)
    points = GAUSS_HERMITE if f.name == "gaussian" else len(f.nodes(QUAD_POINTS)[1])
    discrete = points < QUAD_POINTS and f.name != "gaussian"
    frozen = {p for pair in crossed for p in pair}
    held: set[int] = set()  # pieces held as given because refining them made pieces cross
    new: set[tuple[int, int]] = set()  # crossings the last solve made
    for _ in range(HOLDS + 1):
        params = _Params(start, curves.degree, W, H, frozen=frozen | held)
        if params.frozen.all():
            break
        solved = _solve(pixels, start, params, f, reach, points, discrete, rounds)
        if solved is None:
            return Refined(curves, moved_from_first(start), 0, 0.0, 0.0, pixel_filter=str(f))
        cp, data, loss_of = solved
        new = set(crossings(cp)) - set(crossed)
        if not new:
            break
        held |= {p for pair in new for p in pair}
    if params.frozen.all() or new:
        warning = (_crossing_warning(curves, crossed, "them") if not held
                   else "refining the curves would make them cross: left as given")
        return Refined(curves, moved_from_first(start), 0, 0.0, 0.0, warning, len(start), str(f))
    warnings = [_crossing_warning(curves, crossed, "those pieces")] if crossed else []
    if held:
        names = sorted({_name(curves, p) for p in held})
        named = " and ".join(names) if len(names) <= 3 else f"{', '.join(names[:3])} and {len(names) - 3} more"
        warnings.append(f"refining {named} would make curves cross: {len(held)} of their pieces left as given")
    out = replace(curves, control_points=cp / scale + offset)
    used = len(data["piece"])
    before, after = (float(np.sqrt(_total(loss_of, c, data) / used)) for c in (first, cp))
    return Refined(out, moved_from_first(cp), used, before, after, "; ".join(warnings) or None,
                   int(params.frozen.sum()), str(f))


def _solve(pixels, start, params, f, reach, points, discrete, rounds):
    """(control points (P, 4, 2) px, the last round's pixel data, its loss) of ``rounds`` least-squares rounds
    from ``start`` with the free variables of ``params``; None when no clean pixel lies near the curves."""
    import torch

    cp, data = start, None
    for k in range(max(1, rounds)):
        data = _pixel_data(pixels, cp, reach) or data
        if data is None:
            return None
        soft = SOFT_DISCRETE[min(k, len(SOFT_DISCRETE) - 1)] if discrete else SOFT
        loss_of = _loss(data, f, soft)
        x = torch.from_numpy(params.pack(cp)).requires_grad_(True)
        x_start = torch.from_numpy(params.pack(start))
        opt = torch.optim.LBFGS([x], lr=1.0, max_iter=STEPS, line_search_fn="strong_wolfe", tolerance_grad=1e-12,
                                tolerance_change=1e-15)
        chunk = max(1, CHUNK // points)
        parts = [slice(i, i + chunk) for i in range(0, len(data["piece"]), chunk)]

        def closure():
            opt.zero_grad()
            loss = PENALTY * ((x - x_start) ** 2).sum()
            loss.backward()
            total = loss.detach()
            for part in parts:  # the pixels in chunks: memory stays bounded on large images
                loss = loss_of(params.build(x), part)
                loss.backward()
                total = total + loss.detach()
            return total

        opt.step(closure)
        with torch.no_grad():
            cp = params.limit(params.build(x).numpy(), start)
    return cp, data, loss_of


def _crossing_warning(curves: Curves, crossed: list[tuple[int, int]], what: str) -> str:
    i, j = crossed[0]
    more = f" and {len(crossed) - 1} more pair(s)" if len(crossed) > 1 else ""
    return (f"curves cross each other ({_name(curves, i)} and {_name(curves, j)}{more}) where they share no point: "
            f"refinement left {what} as given")


def _name(curves: Curves, piece: int) -> str:
    c = int(curves.curve[piece])
    return repr(curves.names[c]) if c < len(curves.names) else f"curve {c}"


def _check_inside(cp: np.ndarray, curves: Curves, W: int, H: int) -> None:
    """Raise ``InputError`` naming the first curve with a control point outside ``[0, W] × [0, H]``."""
    tol = 1e-6 * max(W, H)
    out = (cp[..., 0] < -tol) | (cp[..., 0] > W + tol) | (cp[..., 1] < -tol) | (cp[..., 1] > H + tol)
    if out.any():
        piece = int(np.nonzero(out.any(axis=1))[0][0])
        raise InputError(f"curve {_name(curves, piece)} reaches outside the image ({W} × {H} px): curves to refine "
                         "must lie inside it")


def _reach(f) -> float:
    """Effective radius (px) of a filter's support: the Gaussian's 3σ (its tail beyond holds < 0.2 %)."""
    return min(f.radius, 3.0 * f.param) if f.name == "gaussian" else f.radius


class _Params:
    """The free variables of a piece set (P, 4, 2) in pixel units: one point per group of coinciding endpoints
    (T endpoints: none, they follow their piece), the inner control points of cubics, the middle point of
    quadratics; coordinates of endpoints on the image border along the border only. Pieces in ``frozen`` (and the
    pieces their T endpoints lie on, and so on) stay as given, with every endpoint they share."""

    def __init__(self, cp: np.ndarray, degree: np.ndarray, W: int, H: int, frozen=()):
        from scipy.sparse.csgraph import connected_components
        from scipy.spatial import cKDTree

        self.degree, self.W, self.H = np.asarray(degree), W, H
        ends = np.concatenate([cp[:, 0], cp[:, 3]])  # (2P, 2): starts then ends
        P = len(cp)
        pairs = cKDTree(ends).query_pairs(JOIN, output_type="ndarray")
        from scipy.sparse import coo_matrix

        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(2 * P, 2 * P)) if len(pairs) \
            else coo_matrix((2 * P, 2 * P))
        n, label = connected_components(graph, directed=False)
        self.node_of_end = label  # (2P,)
        self.nodes = n
        # T endpoints: a node lying on the inside of a piece it is not an endpoint of
        first = np.zeros(n, dtype=np.int64)
        first[label[::-1]] = np.arange(2 * P)[::-1]
        node_xy = ends[first]
        self.tee: dict[int, tuple[int, float]] = {}
        flat = bezier.flatten(cp, 32)  # (P, 33, 2)
        for node in range(n):
            pieces_here = set(np.nonzero((label[:P] == node) | (label[P:] == node))[0])
            d = np.linalg.norm(flat - node_xy[node], axis=2)  # (P, 33)
            near = np.nonzero(d.min(axis=1) < 2.0)[0]
            for p in near:
                if p in pieces_here:
                    continue
                t0 = np.argmin(d[p]) / 32.0
                t = float(bezier.closest_parameter(cp[p:p + 1], node_xy[node][None], np.array([t0]))[0])
                if 0.0 < t < 1.0 and np.linalg.norm(bezier.evaluate(cp[p:p + 1], np.array([t]))[0] - node_xy[node]) < JOIN * 100:
                    self.tee[node] = (int(p), t)
                    break
        tol = 1e-6 * max(W, H)
        self.fixed = np.stack([(np.abs(node_xy[:, 0]) < tol) | (np.abs(node_xy[:, 0] - W) < tol),
                               (np.abs(node_xy[:, 1]) < tol) | (np.abs(node_xy[:, 1] - H) < tol)], axis=1)
        self.frozen = np.zeros(P, dtype=bool)
        self.frozen[list(frozen)] = True
        while True:  # a frozen piece's T end stays on its host only when the host stays too
            hosts = [p for node, (p, _) in self.tee.items()
                     if not self.frozen[p] and self.frozen[(label[:P] == node) | (label[P:] == node)].any()]
            if not hosts:
                break
            self.frozen[hosts] = True
        self.fixed[np.unique(np.concatenate([label[:P][self.frozen], label[P:][self.frozen]]))] = True
        self.start = cp.copy()
        self.node_xy = node_xy
        self.free_nodes = np.array([k for k in range(n) if k not in self.tee], dtype=np.int64)
        self.cubic = np.nonzero(self.degree == 3)[0]
        self.quad = np.nonzero(self.degree == 2)[0]

    def pack(self, cp: np.ndarray) -> np.ndarray:
        """The variable vector of control points ``cp`` (P, 4, 2)."""
        P = len(cp)
        ends = np.concatenate([cp[:, 0], cp[:, 3]])
        first = np.zeros(self.nodes, dtype=np.int64)
        first[self.node_of_end[::-1]] = np.arange(2 * P)[::-1]
        nodes = ends[first][self.free_nodes]
        middle = 1.5 * cp[self.quad, 1] - 0.5 * cp[self.quad, 0]
        return np.concatenate([nodes.ravel(), cp[self.cubic, 1:3].ravel(), middle.ravel()])

    def build(self, x):
        """Control points (P, 4, 2) torch of the variable vector ``x`` (torch, float64)."""
        import torch

        P = len(self.degree)
        nf, nc, nq = len(self.free_nodes), len(self.cubic), len(self.quad)
        free = x[:2 * nf].reshape(nf, 2)
        fixed = torch.from_numpy(self.fixed[self.free_nodes])
        free = torch.where(fixed, torch.from_numpy(self.node_xy[self.free_nodes]), free)
        inner = x[2 * nf:2 * nf + 4 * nc].reshape(nc, 2, 2)
        middle = x[2 * nf + 4 * nc:].reshape(nq, 2)
        nodes = torch.from_numpy(self.node_xy).clone()
        nodes[torch.from_numpy(self.free_nodes)] = free
        cp = None
        for _ in range(2 if self.tee else 1):  # T endpoints follow their piece (one level of T on T)
            if cp is not None:
                nodes = nodes.clone()
                for node, (p, t) in self.tee.items():
                    nodes[node] = _point(cp[p], t)
            a, b = nodes[torch.from_numpy(self.node_of_end[:P])], nodes[torch.from_numpy(self.node_of_end[P:])]
            p1, p2 = a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0
            if nc:
                idx = torch.from_numpy(self.cubic)
                p1, p2 = p1.clone(), p2.clone()
                p1[idx], p2[idx] = inner[:, 0], inner[:, 1]
            if nq:
                idx = torch.from_numpy(self.quad)
                p1[idx] = a[idx] + 2.0 / 3.0 * (middle - a[idx])
                p2[idx] = b[idx] + 2.0 / 3.0 * (middle - b[idx])
            cp = torch.stack([a, p1, p2, b], dim=1)
        if self.frozen.any():
            cp = torch.where(torch.from_numpy(self.frozen)[:, None, None], torch.from_numpy(self.start), cp)
        lo = torch.zeros(2, dtype=cp.dtype)
        hi = torch.tensor([float(self.W), float(self.H)], dtype=cp.dtype)
        return torch.minimum(torch.maximum(cp, lo), hi)

    def limit(self, cp: np.ndarray, start: np.ndarray) -> np.ndarray:
        """``cp`` with every control point within ``MAX_MOVE`` of ``start``, re-assembled so the constraints hold."""
        import torch

        step = cp - start
        norm = np.linalg.norm(step, axis=2, keepdims=True)
        clipped = start + step * np.minimum(1.0, MAX_MOVE / np.maximum(norm, 1e-12))
        return self.build(torch.from_numpy(self.pack(clipped))).numpy()


def _point(cp, t: float):
    s = 1.0 - t
    return s**3 * cp[0] + 3 * s * s * t * cp[1] + 3 * s * t * t * cp[2] + t**3 * cp[3]


def _samples(cp: np.ndarray):
    """Points (M, 2), pieces (M,), parameters (M,) every ≤ ``_SPACING`` px along the pieces (P, 4, 2)."""
    length = np.linalg.norm(np.diff(cp, axis=1), axis=2).sum(axis=1)
    counts = np.maximum(2, np.ceil(length / _SPACING).astype(int) + 1)
    piece = np.repeat(np.arange(len(cp)), counts)
    t = np.concatenate([np.linspace(0.0, 1.0, n) for n in counts])
    return bezier.evaluate(cp[piece], t), piece, t


def _pixel_data(pixels: np.ndarray, cp: np.ndarray, reach: float) -> dict | None:
    """The clean pixels of the module notes near curves ``cp`` (P, 4, 2) px, None when there are none: {"centre"
    (N, 2) px, "piece" (N,) and "t" (N,) of the foot point, "value" (N, C) the pixel, "side_b" (N, C) and "grad_b"
    (N, C, 2) side B's plane at the centre (value, gradient per px), "jump" (N, C) and "grad_jump" (N, C, 2) side A's
    plane minus side B's, "scale" (N,) 1 / |jump|}. Side A lies on the curve's normal side (tangent turned +90°)."""
    from scipy.ndimage import map_coordinates
    from scipy.spatial import cKDTree

    H, W, C = pixels.shape
    pts, piece, t = _samples(cp)
    tree = cKDTree(pts)
    near = reach * np.sqrt(2.0) + 0.5  # a pixel's filter support reaches this far from its centre
    jj, ii = np.mgrid[0:H, 0:W]
    centres = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], axis=1)
    dist, foot = tree.query(centres, distance_upper_bound=max(near, 1.0))
    keep = np.isfinite(dist)
    if not keep.any():
        return None
    centres, foot = centres[keep], foot[keep]
    fp = piece[foot]
    ft = bezier.closest_parameter(cp[fp], centres, t[foot])
    p = bezier.evaluate(cp[fp], ft)
    d1, d2 = bezier.derivative(cp[fp], ft), bezier.second_derivative(cp[fp], ft)
    speed = np.linalg.norm(d1, axis=1)
    ok = speed > 1e-9
    tan = d1 / np.maximum(speed, 1e-12)[:, None]
    normal = np.stack([-tan[:, 1], tan[:, 0]], axis=1)
    kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.maximum(speed, 1e-12) ** 3
    # clean: every curve sample near the pixel's filter support follows the foot's parabola
    for k, group in enumerate(tree.query_ball_point(centres, near + 0.5)):
        q = pts[group] - p[k]
        a, b = q @ tan[k], q @ normal[k]
        if np.abs(b - 0.5 * kappa[k] * a * a).max() > STRAIGHT:
            ok[k] = False
    near_side, far_side = reach * np.sqrt(2.0) + SIDE_NEAR, reach * np.sqrt(2.0) + SIDE_FAR
    mid_side = 0.5 * (near_side + far_side)
    across = np.array([near_side, far_side, -near_side, -far_side, mid_side, -mid_side])[:, None] * np.ones(2)
    along = np.array([-ALONG, ALONG])[None, :] * np.ones((6, 1))
    spots = (p[:, None, None, :] + across[None, :, :, None] * normal[:, None, None, :]
             + along[None, :, :, None] * tan[:, None, None, :])  # (N, 6, 2, 2)
    flat = spots.reshape(-1, 2)
    # a reading is clear when no other curve reaches its bilinear footprint through the filter
    clear = tree.query(flat)[0].reshape(-1, 6, 2) >= np.minimum(np.abs(across) - 0.5, near + 1.0)[None]
    inside = ((flat[:, 0] >= 0.5) & (flat[:, 0] <= W - 0.5) & (flat[:, 1] >= 0.5) & (flat[:, 1] <= H - 0.5))
    ok &= clear.all(axis=(1, 2)) & inside.reshape(-1, 12).all(axis=1)
    if not ok.any():
        return None
    rc = [flat[:, 1] - 0.5, flat[:, 0] - 0.5]
    read = np.stack([map_coordinates(pixels[..., c], rc, order=1, mode="nearest") for c in range(C)], axis=-1)
    read = read.reshape(-1, 6, 2, C)
    planes, off_plane = [], []
    for near_k, far_k, mid_k, sign in ((0, 1, 4, 1.0), (2, 3, 5, -1.0)):  # side A (on the normal's side), then B
        m1, m2 = read[:, near_k].mean(axis=1), read[:, far_k].mean(axis=1)  # (N, C)
        gn = (m2 - m1) / (sign * (far_side - near_side))
        v0 = m1 - gn * sign * near_side
        along_near, along_far = read[:, near_k, 1] - read[:, near_k, 0], read[:, far_k, 1] - read[:, far_k, 0]
        gt = 0.5 * (along_near + along_far) / (2 * ALONG)
        grad = gn[..., None] * normal[:, None, :] + gt[..., None] * tan[:, None, :]  # (N, C, 2)
        planes.append((v0 + np.einsum("ncx,nx->nc", grad, centres - p), grad))
        twist, bend = along_far - along_near, read[:, mid_k].mean(axis=1) - 0.5 * (m1 + m2)  # both 0 on a plane
        off_plane.append(np.maximum((twist * twist).sum(axis=1), 4.0 * (bend * bend).sum(axis=1)))
    (a, grad_a), (b, grad_b) = planes
    jump = a - b
    size2 = (jump * jump).sum(axis=1)
    ok &= np.maximum(*off_plane) <= PLANAR**2 * size2
    ok &= step_size(a, b, pixels) >= MIN_JUMP
    ij = np.floor(centres).astype(np.int64)
    value = pixels[ij[:, 1], ij[:, 0]]
    share = np.einsum("ic,ic->i", value - b, jump) / np.maximum(size2, 1e-300)
    ok &= (share > -0.25) & (share < 1.25)
    if not ok.any():
        return None
    return {"centre": centres[ok], "piece": fp[ok], "t": ft[ok], "value": value[ok], "side_b": b[ok],
            "grad_b": grad_b[ok], "jump": jump[ok], "grad_jump": (grad_a - grad_b)[ok],
            "scale": 1.0 / np.sqrt(size2[ok])}


def _loss(data: dict, f, soft: float):
    """The function control points (P, 4, 2) torch → summed squared share misfit over ``data``'s pixels, seen
    through the filter ``f`` (module notes; ``_gaussian_side`` for a Gaussian)."""
    import torch

    centre = torch.from_numpy(data["centre"])
    piece = torch.from_numpy(data["piece"])
    t = torch.from_numpy(data["t"])[:, None]
    value, side_b, grad_b = (torch.from_numpy(data[k]) for k in ("value", "side_b", "grad_b"))
    jump, grad_jump, scale = (torch.from_numpy(data[k]) for k in ("jump", "grad_jump", "scale"))
    gaussian = f.name == "gaussian"
    if gaussian:  # an even filter: side B's plane averages to its centre value
        nodes, weights = np.polynomial.hermite_e.hermegauss(GAUSS_HERMITE)
        nodes, weights = torch.from_numpy(f.param * nodes), torch.from_numpy(weights / weights.sum())
        base = side_b
    else:
        offsets, weights = (torch.from_numpy(a) for a in f.nodes(QUAD_POINTS))
        base = side_b + torch.einsum("ncx,kx,k->nc", grad_b, offsets, weights)  # side B's mean over the filter
    s = 1.0 - t
    basis = torch.cat([s**3, 3 * s * s * t, 3 * s * t * t, t**3], dim=1)  # (N, 4)
    dbasis = torch.cat([-3 * s * s, 3 * s * s - 6 * s * t, 6 * s * t - 3 * t * t, 3 * t * t], dim=1)
    ddbasis = torch.cat([6 * s, -12 * s + 6 * t, 6 * s - 12 * t, 6 * t], dim=1)

    def loss(cp, part=slice(None)):
        c = cp[piece[part]]  # (n, 4, 2)
        p = torch.einsum("nk,nkd->nd", basis[part], c)
        d1 = torch.einsum("nk,nkd->nd", dbasis[part], c)
        d2 = torch.einsum("nk,nkd->nd", ddbasis[part], c)
        speed = torch.sqrt(d1[:, 0] ** 2 + d1[:, 1] ** 2).clamp_min(1e-9)
        tan = d1 / speed[:, None]
        normal = torch.stack([-tan[:, 1], tan[:, 0]], dim=1)
        kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed**3
        r = centre[part] - p  # the pixel centre from the curve point
        along0 = (r[:, 0] * tan[:, 0] + r[:, 1] * tan[:, 1])[:, None]
        across0 = (r[:, 0] * normal[:, 0] + r[:, 1] * normal[:, 1])[:, None]
        if gaussian:
            share, moment = _gaussian_side(along0, across0, kappa[:, None], nodes, weights, f.param)
            moment = tan * moment[:, :1] + normal * moment[:, 1:]
        else:  # the filter's points are r + offsets: a logistic side test of each
            along = along0 + tan @ offsets.T  # (n, K)
            signed = across0 + normal @ offsets.T - 0.5 * kappa[:, None] * along * along
            on_a = torch.sigmoid(signed / soft) * weights
            share, moment = on_a.sum(dim=1), on_a @ offsets
        predicted = (base[part] + share[:, None] * jump[part] + torch.einsum("ncx,nx->nc", grad_jump[part], moment))
        return (((predicted - value[part]) * scale[part, None]) ** 2).sum()

    return loss


def _gaussian_side(along, across, kappa, nodes, weights, sigma: float):
    """(share (n,), moment (n, 2)) of an isotropic Gaussian filter of σ ``sigma`` px on side A of the parabola
    ``across' = κ/2 · along'²`` through the foot point, for pixel centres at ``along``, ``across`` (n, 1) px from
    it: the filter's points along the curve by Gauss–Hermite ``nodes``, ``weights`` (G,), across it exactly (the
    normal distribution's tail and its first moment). ``moment`` is ``E[offset · on A]`` in (along, across)
    coordinates. Mitsuba's Gaussian is cut at 4σ, which this ignores (a share off by < 3e-4)."""
    import torch

    a = along + nodes  # (n, G) points along the curve
    z = (0.5 * kappa * a * a - across) / sigma  # the filter's points across the curve lie on A above z·σ
    tail = torch.special.ndtr(-z) * weights
    density = torch.exp(-0.5 * z * z) * (sigma / np.sqrt(2.0 * np.pi)) * weights  # E[v · 1{v > zσ}] per node
    return tail.sum(dim=1), torch.stack([tail @ nodes, density.sum(dim=1)], dim=1)


def _total(loss_of, cp: np.ndarray, data: dict) -> float:
    """``loss_of`` summed over ``data``'s pixels in chunks, for control points ``cp`` (P, 4, 2)."""
    import torch

    n = len(data["piece"])
    step = max(1, CHUNK // QUAD_POINTS)
    with torch.no_grad():
        return float(sum(loss_of(torch.from_numpy(cp), slice(i, i + step)).item() for i in range(0, n, step)))


def crossings(cp: np.ndarray, samples: int = 16) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of pieces (P, 4, 2) that cross or touch away from every shared endpoint and T
    (points within ``10 × JOIN``·scale of an endpoint of either piece do not count)."""
    from scipy.spatial import cKDTree

    P = len(cp)
    if P < 2:
        return []
    poly = bezier.flatten(cp, samples)  # (P, S + 1, 2)
    a, b = poly[:, :-1].reshape(-1, 2), poly[:, 1:].reshape(-1, 2)
    owner = np.repeat(np.arange(P), samples)
    mid = 0.5 * (a + b)
    half = 0.5 * np.linalg.norm(b - a, axis=1).max()
    pairs = cKDTree(mid).query_pairs(2.0 * half + 1e-9, output_type="ndarray")
    if not len(pairs):
        return []
    pairs = pairs[owner[pairs[:, 0]] != owner[pairs[:, 1]]]
    i, j = pairs[:, 0], pairs[:, 1]
    p, r = a[i], b[i] - a[i]
    q, s = a[j], b[j] - a[j]
    denom = r[:, 0] * s[:, 1] - r[:, 1] * s[:, 0]
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / denom
        v = (qp[:, 0] * r[:, 1] - qp[:, 1] * r[:, 0]) / denom
    hit = (np.abs(denom) > 1e-15) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    if not hit.any():
        return []
    point = p[hit] + u[hit, None] * r[hit]
    pi, pj = owner[i[hit]], owner[j[hit]]
    scale = max(1.0, float(np.abs(cp).max()))
    ends = np.concatenate([cp[:, 0], cp[:, 3]])
    joint = cKDTree(ends).query(point)[0] <= 1e-3 * scale  # at a shared endpoint or the end of a T
    out = sorted({(int(min(x, y)), int(max(x, y))) for x, y, k in zip(pi, pj, joint) if not k})
    return out
